"""Deterministic sample instances of every microball_msgs message (shared by the smoke test).

Each field gets a value derived from its position and type, so a message that loses, swaps or
truncates a field on the way through DDS compares unequal.
"""

import re

from builtin_interfaces.msg import Time
import microball_msgs.msg
from std_msgs.msg import Header

MESSAGE_TYPES = [
    microball_msgs.msg.BenchState,
    microball_msgs.msg.DerivativeEstimate,
    microball_msgs.msg.FrictionModel,
    microball_msgs.msg.ServoCommand,
    microball_msgs.msg.TrackedPositions,
]

_SCALARS = {
    'double': lambda i: 0.1 * i + 1e-7,
    'float': lambda i: 0.5 * i + 0.25,
    'boolean': lambda i: True,
    'string': lambda i: f'value-{i}',
    'uint8': lambda i: i,
    'uint32': lambda i: 1000 + i,
    'int32': lambda i: -1000 - i,
    'uint64': lambda i: 2**40 + i,
}


def _value(type_name, index):
    if type_name == 'std_msgs/Header':
        return Header(stamp=Time(sec=1700000000 + index, nanosec=123456789), frame_id='camera')
    sequence = re.fullmatch(r'sequence<(\w+)>', type_name)
    if sequence:
        return [_SCALARS[sequence.group(1)](index + k) for k in range(3 + index % 4)]
    array = re.fullmatch(r'(\w+)\[(\d+)\]', type_name)
    if array:
        return [_SCALARS[array.group(1)](index + k) for k in range(int(array.group(2)))]
    return _SCALARS[type_name](index)


def sample_message(message_type):
    """Return an instance of message_type with every field set to a distinct value."""
    message = message_type()
    fields = message_type.get_fields_and_field_types()
    for index, (name, type_name) in enumerate(fields.items()):
        setattr(message, name, _value(type_name, index))
    return message


def topic_for(message_type):
    """Return the smoke-test topic of a message type."""
    return f'/smoke/{message_type.__name__}'
