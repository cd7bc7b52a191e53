"""Bags as rosbag2 writes them: times, the 'rosbag2' record at open, a killed recorder, Foxglove.

A recorder process killed with SIGKILL mid-run leaves a bag that reindex repairs and that info,
analyze and reprocess then use, with its custom_data (and platform fingerprint) intact; publish
times are the middleware's source timestamps, on the clock of log times; bags read as Foxglove
reads them (test/foxglove, when its node_modules are installed).
"""

from importlib.metadata import version
import json
import os
import shutil
import signal
import subprocess
import sys

from mcap.exceptions import EndOfFile
from mcap.reader import make_reader
from mcap.records import Metadata
from mcap.stream_reader import StreamReader
from microball_msgs.msg import TrackedPositions
import pytest
import rclpy
from rclpy.serialization import deserialize_message, serialize_message
import yaml

from microball_ros.io import fingerprint
from microball_ros.io.bags import BagWriter, open_bag, qos_profiles_yaml, reindex
from microball_ros.io.bags.mcap_file import scan_file
from microball_ros.io.bags.metadata import RCLPY_SERIES, bag_metadata, ros_distro
from microball_ros.io.bags.writer import McapFileWriter
from microball_ros.nodes.common import DATA_QOS
from microball_ros.testing import Harness, killable_env

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SAMPLE = os.path.join(ROOT, 'bags', 'paper_sample')
FOXGLOVE = os.path.join(ROOT, 'test', 'foxglove')
POSITIONS = '/tracking/positions'
POSITIONS_TYPE = 'microball_msgs/msg/TrackedPositions'
SECOND = 1_000_000_000


def _cli(*arguments, timeout=300):
    return subprocess.run([sys.executable, '-m', 'microball_ros.cli', *arguments],
                          capture_output=True, text=True, timeout=timeout)


def _rosbag2_records(path):
    """Return the 'rosbag2' records (parsed serialized_metadata) mcap's stream reader meets.

    A file still being written ends without a footer: read up to there.
    """
    found = []
    with open(path, 'rb') as handle:
        try:
            for record in StreamReader(handle).records:
                if isinstance(record, Metadata) and record.name == 'rosbag2':
                    found.append(yaml.safe_load(record.metadata['serialized_metadata']))
        except EndOfFile:
            pass
    return found


def _position_message(k):
    message = TrackedPositions(frame_index=k, slider_position=1e-4 * k, stator_position=2e-4,
                               slider_quality=1.0, stator_quality=1.0, slider_valid=True,
                               stator_valid=True)
    message.header.stamp.sec = k
    return message


# --- the 'rosbag2' record and metadata.yaml at open ------------------------------------------

def test_a_bag_never_closed_carries_its_rosbag2_record_and_metadata_yaml(tmp_path):
    directory = tmp_path / 'open'
    bag = BagWriter(str(directory), custom_data={'microball.note': 'never closed'})
    bag.add_topic(POSITIONS, POSITIONS_TYPE)
    for k in range(5):
        bag.write(POSITIONS, serialize_message(_position_message(k)), (k + 1) * SECOND,
                  (k + 1) * SECOND)
    bag.flush()
    try:
        here = fingerprint.fingerprint()
        # the file, as a killed writer leaves it: no summary, one 'rosbag2' record
        scan = scan_file(bag.path)
        assert not scan.complete and scan.message_count == 5
        assert scan.rosbag2['custom_data']['microball.note'] == 'never closed'
        assert fingerprint.from_custom_data(scan.rosbag2['custom_data'])['key'] == here['key']
        assert scan.rosbag2['ros_distro'] == ros_distro()
        [record] = _rosbag2_records(bag.path)  # mcap's own streaming reader sees it too
        assert record['custom_data'] == scan.rosbag2['custom_data']
        information = yaml.safe_load((directory / 'metadata.yaml').read_text())[
            'rosbag2_bagfile_information']
        assert information['custom_data'] == scan.rosbag2['custom_data']
        assert information['relative_file_paths'] == ['open_0.mcap']
    finally:
        bag.close()
    # closed: the summary indexes exactly one 'rosbag2' record, the complete one ...
    with open(bag.path, 'rb') as handle:
        reader = make_reader(handle)
        indexed = [m for m in reader.iter_metadata() if m.name == 'rosbag2']
        statistics = reader.get_summary().statistics
    assert len(indexed) == 1 and statistics.metadata_count == 1
    final = yaml.safe_load(indexed[0].metadata['serialized_metadata'])
    assert final['message_count'] == 5
    assert [t['topic_metadata']['name'] for t in final['topics_with_message_count']] == [
        POSITIONS]
    # ... which a front-to-back reader meets last, after the one written at open
    opened, closed = _rosbag2_records(bag.path)
    assert opened['message_count'] == 0 and closed == final
    reopened = open_bag(str(directory))
    assert reopened.custom_data == final['custom_data'] == information['custom_data']
    assert reopened.platform['key'] == here['key']


