"""Read rosbag2 MCAP bags (a bag directory or one .mcap file) without a ROS runtime.

open_bag() checks a bag and reads its summary: topics, types, counts, QoS, time range. It never
writes; every problem is a BagError with a one-line message that says what to do (a killed
recorder leaves a file without summary and a cut last chunk: ``microball reindex DIR``).
Bag.messages() yields the serialized messages in log-time order, checking chunk CRCs.
reindex() is ``ros2 bag reindex`` plus recovery: it keeps every complete chunk of a truncated or
damaged file, writes a complete copy and a fresh metadata.yaml, and keeps the original as
``<name>.mcap.truncated``. read_positions() turns /tracking/positions into a PositionRecord
and read_frames() /camera/image_raw into gray frames, with rosbags (types from the bag's own
schemas); recorded_parameters() returns a node's parameters kept in the bag's metadata.
"""

import contextlib
import heapq
import io
import math
import os
from pathlib import Path
import re
import struct
import time
from typing import NamedTuple

from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.reader import SeekingReader
from mcap.records import Channel, Chunk, DataEnd, Footer, Header, Message, Metadata, Schema
from mcap.stream_reader import get_chunk_data_stream
import numpy as np
from rosbags.highlevel import AnyReader
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
import yaml

from microball_ros.core.records import PositionRecord, check_time_base
from microball_ros.core.tracking import image_to_gray
from microball_ros.io.bags.schema import BagError, parse_qos_profiles, qos_profiles_yaml
from microball_ros.io.bags.writer import (
    ROS_DISTRO,
    McapFileWriter,
    bag_metadata,
    write_metadata_yaml,
)

__all__ = ['Bag', 'BagError', 'BagMessage', 'TopicInfo', 'open_bag', 'read_frames',
           'read_positions', 'recorded_parameters', 'reindex']

MAGIC = b'\x89MCAP0\r\n'
METADATA_FILE = 'metadata.yaml'
TRUNCATED_SUFFIX = '.truncated'
_RECORD_HEAD = struct.Struct('<BQ')
_MESSAGE_FIELDS = struct.Struct('<HIQQ')  # channel id, sequence, log time, publish time
_KNOWN_OPCODES = frozenset(int(op) for op in Opcode)
_PARSERS = {Opcode.HEADER: Header.read, Opcode.SCHEMA: Schema.read,
            Opcode.CHANNEL: Channel.read, Opcode.CHUNK: Chunk.read, Opcode.METADATA: Metadata.read,
            Opcode.DATA_END: DataEnd.read, Opcode.FOOTER: Footer.read}


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


class _Damage(Exception):
    """Where and why reading an MCAP file front to back had to stop."""

    def __init__(self, offset, reason):
        super().__init__(f'at byte {offset}: {reason}')
        self.offset = offset
        self.reason = reason


def _one_line(error):
    text = str(error).strip() or type(error).__name__
    return text.splitlines()[0]


def _natural_key(name):
    return [int(part) if part.isdigit() else part for part in re.split(r'(\d+)', name)]


def _decode_record(opcode, body, offset):
    """Parse one top-level record body with mcap's record classes; _Damage if malformed."""
    try:
        stream = ReadDataStream(io.BytesIO(body))
        if opcode == Opcode.MESSAGE:
            record = Message.read(stream, len(body))
        else:
            record = _PARSERS[opcode](stream)
    except Exception as error:  # noqa: B902 - any parse failure means a damaged record
        raise _Damage(offset, f'malformed {Opcode(opcode).name.lower()} record '
                              f'({_one_line(error)})') from None
    if stream.count > len(body):
        raise _Damage(offset, f'malformed {Opcode(opcode).name.lower()} record')
    return record


