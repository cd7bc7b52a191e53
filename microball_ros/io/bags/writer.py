"""Write rosbag2 bags: a directory with one MCAP file and a metadata.yaml (no rclpy needed).

The layout is the one rosbag2_storage_mcap writes (ros2/rosbag2, rosbag2_storage_mcap/src/
mcap_storage.cpp): MCAP profile ``ros2``; one schema per type, encoding ``ros2msg``
(schema.message_definition); one channel per topic, message encoding ``cdr``, channel metadata
``offered_qos_profiles`` (a YAML string) and ``topic_type_hash``; Metadata records named
``rosbag2`` whose ``serialized_metadata`` is the bag metadata as YAML (version 9); and
``metadata.yaml`` (rosbag2_bagfile_information, version 9) next to the file. As rosbag2's
SequentialWriter does, the ``rosbag2`` record is written when the bag opens (custom_data and
ros_distro, no topics yet) and again when it closes (complete). An MCAP file is append-only, so
a closed file holds both in its data section; only the closing one is in the summary (metadata
index, statistics), so indexed readers see exactly one, and front-to-back readers meet the
complete one last and keep the last, as rosbag2's MCAPStorage::read_metadata does (rosbag2
itself indexes both). metadata.yaml is written at open too, and replaced at close. Every bag's
custom_data carries the platform fingerprint (fingerprint.to_custom_data).

Crash safety: messages are grouped in chunks (CRC-checked, optionally compressed); flush()
closes the current chunk and fsyncs, so a killed recorder loses only what came after the last
flush(), and its bag keeps custom_data (in the open-time record) and its topics (in the
channels). repair.reindex() rebuilds such a bag.
"""

from importlib.metadata import PackageNotFoundError, version
import os

from mcap.data_stream import RecordBuilder
from mcap.records import Metadata
from mcap.writer import CompressionType, Writer

from microball_ros import __version__ as _package_version
from microball_ros.core.errors import BagError
from microball_ros.io import fingerprint
from microball_ros.io.bags.metadata import (
    MESSAGE_ENCODING,
    RECORD_NAME,
    bag_metadata,
    record_fields,
    ros_distro,
    write_metadata_yaml,
)
from microball_ros.io.bags.schema import (
    message_definition,
    normalize_type_name,
    parse_qos_profiles,
    type_hash,
)

PROFILE = 'ros2'
SCHEMA_ENCODING = 'ros2msg'

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

    def write_opening_metadata(self, information):
        """Write a 'rosbag2' Metadata record now, outside the summary, and make it durable.

        What rosbag2's SequentialWriter::open stores (MCAPStorage::update_metadata), so that a
        file whose writer is killed still carries custom_data and ros_distro. The record goes
        straight to the data section (Metadata records are never inside chunks) but, unlike
        mcap's Writer.add_metadata, into neither the metadata index nor the statistics: the
        record close() writes is then the only one an indexed reader (mcap's SeekingReader,
        Foxglove's indexed reader, rosbag2) finds, and a front-to-back reader meets it last.
        """
        self._mcap.flush()  # the header and any chunk in progress go first
        builder = RecordBuilder()
        Metadata(name=RECORD_NAME, metadata=record_fields(information)).write(builder)
        self._file.write(builder.end())
        self._file.flush()
        os.fsync(self._file.fileno())

    def close(self, rosbag2_metadata=None):
        """Write the Metadata record (if given), the summary and the footer; fsync; close."""
        if self.closed:
            return
        try:
            if rosbag2_metadata is not None:
                self._mcap.add_metadata(RECORD_NAME, record_fields(rosbag2_metadata))
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

        with BagWriter('run1', custom_data={'note': 'bench 3'}) as bag:
            bag.add_topic('/tracking/positions', 'microball_msgs/msg/TrackedPositions', qos)
            bag.write('/tracking/positions', cdr_bytes, log_time_ns, publish_time_ns)
            bag.flush()  # about once a second: a kill -9 loses at most what follows

    ``custom_data`` (strings to strings) is known at open, so a bag whose writer is killed
    keeps it; the platform fingerprint (key fingerprint.CUSTOM_DATA_KEY) is merged in unless
    given. Entries added to ``bag.custom_data`` later are in the bag once it closes.
    """

    def __init__(self, directory, *, compression='zstd', chunk_size=1024 * 1024,
                 custom_data=None, distro=None):
        compression_type(compression)
        custom = {**fingerprint.to_custom_data(), **dict(custom_data or {})}
        if not all(isinstance(k, str) and isinstance(v, str) for k, v in custom.items()):
            raise BagError('custom_data must map strings to strings')
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
        self.custom_data = custom
        self.ros_distro = ros_distro() if distro is None else distro
        # What rosbag2's SequentialWriter::open stores: custom_data and ros_distro, no topics.
        information = self.metadata()
        try:
            self._file.write_opening_metadata(information)
            self.metadata_path = write_metadata_yaml(self.directory, information)
        except OSError as error:
            self._file.close()
            raise BagError(f'{directory}: cannot write the bag ({error.strerror or error})'
                           ) from None

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
                            custom_data=self.custom_data, ros_distro=self.ros_distro)

    def close(self):
        """Finish the MCAP file (final 'rosbag2' record, summary, indexes), rewrite metadata.yaml.

        Return {topic: message count}. Calling it again does nothing more.
        """
        if not self._file.closed:
            information = self.metadata()
            self._file.close(information)
            self.metadata_path = write_metadata_yaml(self.directory, information)
        return self.counts
