"""Message decoding: a bag's positions and camera frames as arrays, and recorded parameters.

``read_positions`` turns /tracking/positions (microball_msgs/TrackedPositions) into a
PositionRecord and ``read_frames`` /camera/image_raw (sensor_msgs/Image) into gray frames. Both
decode with rosbags, using the types of the bag's own schemas (no installed message package
needed); positions that all share one CDR layout are decoded by numpy at once, checked against
rosbags on the first, middle and last message. ``recorded_parameters`` returns a node's
parameters that ``microball experiment`` kept in the bag's custom_data.
"""

import math
import os
from pathlib import Path

import numpy as np
from rosbags.highlevel import AnyReader
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
import yaml

from microball_ros.core.errors import BagError
from microball_ros.core.records import PositionRecord, check_time_base
from microball_ros.io.bags.bag import Bag, open_bag
from microball_ros.io.bags.mcap_file import one_line
from microball_ros.io.video import image_to_gray

POSITIONS_TOPIC = '/tracking/positions'
POSITIONS_TYPE = 'microball_msgs/msg/TrackedPositions'


IMAGES_TOPIC = '/camera/image_raw'
IMAGE_TYPE = 'sensor_msgs/msg/Image'


def recorded_parameters(bag, node):
    """Return the parameters of ``node`` kept in the bag's metadata ({} if none).

    ``microball experiment --output`` keeps them in custom_data (metadata.yaml, and the MCAP
    file's 'rosbag2' record, so a lone .mcap has them too), under 'microball.<node>', as a
    YAML mapping (custom_data values are strings).
    """
    text = bag.custom_data.get(f'microball.{node}')
    if not text:
        return {}
    try:
        parameters = yaml.safe_load(text)
    except yaml.YAMLError as error:
        raise BagError(f'{bag.path}: custom_data microball.{node} is not YAML '
                       f'({one_line(error)})') from None
    if not isinstance(parameters, dict):
        raise BagError(f'{bag.path}: custom_data microball.{node} is not a mapping')
    return parameters


def _check_topic(bag, topic, type_name):
    if topic not in bag.topics:
        raise BagError(f'{bag.path}: bag has no topic {topic}; it has: '
                       f'{", ".join(sorted(bag.topics)) or "no topics"}')
    recorded = bag.topics[topic].type
    if recorded.replace('/msg/', '/') != type_name.replace('/msg/', '/'):
        raise BagError(f'{bag.path}: topic {topic} has type {recorded}, not {type_name}')
    if not bag.topics[topic].count:
        raise BagError(f'{bag.path}: topic {topic} has no messages')


def read_frames(bag, topic=IMAGES_TOPIC):
    """Yield (header stamp in s, gray H x W uint8 frame) for each image of ``topic``.

    ``bag`` is an open Bag. Frames come in log-time order, deserialized by rosbags; an
    encoding that is not 8-bit, or a message rosbags cannot read, is a BagError.
    """
    _check_topic(bag, topic, IMAGE_TYPE)
    try:
        for image in _deserialized(bag, topic):
            stamp = image.header.stamp.sec + image.header.stamp.nanosec * 1e-9
            yield stamp, image_to_gray(image.encoding, image.height, image.width, image.step,
                                       image.data, image.is_bigendian)
    except BagError:
        raise
    except Exception as error:  # noqa: B902 - rosbags' errors vary; report them in one line
        raise BagError(f'{bag.path}: cannot read {topic}: {one_line(error)}') from None