def _chunk_records(chunk, offset):
    """Decompress a chunk and check its CRC; return its records or raise _Damage.

    Decompression and CRC are mcap's; the records are split here, each Message with one
    struct call: mcap's field-by-field stream reads cost about 5 us per message, most of the
    time it took to read an hour of positions (0.55 of 1.2 s). Schema and Channel records
    (rare in chunks) are parsed by mcap.
    """
    try:
        stream, length = get_chunk_data_stream(chunk, validate_crc=True)
        data = stream.read(length)
    except Exception as error:  # noqa: B902 - bad CRC, bad compression
        raise _Damage(offset, f'corrupted chunk ({_one_line(error)})') from None
    records = []
    position, end = 0, len(data)
    while position < end:
        if end - position < _RECORD_HEAD.size:
            raise _Damage(offset, 'corrupted chunk (a record cut short)')
        opcode, length = _RECORD_HEAD.unpack_from(data, position)
        body = position + _RECORD_HEAD.size
        position = body + length
        if position > end:
            raise _Damage(offset, 'corrupted chunk (a record longer than the chunk)')
        if opcode == Opcode.MESSAGE:
            if length < _MESSAGE_FIELDS.size:
                raise _Damage(offset, 'corrupted chunk (a message record too short)')
            channel_id, sequence, log_time, publish_time = _MESSAGE_FIELDS.unpack_from(data, body)
            records.append(Message(channel_id=channel_id, log_time=log_time,
                                   data=data[body + _MESSAGE_FIELDS.size:position],
                                   publish_time=publish_time, sequence=sequence))
        elif opcode in (Opcode.SCHEMA, Opcode.CHANNEL):
            records.append(_decode_record(opcode, data[body:position], offset))
    return records


class _Scan:
    """What a front-to-back read of one MCAP file found."""

    def __init__(self, path, size):
        self.path = path
        self.size = size
        self.header = None
        self.schemas = {}
        self.channels = {}
        self.counts = {}
        self.start_ns = None
        self.end_ns = None
        self.compression = None
        self.complete = False  # reached a valid footer and the closing magic
        self.readable_end = 8  # end of the last intact record
        self.damage = None  # _Damage that stopped the read, if any
        self.skipped = []  # _Damage of corrupted chunks skipped (framing intact)
        self.rosbag2_metadata = None

    @property
    def message_count(self):
        return sum(self.counts.values())

    def describe(self):
        """Return e.g. 'readable up to byte 1234 of 5678 (why)' for a damaged file."""
        parts = []
        if self.damage is not None:
            parts.append(f'readable up to byte {self.damage.offset} of {self.size} '
                         f'({self.damage.reason})')
        for skipped in self.skipped:
            parts.append(f'corrupted chunk at byte {skipped.offset}')
        return '; '.join(parts) or 'intact'


def _scan_file(path, on_record=None):
    """Read an MCAP file record by record, stopping cleanly at the first broken record.

    Every chunk is decompressed and CRC-checked; a chunk whose framing is intact but whose
    content is corrupted is skipped (noted in ``skipped``). ``on_record(record)`` receives the
    Schema, Channel and Message records of the data section in file order (messages of intact
    chunks only).
    """
    size = os.path.getsize(path)
    scan = _Scan(path, size)
    with open(path, 'rb') as handle:
        if handle.read(8) != MAGIC:
            scan.readable_end = 0
            scan.damage = _Damage(0, 'not an MCAP file (bad magic)')
            return scan
        offset = 8
        in_data_section = True
        try:
            while True:
                head = handle.read(_RECORD_HEAD.size)
                if not head:
                    raise _Damage(offset, 'file ends without a footer')
                if len(head) < _RECORD_HEAD.size:
                    raise _Damage(offset, 'file ends inside a record header')
                opcode, length = _RECORD_HEAD.unpack(head)
                if opcode not in _KNOWN_OPCODES and opcode < 0x80:
                    raise _Damage(offset, f'unknown record opcode 0x{opcode:02x}')
                end = offset + _RECORD_HEAD.size + length
                if end > size:
                    raise _Damage(offset, f'record of {length} bytes cut off at the end of file')
                body = handle.read(length)
                if opcode in _PARSERS or opcode == Opcode.MESSAGE:
                    record = _decode_record(opcode, body, offset)
                    if isinstance(record, Header):
                        scan.header = record
                    elif isinstance(record, DataEnd):
                        in_data_section = False
                    elif isinstance(record, Footer):
                        if handle.read(8) != MAGIC:
                            raise _Damage(end, 'missing closing magic after the footer')
                        scan.readable_end = end + 8
                        scan.complete = True
                        return scan
                    elif in_data_section:
                        if isinstance(record, Chunk):
                            try:
                                records = _chunk_records(record, offset)
                            except _Damage as damage:
                                scan.skipped.append(damage)
                                records = []
                            if scan.compression is None:
                                scan.compression = record.compression
                        else:
                            records = [record]
                        for inner in records:
                            _note(scan, inner, on_record)
                offset = end
                scan.readable_end = end
        except _Damage as damage:
            scan.damage = damage
    return scan


