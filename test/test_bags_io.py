"""Bag I/O: rosbag2/MCAP layout, round trips through three readers, crash recovery, bad input.

Messages are real microball_msgs / sensor_msgs instances serialized by rclpy (no DDS needed).
"""

import os
import shutil
import signal
import struct
import subprocess
import sys
import textwrap
import warnings

from builtin_interfaces.msg import Time
from mcap.reader import make_reader
from microball_msgs.msg import FrictionModel, TrackedPositions
import numpy as np
import pytest
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import deserialize_message, serialize_message
from rosbags.highlevel import AnyReader
from rosbags.rosbag2 import StoragePlugin
from rosbags.rosbag2 import Writer as RosbagsWriter
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from sensor_msgs.msg import Image
from std_msgs.msg import Header
import yaml

from microball_ros.io.bags import (
    BagError,
    BagWriter,
    message_definition,
    open_bag,
    qos_profiles_yaml,
    read_positions,
    reindex,
)
from microball_ros.io.bags.schema import msg_file, parse_qos_profiles, type_hash

with warnings.catch_warnings():
    warnings.simplefilter('ignore', DeprecationWarning)  # the module warns on import
    from mcap_ros2.reader import read_ros2_messages

POSITIONS = '/tracking/positions'
IMAGES = '/camera/image_raw'
MODELS = '/friction/model'
T0 = 1_700_000_000_000_000_000
PERIOD = 1_000_000_000 // 30
TYPES = {POSITIONS: 'microball_msgs/msg/TrackedPositions', IMAGES: 'sensor_msgs/msg/Image',
         MODELS: 'microball_msgs/msg/FrictionModel'}


