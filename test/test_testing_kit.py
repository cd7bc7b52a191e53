"""microball_ros.testing: bag replay through nodes, node processes, the sample bags, the plugin."""

import os
import signal
import sys

from microball_msgs.msg import TrackedPositions
import pytest

from microball_ros.io import fingerprint
from microball_ros.io.bags.reader import open_bag, recorded_parameters
from microball_ros.io.compare import BYTE_IDENTICAL, decode
from microball_ros.nodes.camera_tracker import CameraTracker
from microball_ros.nodes.friction_identifier import FrictionIdentifier
from microball_ros.testing import SAMPLE_BAGS, NodeExited, NodeProcess, replay, sample_bag

pytestmark = pytest.mark.ros


def _expect_reproduced(result):
    """Check the contract, spelled out: byte identity on the recording platform, else 1e-9."""
    result.assert_reproduces()
    assert result.verdict.ok and not result.timed_out
    if result.bag.platform and result.bag.platform['key'] == fingerprint.fingerprint()['key']:
        assert result.verdict.status == BYTE_IDENTICAL, result.report()
    for topic in result.outputs:
        assert result.received.count(topic) == result.bag.topics[topic].count > 0


def test_sample_bags_are_small_consistent_and_carry_the_platform():
    tracker, estimator = open_bag(sample_bag('camera_tracker')), open_bag(
        sample_bag('three_stage_estimator'))
    for name in SAMPLE_BAGS:
        bag = open_bag(sample_bag(name))
        assert bag.size < 512 * 1024, (name, bag.size)
        assert bag.platform is not None and bag.platform['key'] == fingerprint.numeric_key(
            bag.platform)
    # The estimator's input positions are what camera_tracker published for the same frames
    # (rendered the same way, more of them): the tracker sample's outputs are their start.
    tracked = decode(tracker, '/tracking/positions')
    assert len(tracked) == tracker.topics['/camera/image_raw'].count == 12
    assert decode(estimator, '/tracking/positions')[:12] == tracked
    # ... and the identifier's inputs are the estimator's recorded outputs.
    identifier = open_bag(sample_bag('friction_identifier'))
    assert [m.data for m in identifier.messages(['/estimation/derivatives'])] == \
        [m.data for m in estimator.messages(['/estimation/derivatives'])]
    # The positions follow the scale the bag recorded: the stator's stroke is the paper's
    # +-1.2 mm, reached within a few frames at 2.95 Hz, so 12 frames move it by < 2.4 mm.
    stator = [m.stator_position for m in tracked]
    assert 0 < max(stator) - min(stator) < 2.4e-3
    assert recorded_parameters(tracker, 'camera_tracker')['meters_per_pixel'] > 0


def test_tracker_in_process_reproduces_its_sample(ros_context, tmp_path):
    result = replay(sample_bag('camera_tracker'), CameraTracker, context=ros_context)
    _expect_reproduced(result)
    assert result.published == 12 and result.process is None
    # The bag it writes is a sample in turn, with the parameters the node ran with and the
    # bytes the node published (the recorded ones only on the recording platform).
    again = open_bag(result.write_bag(tmp_path / 'again'))
    assert recorded_parameters(again, 'camera_tracker') == result.parameters
    assert [m.data for m in again.messages(['/tracking/positions'])] == \
        [m.data for m in result.received.messages(['/tracking/positions'])]
    assert again.platform['key'] == fingerprint.fingerprint()['key']


def test_estimator_as_a_process_reproduces_its_sample(node_replay):
    result = node_replay(sample_bag('three_stage_estimator'), 'three_stage_estimator')
    _expect_reproduced(result)
    assert result.process.returncode == 0, result.process.log
    assert result.parameters == {'exposure': pytest.approx(1 / 60)}


def test_identifier_in_process_reproduces_its_sample(node_replay):
    _expect_reproduced(node_replay(sample_bag('friction_identifier'), FrictionIdentifier))


def test_a_changed_parameter_fails_with_the_first_differing_field(node_replay):
    result = node_replay(sample_bag('three_stage_estimator'), 'three_stage_estimator',
                         parameters={'epsilon': 0.1})
    assert not result.verdict.ok
    with pytest.raises(AssertionError) as failure:
        result.assert_reproduces()
    first = result.verdict.comparisons[0].first
    text = str(failure.value)
    assert text.splitlines()[0].startswith(
        'three_stage_estimator: differs: first differing message 0 on /estimation/derivatives'
        f', field {first.field}: recorded {first.recorded!r}, new {first.new!r}')
    # epsilon is carried in every message: the first difference is found, whatever it is.
    assert result.messages('/estimation/derivatives')[0].epsilon == pytest.approx(0.1)
    assert result.recorded('/estimation/derivatives')[0].epsilon == 0.0