def _note(scan, record, on_record):
    if isinstance(record, Schema):
        scan.schemas.setdefault(record.id, record)
    elif isinstance(record, Channel):
        scan.channels.setdefault(record.id, record)
    elif isinstance(record, Message):
        scan.counts[record.channel_id] = scan.counts.get(record.channel_id, 0) + 1
        t = record.log_time
        scan.start_ns = t if scan.start_ns is None else min(scan.start_ns, t)
        scan.end_ns = t if scan.end_ns is None else max(scan.end_ns, t)
    elif isinstance(record, Metadata):
        if record.name == 'rosbag2':
            scan.rosbag2_metadata = record.metadata
        return
    else:
        return
    if on_record is not None:
        on_record(record)


class _McapFile:
    """One complete MCAP file of a bag, described by its summary (or a full scan)."""

    def __init__(self, path):
        self.path = path
        self.size = os.path.getsize(path)
        self.ros_distro = None
        self.chunk_indexes = None
        with open(path, 'rb') as handle:
            if handle.read(8) != MAGIC:
                raise BagError(f'{path}: not an MCAP file')
            summary = self._read_summary(handle)
        if summary is None:
            # No usable summary (a killed writer, or a writer that leaves it out): read it all.
            scan = _scan_file(path)
            if not scan.complete or scan.skipped:
                raise _Damage(scan.damage.offset if scan.damage else scan.skipped[0].offset,
                              scan.describe())
            self.header = scan.header
            self.schemas, self.channels, self.counts = scan.schemas, scan.channels, scan.counts
            self.start_ns, self.end_ns = scan.start_ns, scan.end_ns
            self._read_distro(scan.rosbag2_metadata)
        if self.header is None or self.header.profile != 'ros2':
            profile = None if self.header is None else self.header.profile
            raise BagError(f'{path}: not a ROS 2 MCAP file (profile {profile!r}, expected ros2)')

    def _read_summary(self, handle):
        """Read header and summary; None if the file has no complete, consistent summary."""
        try:
            handle.seek(0)
            reader = SeekingReader(handle)
            summary = reader.get_summary()
            if summary is None or summary.statistics is None:
                return None
            self.header = reader.get_header()
            statistics = summary.statistics
            for index in summary.chunk_indexes:
                handle.seek(index.chunk_start_offset)
                opcode, length = _RECORD_HEAD.unpack(handle.read(_RECORD_HEAD.size))
                if opcode != Opcode.CHUNK or length + _RECORD_HEAD.size != index.chunk_length:
                    return None
                if index.chunk_start_offset + index.chunk_length > self.size:
                    return None
            if statistics.message_count and not summary.chunk_indexes:
                return None  # unchunked: no index to read by; a scan handles it
            self.schemas = dict(summary.schemas)
            self.channels = dict(summary.channels)
            self.counts = {cid: int(n) for cid, n in statistics.channel_message_counts.items()}
            for cid in self.channels:
                self.counts.setdefault(cid, 0)
            if statistics.message_count:
                self.start_ns = statistics.message_start_time
                self.end_ns = statistics.message_end_time
            else:
                self.start_ns = self.end_ns = None
            self.chunk_indexes = list(summary.chunk_indexes)
            for metadata in reader.iter_metadata():
                if metadata.name == 'rosbag2':
                    self._read_distro(metadata.metadata)
            return summary
        except Exception:  # noqa: B902 - any failure: no trustworthy summary
            return None

    def _read_distro(self, metadata):
        if not metadata:
            return
        try:
            info = yaml.safe_load(metadata.get('serialized_metadata', '')) or {}
            self.ros_distro = info.get('ros_distro') or metadata.get('ROS_DISTRO')
        except (yaml.YAMLError, AttributeError):
            self.ros_distro = metadata.get('ROS_DISTRO')

    def topic_of(self, channel_id):
        return self.channels[channel_id].topic

    def type_of(self, channel_id):
        channel = self.channels[channel_id]
        schema = self.schemas.get(channel.schema_id)
        return schema.name if schema is not None else ''

    def iter_messages(self, channel_ids):
        """Yield Message records of the given channels in log-time order (ties: file order)."""
        if self.chunk_indexes is None:
            messages = []
            _scan_file(self.path, lambda r: messages.append(r) if isinstance(r, Message)
                       and r.channel_id in channel_ids else None)
            messages.sort(key=lambda m: m.log_time)
            yield from messages
            return
        chunks = sorted(
            (c for c in self.chunk_indexes
             if not c.message_index_offsets or channel_ids & set(c.message_index_offsets)),
            key=lambda c: (c.message_start_time, c.chunk_start_offset))
        heap = []
        position = 0
        with open(self.path, 'rb') as handle:
            while position < len(chunks) or heap:
                while position < len(chunks) and (
                        not heap or chunks[position].message_start_time <= heap[0][0]):
                    index = chunks[position]
                    position += 1
                    for k, record in enumerate(self._load_chunk(handle, index)):
                        if isinstance(record, Message) and record.channel_id in channel_ids:
                            heapq.heappush(heap, (record.log_time, index.chunk_start_offset, k,
                                                  record))
                yield heapq.heappop(heap)[3]

    def iter_data(self, channel_ids):
        """Yield the data of the given channels' messages in file order (bulk reads)."""
        if self.chunk_indexes is None:
            yield from (message.data for message in self.iter_messages(channel_ids))
            return
        chunks = sorted((c for c in self.chunk_indexes
                         if not c.message_index_offsets
                         or channel_ids & set(c.message_index_offsets)),
                        key=lambda c: c.chunk_start_offset)
        with open(self.path, 'rb') as handle:
            for index in chunks:
                for record in self._load_chunk(handle, index):
                    if isinstance(record, Message) and record.channel_id in channel_ids:
                        yield record.data

    def _load_chunk(self, handle, index):
        offset = index.chunk_start_offset
        handle.seek(offset)
        data = handle.read(index.chunk_length)
        if len(data) != index.chunk_length:
            raise _Damage(offset, 'chunk cut off at the end of file')
        opcode, length = _RECORD_HEAD.unpack_from(data)
        if opcode != Opcode.CHUNK:
            raise _Damage(offset, 'no chunk where the index says')
        chunk = _decode_record(opcode, data[_RECORD_HEAD.size:], offset)
        return _chunk_records(chunk, offset)


