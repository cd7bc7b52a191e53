"""Recording, replay and reprocessing over DDS, and the determinism promise."""

import json
import math
import os
import signal
import subprocess
import sys

from microball_msgs.msg import TrackedPositions
import numpy as np
import pytest
import rclpy
from rclpy.parameter import Parameter
from rclpy.serialization import deserialize_message, serialize_message
import yaml

from microball_ros.app.experiment import run_experiment
from microball_ros.app.play import Player
from microball_ros.app.reprocess import check
from microball_ros.cli import main
from microball_ros.io import conversions, fingerprint
from microball_ros.io.bags.reader import open_bag, reindex
from microball_ros.io.bags.writer import BagWriter
from microball_ros.io.compare import compare_messages, decode
from microball_ros.nodes.common import DATA_QOS
from microball_ros.nodes.recorder import Recorder
from microball_ros.testing import Harness, killable_env


def _positions(n):
    # Finite sigmas: messages are compared with ==, and NaN never equals NaN.
    return [conversions.tracked_positions(1.0 + k / 30, k, 1e-3 * math.sin(k / 3),
                                          1e-3 * math.cos(k / 3), 1.0, 0.5, slider_sigma=1e-7,
                                          stator_sigma=2e-7) for k in range(n)]


def test_recorder_writes_received_bytes_and_player_replays_them_lockstep(ros_context, tmp_path):
    bag_dir = str(tmp_path / 'bag')
    recorder = Recorder(context=ros_context, parameter_overrides=[
        Parameter('output', value=bag_dir),
        Parameter('topics', value=['/tracking/positions'])])
    harness = Harness(ros_context, recorder)
    sent = _positions(200)
    try:
        publisher = harness.probe.create_publisher(TrackedPositions, '/tracking/positions',
                                                   DATA_QOS)
        harness.spin_until(lambda: recorder.matched.get('/tracking/positions', 0) >= 1,
                           message='the recorder to subscribe')
        for msg in sent:
            publisher.publish(msg)
        harness.spin_until(lambda: recorder.counts.get('/tracking/positions', 0) == 200,
                           message='200 recorded messages')
        assert recorder.close() == {'/tracking/positions': 200}
        assert recorder.lost['/tracking/positions'] == 0
    finally:
        harness.close()

    bag = open_bag(bag_dir)
    messages = list(bag.messages())
    # Compare decoded: CDR padding bytes are not defined (local serialisation leaves
    # whatever was in the buffer), so equal messages need not be equal bytes.
    assert [deserialize_message(m.data, TrackedPositions) for m in messages] == sent
    # publish_time is the middleware's source timestamp (as rosbag2 records it), never the
    # header stamp: sent a moment before the receipt that stamps log_time.
    assert all(0 <= m.log_time_ns - m.publish_time_ns < 10**9 for m in messages)
    assert 'reliability: reliable' in bag.topics['/tracking/positions'].qos_profiles_yaml

    context = rclpy.Context()
    rclpy.init(context=context)
    try:
        player = Player(bag, context=context)
        harness = Harness(context, player)
        received = []
        harness.probe.create_subscription(TrackedPositions, '/tracking/positions',
                                          received.append, DATA_QOS)
        player.wait_for_subscribers(harness.executor, ['/tracking/positions'])
        assert player.play(harness.executor, lockstep=True) == 200
        harness.spin_until(lambda: len(received) == 200, message='200 replayed messages')
        assert received == sent
        harness.close()
    finally:
        rclpy.shutdown(context=context)


@pytest.fixture(scope='module')
def recorded_run(tmp_path_factory):
    folder = tmp_path_factory.mktemp('run')
    bag_dir = str(folder / 'run')
    monitor = run_experiment('paper', 8.0, 1.5, progress=lambda line: None, output=bag_dir)
    return bag_dir, monitor


def test_experiment_output_records_every_topic_of_the_run(recorded_run):
    bag_dir, monitor = recorded_run
    bag = open_bag(bag_dir)
    counts = {name: info.count for name, info in bag.topics.items()}
    assert counts['/camera/image_raw'] == counts['/bench/ground_truth'] == 240
    assert counts['/tracking/positions'] == 240
    assert counts['/estimation/derivatives'] == len(monitor.windows) >= 2
    assert counts['/friction/model'] == len(monitor.models)
    assert counts['/servo/command'] >= 1


OUTPUTS = ('/estimation/derivatives', '/friction/model')