def _stamp(nanoseconds):
    return Time(sec=nanoseconds // 1_000_000_000, nanosec=nanoseconds % 1_000_000_000)


def _positions(i):
    t = T0 + i * PERIOD
    return TrackedPositions(
        header=Header(stamp=_stamp(t), frame_id='camera'), frame_index=i,
        slider_position=1e-3 * np.sin(0.1 * i), stator_position=1.2e-3 * np.cos(0.1 * i),
        slider_quality=0.5 + 0.001 * i, stator_quality=0.25, slider_valid=i % 5 != 3,
        stator_valid=i % 7 != 2)


def _image(i):
    width, height = 8, 4
    return Image(header=Header(stamp=_stamp(T0 + i * PERIOD), frame_id='camera'), height=height,
                 width=width, encoding='mono8', is_bigendian=0, step=width,
                 data=bytes((i + k) % 256 for k in range(width * height)))


def _model(i):
    return FrictionModel(header=Header(stamp=_stamp(T0 + i * PERIOD), frame_id=''),
                         name='langevin', a=1.2 + i, alpha=110.0 - i, a_ci95=[1.1, 1.3 + i],
                         alpha_ci95=[100.0, float('inf')], rmse=0.001, sample_count=10 + i,
                         window_count=i)


def _qos(depth=2000, transient=False):
    return qos_profiles_yaml([QoSProfile(
        depth=depth, reliability=ReliabilityPolicy.RELIABLE,
        durability=DurabilityPolicy.TRANSIENT_LOCAL if transient else DurabilityPolicy.VOLATILE)])


def _record_run(directory, count=60, flush_every=10, compression='zstd', out_of_order=True):
    """Write interleaved positions, images and models; return (topic, msg, log time, bytes)s.

    rclpy leaves CDR padding bytes uninitialised, so serializing a message twice need not give
    the same bytes: compare with the bytes that were written.
    """
    written = []
    with BagWriter(directory, compression=compression) as bag:
        bag.add_topic(POSITIONS, TYPES[POSITIONS], _qos())
        bag.add_topic(IMAGES, TYPES[IMAGES], _qos(depth=10))
        bag.add_topic(MODELS, TYPES[MODELS], _qos(depth=1, transient=True))
        for i in range(count):
            log_time = T0 + i * PERIOD + 1000
            if out_of_order and i == count // 2:
                log_time = T0 + 5 * PERIOD + 500  # very late: sorts back before 4 older chunks
            for topic, message in ((IMAGES, _image(i)), (POSITIONS, _positions(i))):
                data = serialize_message(message)
                bag.write(topic, data, log_time, T0 + i * PERIOD)
                written.append((topic, message, log_time, data))
            if i % 10 == 9:
                model = _model(i)
                data = serialize_message(model)
                bag.write(MODELS, data, log_time + 5, T0 + i * PERIOD)
                written.append((MODELS, model, log_time + 5, data))
            if i % flush_every == flush_every - 1:
                bag.flush()
    return written


def _sorted(written):
    order = sorted(range(len(written)), key=lambda k: (written[k][2], k))
    return [written[k] for k in order]


def _snapshot(directory):
    result = {}
    for root, _, names in os.walk(directory):
        for name in names:
            path = os.path.join(root, name)
            with open(path, 'rb') as handle:
                result[path] = (handle.read(), os.stat(path).st_mtime_ns)
    return result


def _one_line_bag_error(call):
    with pytest.raises(BagError) as caught:
        call()
    message = str(caught.value)
    assert message and '\n' not in message
    return message


# --- schemas -------------------------------------------------------------------------------

def test_message_definition_has_msg_text_then_each_dependency_once():
    text = message_definition('microball_msgs/msg/TrackedPositions')
    own = open(msg_file('microball_msgs/msg/TrackedPositions')).read()
    header = open(msg_file('std_msgs/msg/Header')).read()
    stamp = open(msg_file('builtin_interfaces/msg/Time')).read()
    separator = '\n' + '=' * 80 + '\n'
    assert text == (own + separator + 'MSG: std_msgs/Header\n' + header
                    + separator + 'MSG: builtin_interfaces/Time\n' + stamp)
    image = message_definition('sensor_msgs/Image')  # pkg/Type is accepted too
    assert image.count('MSG: ') == 2 and image.count('MSG: builtin_interfaces/Time\n') == 1
    # rosbag2's order: direct dependencies sorted by name, each followed by its own (depth
    # first); a type named without package ('RegionOfInterest roi') gets its package's name
    camera = message_definition('sensor_msgs/msg/CameraInfo')
    assert [line for line in camera.splitlines() if line.startswith('MSG: ')] == [
        'MSG: sensor_msgs/RegionOfInterest', 'MSG: std_msgs/Header',
        'MSG: builtin_interfaces/Time']


@pytest.mark.parametrize('type_name', ['microball_msgs/msg/TrackedPositions',
                                       'microball_msgs/msg/DerivativeEstimate',
                                       'microball_msgs/msg/FrictionModel',
                                       'sensor_msgs/msg/Image', 'sensor_msgs/msg/CameraInfo',
                                       'builtin_interfaces/msg/Duration'])
def test_message_definition_is_complete_enough_to_rebuild_the_rosidl_type_hash(type_name):
    # rosbags parses our text and hashes the parsed type (RIHS01); it equals the hash rosidl
    # generated at build time only if every field of every nested type made it into the text.
    store = get_typestore(Stores.EMPTY)
    store.register(get_types_from_msg(message_definition(type_name), type_name))
    assert type_hash(type_name).startswith('RIHS01_')
    assert store.hash_rihs01(type_name) == type_hash(type_name)


@pytest.mark.parametrize('type_name', ['microball_msgs/msg/NoSuchType', 'no_such_pkg/msg/Foo',
                                       'not a type', ''])
def test_unknown_message_type_is_a_one_line_error(type_name):
    message = _one_line_bag_error(lambda: message_definition(type_name))
    assert 'unknown message type' in message


def test_qos_profiles_yaml_is_rosbag2_version_9_form():
    text = _qos(depth=7, transient=True)
    [profile] = parse_qos_profiles(text)
    assert profile == {
        'history': 'keep_last', 'depth': 7, 'reliability': 'reliable',
        'durability': 'transient_local', 'deadline': {'sec': 0, 'nsec': 0},
        'lifespan': {'sec': 0, 'nsec': 0}, 'liveliness': 'system_default',
        'liveliness_lease_duration': {'sec': 0, 'nsec': 0},
        'avoid_ros_namespace_conventions': False}
    assert list(profile) == ['history', 'depth', 'reliability', 'durability', 'deadline',
                             'lifespan', 'liveliness', 'liveliness_lease_duration',
                             'avoid_ros_namespace_conventions']
    assert qos_profiles_yaml([]) == ''


# --- round trip ------------------------------------------------------------------------------

@pytest.fixture(scope='module')
def recorded(tmp_path_factory):
    directory = str(tmp_path_factory.mktemp('bags') / 'run')
    return directory, _record_run(directory)


def test_our_reader_returns_every_message_byte_for_byte_in_log_time_order(recorded):
    directory, written = recorded
    bag = open_bag(directory)
    expected = _sorted(written)
    got = list(bag.messages())
    assert [(m.topic, m.log_time_ns) for m in got] == [(t, lt) for t, _, lt, _ in expected]
    assert [m.data for m in got] == [data for _, _, _, data in expected]
    assert all(m.type == TYPES[m.topic] for m in got)
    for m in got:
        if m.topic == POSITIONS:
            frame = deserialize_message(m.data, TrackedPositions).frame_index
            assert m.publish_time_ns == T0 + frame * PERIOD
    counts = {topic: sum(1 for t, *_ in written if t == topic) for topic in TYPES}
    assert {name: info.count for name, info in bag.topics.items()} == counts == {
        POSITIONS: 60, IMAGES: 60, MODELS: 6}
    assert bag.message_count == 126
    assert bag.start_ns == min(w[2] for w in written)
    assert bag.end_ns == max(w[2] for w in written)
    assert bag.files == [os.path.join(directory, 'run_0.mcap')]
    assert parse_qos_profiles(bag.topics[MODELS].qos_profiles_yaml)[0]['durability'] == \
        'transient_local'
    assert bag.definition(TYPES[IMAGES]) == message_definition(TYPES[IMAGES])
    only_models = list(bag.messages(topics=[MODELS]))
    assert [deserialize_message(m.data, FrictionModel).window_count for m in only_models] == [
        9, 19, 29, 39, 49, 59]


def test_metadata_yaml_is_rosbag2_version_9(recorded):
    directory, written = recorded
    with open(os.path.join(directory, 'metadata.yaml')) as handle:
        info = yaml.safe_load(handle)['rosbag2_bagfile_information']
    start = min(w[2] for w in written)
    end = max(w[2] for w in written)
    assert info['version'] == 9
    assert info['storage_identifier'] == 'mcap'
    assert info['relative_file_paths'] == ['run_0.mcap']
    assert info['starting_time'] == {'nanoseconds_since_epoch': start}
    assert info['duration'] == {'nanoseconds': end - start}
    assert info['message_count'] == 126
    assert info['compression_format'] == '' and info['compression_mode'] == ''
    assert info['ros_distro'] == 'kilted'
    assert info['files'] == [{'path': 'run_0.mcap',
                              'starting_time': {'nanoseconds_since_epoch': start},
                              'duration': {'nanoseconds': end - start}, 'message_count': 126}]
    topics = {t['topic_metadata']['name']: t for t in info['topics_with_message_count']}
    assert {name: t['message_count'] for name, t in topics.items()} == {
        POSITIONS: 60, IMAGES: 60, MODELS: 6}
    for name, entry in topics.items():
        metadata = entry['topic_metadata']
        assert metadata['type'] == TYPES[name]
        assert metadata['serialization_format'] == 'cdr'
        assert metadata['type_description_hash'] == type_hash(TYPES[name])
        assert isinstance(metadata['offered_qos_profiles'], list)  # v9: a list, not a string
        assert metadata['offered_qos_profiles'][0]['reliability'] == 'reliable'


def test_mcap_file_has_the_ros2_profile_layout(recorded):
    directory, _ = recorded
    with open(os.path.join(directory, 'run_0.mcap'), 'rb') as handle:
        reader = make_reader(handle)
        header = reader.get_header()
        summary = reader.get_summary()
        metadata = list(reader.iter_metadata())
    assert header.profile == 'ros2'
    assert header.library.startswith('microball_ros ') and '; mcap ' in header.library
    assert sorted(s.name for s in summary.schemas.values()) == sorted(set(TYPES.values()))
    for schema in summary.schemas.values():
        assert schema.encoding == 'ros2msg'
        assert schema.data.decode() == message_definition(schema.name)
    for channel in summary.channels.values():
        assert channel.message_encoding == 'cdr'
        assert summary.schemas[channel.schema_id].name == TYPES[channel.topic]
        assert parse_qos_profiles(channel.metadata['offered_qos_profiles'])[0]['depth'] > 0
        assert channel.metadata['topic_type_hash'] == type_hash(TYPES[channel.topic])
    assert summary.statistics.message_count == 126
    assert len(summary.chunk_indexes) >= 6  # flushed every 10 frames
    [rosbag2] = [m for m in metadata if m.name == 'rosbag2']
    serialized = yaml.safe_load(rosbag2.metadata['serialized_metadata'])
    assert serialized['version'] == 9 and serialized['message_count'] == 126


def test_rosbags_anyreader_deserializes_every_message_without_registration(recorded):
    directory, written = recorded
    expected = _sorted(written)
    from pathlib import Path

    with AnyReader([Path(directory)]) as reader:  # checks our type hashes against its own
        decoded = [(c.topic, t, reader.deserialize(raw, c.msgtype))
                   for c, t, raw in reader.messages()]
    assert [(topic, t) for topic, t, _ in decoded] == [(w[0], w[2]) for w in expected]
    for (topic, _, got), (_, sent, *_) in zip(decoded, expected, strict=True):
        assert got.header.stamp.sec == sent.header.stamp.sec
        assert got.header.stamp.nanosec == sent.header.stamp.nanosec
        if topic == POSITIONS:
            assert (got.frame_index, got.slider_position, got.stator_valid) == (
                sent.frame_index, sent.slider_position, sent.stator_valid)
            assert got.slider_quality == pytest.approx(sent.slider_quality)
        elif topic == IMAGES:
            assert (got.width, got.encoding, got.data.tobytes()) == (
                sent.width, sent.encoding, bytes(sent.data))
        else:
            assert (got.name, got.a, list(got.alpha_ci95)) == (
                sent.name, sent.a, list(sent.alpha_ci95))


def test_mcap_ros2_reader_decodes_every_message(recorded):
    directory, written = recorded
    expected = _sorted(written)
    decoded = list(read_ros2_messages(os.path.join(directory, 'run_0.mcap')))
    assert len(decoded) == len(expected)
    for got, (topic, sent, log_time, _) in zip(decoded, expected, strict=True):
        assert got.channel.topic == topic and got.log_time_ns == log_time
        message = got.ros_msg
        assert message.header.frame_id == sent.header.frame_id
        if topic == POSITIONS:
            assert (message.frame_index, message.stator_position, message.slider_valid) == (
                sent.frame_index, sent.stator_position, sent.slider_valid)
        elif topic == IMAGES:
            assert (message.height, bytes(message.data)) == (sent.height, bytes(sent.data))
        else:
            assert (message.window_count, list(message.a_ci95)) == (
                sent.window_count, list(sent.a_ci95))


@pytest.mark.parametrize('compression', [None, 'lz4'])
def test_other_compressions_round_trip(tmp_path, compression):
    directory = str(tmp_path / 'bag')
    written = _record_run(directory, count=20, compression=compression, out_of_order=False)
    assert [m.data for m in open_bag(directory).messages()] == [w[3] for w in written]
    with open(open_bag(directory).files[0], 'rb') as handle:
        chunk_compression = {c.compression for c in make_reader(handle).get_summary()
                             .chunk_indexes}
    assert chunk_compression == {compression or ''}


def test_read_positions_from_bag_directory_and_single_file(recorded):
    directory, _ = recorded
    frames = np.arange(60)
    sent = [_positions(i) for i in frames]
    for path in (directory, os.path.join(directory, 'run_0.mcap')):
        record = read_positions(path)
        np.testing.assert_array_equal(record.time, (T0 + frames * PERIOD) / 1e9)
        np.testing.assert_array_equal(
            record.slider_position,
            [m.slider_position if m.slider_valid else np.nan for m in sent])
        np.testing.assert_array_equal(
            record.stator_position,
            [m.stator_position if m.stator_valid else np.nan for m in sent])
        assert np.isnan(record.slider_position[3]) and np.isnan(record.stator_position[2])
        np.testing.assert_allclose(record.extra['slider_quality'], 0.5 + 0.001 * frames,
                                   rtol=1e-6)
        np.testing.assert_array_equal(record.extra['stator_quality'], 0.25)


@pytest.mark.parametrize('frame_ids', [['c'], ['camera_left_rectified'], ['camera', 'cam']])
def test_read_positions_decodes_every_layout_like_rclpy(tmp_path, frame_ids):
    # One frame_id (of any length: it moves the aligned fields) is decoded by numpy all at
    # once; mixed lengths by rosbags message by message. Both must give what rclpy decodes.
    sent = []
    for i in range(90):
        msg = _positions(i)
        msg.header.frame_id = frame_ids[i % len(frame_ids)]
        sent.append(msg)
    directory = str(tmp_path / 'bag')
    with BagWriter(directory) as bag:
        bag.add_topic(POSITIONS, TYPES[POSITIONS], _qos())
        for msg in sent:
            t = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
            bag.write(POSITIONS, serialize_message(msg), t, t)
    decoded = [deserialize_message(m.data, TrackedPositions)
               for m in open_bag(directory).messages([POSITIONS])]
    record = read_positions(directory)
    np.testing.assert_array_equal(record.time, [
        (m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec) / 1e9 for m in decoded])
    np.testing.assert_array_equal(record.stator_position, [
        m.stator_position if m.stator_valid else np.nan for m in decoded])
    np.testing.assert_array_equal(record.slider_position, [
        m.slider_position if m.slider_valid else np.nan for m in decoded])
    np.testing.assert_array_equal(record.extra['slider_quality'],
                                  [m.slider_quality for m in decoded])
    np.testing.assert_array_equal(record.extra['stator_quality'],
                                  [m.stator_quality for m in decoded])


def test_info_lines_read_like_ros2_bag_info(recorded):
    directory, _ = recorded
    lines = open_bag(directory).info_lines()
    assert lines[0] == 'Files:             run_0.mcap'
    assert lines[1].startswith('Bag size:          ') and lines[1].endswith('KiB')
    assert lines[2] == 'Storage id:        mcap'
    assert lines[3] == 'ROS Distro:        kilted'
    assert lines[4] == 'Duration:          1.966666652s'  # 59 periods + 5 ns (the last model)
    assert lines[5].startswith('Start:             ') and lines[5].endswith(
        '(1700000000.000001000)')
    assert lines[7] == 'Messages:          126'
    assert lines[8] == ('Topic information: Topic: /tracking/positions | Type: '
                        'microball_msgs/msg/TrackedPositions | Count: 60 | '
                        'Serialization Format: cdr')
    assert lines[9].startswith(' ' * 19 + 'Topic: /camera/image_raw | ')


# --- a bag written by rosbags ----------------------------------------------------------------

def test_bag_written_by_rosbags_opens_and_analyses(tmp_path):
    store = get_typestore(Stores.EMPTY)
    for type_name in ('builtin_interfaces/msg/Time', 'std_msgs/msg/Header',
                      'microball_msgs/msg/TrackedPositions'):
        store.register(get_types_from_msg(open(msg_file(type_name)).read(), type_name))
    make = store.types
    directory = tmp_path / 'rosbags_bag'
    frames = np.arange(90)
    stamps = T0 + frames * PERIOD
    slider = 1e-3 * np.sin(0.2 * frames)
    with RosbagsWriter(directory, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        connection = writer.add_connection(POSITIONS, TYPES[POSITIONS], typestore=store)
        for i, stamp in zip(frames, stamps, strict=True):
            header = make['std_msgs/msg/Header'](
                stamp=make['builtin_interfaces/msg/Time'](sec=int(stamp // 10**9),
                                                          nanosec=int(stamp % 10**9)),
                frame_id='cam')
            message = make[TYPES[POSITIONS]](
                header=header, frame_index=int(i), slider_position=float(slider[i]),
                stator_position=2e-3, slider_quality=np.float32(0.75),
                stator_quality=np.float32(1.0), slider_valid=bool(i != 40), stator_valid=True,
                slider_sigma=1e-7, stator_sigma=1e-7)
            writer.write(connection, int(stamp) + 10, store.serialize_cdr(message,
                                                                          TYPES[POSITIONS]))
    bag = open_bag(str(directory))
    assert bag.topics[POSITIONS].count == 90 and bag.topics[POSITIONS].type == TYPES[POSITIONS]
    decoded = [deserialize_message(m.data, TrackedPositions) for m in bag.messages()]
    assert [m.frame_index for m in decoded] == frames.tolist()
    record = read_positions(str(directory))
    np.testing.assert_array_equal(record.time, stamps / 1e9)
    expected = slider.copy()
    expected[40] = np.nan
    np.testing.assert_array_equal(record.slider_position, expected)
    np.testing.assert_array_equal(record.stator_position, 2e-3)
    np.testing.assert_array_equal(record.extra['slider_quality'], 0.75)


# --- crash safety --------------------------------------------------------------------------

def test_file_cut_after_flush_is_reported_then_recovered_by_reindex(tmp_path):
    source = str(tmp_path / 'source')
    flushed = []
    with BagWriter(source) as bag:
        bag.add_topic(POSITIONS, TYPES[POSITIONS], _qos())
        for i in range(45):
            data = serialize_message(_positions(i))
            bag.write(POSITIONS, data, T0 + i * PERIOD, T0 + i * PERIOD)
            flushed.append(data)
            if i % 15 == 14:
                bag.flush()
        flushed_size = os.path.getsize(bag.path)
        for i in range(45, 57):  # the chunk a kill -9 cuts while it is being written
            bag.write(POSITIONS, serialize_message(_positions(i)), T0 + i * PERIOD, 0)
        bag.flush()
        with open(bag.path, 'rb') as handle:
            handle.seek(flushed_size)
            opcode, length = struct.unpack('<BQ', handle.read(9))
    assert opcode == 0x06  # a chunk record starts right where the last flush ended
    with open(os.path.join(source, 'source_0.mcap'), 'rb') as handle:
        complete = handle.read()
    cuts = [flushed_size, flushed_size + 4, flushed_size + 9, flushed_size + 9 + length // 2,
            flushed_size + 9 + length - 1]
    for number, cut in enumerate(cuts):
        directory = tmp_path / f'killed{number}'
        directory.mkdir()
        path = directory / 'source_0.mcap'
        path.write_bytes(complete[:cut])
        before = _snapshot(directory)
        message = _one_line_bag_error(lambda d=directory: open_bag(str(d)))
        assert 'no metadata.yaml' in message and 'truncated' in message
        assert f'microball reindex {directory}' in message and '45 messages' in message
        single = _one_line_bag_error(lambda p=path: open_bag(str(p)))
        assert f'byte {cut}' in single or f'byte {flushed_size}' in single
        assert _snapshot(directory) == before  # reading wrote nothing

        lines = []
        assert reindex(str(directory), log=lines.append) == {POSITIONS: 45}
        # the original is kept beside the bag, which holds only what rosbag2 lists
        backup = tmp_path / f'killed{number}.truncated' / 'source_0.mcap'
        assert len(lines) == 1 and str(backup) in lines[0]
        assert backup.read_bytes() == complete[:cut]
        assert sorted(os.listdir(directory)) == ['metadata.yaml', 'source_0.mcap']
        bag = open_bag(str(directory))
        assert [m.data for m in bag.messages()] == flushed
        assert bag.topics[POSITIONS].qos_profiles_yaml == _qos()
        info = yaml.safe_load((directory / 'metadata.yaml').read_text())
        assert info['rosbag2_bagfile_information']['message_count'] == 45
        np.testing.assert_array_equal(read_positions(str(directory)).time,
                                      (T0 + np.arange(45) * PERIOD) / 1e9)


CHILD = textwrap.dedent("""
    import sys
    from microball_msgs.msg import TrackedPositions
    from rclpy.serialization import serialize_message
    from microball_ros.io.bags import BagWriter
    bag = BagWriter(sys.argv[1])
    bag.add_topic('/tracking/positions', 'microball_msgs/msg/TrackedPositions')
    i = 0
    while True:
        message = TrackedPositions(frame_index=i, slider_position=float(i))
        message.header.stamp.sec = i
        bag.write('/tracking/positions', serialize_message(message), 10**9 * (i + 1), 0)
        i += 1
        if i % 50 == 0:
            bag.flush()
            print(i, flush=True)
""")


def test_real_kill_9_loses_only_what_followed_the_last_flush(tmp_path):
    directory = tmp_path / 'killed'
    child = subprocess.Popen([sys.executable, '-c', CHILD, str(directory)],
                             stdout=subprocess.PIPE, text=True)
    try:
        seen = 0
        while seen < 300:
            line = child.stdout.readline()
            assert line, 'the recorder child died'
            seen = int(line)
        child.send_signal(signal.SIGKILL)
        child.wait(timeout=10)
    finally:
        if child.poll() is None:
            child.kill()
        child.stdout.close()
    assert child.returncode == -signal.SIGKILL
    counts = reindex(str(directory))
    assert counts[POSITIONS] >= seen and counts[POSITIONS] % 50 == 0
    frames = [deserialize_message(m.data, TrackedPositions).frame_index
              for m in open_bag(str(directory)).messages()]
    assert frames == list(range(counts[POSITIONS]))


# --- bad input -----------------------------------------------------------------------------

def test_missing_path_and_not_a_bag(tmp_path):
    assert 'no such file' in _one_line_bag_error(lambda: open_bag(str(tmp_path / 'nope')))
    empty = tmp_path / 'empty_dir'
    empty.mkdir()
    (empty / 'notes.txt').write_text('hello')
    before = _snapshot(empty)
    assert 'not a bag' in _one_line_bag_error(lambda: open_bag(str(empty)))
    assert 'not a bag' in _one_line_bag_error(lambda: open_bag(str(empty / 'notes.txt')))
    assert _snapshot(empty) == before
    assert 'no .mcap' in _one_line_bag_error(lambda: reindex(str(empty)))
    assert _snapshot(empty) == before


def test_empty_bag(tmp_path):
    directory = str(tmp_path / 'empty')
    with BagWriter(directory) as bag:
        bag.add_topic(POSITIONS, TYPES[POSITIONS])
    assert bag.counts == {POSITIONS: 0}
    before = _snapshot(directory)
    assert 'no messages' in _one_line_bag_error(lambda: open_bag(directory))
    assert 'no messages' in _one_line_bag_error(lambda: read_positions(directory))
    assert _snapshot(directory) == before


def test_missing_metadata_yaml_next_to_a_complete_file(tmp_path):
    directory = str(tmp_path / 'bag')
    written = _record_run(directory, count=12, out_of_order=False)
    os.remove(os.path.join(directory, 'metadata.yaml'))
    before = _snapshot(directory)
    message = _one_line_bag_error(lambda: open_bag(directory))
    assert 'no metadata.yaml' in message and f'microball reindex {directory}' in message
    assert 'truncated' not in message
    assert _snapshot(directory) == before
    # the file itself is complete: it opens alone, and reindex only rebuilds metadata.yaml
    assert open_bag(os.path.join(directory, 'bag_0.mcap')).message_count == len(written)
    assert reindex(directory) == {POSITIONS: 12, IMAGES: 12, MODELS: 1}
    assert sorted(os.listdir(directory)) == ['bag_0.mcap', 'metadata.yaml']
    assert open_bag(directory).message_count == len(written)


def test_corrupted_chunk_in_the_middle(tmp_path):
    directory = str(tmp_path / 'bag')
    _record_run(directory, count=40, out_of_order=False)
    path = os.path.join(directory, 'bag_0.mcap')
    with open(path, 'rb') as handle:
        chunks = make_reader(handle).get_summary().chunk_indexes
    victim = sorted(chunks, key=lambda c: c.chunk_start_offset)[1]
    data = bytearray(open(path, 'rb').read())
    middle = victim.chunk_start_offset + victim.chunk_length // 2
    data[middle:middle + 16] = bytes(16)
    with open(path, 'wb') as handle:
        handle.write(data)
    before = _snapshot(directory)
    bag = open_bag(directory)
    message = _one_line_bag_error(lambda: list(bag.messages()))
    assert f'corrupted at byte {victim.chunk_start_offset}' in message and 'reindex' in message
    assert 'corrupted' in _one_line_bag_error(lambda: read_positions(directory))
    assert _snapshot(directory) == before

    # the second chunk held frames 10..19 (positions and images) and the model of frame 19
    assert reindex(directory) == {POSITIONS: 30, IMAGES: 30, MODELS: 3}
    assert os.path.exists(os.path.join(directory + '.truncated', 'bag_0.mcap'))
    assert sorted(os.listdir(directory)) == ['bag_0.mcap', 'metadata.yaml']
    frames = [deserialize_message(m.data, TrackedPositions).frame_index
              for m in open_bag(directory).messages(POSITIONS)]
    assert frames == list(range(10)) + list(range(20, 40))


def test_garbage_metadata_and_unreadable_file(tmp_path):
    directory = str(tmp_path / 'bag')
    _record_run(directory, count=5, out_of_order=False)
    metadata = os.path.join(directory, 'metadata.yaml')
    with open(metadata, 'w') as handle:
        handle.write('rosbag2_bagfile_information: [unclosed\n')
    before = _snapshot(directory)
    assert 'metadata.yaml: unreadable' in _one_line_bag_error(lambda: open_bag(directory))
    assert _snapshot(directory) == before
    not_mcap = tmp_path / 'fake.mcap'
    not_mcap.write_bytes(b'this is not an mcap file at all')
    assert 'not an MCAP file' in _one_line_bag_error(lambda: open_bag(str(not_mcap)))


def test_missing_topic_in_read_positions(tmp_path):
    directory = str(tmp_path / 'bag')
    with BagWriter(directory) as bag:
        bag.add_topic(MODELS, TYPES[MODELS])
        bag.write(MODELS, serialize_message(_model(1)), T0, T0)
    before = _snapshot(directory)
    message = _one_line_bag_error(lambda: read_positions(directory))
    assert message == f'{directory}: bag has no topic /tracking/positions; it has: {MODELS}'
    # Neither positions nor frames: analyze and reprocess say so in one line, exit 2.
    for command in (['analyze', directory], ['reprocess', directory, '--output',
                                             str(tmp_path / 'out')]):
        result = subprocess.run([sys.executable, '-m', 'microball_ros.cli', *command],
                                capture_output=True, text=True, timeout=120)
        assert result.returncode == 2, result.stderr
        lines = result.stderr.strip().splitlines()
        assert len(lines) == 1 and '/camera/image_raw' in lines[0], result.stderr
    assert not os.path.exists(tmp_path / 'out')
    assert _snapshot(directory) == before


def test_writer_refuses_a_non_empty_directory_and_unknown_types(tmp_path):
    (tmp_path / 'used').mkdir()
    (tmp_path / 'used' / 'keep.txt').write_text('x')
    assert 'not empty' in _one_line_bag_error(lambda: BagWriter(str(tmp_path / 'used')))
    assert (tmp_path / 'used' / 'keep.txt').read_text() == 'x'
    with BagWriter(str(tmp_path / 'new')) as bag:
        assert 'unknown message type' in _one_line_bag_error(
            lambda: bag.add_topic('/x', 'microball_msgs/msg/Nope'))
        assert 'was not added' in _one_line_bag_error(lambda: bag.write('/x', b'', 0, 0))
    assert 'unknown compression' in _one_line_bag_error(
        lambda: BagWriter(str(tmp_path / 'other'), compression='gzip'))
    assert not os.path.exists(tmp_path / 'other')
    shutil.rmtree(tmp_path / 'new')


def test_split_bag_of_two_files_is_indexed_and_read_in_log_time_order(tmp_path):
    # rosbag2 splits long recordings into <name>_0.mcap, <name>_1.mcap, ...; reindex lists them
    # all in metadata.yaml and the reader merges them by log time.
    parts = []
    for number, frames in enumerate((range(0, 40, 2), range(1, 40, 2))):
        directory = tmp_path / f'part{number}'
        with BagWriter(str(directory)) as bag:
            bag.add_topic(POSITIONS, TYPES[POSITIONS], _qos())
            for i in frames:
                bag.write(POSITIONS, serialize_message(_positions(i)), T0 + i * PERIOD, 0)
        parts.append(directory / f'part{number}_0.mcap')
    split = tmp_path / 'split'
    split.mkdir()
    for number, part in enumerate(parts):
        shutil.copy(part, split / f'split_{number}.mcap')
    assert reindex(str(split)) == {POSITIONS: 40}
    info = yaml.safe_load((split / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    assert info['relative_file_paths'] == ['split_0.mcap', 'split_1.mcap']
    assert [f['message_count'] for f in info['files']] == [20, 20]
    assert info['duration'] == {'nanoseconds': 39 * PERIOD}
    bag = open_bag(str(split))
    frames = [deserialize_message(m.data, TrackedPositions).frame_index for m in bag.messages()]
    assert frames == list(range(40))
    assert bag.info_lines()[1] == ' ' * 19 + 'split_1.mcap'