@contextlib.contextmanager
def _file_errors(mcap_file):
    """Turn damage and I/O errors met while reading mcap_file into one-line BagErrors."""
    try:
        yield
    except _Damage as damage:
        raise BagError(f'{mcap_file.path}: corrupted at byte {damage.offset} '
                       f'({damage.reason}); run `microball reindex '
                       f'{os.path.dirname(mcap_file.path)}` to keep the intact chunks') from None
    except OSError as error:
        raise BagError(f'{mcap_file.path}: {_one_line(error)}') from None


def _load_metadata_yaml(directory):
    path = os.path.join(directory, METADATA_FILE)
    try:
        with open(path, encoding='utf-8') as handle:
            document = yaml.safe_load(handle)
        information = document['rosbag2_bagfile_information']
        paths = information['relative_file_paths']
        if not isinstance(paths, list):
            raise TypeError('relative_file_paths is not a list')
    except (OSError, yaml.YAMLError, KeyError, TypeError) as error:
        raise BagError(f'{path}: unreadable ({_one_line(error)}); run `microball reindex '
                       f'{directory}` to rebuild it') from None
    return information


class Bag:
    """An opened, checked bag: its files, topics and time range; messages read on demand.

    Attributes: ``path``, ``files`` (.mcap paths), ``topics`` ({name: TopicInfo}),
    ``start_ns``, ``end_ns``, ``message_count``, ``ros_distro``, ``storage_identifier``,
    ``size`` (bytes), ``metadata`` (the metadata.yaml mapping, or None for a lone .mcap).
    """

    storage_identifier = 'mcap'

    def __init__(self, path, files, metadata=None):
        self.path = path
        self.files = [f.path for f in files]
        self.metadata = metadata
        self._files = files
        self.size = sum(f.size for f in files)
        qos_from_yaml = {}
        for entry in (metadata or {}).get('topics_with_message_count') or []:
            topic = entry.get('topic_metadata', {})
            qos_from_yaml[topic.get('name')] = topic.get('offered_qos_profiles', '')
        topics = {}
        for mcap_file in files:
            for cid, channel in mcap_file.channels.items():
                count = mcap_file.counts.get(cid, 0)
                if channel.topic in topics:
                    known = topics[channel.topic]
                    topics[channel.topic] = known._replace(count=known.count + count)
                    continue
                qos = channel.metadata.get('offered_qos_profiles', '')
                if not qos and qos_from_yaml.get(channel.topic):
                    qos = _qos_text(qos_from_yaml[channel.topic])
                topics[channel.topic] = TopicInfo(channel.topic, mcap_file.type_of(cid), count,
                                                  qos)
        self.topics = topics
        self.message_count = sum(t.count for t in topics.values())
        starts = [f.start_ns for f in files if f.start_ns is not None]
        ends = [f.end_ns for f in files if f.end_ns is not None]
        self.start_ns = min(starts) if starts else 0
        self.end_ns = max(ends) if ends else 0
        self.ros_distro = ((metadata or {}).get('ros_distro')
                           or next((f.ros_distro for f in files if f.ros_distro), None)
                           or 'unknown')

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
                with _file_errors(mcap_file):
                    data.extend(mcap_file.iter_data(channel_ids))
        return data

    def _file_messages(self, number, mcap_file, channel_ids):
        names = {cid: (mcap_file.topic_of(cid), mcap_file.type_of(cid)) for cid in channel_ids}
        with _file_errors(mcap_file):
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


