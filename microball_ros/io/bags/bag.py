"""The Bag reader: open a rosbag2 bag (a directory or one .mcap file) and read its messages.

``open_bag`` checks a bag and reads its summary, never writing: topics, types, counts, QoS,
time range, and what the recording kept about itself (custom_data, with the platform
fingerprint, and ros_distro), from metadata.yaml or else from the MCAP files' own 'rosbag2'
records. Every problem is a BagError with a one-line message that says what to do (a killed
recorder leaves a file without summary and a cut last chunk: ``microball reindex DIR``).
``Bag.messages()`` yields the serialized messages of all files merged in log-time order,
``Bag.message_data()`` one topic's payloads in bulk, both from CRC-checked chunks.
"""

import heapq
import os
import time
from typing import NamedTuple

from microball_ros.core.errors import BagError
from microball_ros.io import fingerprint
from microball_ros.io.bags.mcap_file import (
    MAGIC,
    damage_report,
    file_errors,
    mcap_files_in,
    one_line,
    open_mcap_file,
)
from microball_ros.io.bags.metadata import (
    METADATA_FILE,
    custom_data_of,
    load_metadata_yaml,
    topic_qos_of,
)


class TopicInfo(NamedTuple):
    """One topic of a bag: name, message type, message count, offered QoS profiles (YAML)."""

    name: str
    type: str
    count: int
    qos_profiles_yaml: str


class BagMessage(NamedTuple):
    """One recorded message: topic, type, CDR bytes, log (receive) and publish times in ns."""

    topic: str
    type: str
    data: bytes
    log_time_ns: int
    publish_time_ns: int




class Bag:
    """An opened, checked bag: its files, topics and time range; messages read on demand.

    Attributes: ``path``, ``files`` (.mcap paths), ``topics`` ({name: TopicInfo}),
    ``start_ns``, ``end_ns``, ``message_count``, ``ros_distro``, ``storage_identifier``,
    ``size`` (bytes), ``metadata`` (the metadata.yaml mapping, or None for a lone .mcap),
    ``custom_data`` (metadata.yaml's, else the last file's 'rosbag2' record's: a dict of
    strings) and ``platform`` (the fingerprint in it).
    """

    storage_identifier = 'mcap'

    def __init__(self, path, files, metadata=None):
        self.path = path
        self.files = [f.path for f in files]
        self.metadata = metadata
        self._files = files
        self.size = sum(f.size for f in files)
        # QoS where a channel lacks it: metadata.yaml, else the files' own 'rosbag2' records.
        qos_known = {}
        for information in [*(f.rosbag2 for f in files), metadata]:
            qos_known.update(topic_qos_of(information))
        topics = {}
        for mcap_file in files:
            for cid, channel in mcap_file.channels.items():
                count = mcap_file.counts.get(cid, 0)
                if channel.topic in topics:
                    known = topics[channel.topic]
                    topics[channel.topic] = known._replace(count=known.count + count)
                    continue
                qos = channel.metadata.get('offered_qos_profiles', '') or qos_known.get(
                    channel.topic, '')
                topics[channel.topic] = TopicInfo(channel.topic, mcap_file.type_of(cid), count,
                                                  qos)
        self.topics = topics
        self.message_count = sum(t.count for t in topics.values())
        starts = [f.start_ns for f in files if f.start_ns is not None]
        ends = [f.end_ns for f in files if f.end_ns is not None]
        self.start_ns = min(starts) if starts else 0
        self.end_ns = max(ends) if ends else 0
        self.ros_distro = ((metadata or {}).get('ros_distro')
                           or next((f.ros_distro for f in reversed(files) if f.ros_distro), None)
                           or 'unknown')
        self.custom_data = custom_data_of(metadata) or next(
            (custom_data_of(f.rosbag2) for f in reversed(files) if custom_data_of(f.rosbag2)),
            {})

    @property
    def platform(self):
        """Return the platform fingerprint the recording kept (a dict), or None if it has none.

        It is ``fingerprint.from_custom_data(bag.custom_data)``: compare it with
        ``fingerprint.fingerprint()`` to know whether numbers can agree byte for byte.
        """
        return fingerprint.from_custom_data(self.custom_data)

    @property
    def duration_ns(self):
        """Return end_ns - start_ns."""
        return self.end_ns - self.start_ns

    def messages(self, topics=None):
        """Yield BagMessage(topic, type, data, log_time_ns, publish_time_ns) in log-time order.

        ``topics``: a topic name or an iterable of names (None: all). Raise BagError on a
        corrupted chunk.
        """
        if isinstance(topics, str):
            topics = [topics]
        wanted = None if topics is None else set(topics)
        streams = []
        for number, mcap_file in enumerate(self._files):
            channel_ids = {cid for cid, channel in mcap_file.channels.items()
                           if wanted is None or channel.topic in wanted}
            if channel_ids:
                streams.append(self._file_messages(number, mcap_file, channel_ids))
        yield from heapq.merge(*streams, key=lambda m: m.log_time_ns)

    def message_data(self, topic):
        """Return the serialized messages of one topic as a list of bytes, in file order.

        A bulk read for analysis (no log-time merge); the same checks as messages().
        """
        data = []
        for mcap_file in self._files:
            channel_ids = {cid for cid, channel in mcap_file.channels.items()
                           if channel.topic == topic}
            if channel_ids:
                with file_errors(mcap_file):
                    data.extend(mcap_file.iter_data(channel_ids))
        return data

    def _file_messages(self, number, mcap_file, channel_ids):
        names = {cid: (mcap_file.topic_of(cid), mcap_file.type_of(cid)) for cid in channel_ids}
        with file_errors(mcap_file):
            for record in mcap_file.iter_messages(channel_ids):
                topic, type_name = names[record.channel_id]
                yield BagMessage(topic, type_name, record.data, record.log_time,
                                 record.publish_time)

    def definition(self, type_name):
        """Return the schema text (ros2msg) the bag stores for a message type."""
        for mcap_file in self._files:
            for schema in mcap_file.schemas.values():
                if schema.name == type_name:
                    return schema.data.decode('utf-8')
        raise BagError(f'{self.path}: no schema for message type {type_name!r} in the bag')

    def info_lines(self):
        """Return the lines ``ros2 bag info`` prints for this bag."""
        indent = ' ' * 19
        names = [os.path.basename(f) for f in self.files]
        lines = [f'Files:             {names[0]}'] + [indent + n for n in names[1:]]
        lines += [
            f'Bag size:          {_format_size(self.size)}',
            f'Storage id:        {self.storage_identifier}',
            f'ROS Distro:        {self.ros_distro}',
            f'Duration:          {_format_seconds(self.duration_ns)}s',
            f'Start:             {_format_time(self.start_ns)}',
            f'End:               {_format_time(self.end_ns)}',
            f'Messages:          {self.message_count}',
        ]
        topic_lines = [f'Topic: {t.name} | Type: {t.type} | Count: {t.count} | '
                       f'Serialization Format: cdr' for t in self.topics.values()]
        if not topic_lines:
            topic_lines = ['']
        lines.append(f'Topic information: {topic_lines[0]}')
        lines += [indent + line for line in topic_lines[1:]]
        return lines