def test_a_node_that_publishes_less_is_a_count_difference(node_replay):
    # Windows of 100 periods (34 s) in 10 s of positions: none. The wait gives up after 3 s
    # without a new message, then compares.
    result = node_replay(sample_bag('three_stage_estimator'), 'three_stage_estimator',
                         parameters={'window_periods': 100.0}, timeout=3.0)
    assert result.timed_out
    assert result.verdict.line == ('differs: message count on /estimation/derivatives: '
                                   'recorded 5, new 0')
    assert 'the node stopped publishing before the recorded message counts' in \
        '\n'.join(result.report())


def test_node_process_starts_with_parameters_is_ready_and_stops_on_sigint(node_process,
                                                                         ros_harness):
    process = node_process('three_stage_estimator', {'epsilon': 0.05},
                           ros_args=['-p', 'memory_k:=4.0'])
    assert process.running
    positions = ros_harness.probe.create_publisher(TrackedPositions, '/tracking/positions', 10)
    ros_harness.wait_for_subscribers(positions)
    from rcl_interfaces.srv import GetParameters

    client = ros_harness.probe.create_client(GetParameters,
                                             '/three_stage_estimator/get_parameters')
    ros_harness.spin_until(client.service_is_ready, message='the parameter service')
    future = client.call_async(GetParameters.Request(names=['epsilon', 'memory_k']))
    ros_harness.spin_until(future.done, message='the parameters')
    assert [v.double_value for v in future.result().values] == [0.05, 4.0]
    assert process.stop() == 0 and not process.killed


def test_node_process_that_exits_is_reported_with_its_log(ros_harness, tmp_path):
    process = NodeProcess('three_stage_estimator', {'method': 'guess'}, log_dir=tmp_path)
    process.start()
    with pytest.raises(NodeExited) as failure:
        process.wait_until_ready(ros_harness, timeout=60.0)
    assert process.returncode == 2
    assert "unknown method 'guess'" in str(failure.value)
    assert str(tmp_path / 'three_stage_estimator.log') in str(failure.value)


IGNORES_SIGINT = """
import signal, sys
signal.signal(signal.SIGINT, signal.SIG_IGN)
print('ignoring SIGINT', flush=True)
signal.pause()
"""


def test_a_process_that_ignores_sigint_is_killed_after_the_deadline(ros_harness, tmp_path):
    process = NodeProcess([sys.executable, '-c', IGNORES_SIGINT], name='stubborn',
                          log_dir=tmp_path).start()
    process.wait_until_ready(ros_harness, lambda: 'ignoring SIGINT' in process.log)
    assert process.stop(timeout=1.0) == -signal.SIGKILL
    assert process.killed


USER_TEST = """
from microball_ros.nodes.three_stage_estimator import ThreeStageEstimator


def test_estimator(node_replay, sample_bag):
    node_replay(sample_bag('three_stage_estimator'), ThreeStageEstimator,
                parameters=PARAMETERS).assert_reproduces()
"""


@pytest.mark.parametrize('parameters, passes', [({}, True), ({'epsilon': 0.1}, False)])
def test_the_plugin_serves_a_test_outside_the_project(tmp_path, parameters, passes):
    # A user's test folder with only the installed package: the plugin (named with -p, as the
    # pytest11 entry point does once the package is installed) gives the fixtures.
    import subprocess

    (tmp_path / 'test_mine.py').write_text(USER_TEST.replace('PARAMETERS', repr(parameters)))
    env = {k: v for k, v in os.environ.items() if k not in ('ROS_DOMAIN_ID',
                                                            'FASTDDS_DEFAULT_PROFILES_FILE')}
    result = subprocess.run(
        [sys.executable, '-m', 'pytest', '-p', 'microball_ros.testing.plugin',
         '-p', 'no:cacheprovider', 'test_mine.py'], cwd=tmp_path, env=env,
        capture_output=True, text=True, timeout=240)
    assert ('1 passed' in result.stdout) is passes, result.stdout[-3000:]
    assert result.returncode == (0 if passes else 1), result.stdout[-3000:]
    assert 'ROS_DOMAIN_ID=' in result.stdout
    if not passes:
        assert ('three_stage_estimator: differs: first differing message'
                in result.stdout), result.stdout[-3000:]


README = os.path.join(os.path.dirname(os.path.abspath(__file__)), os.pardir, 'microball_ros',
                      'testing', 'README.md')


def test_the_readme_example_runs_as_written(tmp_path):
    import subprocess

    text = open(README).read()
    example = text.split('```python\n', 1)[1].split('```', 1)[0]
    (tmp_path / 'test_my_nodes.py').write_text(example)
    env = {k: v for k, v in os.environ.items() if k not in ('ROS_DOMAIN_ID',
                                                            'FASTDDS_DEFAULT_PROFILES_FILE')}
    result = subprocess.run(
        [sys.executable, '-m', 'pytest', '-p', 'microball_ros.testing.plugin',
         '-p', 'no:cacheprovider', 'test_my_nodes.py'], cwd=tmp_path, env=env,
        capture_output=True, text=True, timeout=240)
    assert result.returncode == 0 and '3 passed' in result.stdout, result.stdout[-3000:]