def _qos_text(value):
    if isinstance(value, str):
        return value
    try:
        return qos_profiles_yaml(value)
    except (KeyError, TypeError, ValueError, AttributeError):
        return ''


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


def _damaged_file_error(path, scan, directory):
    return BagError(f'{path}: truncated or corrupted: {scan.describe()}; '
                    f'{scan.message_count} messages in intact chunks are recoverable with '
                    f'`microball reindex {directory}`')


def _open_file(path, directory):
    try:
        return _McapFile(path)
    except _Damage:
        pass
    except OSError as error:
        raise BagError(f'{path}: {_one_line(error)}') from None
    raise _damaged_file_error(path, _scan_file(path), directory)


def _mcap_files_in(directory):
    names = [n for n in os.listdir(directory)
             if n.endswith('.mcap') and os.path.isfile(os.path.join(directory, n))]
    return [os.path.join(directory, n) for n in sorted(names, key=_natural_key)]


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
        raise BagError(f'{path}: {error.strerror or _one_line(error)}') from None


def _open_bag(path):
    if not os.path.exists(path):
        raise BagError(f'{path}: no such file or directory')
    if os.path.isdir(path):
        directory = path
        found = _mcap_files_in(directory)
        if not os.path.isfile(os.path.join(directory, METADATA_FILE)):
            if not found:
                raise BagError(f'{path}: not a bag (no {METADATA_FILE} and no .mcap file)')
            problems = []
            for name in found:
                scan_result = _peek_damage(name)
                if scan_result is not None:
                    problems.append(f'{os.path.basename(name)} is {scan_result}')
            if problems:
                raise BagError(f'{path}: no {METADATA_FILE}, and {"; ".join(problems)}; was the '
                               f'recorder killed? run `microball reindex {path}` to recover it')
            names = ', '.join(os.path.basename(n) for n in found)
            raise BagError(f'{path}: no {METADATA_FILE} next to {names}; run '
                           f'`microball reindex {path}` to rebuild it')
        metadata = _load_metadata_yaml(directory)
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
            files.append(_open_file(file_path, directory))
        if not files:
            raise BagError(f'{path}: {METADATA_FILE} lists no files')
    else:
        directory = os.path.dirname(os.path.abspath(path))
        metadata = None
        if not path.endswith('.mcap'):
            with open(path, 'rb') as handle:
                if handle.read(8) != MAGIC:
                    raise BagError(f'{path}: not a bag (neither a directory nor an MCAP file)')
        files = [_open_file(path, directory)]
    bag = Bag(path, files, metadata)
    if bag.message_count == 0:
        raise BagError(f'{path}: the bag has no messages')
    return bag


