"""Write rosbag2 bags: a directory with one MCAP file and a metadata.yaml (no rclpy needed).

The layout is the one rosbag2_storage_mcap writes (ros2/rosbag2, rosbag2_storage_mcap/src/
mcap_storage.cpp): MCAP profile ``ros2``; one schema per type, encoding ``ros2msg``
(schema.message_definition); one channel per topic, message encoding ``cdr``, channel metadata
``offered_qos_profiles`` (a YAML string) and ``topic_type_hash``; at the end a Metadata record
named ``rosbag2`` whose ``serialized_metadata`` is the bag metadata as YAML, so that rosbag2
reads the QoS strings as version 9; and ``metadata.yaml`` (rosbag2_bagfile_information,
version 9) next to the file.

Crash safety: messages are grouped in chunks (CRC-checked, optionally compressed); flush()
closes the current chunk and fsyncs, so a killed recorder loses only what came after the last
flush(). reader.reindex() rebuilds such a bag.
"""

from importlib.metadata import PackageNotFoundError, version
import os

from mcap.writer import CompressionType, Writer
import yaml

from microball_ros import __version__ as _package_version
from microball_ros.io.bags.schema import (
    BagError,
    message_definition,
    normalize_type_name,
    parse_qos_profiles,
    type_hash,
)

METADATA_VERSION = 9
ROS_DISTRO = 'kilted'
PROFILE = 'ros2'
SCHEMA_ENCODING = 'ros2msg'
MESSAGE_ENCODING = 'cdr'

_COMPRESSION = {None: CompressionType.NONE, '': CompressionType.NONE, 'none': CompressionType.NONE,
                'zstd': CompressionType.ZSTD, 'lz4': CompressionType.LZ4}


def _mcap_version():
    try:
        return version('mcap')
    except PackageNotFoundError:  # pragma: no cover - mcap is a dependency
        return 'unknown'


def library_string():
    """Return the MCAP header's library field: 'microball_ros <version>; mcap <version>'."""
    return f'microball_ros {_package_version}; mcap {_mcap_version()}'


def compression_type(compression):
    """Map None, 'zstd' or 'lz4' to the mcap CompressionType, or raise BagError."""
    try:
        return _COMPRESSION[compression]
    except (KeyError, TypeError):
        raise BagError(f'unknown compression {compression!r} (use none, zstd or lz4)') from None


def bag_metadata(files, topics, *, custom_data=None, ros_distro=ROS_DISTRO):
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
        'ros_distro': ros_distro,
    }


def dump_yaml(data):
    """Return YAML text in the key order given (block style, like rosbag2's yaml-cpp output)."""
    return yaml.safe_dump(data, sort_keys=False, default_flow_style=False, allow_unicode=True)


def write_metadata_yaml(directory, information):
    """Write <directory>/metadata.yaml atomically (temporary file, fsync, rename)."""
    path = os.path.join(directory, 'metadata.yaml')
    temporary = path + '.tmp'
    with open(temporary, 'w', encoding='utf-8') as handle:
        handle.write(dump_yaml({'rosbag2_bagfile_information': information}))
        handle.flush()
        os.fsync(handle.fileno())
    os.replace(temporary, path)
    return path


class McapFileWriter:
    """One rosbag2-style MCAP file: schemas per type, channels per topic, chunked messages.

    The building block of BagWriter and of reader.reindex; ``add_channel`` takes ready-made
    schema text and channel metadata so that a rebuilt file keeps what the original recorded.
    """

    def __init__(self, path, *, compression='zstd', chunk_size=1024 * 1024):
        self.path = path
        self._file = open(path, 'xb')
        try:
            self._mcap = Writer(self._file, chunk_size=int(chunk_size),
                                compression=compression_type(compression))
            self._mcap.start(profile=PROFILE, library=library_string())
        except BaseException:
            self._file.close()
            raise
        self._schema_ids = {}
        self._channels = {}  # topic -> dict(id, type, qos_profiles_yaml, type_hash)
        self._sequence = {}
        self.counts = {}
        self.start_ns = None
        self.end_ns = None
        self.closed = False

    @property
    def topics(self):
        """Return the registered topics as dicts (name, type, qos_profiles_yaml, type_hash)."""
        return [dict(name=name, **{k: v for k, v in info.items() if k != 'id'})
                for name, info in self._channels.items()]

    def add_channel(self, topic, type_name, definition, *, qos_profiles_yaml='',
                    topic_type_hash='', schema_encoding=SCHEMA_ENCODING):
        """Register the schema (once per type) and the channel (once per topic); return its id."""
        if topic in self._channels:
            known = self._channels[topic]
            if known['type'] != type_name:
                raise BagError(f'topic {topic} was added as {known["type"]}, not {type_name}')
            return known['id']
        if type_name not in self._schema_ids:
            self._schema_ids[type_name] = self._mcap.register_schema(
                name=type_name, encoding=schema_encoding, data=definition.encode('utf-8'))
        metadata = {'offered_qos_profiles': qos_profiles_yaml or '',
                    'topic_type_hash': topic_type_hash or ''}
        channel_id = self._mcap.register_channel(
            topic=topic, message_encoding=MESSAGE_ENCODING,
            schema_id=self._schema_ids[type_name], metadata=metadata)
        self._channels[topic] = {'id': channel_id, 'type': type_name,
                                 'qos_profiles_yaml': qos_profiles_yaml or '',
                                 'type_hash': topic_type_hash or ''}
        self._sequence[channel_id] = 0
        self.counts[topic] = 0
        return channel_id

    def write(self, topic, data, log_time_ns, publish_time_ns):
        """Append one serialized message to the current chunk."""
        try:
            channel_id = self._channels[topic]['id']
        except KeyError:
            raise BagError(f'topic {topic} was not added to the bag before writing') from None
        self._sequence[channel_id] += 1
        log_time_ns = int(log_time_ns)
        self._mcap.add_message(channel_id=channel_id, log_time=log_time_ns, data=bytes(data),
                               publish_time=int(publish_time_ns),
                               sequence=self._sequence[channel_id])
        self.counts[topic] += 1
        self.start_ns = log_time_ns if self.start_ns is None else min(self.start_ns, log_time_ns)
        self.end_ns = log_time_ns if self.end_ns is None else max(self.end_ns, log_time_ns)

    def flush(self):
        """Close the current chunk, write it out and fsync the file."""
        # mcap >= 1.3's public Writer.flush() finishes the chunk in progress and flushes the
        # stream; it does not fsync, so do that here.
        self._mcap.flush()
        self._file.flush()
        os.fsync(self._file.fileno())

    @property
    def message_count(self):
        """Return the number of messages written so far."""
        return sum(self.counts.values())

    def file_information(self, relative_path):
        """Return the per-file dict bag_metadata() expects."""
        return {'path': relative_path, 'start_ns': self.start_ns or 0,
                'end_ns': self.end_ns or 0, 'message_count': self.message_count}

    def close(self, rosbag2_metadata=None):
        """Write the Metadata record (if given), the summary and the footer; fsync; close."""
        if self.closed:
            return
        try:
            if rosbag2_metadata is not None:
                self._mcap.add_metadata('rosbag2', {
                    'serialized_metadata': dump_yaml(rosbag2_metadata).strip(),
                    'ROS_DISTRO': rosbag2_metadata.get('ros_distro', ROS_DISTRO)})
            self._mcap.finish()
            self._file.flush()
            os.fsync(self._file.fileno())
        finally:
            self._file.close()
            self.closed = True


