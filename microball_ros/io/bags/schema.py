"""Message schemas and QoS text for rosbag2 MCAP files, from the installed .msg files (no rclpy).

A rosbag2 MCAP file stores one schema per message type, encoding ``ros2msg``: the type's .msg
text, then each dependency (transitively, depth first, in sorted order, each once) after a line
of 80 ``=`` and a line ``MSG: <type as written in the field>``, exactly as rosbag2's
LocalMessageDefinitionSource builds it (docs/message_definition_encoding.md in ros2/rosbag2).
The .msg files are found through the ament index (``share/<pkg>/msg/<Type>.msg``), in
AMENT_PREFIX_PATH or, when that is unset (a venv with ROS from PyPI wheels), in ``sys.prefix``.

QoS profiles travel as rosbag2 writes them for metadata version 9: a YAML list of mappings with
policy names as lower-case strings (``keep_last``, ``reliable``, ...) and durations as
``{sec, nsec}``; a string of that YAML in the MCAP channel metadata, the list itself in
metadata.yaml.
"""

import json
import os
import re
import sys

import yaml

from microball_ros.core.errors import BagError

DELIMITER = '=' * 80 + '\n'

PRIMITIVE_TYPES = frozenset((
    'bool', 'byte', 'char', 'float32', 'float64', 'int8', 'uint8', 'int16', 'uint16', 'int32',
    'uint32', 'int64', 'uint64', 'string', 'wstring'))

_NAME = r'[A-Za-z][A-Za-z0-9_]*'
_TYPE_NAME = re.compile(rf'^({_NAME})/(?:(msg)/)?({_NAME})$')
_MAX_DEPTH = 50

QOS_KEYS = ('history', 'depth', 'reliability', 'durability', 'deadline', 'lifespan', 'liveliness',
            'liveliness_lease_duration', 'avoid_ros_namespace_conventions')
_DURATION_KEYS = ('deadline', 'lifespan', 'liveliness_lease_duration')


def _split_type_name(type_name):
    match = _TYPE_NAME.match(type_name or '')
    if not match:
        raise BagError(f'unknown message type {type_name!r} (expected pkg/msg/Type)')
    return match.group(1), match.group(3)


def _share_directories(package):
    """Yield candidate share directories of a package: the ament index, then sys.prefix."""
    try:
        from ament_index_python.packages import get_package_share_directory

        yield get_package_share_directory(package)
    except (LookupError, OSError, ImportError):
        # PackageNotFoundError is a KeyError; an unset AMENT_PREFIX_PATH is an EnvironmentError.
        pass
    marker = os.path.join(sys.prefix, 'share', 'ament_index', 'resource_index', 'packages',
                          package)
    if os.path.exists(marker):
        yield os.path.join(sys.prefix, 'share', package)


def _interface_file(type_name, extension):
    package, name = _split_type_name(type_name)
    for share in _share_directories(package):
        path = os.path.join(share, 'msg', name + extension)
        if os.path.isfile(path):
            return path
    return None


def msg_file(type_name):
    """Return the path of the installed .msg file of a message type, or raise BagError."""
    path = _interface_file(type_name, '.msg')
    if path is None:
        raise BagError(f'unknown message type {type_name!r}: no {type_name.split("/")[-1]}.msg '
                       f'in the share directory of package {type_name.split("/")[0]!r}')
    return path


def normalize_type_name(type_name):
    """Return 'pkg/msg/Type' for 'pkg/Type' or 'pkg/msg/Type'."""
    package, name = _split_type_name(type_name)
    return f'{package}/msg/{name}'


def field_types(msg_text, package):
    """Return the sorted set of non-primitive field types a .msg text refers to.

    Types are returned as written ('std_msgs/Header'), or prefixed with the package when written
    without one ('Header' in package std_msgs -> 'std_msgs/Header'), as rosbag2 names them.
    """
    dependencies = set()
    for line in msg_text.splitlines():
        line = line.split('#', 1)[0].strip()
        if not line:
            continue
        token = line.split()[0]
        token = re.sub(r'\[[^\]]*\]$', '', token)  # arrays: T[], T[3], T[<=3]
        token = re.sub(r'<=\d+$', '', token)  # bounded strings: string<=10
        if token in PRIMITIVE_TYPES:
            continue
        dependencies.add(token if '/' in token else f'{package}/{token}')
    return sorted(dependencies)