def _peek_damage(path):
    """Return a description of how a file is damaged, or None if it is complete."""
    try:
        _McapFile(path)
        return None
    except _Damage:
        scan = _scan_file(path)
        return (f'truncated or corrupted ({scan.describe()}; {scan.message_count} messages '
                f'in intact chunks)')
    except BagError as error:
        return str(error).split(': ', 1)[-1]
    except OSError as error:
        return _one_line(error)


def _backup_name(path):
    candidate = path + TRUNCATED_SUFFIX
    number = 1
    while os.path.exists(candidate):
        candidate = f'{path}{TRUNCATED_SUFFIX}.{number}'
        number += 1
    return candidate


def reindex(directory, log=None):
    """Rebuild a bag directory's metadata.yaml and repair its MCAP files, like ros2 bag reindex.

    Every file is read front to back. An intact file is left as it is. A file without summary
    or with a cut or corrupted chunk (a killed recorder) is rewritten with every intact chunk's
    messages and a full summary; the original is kept as ``<name>.mcap.truncated``. Works
    without metadata.yaml. ``log(line)`` receives a line per repaired file. Return
    {topic: message count}; BagError if nothing can be recovered.
    """
    directory = os.fspath(directory)
    if not os.path.isdir(directory):
        raise BagError(f'{directory}: not a directory')
    paths = _mcap_files_in(directory)
    if not paths:
        raise BagError(f'{directory}: no .mcap file to reindex')
    old_custom_data = {}
    try:
        old_custom_data = dict(_load_metadata_yaml(directory).get('custom_data') or {})
    except (BagError, AttributeError, TypeError, ValueError):
        pass

    rebuilt = []  # (path, temporary path, McapFileWriter, scan)
    entries = []  # per file: (relative path, file info dict, topics list)
    try:
        for path in paths:
            scan, writer, temporary = _rebuild(path)
            if writer is None:
                entries.append(_entry_from_scan(path, scan))
            else:
                rebuilt.append((path, temporary, writer, scan))
                entries.append((os.path.basename(path),
                                writer.file_information(os.path.basename(path)),
                                [dict(t, message_count=writer.counts[t['name']])
                                 for t in writer.topics]))
        files = [info for _, info, _ in entries]
        topics = {}
        for _, _, file_topics in entries:
            for topic in file_topics:
                if topic['name'] in topics:
                    topics[topic['name']]['message_count'] += topic['message_count']
                else:
                    topics[topic['name']] = dict(topic)
        total = sum(f['message_count'] for f in files)
        if total == 0:
            raise BagError(f'{directory}: no intact message to recover '
                           f'({"; ".join(s.describe() for _, _, _, s in rebuilt) or "empty"})')
        information = bag_metadata(files, list(topics.values()), custom_data=old_custom_data,
                                   ros_distro=ROS_DISTRO)
        for _, _, writer, _ in rebuilt:
            writer.close(information)
    except BaseException:
        for _, temporary, writer, _ in rebuilt:
            writer.close()
            os.remove(temporary)
        raise
    for path, temporary, writer, scan in rebuilt:
        backup = _backup_name(path)
        os.replace(path, backup)
        os.replace(temporary, path)
        if log is not None:
            log(f'{os.path.basename(path)}: {scan.describe()}; kept {writer.message_count} '
                f'messages; original kept as {os.path.basename(backup)}')
    write_metadata_yaml(directory, information)
    return {name: topic['message_count'] for name, topic in topics.items()}