def _reprocess(bag_dir, out):
    """Run `microball reprocess` as a user does; return (completed process, verdict line).

    A fresh process: Fast DDS reads its profile file once per process.
    """
    result = subprocess.run([sys.executable, '-m', 'microball_ros.cli', 'reprocess', bag_dir,
                             '--output', out], capture_output=True, text=True, timeout=240)
    lines = result.stdout.strip().splitlines()
    return result, lines[-1] if lines else ''


def test_reprocessing_reproduces_the_recorded_outputs_byte_for_byte(recorded_run, tmp_path):
    # The run was recorded live (1.5x speed); reprocessing is lock-step, at whatever rate the
    # nodes keep up with: the outputs are the same bytes at any playback rate, every time.
    bag_dir, _ = recorded_run
    recorded = open_bag(bag_dir)
    outputs = {}
    for attempt in ('first', 'second'):
        out = str(tmp_path / attempt)
        result, verdict = _reprocess(bag_dir, out)
        assert result.returncode == 0, result.stderr[-2000:]
        assert verdict == 'byte-identical', result.stdout
        again = open_bag(out)
        for topic in OUTPUTS:
            old = [m.data for m in recorded.messages([topic])]
            new = [m.data for m in again.messages([topic])]
            assert new == old, topic
            outputs.setdefault(topic, []).append(new)
    for topic, (first, second) in outputs.items():
        assert first == second and len(first) == recorded.topics[topic].count >= 2, topic


def test_analyzing_the_bag_equals_analyzing_its_positions_as_csv(recorded_run, tmp_path):
    bag_dir, _ = recorded_run
    from microball_ros.io.bags.reader import read_positions
    from microball_ros.io.positions_csv import write_positions_csv

    record = read_positions(bag_dir)
    csv_path = tmp_path / 'positions.csv'
    write_positions_csv(str(csv_path), {'time': record.time,
                                        'stator_position': record.stator_position,
                                        'slider_position': record.slider_position})
    results = []
    # The bag's analysis takes the exposure its estimator was given; the CSV's is told.
    for source, options in ((bag_dir, []), (str(csv_path), ['--exposure', repr(1 / 60)])):
        out = tmp_path / f'{len(results)}.json'
        assert main(['analyze', source, '--json', str(out), *options]) == 0
        results.append(json.loads(out.read_text()))
    assert results[0]['exposure'] == pytest.approx(1 / 60)
    for key in ('exposure', 'phase_difference', 'memoryless', 'model', 'validation'):
        assert results[0][key] == results[1][key]


def _frames_only(bag_dir, out, keep_parameters=True, keep=()):
    """Copy a bag's /camera/image_raw (and its recorded parameters, and topics keep)."""
    bag = open_bag(bag_dir)
    topics = ('/camera/image_raw', *keep)
    with BagWriter(out) as cut:
        if keep_parameters:
            cut.custom_data.update(bag.metadata['custom_data'])
        for topic in topics:
            cut.add_topic(topic, bag.topics[topic].type, bag.topics[topic].qos_profiles_yaml)
        for message in bag.messages(topics):
            cut.write(message.topic, message.data, message.log_time_ns, message.publish_time_ns)
    return out


def test_a_bag_of_frames_reprocesses_to_the_recorded_positions_and_outputs(recorded_run,
                                                                            tmp_path):
    bag_dir, _ = recorded_run
    # Frames and the recorded outputs, not the positions: reprocess tracks, then compares.
    frames = _frames_only(bag_dir, str(tmp_path / 'frames'), keep=OUTPUTS)
    out = str(tmp_path / 'again')
    result, verdict = _reprocess(frames, out)
    assert result.returncode == 0, result.stderr[-2000:]
    assert 'has only camera frames' in result.stderr
    assert verdict == 'byte-identical', result.stdout
    recorded, again = open_bag(bag_dir), open_bag(out)
    # A fresh camera_tracker given the recorded frames and parameters publishes the recorded
    # positions, and the estimator and identifier then their recorded outputs, to the byte.
    for topic in ('/tracking/positions', '/estimation/derivatives', '/friction/model'):
        old = [m.data for m in recorded.messages([topic])]
        assert [m.data for m in again.messages([topic])] == old, topic
        assert old
    # A bag of only frames has nothing recorded to compare the reprocessed topics with.
    nothing = check(_frames_only(bag_dir, str(tmp_path / 'only')), out)
    assert nothing.topics == () and nothing.verdict.ok
    assert nothing.verdict.line == (f"not compared: {tmp_path / 'only'} has no recorded "
                                    '/tracking/positions, /estimation/derivatives, '
                                    '/friction/model')