def test_ros_distro_is_ROS_DISTRO_else_the_installed_rclpys(tmp_path, monkeypatch):
    monkeypatch.setenv('ROS_DISTRO', 'lyrical')
    assert ros_distro() == 'lyrical'
    with BagWriter(str(tmp_path / 'a')) as bag:
        bag.add_topic(POSITIONS, POSITIONS_TYPE)
        bag.write(POSITIONS, serialize_message(_position_message(0)), SECOND, SECOND)
    assert open_bag(str(tmp_path / 'a')).ros_distro == 'lyrical'
    assert [r['ros_distro'] for r in _rosbag2_records(bag.path)] == ['lyrical', 'lyrical']

    monkeypatch.delenv('ROS_DISTRO')
    monkeypatch.delenv('AMENT_PREFIX_PATH', raising=False)
    major, minor = (int(n) for n in version('ros-rclpy').split('.')[:2])
    assert ros_distro() == RCLPY_SERIES.get((major, minor), '')
    assert (major, minor) != (9, 1) or ros_distro() == 'kilted'  # this venv: Kilted wheels


def test_reindex_rebuilds_metadata_from_the_mcaps_own_record(tmp_path):
    # A file whose channel lacks QoS, its 'rosbag2' record has it: reindex takes QoS,
    # custom_data and ros_distro from the record (rosbag2's Reindexer), not from this machine.
    directory = tmp_path / 'bag'
    directory.mkdir()
    path = str(directory / 'bag_0.mcap')
    qos = qos_profiles_yaml([{
        'history': 'keep_last', 'depth': 7, 'reliability': 'reliable',
        'durability': 'transient_local', 'deadline': {'sec': 0, 'nsec': 0},
        'lifespan': {'sec': 0, 'nsec': 0}, 'liveliness': 'automatic',
        'liveliness_lease_duration': {'sec': 0, 'nsec': 0},
        'avoid_ros_namespace_conventions': False}])
    writer = McapFileWriter(path)
    writer.add_channel(POSITIONS, POSITIONS_TYPE, open(os.path.join(
        sys.prefix, 'share', 'microball_msgs', 'msg', 'TrackedPositions.msg')).read())
    for k in range(3):
        writer.write(POSITIONS, serialize_message(_position_message(k)), (k + 1) * SECOND,
                     (k + 1) * SECOND)
    topics = [dict(name=POSITIONS, type=POSITIONS_TYPE, qos_profiles_yaml=qos, type_hash='',
                   message_count=3)]
    writer.close(bag_metadata([writer.file_information('bag_0.mcap')], topics,
                              custom_data={'microball.note': 'from the record'},
                              ros_distro='jazzy'))
    assert reindex(str(directory)) == {POSITIONS: 3}
    assert sorted(os.listdir(directory)) == ['bag_0.mcap', 'metadata.yaml']  # intact: kept
    assert not os.path.exists(str(directory) + '.truncated')
    information = yaml.safe_load((directory / 'metadata.yaml').read_text())[
        'rosbag2_bagfile_information']
    assert information['custom_data'] == {'microball.note': 'from the record'}
    assert information['ros_distro'] == 'jazzy'
    [topic] = information['topics_with_message_count']
    assert topic['topic_metadata']['offered_qos_profiles'][0]['depth'] == 7
    bag = open_bag(str(directory))
    assert bag.topics[POSITIONS].qos_profiles_yaml == qos and bag.ros_distro == 'jazzy'


# --- a recorder killed mid-run -----------------------------------------------------------------

