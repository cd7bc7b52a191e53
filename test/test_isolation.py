"""Never mix rigs: each experiment in a domain of its own; a foreign publisher stops a run."""

import os
import subprocess
import sys
import tempfile

import pytest

from microball_ros.app.isolation import ForeignPublisherCheck, IsolationError, claim_domain


def test_two_claims_never_get_the_same_domain_and_a_held_one_is_refused():
    first = claim_domain()
    second = claim_domain()
    try:
        assert first.domain_id != second.domain_id
        with pytest.raises(IsolationError, match='in use by another microball run'):
            claim_domain(first.domain_id)
        env = first.environment({'PATH': '/bin'})
        assert env == {'PATH': '/bin', 'ROS_DOMAIN_ID': str(first.domain_id),
                       'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST'}
        assert first.environment({'ROS_AUTOMATIC_DISCOVERY_RANGE': 'SUBNET'})[
            'ROS_AUTOMATIC_DISCOVERY_RANGE'] == 'SUBNET'
    finally:
        first.release()
        second.release()
    again = claim_domain(first.domain_id)  # released: free again
    again.release()
    with pytest.raises(IsolationError, match='outside'):
        claim_domain(250)


def test_a_held_domain_is_refused_whatever_the_temp_folder(tmp_path, monkeypatch):
    # The locks were in the temp folder: a run with another TMPDIR (or a test that points
    # tempfile elsewhere) took a domain another run held; two test runs at once mixed that way.
    first = claim_domain()
    try:
        monkeypatch.setattr(tempfile, 'tempdir', str(tmp_path))
        with pytest.raises(IsolationError, match='in use by another microball run'):
            claim_domain(first.domain_id)
        second = claim_domain()
        assert second.domain_id != first.domain_id
        second.release()
    finally:
        first.release()


def test_foreign_check_catches_extra_publishers_and_sequences_going_backwards():
    check = ForeignPublisherCheck({'/a': 1, '/b': 1})
    assert check.check({'/a': 1, '/b': 1, '/other': 3}) is None
    assert [check.observe('/a', k) for k in (1, 2, 5)] == [None, None, None]
    assert 'backwards (3 after 5)' in check.observe('/a', 3)
    assert check.backwards['/a'] == 1
    assert '2 publishers where this run started 1' in check.check({'/a': 1, '/b': 2})
    assert 'backwards' in check.problem  # the first problem is kept


def _experiment(*args, output=None):
    command = [sys.executable, '-m', 'microball_ros.cli', 'experiment', '--duration', '6',
               '--speed', '1.5', *args]
    if output is not None:
        command += ['--output', str(output)]
    return subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _frame_indices(bag_path):
    from microball_msgs.msg import TrackedPositions
    from rclpy.serialization import deserialize_message

    from microball_ros.io.bags.reader import open_bag

    bag = open_bag(str(bag_path))
    return [deserialize_message(m.data, TrackedPositions).frame_index
            for m in bag.messages(['/tracking/positions'])]


@pytest.mark.ros
def test_two_concurrent_experiments_each_record_a_clean_bag(tmp_path):
    runs = [_experiment(output=tmp_path / name) for name in ('one', 'two')]
    results = [run.communicate(timeout=240) for run in runs]
    domains = set()
    for run, (_, err) in zip(runs, results, strict=True):
        assert run.returncode == 0, err[-2000:]
        domains.add(next(line for line in err.splitlines() if 'ROS domain' in line))
    assert len(domains) == 2, domains
    for name in ('one', 'two'):
        indices = _frame_indices(tmp_path / name)
        assert indices == list(range(len(indices))), f'{name}: mixed or missing frames'
        assert len(indices) == 180  # 6 s at 30 fps, every frame once


@pytest.mark.ros
def test_an_experiment_refuses_a_domain_another_run_holds(tmp_path):
    claim = claim_domain()
    try:
        run = _experiment('--domain-id', str(claim.domain_id))
        _, err = run.communicate(timeout=60)
    finally:
        claim.release()
    assert run.returncode == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1 and 'in use by another microball run' in lines[0], err


@pytest.mark.ros
def test_a_foreign_publisher_on_the_domain_stops_the_run_with_a_clear_error(tmp_path):
    from microball_msgs.msg import TrackedPositions
    import rclpy

    from microball_ros.nodes.common import DATA_QOS

    run = _experiment(output=tmp_path / 'mixed')
    domain = None
    for line in run.stderr:
        if 'ROS domain' in line:
            domain = int(line.split('ROS domain')[1].split()[0])
            break
    assert domain is not None
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=domain)
    node = rclpy.create_node('another_rig', context=context)
    try:
        node.create_publisher(TrackedPositions, '/tracking/positions', DATA_QOS)
        _, err = run.communicate(timeout=120)
    finally:
        node.destroy_node()
        rclpy.shutdown(context=context)
        if run.poll() is None:
            run.kill()
    assert run.returncode == 2, err[-2000:]
    assert 'another rig is publishing on this ROS domain' in err
    assert str(tmp_path / 'mixed') in err  # it names the bag that may hold foreign data
    assert 'Traceback' not in err
    assert os.environ.get('ROS_DOMAIN_ID') != str(domain)  # never the test session's domain