def _rebuild(path):
    """Scan a file; if damaged, copy its intact content to a temporary file (not closed)."""
    scan = _scan_file(path)
    if scan.header is not None and scan.header.profile != 'ros2':
        raise BagError(f'{path}: not a ROS 2 MCAP file (profile {scan.header.profile!r})')
    if scan.complete and not scan.skipped:
        return scan, None, None
    temporary = path + '.reindex-tmp'
    if os.path.exists(temporary):
        os.remove(temporary)  # a leftover of an interrupted reindex: ours, not recorded data
    writer = McapFileWriter(temporary, compression=scan.compression or 'zstd')
    schemas, channels = {}, {}

    def copy(record):
        if isinstance(record, Schema):
            schemas[record.id] = record
        elif isinstance(record, Channel):
            schema = schemas.get(record.schema_id)
            if schema is None:
                return
            channels[record.id] = record.topic
            writer.add_channel(record.topic, schema.name, schema.data.decode('utf-8'),
                               qos_profiles_yaml=record.metadata.get('offered_qos_profiles', ''),
                               topic_type_hash=record.metadata.get('topic_type_hash', ''),
                               schema_encoding=schema.encoding)
        elif isinstance(record, Message) and record.channel_id in channels:
            writer.write(channels[record.channel_id], record.data, record.log_time,
                         record.publish_time)

    try:
        scan = _scan_file(path, copy)
    except BaseException:
        writer.close()
        os.remove(temporary)
        raise
    return scan, writer, temporary


def _entry_from_scan(path, scan):
    relative = os.path.basename(path)
    info = {'path': relative, 'start_ns': scan.start_ns or 0, 'end_ns': scan.end_ns or 0,
            'message_count': scan.message_count}
    topics = {}
    for cid, channel in scan.channels.items():
        schema = scan.schemas.get(channel.schema_id)
        entry = topics.setdefault(channel.topic, {
            'name': channel.topic, 'type': schema.name if schema else '',
            'qos_profiles_yaml': channel.metadata.get('offered_qos_profiles', ''),
            'type_hash': channel.metadata.get('topic_type_hash', ''), 'message_count': 0})
        entry['message_count'] += scan.counts.get(cid, 0)
    for topic in topics.values():
        parse_qos_profiles(topic['qos_profiles_yaml'])
    return relative, info, list(topics.values())


POSITIONS_TOPIC = '/tracking/positions'
POSITIONS_TYPE = 'microball_msgs/msg/TrackedPositions'


IMAGES_TOPIC = '/camera/image_raw'
IMAGE_TYPE = 'sensor_msgs/msg/Image'


def recorded_parameters(bag, node):
    """Return the parameters of ``node`` kept in the bag's metadata ({} if none).

    ``microball experiment --output`` keeps them in metadata.yaml custom_data, under
    'microball.<node>', as a YAML mapping (custom_data values are strings).
    """
    text = ((bag.metadata or {}).get('custom_data') or {}).get(f'microball.{node}')
    if not text:
        return {}
    try:
        parameters = yaml.safe_load(text)
    except yaml.YAMLError as error:
        raise BagError(f'{bag.path}: custom_data microball.{node} is not YAML '
                       f'({_one_line(error)})') from None
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
                                       image.data)
    except BagError:
        raise
    except Exception as error:  # noqa: B902 - rosbags' errors vary; report them in one line
        raise BagError(f'{bag.path}: cannot read {topic}: {_one_line(error)}') from None


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
        raise BagError(f'{path}: cannot deserialize {topic}: {_one_line(error)}') from None
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