@pytest.fixture(scope='module')
def killed_recording(tmp_path_factory):
    """Record the sample's positions (stamps from 0 s) with a recorder process; SIGKILL it."""
    folder = tmp_path_factory.mktemp('killed')
    bag_dir = str(folder / 'run')
    sample = open_bag(SAMPLE)
    kept = {k: v for k, v in sample.custom_data.items() if k != fingerprint.CUSTOM_DATA_KEY}
    kept['microball.test'] = 'killed mid-run'
    parameters = folder / 'recorder.yaml'
    parameters.write_text(yaml.safe_dump({'recorder': {'ros__parameters': {
        'output': bag_dir, 'topics': [POSITIONS], 'flush_period': 0.1,
        'custom_data': yaml.safe_dump(kept)}}}))
    sent = [deserialize_message(m.data, TrackedPositions) for m in sample.messages(POSITIONS)]
    first = sent[0].header.stamp.sec * SECOND + sent[0].header.stamp.nanosec
    for message in sent:  # simulated time: header stamps 0 .. 20 s, unlike any wall clock
        stamp = message.header.stamp.sec * SECOND + message.header.stamp.nanosec - first
        message.header.stamp.sec, message.header.stamp.nanosec = divmod(stamp, SECOND)
    recorder = subprocess.Popen(
        [sys.executable, '-m', 'microball_ros.nodes.recorder', '--ros-args', '--params-file',
         str(parameters)], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
        env=killable_env(folder))  # SIGKILLed below
    mcap = os.path.join(bag_dir, 'run_0.mcap')
    flushed = 450
    context = rclpy.Context()
    rclpy.init(context=context)
    try:
        harness = Harness(context)
        publisher = harness.probe.create_publisher(TrackedPositions, POSITIONS, DATA_QOS)
        harness.wait_for_subscribers(publisher, timeout=60.0)
        for message in sent[:flushed]:
            publisher.publish(message)
        harness.spin_until(lambda: scan_file(mcap).message_count >= flushed, timeout=60.0,
                           message=f'{flushed} messages flushed to {mcap}')
        for message in sent[flushed:]:
            publisher.publish(message)
        recorder.send_signal(signal.SIGKILL)  # mid-run: the rest may or may not be on disk
        recorder.wait(timeout=30)
        harness.close()
    finally:
        if recorder.poll() is None:
            recorder.kill()
            recorder.wait()
        rclpy.shutdown(context=context)
    assert recorder.returncode == -signal.SIGKILL
    before = scan_file(mcap)
    return {'dir': bag_dir, 'sent': sent, 'kept': kept, 'flushed': flushed, 'before': before,
            'listing': sorted(os.listdir(bag_dir))}


@pytest.fixture(scope='module')
def reindexed(killed_recording):
    """Run `microball reindex` on the killed recording; return (result, recovered count)."""
    result = _cli('reindex', killed_recording['dir'])
    return result, open_bag(killed_recording['dir']).topics[POSITIONS].count


@pytest.fixture(scope='module')
def reprocessed(killed_recording, reindexed, tmp_path_factory):
    """Run `microball reprocess` on the repaired recording; return (result, output dir)."""
    output = str(tmp_path_factory.mktemp('reprocessed') / 'again')
    return _cli('reprocess', killed_recording['dir'], '--output', output, timeout=400), output


def test_killed_recording_keeps_custom_data_and_topics_until_reindex(killed_recording):
    run = killed_recording
    # what the recorder left: its file (no summary) and the metadata.yaml written at open
    assert run['listing'] == ['metadata.yaml', 'run_0.mcap']
    assert not run['before'].complete and run['before'].message_count >= run['flushed']
    assert run['before'].rosbag2['custom_data'] == {
        **run['kept'], fingerprint.CUSTOM_DATA_KEY: run['before'].rosbag2['custom_data'][
            fingerprint.CUSTOM_DATA_KEY]}
    assert [c.topic for c in run['before'].channels.values()] == [POSITIONS]
    result = _cli('info', run['dir'])
    assert result.returncode == 2 and len(result.stderr.strip().splitlines()) == 1
    assert f'microball reindex {run["dir"]}' in result.stderr


def test_reindexed_recording_is_whole_and_holds_only_what_rosbag2_lists(killed_recording,
                                                                        reindexed):
    run = killed_recording
    result, recovered = reindexed
    assert result.returncode == 0, result.stderr
    assert f'{POSITIONS}: {recovered} messages recovered' in result.stdout
    assert run['flushed'] <= recovered <= len(run['sent'])
    assert sorted(os.listdir(run['dir'])) == ['metadata.yaml', 'run_0.mcap']
    backup = run['dir'] + '.truncated'
    assert os.listdir(backup) == ['run_0.mcap']  # the original, beside the bag
    assert scan_file(os.path.join(backup, 'run_0.mcap')).message_count == \
        run['before'].message_count
    bag = open_bag(run['dir'])
    decoded = [deserialize_message(m.data, TrackedPositions) for m in bag.messages()]
    assert decoded == run['sent'][:recovered]
    assert {k: bag.custom_data[k] for k in run['kept']} == run['kept']
    here = fingerprint.fingerprint()
    assert bag.platform['key'] == here['key'] and bag.platform['cpu'] == here['cpu']
    assert set(bag.custom_data) == {*run['kept'], fingerprint.CUSTOM_DATA_KEY}
    assert bag.ros_distro == ros_distro()
    assert 'reliability: reliable' in bag.topics[POSITIONS].qos_profiles_yaml