def read_positions(path, topic=POSITIONS_TOPIC):
    """Read TrackedPositions from a bag into a PositionRecord (time = header.stamp, s).

    ``path``: a bag directory, an .mcap file or an open Bag. Positions whose ``*_valid`` flag
    is false become NaN; ``extra`` holds slider_quality and stator_quality. Messages are
    deserialized by rosbags with the types of the bag's own schemas (AnyReader's for a bag
    directory), or, when they all share one CDR layout (one frame_id), all at once by numpy
    (_fixed_layout_positions: 0.25 s instead of 1.2 s for an hour; it must agree with rosbags
    on the first, middle and last message).
    The bytes come from Bag.message_data(), which checks chunk CRCs. Raise BagError if the
    topic is missing, and RecordError (also a ValueError) if the stamps are not uniformly
    increasing.
    """
    bag = path if isinstance(path, Bag) else open_bag(path)
    path = bag.path
    _check_topic(bag, topic, POSITIONS_TYPE)
    data = bag.message_data(topic)
    if not data:
        raise BagError(f'{path}: topic {topic} has no messages')
    type_name = bag.topics[topic].type
    try:
        store = _typestore(bag, type_name)
        columns = _fixed_layout_positions(data)
        # Trust the fast decoding only where it agrees with rosbags: first, middle, last.
        checked = sorted({0, len(data) // 2, len(data) - 1})
        if columns is None or not all(_same_columns(_position_columns(
                [store.deserialize_cdr(data[k], type_name)]), columns, k) for k in checked):
            columns = _position_columns([store.deserialize_cdr(d, type_name) for d in data])
    except BagError:
        raise
    except Exception as error:  # noqa: B902 - rosbags' errors vary; report them in one line
        raise BagError(f'{path}: cannot deserialize {topic}: {one_line(error)}') from None
    stamps, values = columns
    order = np.argsort(stamps, kind='stable')
    stamps, values = stamps[order], values[order]
    record = PositionRecord(time=stamps / 1e9, stator_position=values[:, 0],
                            slider_position=values[:, 1],
                            extra={'slider_quality': values[:, 2],
                                   'stator_quality': values[:, 3]})
    check_time_base(record.time, source=f'{path} {topic}')
    return record


def _position_columns(messages):
    """Return (stamps, ns; rows of stator, slider (NaN if invalid), slider, stator quality)."""
    stamps = np.array([m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec
                       for m in messages], dtype=np.int64)
    values = np.array([(m.stator_position if m.stator_valid else math.nan,
                        m.slider_position if m.slider_valid else math.nan,
                        m.slider_quality, m.stator_quality) for m in messages],
                      dtype=float).reshape(-1, 4)
    return stamps, values


def _same_columns(a, b, row):
    """Return True if row ``row`` of columns b equals columns a's only row, NaN for NaN."""
    return (int(a[0][0]) == int(b[0][row])
            and np.array_equal(a[1][0], b[1][row], equal_nan=True))


_CDR_LITTLE_ENDIAN = b'\x00\x01'


def _fixed_layout_positions(data):
    """Decode TrackedPositions payloads all at once when they share one layout, else None.

    CDR (little endian, after the 4-byte encapsulation header): stamp sec int32 and nanosec
    uint32, frame_id (uint32 length L counting the NUL, then L bytes), then aligned to 8:
    frame_index uint64, slider and stator position float64, slider and stator quality
    float32, slider_valid and stator_valid bool. Equal payload lengths, encapsulation and L
    make every field sit at the same offset in every message.
    """
    size = len(data[0])
    if size < 16 or any(len(d) != size for d in data):
        return None
    joined = b''.join(data)
    raw = np.frombuffer(joined, dtype=np.uint8).reshape(len(data), size)
    text = int.from_bytes(data[0][12:16], 'little')
    body = 8 * -(-(12 + text) // 8)  # frame_index offset, from the end of the encapsulation
    if 4 + body + 34 > size:
        return None
    if not (np.all(raw[:, :2] == np.frombuffer(_CDR_LITTLE_ENDIAN, np.uint8))
            and np.all(raw[:, 12:16].copy().view('<u4')[:, 0] == text)):
        return None
    layout = np.dtype({'names': ['sec', 'nanosec', 'slider', 'stator', 'slider_quality',
                                 'stator_quality', 'slider_valid', 'stator_valid'],
                       'formats': ['<i4', '<u4', '<f8', '<f8', '<f4', '<f4', 'u1', 'u1'],
                       'offsets': [4, 8, 4 + body + 8, 4 + body + 16, 4 + body + 24,
                                   4 + body + 28, 4 + body + 32, 4 + body + 33],
                       'itemsize': size})
    fields = np.frombuffer(joined, dtype=layout)
    stamps = fields['sec'].astype(np.int64) * 1_000_000_000 + fields['nanosec']
    values = np.column_stack([
        np.where(fields['stator_valid'] != 0, fields['stator'], math.nan),
        np.where(fields['slider_valid'] != 0, fields['slider'], math.nan),
        fields['slider_quality'].astype(float), fields['stator_quality'].astype(float)])
    return stamps, values


def _typestore(bag, type_name):
    """Return a rosbags typestore with the types of the bag's own schemas registered."""
    if os.path.isdir(bag.path):
        # AnyReader registers every type from the schemas stored in the bag (and checks them
        # against the recorded type hashes); keep its typestore after closing it.
        with AnyReader([Path(bag.path)]) as reader:
            return reader.typestore
    store = get_typestore(Stores.EMPTY)
    store.register(get_types_from_msg(bag.definition(type_name), type_name))
    return store


def _deserialized(bag, topic):
    """Yield the messages of one topic, in log-time order, deserialized by rosbags."""
    type_name = bag.topics[topic].type
    store = _typestore(bag, type_name)
    for message in bag.messages(topic):
        yield store.deserialize_cdr(message.data, type_name)