def test_a_bag_of_frames_analyses_like_its_recorded_positions(recorded_run, tmp_path):
    bag_dir, _ = recorded_run
    frames = _frames_only(bag_dir, str(tmp_path / 'frames'))
    results = []
    for source in (bag_dir, frames):
        out = tmp_path / f'{len(results)}.json'
        assert main(['analyze', source, '--json', str(out)]) == 0
        results.append(json.loads(out.read_text()))
    for result in results:
        result.pop('source')
    assert results[0] == results[1]


def test_a_bag_of_frames_without_parameters_needs_the_scale(recorded_run, tmp_path, capsys):
    bag_dir, _ = recorded_run
    frames = _frames_only(bag_dir, str(tmp_path / 'frames'), keep_parameters=False)
    assert main(['analyze', frames]) == 2
    error = capsys.readouterr().err.strip().splitlines()
    assert len(error) == 1 and '--meters-per-pixel' in error[0]
    # Given the scale, the ROIs are detected in the first frames.
    scale = yaml.safe_load(open_bag(bag_dir).metadata['custom_data'][
        'microball.camera_tracker'])['meters_per_pixel']
    out = tmp_path / 'analysis.json'
    assert main(['analyze', frames, '--meters-per-pixel', repr(scale), '--exposure',
                 repr(1 / 60), '--json', str(out)]) == 0
    result = json.loads(out.read_text())
    assert result['memoryless'] is True
    assert result['window']['samples_invalid'] == 0
    low, high = result['model']['A_ci95']
    assert low <= 1.2 <= high


def test_killed_recorder_leaves_a_bag_that_reindex_repairs(tmp_path, ros_harness,
                                                          node_process):
    bag_dir = str(tmp_path / 'bag')
    publisher = ros_harness.probe.create_publisher(TrackedPositions, '/tracking/positions',
                                                   DATA_QOS)
    recorder = node_process('recorder', {'output': bag_dir, 'topics': ['/tracking/positions'],
                                         'flush_period': 0.2},
                            ready=lambda: publisher.get_subscription_count() >= 1,
                            env=killable_env(tmp_path))  # SIGKILLed below
    sent = _positions(300)
    for msg in sent:
        publisher.publish(msg)
    mcap = os.path.join(bag_dir, os.path.basename(bag_dir) + '_0.mcap')
    # Wait until the recorder has flushed at least one chunk to disk.
    ros_harness.spin_until(lambda: os.path.exists(mcap) and os.path.getsize(mcap) > 4096,
                           message='a flushed chunk')
    assert recorder.stop(sig=signal.SIGKILL) == -signal.SIGKILL
    counts = reindex(bag_dir)
    recovered = counts['/tracking/positions']
    assert 0 < recovered <= 300
    bag = open_bag(bag_dir)
    data = [deserialize_message(m.data, TrackedPositions) for m in bag.messages()]
    assert data == sent[:recovered]
    assert sorted(os.listdir(bag_dir)) == ['bag_0.mcap', 'metadata.yaml']  # as rosbag2 lists
    assert np.isfinite(bag.start_ns)


SAMPLE = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), 'bags',
                      'paper_sample')


def _close(a, b):
    if isinstance(a, dict):
        return a.keys() == b.keys() and all(_close(a[k], b[k]) for k in a)
    if isinstance(a, list):
        return len(a) == len(b) and all(_close(x, y) for x, y in zip(a, b, strict=True))
    if isinstance(a, float) and isinstance(b, float):
        return math.isclose(a, b, rel_tol=1e-6, abs_tol=1e-12)
    return a == b


def test_sample_bag_analyses_to_its_expected_result(tmp_path):
    out = tmp_path / 'analysis.json'
    assert main(['analyze', SAMPLE, '--json', str(out)]) == 0
    result = json.loads(out.read_text())
    expected = json.loads(open(SAMPLE + '.expected.json').read())
    for data in (result, expected):
        data.pop('source')
    assert _close(result, expected)
    assert result['memoryless'] is True
    low, high = result['model']['A_ci95']
    assert low <= 1.2 <= high