def test_publish_time_is_the_source_timestamp_not_the_header_stamp(killed_recording, reindexed):
    messages = list(open_bag(killed_recording['dir']).messages())
    assert messages
    for message in messages:
        # same clock as log time, published before it was received, never the 0-20 s stamps
        assert 0 <= message.log_time_ns - message.publish_time_ns < SECOND
        assert message.publish_time_ns > 1000 * SECOND
    assert len({m.publish_time_ns for m in messages}) == len(messages)


def test_info_and_analyze_use_the_repaired_recording(killed_recording, reindexed, tmp_path):
    _, recovered = reindexed
    result = _cli('info', killed_recording['dir'])
    assert result.returncode == 0, result.stderr
    assert f'Messages:          {recovered}' in result.stdout
    assert f'ROS Distro:        {ros_distro() or "unknown"}' in result.stdout
    out = tmp_path / 'analysis.json'
    result = _cli('analyze', killed_recording['dir'], '--json', str(out))
    assert result.returncode == 0, result.stderr
    analysis = json.loads(out.read_text())
    # the analysed window lies within the recovered positions (stamps from 0 s, 30 frames/s)
    sent = killed_recording['sent'][recovered - 1].header.stamp
    last = sent.sec + sent.nanosec * 1e-9
    assert 0 <= analysis['window']['start'] < analysis['window']['end'] <= last + 1e-6
    assert analysis['window']['samples_used'] <= recovered
    assert analysis['memoryless'] is True
    low, high = analysis['model']['A_ci95']
    assert low <= 1.2 <= high


def test_reprocess_uses_the_repaired_recording(killed_recording, reindexed, reprocessed):
    _, recovered = reindexed
    result, output = reprocessed
    assert result.returncode == 0, result.stderr[-2000:]
    again = open_bag(output)
    assert again.topics[POSITIONS].count == recovered
    assert again.topics['/friction/model'].count >= 1
    assert again.platform['key'] == fingerprint.fingerprint()['key']
    assert sorted(os.listdir(output)) == ['again_0.mcap', 'metadata.yaml']
    # a fresh recording (reprocess's own recorder): every publish time within 1 s of log time
    messages = list(again.messages())
    assert len(messages) == again.message_count
    assert all(abs(m.log_time_ns - m.publish_time_ns) < SECOND for m in messages)


# --- Foxglove's readers --------------------------------------------------------------------------

def _foxglove(path):
    if not os.path.isdir(os.path.join(FOXGLOVE, 'node_modules')):
        pytest.skip('test/foxglove/node_modules is not installed (npm ci --prefix test/foxglove)')
    node = shutil.which('node')
    if node is None:
        pytest.skip('node is not on PATH')
    result = subprocess.run([node, os.path.join(FOXGLOVE, 'check_bag.js'), path],
                            capture_output=True, text=True, timeout=300)
    report = json.loads(result.stdout)
    assert result.returncode == 0 and report['errors'] == [], report['errors'][:5]
    return report


def _check_with_foxglove(path, streaming_records):
    bag = open_bag(path)
    report = _foxglove(bag.files[0])
    counts = {name: info.count for name, info in bag.topics.items() if info.count}
    for reader in ('indexed', 'streaming'):
        assert report[reader]['messages'] == report[reader]['decoded'] == bag.message_count
        assert report[reader]['topics'] == counts
        assert report[reader]['maxSkewNs'] < SECOND
    assert report['indexed']['profile'] == 'ros2'
    assert report['indexed']['rosbag2Records'] == 1
    assert report['streaming']['rosbag2Records'] == streaming_records
    last = yaml.safe_load(report['indexed']['lastRosbag2'])
    assert last == yaml.safe_load(report['streaming']['lastRosbag2'])
    assert last['custom_data'] == bag.custom_data and last['message_count'] == bag.message_count


def test_foxglove_reads_the_repaired_recording(killed_recording, reindexed):
    # rewritten by reindex: one 'rosbag2' record, the rebuilt one
    _check_with_foxglove(killed_recording['dir'], streaming_records=1)


def test_foxglove_reads_a_fresh_closed_recording(reprocessed):
    # written by a recorder that closed it: the record of the open, then the complete one
    _check_with_foxglove(reprocessed[1], streaming_records=2)
