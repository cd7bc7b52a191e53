"""rosbag2 bag metadata: the metadata.yaml file, the MCAP 'rosbag2' record, and the ROS distro.

A rosbag2 bag describes itself twice: ``metadata.yaml`` (``rosbag2_bagfile_information``,
version 9) beside its files, and, inside each MCAP file, a Metadata record named ``rosbag2``
whose ``serialized_metadata`` is the same mapping as YAML. rosbag2 writes that record when a
file opens (custom_data and ros_distro already known, no topics yet) and again when it closes
(ros2/rosbag2: SequentialWriter::open and ::close call MCAPStorage::update_metadata); a reader
applies every record in file order, so the last one wins (MCAPStorage::read_metadata). This
module builds, writes and parses both forms, and finds the ROS distro to put in them:
``ROS_DISTRO`` as rosbag2 does, else the distro of the installed rclpy.
"""

from importlib.metadata import PackageNotFoundError, version
import os
import re
import sys

import yaml

from microball_ros.core.errors import BagError
from microball_ros.io.bags.schema import parse_qos_profiles, qos_profiles_yaml

METADATA_VERSION = 9
METADATA_FILE = 'metadata.yaml'
RECORD_NAME = 'rosbag2'
MESSAGE_ENCODING = 'cdr'

# rclpy's major.minor release series of each ROS 2 distribution: a distro branches rclpy with its
# own series and keeps it for its lifetime (ros2/rclpy branches; kilted from its release packages).
# Rolling's development series in between are not listed: they belong to no distro.
RCLPY_SERIES = {(1, 0): 'foxy', (1, 9): 'galactic', (3, 3): 'humble', (4, 1): 'iron',
                (7, 1): 'jazzy', (9, 1): 'kilted'}


def _rclpy_version():
    """Return the installed rclpy's version string (PyPI wheel or ament package.xml), or None."""
    try:
        return version('ros-rclpy')
    except PackageNotFoundError:
        pass
    prefixes = [p for p in os.environ.get('AMENT_PREFIX_PATH', '').split(os.pathsep) if p]
    for prefix in [*prefixes, sys.prefix]:
        try:
            with open(os.path.join(prefix, 'share', 'rclpy', 'package.xml'),
                      encoding='utf-8') as handle:
                match = re.search(r'<version>\s*([^<\s]+)\s*</version>', handle.read())
        except OSError:
            continue
        if match:
            return match.group(1)
    return None


def _distro_from_ament_index():
    """Return the distro the ros_environment package of a sourced ROS install names, or None."""
    prefixes = [p for p in os.environ.get('AMENT_PREFIX_PATH', '').split(os.pathsep) if p]
    for prefix in [*prefixes, sys.prefix]:
        path = os.path.join(prefix, 'share', 'ros_environment', 'environment', '1.ros_distro.dsv')
        try:
            with open(path, encoding='utf-8') as handle:
                for line in handle:
                    parts = line.strip().split(';')
                    if len(parts) == 3 and parts[1] == 'ROS_DISTRO' and parts[2]:
                        return parts[2]
        except OSError:
            continue
    return None


def ros_distro():
    """Return the ROS distro a bag written now records.

    ``ROS_DISTRO`` when set (what rosbag2 stores); else what the ros_environment package of a
    ROS install sets it to; else the distro whose rclpy release series is installed (a venv
    with ROS from PyPI wheels sets nothing); else '' (rosbag2 also stores '' when unset).
    """
    distro = os.environ.get('ROS_DISTRO', '').strip()
    if distro:
        return distro
    distro = _distro_from_ament_index()
    if distro:
        return distro
    found = re.match(r'(\d+)\.(\d+)', _rclpy_version() or '')
    if found:
        return RCLPY_SERIES.get((int(found.group(1)), int(found.group(2))), '')
    return ''