def _check_reproduction(bag_dir, out):
    """Reprocess bag_dir into out, check the determinism contract; return (same, verdict).

    Everywhere, decoded field by field: the counts are equal and every number is within
    relative 1e-9 (io.compare). Where the bag's platform fingerprint key is the one the
    reprocessing wrote into its output (same platform, same stack): the bytes are equal.
    """
    result, verdict = _reprocess(bag_dir, out)
    assert result.returncode == 0, result.stderr[-2000:] + result.stdout
    recorded, again = open_bag(bag_dir), open_bag(out)
    platform = fingerprint.from_custom_data(recorded.metadata['custom_data'])
    current = fingerprint.from_custom_data(again.metadata['custom_data'])
    assert current is not None and current['key'] == fingerprint.numeric_key(current)
    same = platform is not None and platform.get('key') == current['key']
    identical = True
    for topic in OUTPUTS:
        old, new = decode(recorded, topic), decode(again, topic)
        assert len(old) == len(new) == recorded.topics[topic].count >= 2, topic
        comparison = compare_messages(old, new, topic)
        assert not comparison.differs, comparison
        old_bytes = [m.data for m in recorded.messages([topic])]
        new_bytes = [m.data for m in again.messages([topic])]
        if same:
            assert new_bytes == old_bytes, topic
        identical = identical and new_bytes == old_bytes
    if identical:
        assert verdict == 'byte-identical', result.stdout
    else:
        assert verdict.startswith('within tolerance (largest relative difference '), verdict
        figure = float(verdict.split('difference ')[1].split()[0])
        assert 0 < figure <= 1e-9
    if platform is None:
        assert 'platform: no fingerprint recorded' in result.stdout
    elif not identical:
        assert 'platform differs: ' in result.stdout
    return same, verdict


def test_sample_bag_reprocesses_to_its_recorded_outputs(tmp_path):
    # The sample was recorded on another CPU (and before bags carried a fingerprint): every
    # number within relative 1e-9, verdicts and counts identical; bytes only on its platform.
    first = str(tmp_path / 'first')
    _check_reproduction(SAMPLE, first)
    # The output carries this platform's fingerprint and the nodes' parameters, so it
    # reprocesses in turn, here byte for byte: reprocessing twice gives the same bytes.
    assert yaml.safe_load(open_bag(first).metadata['custom_data'][
        'microball.three_stage_estimator']) == {'exposure': 1 / 60}
    same, verdict = _check_reproduction(first, str(tmp_path / 'second'))
    assert same and verdict == 'byte-identical'


def test_reprocess_names_the_first_difference_and_the_platforms_and_exits_3(tmp_path):
    # A bag whose recorded /friction/model 4 has A off by 1e-6, from another (made-up) CPU.
    bag = open_bag(SAMPLE)
    from microball_msgs.msg import FrictionModel

    other = dict(fingerprint.fingerprint(), cpu='Other CPU', numpy_simd='X86_V1 MADE_UP')
    other['key'] = fingerprint.numeric_key(other)
    tampered, models = str(tmp_path / 'tampered'), 0
    with BagWriter(tampered) as writer:
        writer.custom_data.update(bag.metadata['custom_data'])
        writer.custom_data.update(fingerprint.to_custom_data(other))
        for name, info in sorted(bag.topics.items()):
            writer.add_topic(name, info.type, info.qos_profiles_yaml)
        for message in bag.messages():
            data = message.data
            if message.topic == '/friction/model':
                if models == 4:
                    model = deserialize_message(data, FrictionModel)
                    recorded_a, model.a = model.a, model.a * (1 + 1e-6)
                    data = serialize_message(model)
                models += 1
            writer.write(message.topic, data, message.log_time_ns, message.publish_time_ns)
    result, verdict = _reprocess(tampered, str(tmp_path / 'again'))
    assert result.returncode == 3, result.stderr[-2000:] + result.stdout
    assert verdict.startswith('differs: first differing message 4 on /friction/model, field a: '
                              f'recorded {recorded_a * (1 + 1e-6)!r}, new ')
    assert verdict.endswith(' (relative difference 1e-06)')
    new_a = float(verdict.split(', new ')[1].split()[0])
    assert new_a == pytest.approx(recorded_a, rel=1e-9)
    assert 'platform differs: numpy_simd: X86_V1 MADE_UP -> ' in result.stdout
    assert 'platform differs: cpu: Other CPU -> ' in result.stdout