def message_definition(type_name):
    """Return the ros2msg schema text of a message type (its .msg text and its dependencies).

    The top-level .msg text comes first; every dependency follows once, depth first in sorted
    order, after ``'=' * 80`` and ``MSG: pkg/Type`` lines, as rosbag2 and Foxglove write it.
    Raise BagError if a .msg file cannot be found.
    """
    seen = set()

    def expand(name, depth):
        if depth > _MAX_DEPTH:
            raise BagError(f'message type {type_name!r} nests deeper than {_MAX_DEPTH} levels')
        with open(msg_file(name), encoding='utf-8') as handle:
            text = handle.read()
        package = _split_type_name(name)[0]
        for dependency in field_types(text, package):
            key = normalize_type_name(dependency)
            if key in seen:
                continue
            seen.add(key)
            text += '\n' + DELIMITER + f'MSG: {dependency}\n' + expand(dependency, depth + 1)
        return text

    _split_type_name(type_name)
    return expand(type_name, 0)


def type_hash(type_name):
    """Return the RIHS01 type hash rosidl generated for a type (from its .json), or ''."""
    path = _interface_file(type_name, '.json')
    if path is None:
        return ''
    try:
        with open(path, encoding='utf-8') as handle:
            description = json.load(handle)
        wanted = normalize_type_name(type_name)
        for entry in description.get('type_hashes', []):
            if entry.get('type_name') == wanted:
                return str(entry.get('hash_string', ''))
    except (OSError, ValueError, AttributeError):
        pass
    return ''


# rmw enum values (metadata version 8 and older stored these integers) -> version 9 names.
_POLICY_NAMES = {
    'history': ('system_default', 'keep_last', 'keep_all', 'unknown'),
    'reliability': ('system_default', 'reliable', 'best_effort', 'unknown', 'best_available'),
    'durability': ('system_default', 'transient_local', 'volatile', 'unknown', 'best_available'),
    'liveliness': ('system_default', 'automatic', 'manual_by_node', 'manual_by_topic', 'unknown',
                   'best_available'),
}


def _policy_name(policy, value):
    names = _POLICY_NAMES[policy]
    if isinstance(value, int) and not isinstance(value, bool):
        return names[value] if 0 <= value < len(names) else 'unknown'
    name = str(getattr(value, 'name', value)).lower()
    return name if name in names else 'unknown'


def _duration(value):
    if isinstance(value, dict):
        return {'sec': int(value['sec']), 'nsec': int(value['nsec'])}
    nanoseconds = int(getattr(value, 'nanoseconds', value or 0))
    return {'sec': nanoseconds // 1_000_000_000, 'nsec': nanoseconds % 1_000_000_000}


def qos_profile_dict(profile):
    """Return one QoS profile as rosbag2 (metadata version 9) stores it.

    ``profile`` is a mapping with the rosbag2 keys, or an object with the attributes of an
    rclpy QoSProfile (policies as enums, durations as rclpy Durations); no rclpy import here.
    """
    if isinstance(profile, dict):
        values = dict(profile)
    else:
        values = {key: getattr(profile, key) for key in QOS_KEYS}
    return {
        'history': _policy_name('history', values['history']),
        'depth': int(values['depth']),
        'reliability': _policy_name('reliability', values['reliability']),
        'durability': _policy_name('durability', values['durability']),
        'deadline': _duration(values['deadline']),
        'lifespan': _duration(values['lifespan']),
        'liveliness': _policy_name('liveliness', values['liveliness']),
        'liveliness_lease_duration': _duration(values['liveliness_lease_duration']),
        'avoid_ros_namespace_conventions': bool(values['avoid_ros_namespace_conventions']),
    }


def qos_profiles_yaml(profiles):
    """Return the YAML string of a list of QoS profiles, as in rosbag2's channel metadata."""
    dicts = [qos_profile_dict(profile) for profile in profiles]
    if not dicts:
        return ''
    return yaml.safe_dump(dicts, sort_keys=False, default_flow_style=False).strip()


def parse_qos_profiles(text):
    """Parse offered_qos_profiles (a YAML string or an already parsed list) into a list of dicts.

    Accepts the version 9 form (policy names) and the older one (integer enum values, as a
    string). Raise BagError on anything else.
    """
    if text in ('', None):
        return []
    try:
        items = yaml.safe_load(text) if isinstance(text, str) else text
    except yaml.YAMLError as error:
        message = f'offered_qos_profiles is not valid YAML: {error}'.splitlines()[0]
        raise BagError(message) from None
    if items is None:
        return []
    if not isinstance(items, list) or not all(isinstance(item, dict) for item in items):
        raise BagError('offered_qos_profiles is not a list of QoS profiles')
    return items