def bag_metadata(files, topics, *, custom_data=None, ros_distro=''):
    """Return the rosbag2_bagfile_information mapping (metadata version 9).

    ``files``: list of dicts with path (relative to the bag), start_ns, end_ns, message_count.
    ``topics``: list of dicts with name, type, qos_profiles_yaml, type_hash, message_count.
    """
    counted = [f for f in files if f['message_count']]
    start = min((f['start_ns'] for f in counted), default=0)
    end = max((f['end_ns'] for f in counted), default=0)
    return {
        'version': METADATA_VERSION,
        'storage_identifier': 'mcap',
        'duration': {'nanoseconds': end - start},
        'starting_time': {'nanoseconds_since_epoch': start},
        'message_count': sum(f['message_count'] for f in files),
        'topics_with_message_count': [
            {
                'topic_metadata': {
                    'name': topic['name'],
                    'type': topic['type'],
                    'serialization_format': MESSAGE_ENCODING,
                    'offered_qos_profiles': parse_qos_profiles(topic['qos_profiles_yaml']),
                    'type_description_hash': topic.get('type_hash', ''),
                },
                'message_count': topic['message_count'],
            }
            for topic in topics
        ],
        'compression_format': '',
        'compression_mode': '',
        'relative_file_paths': [f['path'] for f in files],
        'files': [
            {
                'path': f['path'],
                'starting_time': {'nanoseconds_since_epoch': f['start_ns'] if f['message_count']
                                  else 0},
                'duration': {'nanoseconds': (f['end_ns'] - f['start_ns'])
                             if f['message_count'] else 0},
                'message_count': f['message_count'],
            }
            for f in files
        ],
        'custom_data': dict(custom_data or {}),
        'ros_distro': ros_distro or '',
    }


def dump_yaml(data):
    """Return YAML text in the key order given (block style, like rosbag2's yaml-cpp output)."""
    return yaml.safe_dump(data, sort_keys=False, default_flow_style=False, allow_unicode=True)


def record_fields(information):
    """Return the key-value map of the MCAP 'rosbag2' Metadata record for a mapping."""
    return {'serialized_metadata': dump_yaml(information).strip()}


def parse_record(fields):
    """Return the mapping a 'rosbag2' Metadata record's key-value map carries ({} if none).

    ``ros_distro`` falls back on the record's ``ROS_DISTRO`` key (older rosbag2 wrote it there).
    """
    try:
        information = yaml.safe_load((fields or {}).get('serialized_metadata') or '') or {}
    except yaml.YAMLError:
        information = {}
    if not isinstance(information, dict):
        information = {}
    if not information.get('ros_distro') and (fields or {}).get('ROS_DISTRO'):
        information['ros_distro'] = fields['ROS_DISTRO']
    return information


def custom_data_of(information):
    """Return the custom_data of a metadata mapping as a dict of strings ({} if none)."""
    custom = (information or {}).get('custom_data') or {}
    if not isinstance(custom, dict):
        return {}
    return {str(key): '' if value is None else str(value) for key, value in custom.items()}


def topic_qos_of(information):
    """Return {topic: offered QoS profiles as a YAML string} from a metadata mapping."""
    qos = {}
    for entry in (information or {}).get('topics_with_message_count') or []:
        topic = (entry or {}).get('topic_metadata') or {}
        text = qos_text(topic.get('offered_qos_profiles', ''))
        if topic.get('name') and text:
            qos[topic['name']] = text
    return qos


def qos_text(value):
    """Return offered_qos_profiles as the YAML string channel metadata holds ('' if unusable)."""
    if isinstance(value, str):
        return value
    try:
        return qos_profiles_yaml(value or [])
    except (KeyError, TypeError, ValueError, AttributeError):
        return ''


def write_metadata_yaml(directory, information):
    """Write <directory>/metadata.yaml atomically (temporary file, fsync, rename)."""
    path = os.path.join(directory, METADATA_FILE)
    temporary = path + '.tmp'
    with open(temporary, 'w', encoding='utf-8') as handle:
        handle.write(dump_yaml({'rosbag2_bagfile_information': information}))
        handle.flush()
        os.fsync(handle.fileno())
    os.replace(temporary, path)
    return path


def load_metadata_yaml(directory):
    """Return the rosbag2_bagfile_information mapping of <directory>/metadata.yaml.

    Raise BagError (saying to run ``microball reindex``) if it is missing or unreadable.
    """
    path = os.path.join(directory, METADATA_FILE)
    try:
        with open(path, encoding='utf-8') as handle:
            document = yaml.safe_load(handle)
        information = document['rosbag2_bagfile_information']
        paths = information['relative_file_paths']
        if not isinstance(paths, list):
            raise TypeError('relative_file_paths is not a list')
    except (OSError, yaml.YAMLError, KeyError, TypeError) as error:
        reason = (str(error).strip() or type(error).__name__).splitlines()[0]
        raise BagError(f'{path}: unreadable ({reason}); run `microball reindex '
                       f'{directory}` to rebuild it') from None
    return information