class BagWriter:
    """Write a rosbag2 bag directory: ``<dir>/<dir name>_0.mcap`` plus ``metadata.yaml``.

    Use as a context manager (closing also on an exception, so what was written stays a
    complete bag)::

        with BagWriter('run1') as bag:
            bag.add_topic('/tracking/positions', 'microball_msgs/msg/TrackedPositions', qos)
            bag.write('/tracking/positions', cdr_bytes, log_time_ns, publish_time_ns)
            bag.flush()  # about once a second: a kill -9 loses at most what follows
    """

    def __init__(self, directory, *, compression='zstd', chunk_size=1024 * 1024):
        compression_type(compression)
        directory = os.path.abspath(directory)
        try:
            if os.path.exists(directory):
                if not os.path.isdir(directory):
                    raise BagError(f'{directory}: exists and is not a directory')
                if os.listdir(directory):
                    raise BagError(f'{directory}: exists and is not empty; choose a new bag '
                                   f'directory')
            else:
                os.makedirs(directory)
            self.directory = directory
            self.compression = compression
            self.relative_path = f'{os.path.basename(directory)}_0.mcap'
            self.path = os.path.join(directory, self.relative_path)
            self._file = McapFileWriter(self.path, compression=compression,
                                        chunk_size=chunk_size)
        except OSError as error:
            raise BagError(f'{directory}: cannot create the bag ({error.strerror or error})'
                           ) from None
        self.custom_data = {}
        self.metadata_path = None

    def __enter__(self):
        return self

    def __exit__(self, *exc_info):
        self.close()
        return False

    @property
    def counts(self):
        """Return {topic: messages written} for every added topic."""
        return dict(self._file.counts)

    @property
    def message_count(self):
        """Return the number of messages written so far."""
        return self._file.message_count

    @property
    def closed(self):
        """Return True once close() has run."""
        return self._file.closed

    def add_topic(self, name, type_name, qos_profiles_yaml=''):
        """Register a topic of a message type ('pkg/msg/Type'); return its MCAP channel id.

        The schema comes from the installed .msg files (BagError for an unknown type); the QoS
        profiles are the YAML string of schema.qos_profiles_yaml(). Adding a topic again
        returns the same id.
        """
        type_name = normalize_type_name(type_name)
        if name in self._file.counts:
            return self._file.add_channel(name, type_name, '')
        parse_qos_profiles(qos_profiles_yaml)
        return self._file.add_channel(name, type_name, message_definition(type_name),
                                      qos_profiles_yaml=qos_profiles_yaml,
                                      topic_type_hash=type_hash(type_name))

    def write(self, topic, data, log_time_ns, publish_time_ns):
        """Write one CDR-serialized message (bytes as rclpy gives them with raw=True)."""
        self._file.write(topic, data, log_time_ns, publish_time_ns)

    def flush(self):
        """Close the current chunk and flush + fsync the file (call about once a second)."""
        self._file.flush()

    def metadata(self):
        """Return the rosbag2_bagfile_information mapping for what was written so far."""
        return bag_metadata([self._file.file_information(self.relative_path)],
                            [dict(topic, message_count=self._file.counts[topic['name']])
                             for topic in self._file.topics],
                            custom_data=self.custom_data)

    def close(self):
        """Finish the MCAP file (summary, statistics, indexes), write metadata.yaml.

        Return {topic: message count}. Calling it again does nothing more.
        """
        if not self._file.closed:
            information = self.metadata()
            self._file.close(information)
            self.metadata_path = write_metadata_yaml(self.directory, information)
        return self.counts