def _format_size(size):
    units = ['B', 'KiB', 'MiB', 'GiB', 'TiB']
    value, index = float(size), 0
    while value >= 1024 and index < len(units) - 1:
        value /= 1024
        index += 1
    return f'{value:.0f} B' if index == 0 else f'{value:.1f} {units[index]}'


def _format_seconds(nanoseconds):
    return f'{nanoseconds // 1_000_000_000}.{nanoseconds % 1_000_000_000:09d}'


def _format_time(nanoseconds):
    local = time.localtime(nanoseconds // 1_000_000_000)
    day = time.strftime('%b %e %Y %H:%M:%S', local)
    return f'{day}.{nanoseconds % 1_000_000_000:09d} ({_format_seconds(nanoseconds)})'


def open_bag(path):
    """Open a bag directory (with metadata.yaml) or a single .mcap file; never writes.

    Raise BagError (one line) for a missing path, a directory that is not a bag, a missing
    metadata.yaml, a truncated or corrupted file (saying how far it is readable) and a bag
    without messages.
    """
    path = os.fspath(path)
    try:
        return _open_bag(path)
    except OSError as error:
        raise BagError(f'{path}: {error.strerror or one_line(error)}') from None


def _open_bag(path):
    if not os.path.exists(path):
        raise BagError(f'{path}: no such file or directory')
    if os.path.isdir(path):
        directory = path
        found = mcap_files_in(directory)
        if not os.path.isfile(os.path.join(directory, METADATA_FILE)):
            if not found:
                raise BagError(f'{path}: not a bag (no {METADATA_FILE} and no .mcap file)')
            problems = []
            for name in found:
                scan_result = damage_report(name)
                if scan_result is not None:
                    problems.append(f'{os.path.basename(name)} is {scan_result}')
            if problems:
                raise BagError(f'{path}: no {METADATA_FILE}, and {"; ".join(problems)}; was the '
                               f'recorder killed? run `microball reindex {path}` to recover it')
            names = ', '.join(os.path.basename(n) for n in found)
            raise BagError(f'{path}: no {METADATA_FILE} next to {names}; run '
                           f'`microball reindex {path}` to rebuild it')
        metadata = load_metadata_yaml(directory)
        storage = metadata.get('storage_identifier')
        if storage != 'mcap':
            raise BagError(f'{path}: storage {storage!r} is not supported (only mcap)')
        if metadata.get('compression_mode') not in (None, '', 'none', 'None'):
            raise BagError(f'{path}: rosbag2 {metadata["compression_mode"]} compression is not '
                           f'supported (MCAP chunk compression is)')
        files = []
        for relative in metadata['relative_file_paths']:
            file_path = os.path.join(directory, os.path.basename(str(relative)))
            if not os.path.isfile(file_path):
                raise BagError(f'{path}: {METADATA_FILE} lists {relative}, which is missing')
            files.append(open_mcap_file(file_path, directory))
        if not files:
            raise BagError(f'{path}: {METADATA_FILE} lists no files')
    else:
        directory = os.path.dirname(os.path.abspath(path))
        metadata = None
        if not path.endswith('.mcap'):
            with open(path, 'rb') as handle:
                if handle.read(8) != MAGIC:
                    raise BagError(f'{path}: not a bag (neither a directory nor an MCAP file)')
        files = [open_mcap_file(path, directory)]
    bag = Bag(path, files, metadata)
    if bag.message_count == 0:
        raise BagError(f'{path}: the bag has no messages')
    return bag


