"""MCAP files of a bag, read without a ROS runtime: summary and chunk index, or a full scan.

``McapFile`` opens one complete MCAP file through its summary (mcap's SeekingReader), checking
that every chunk index points at a chunk, or, for a file without a usable summary, by reading it
front to back; it yields messages in log-time order from CRC-checked chunks and keeps the
file's own 'rosbag2' metadata (the last such record, as rosbag2 reads it). ``scan_file`` is that
front-to-back read, stopping cleanly at the first broken record: what it returns says how far a
truncated or damaged file is readable, and it is what repair.reindex copies from. Damage met
while reading is a ``Damage`` (an offset and a reason); ``file_errors`` turns it into a
one-line BagError for the user.
"""

import contextlib
import heapq
import io
import os
import re
import struct

from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.reader import SeekingReader
from mcap.records import Channel, Chunk, DataEnd, Footer, Header, Message, Metadata, Schema
from mcap.stream_reader import get_chunk_data_stream

from microball_ros.core.errors import BagError
from microball_ros.io.bags.metadata import RECORD_NAME, parse_record

MAGIC = b'\x89MCAP0\r\n'
_RECORD_HEAD = struct.Struct('<BQ')
_MESSAGE_FIELDS = struct.Struct('<HIQQ')  # channel id, sequence, log time, publish time
_KNOWN_OPCODES = frozenset(int(op) for op in Opcode)
_PARSERS = {Opcode.HEADER: Header.read, Opcode.SCHEMA: Schema.read,
            Opcode.CHANNEL: Channel.read, Opcode.CHUNK: Chunk.read, Opcode.METADATA: Metadata.read,
            Opcode.DATA_END: DataEnd.read, Opcode.FOOTER: Footer.read}


class Damage(Exception):
    """Where and why reading an MCAP file front to back had to stop."""

    def __init__(self, offset, reason):
        super().__init__(f'at byte {offset}: {reason}')
        self.offset = offset
        self.reason = reason


def one_line(error):
    """Return the first line of an exception's message (its type name if it has none)."""
    text = str(error).strip() or type(error).__name__
    return text.splitlines()[0]


def decode_record(opcode, body, offset):
    """Parse one top-level record body with mcap's record classes; Damage if malformed."""
    try:
        stream = ReadDataStream(io.BytesIO(body))
        if opcode == Opcode.MESSAGE:
            record = Message.read(stream, len(body))
        else:
            record = _PARSERS[opcode](stream)
    except Exception as error:  # noqa: B902 - any parse failure means a damaged record
        raise Damage(offset, f'malformed {Opcode(opcode).name.lower()} record '
                             f'({one_line(error)})') from None
    if stream.count > len(body):
        raise Damage(offset, f'malformed {Opcode(opcode).name.lower()} record')
    return record


def chunk_records(chunk, offset):
    """Decompress a chunk and check its CRC; return its records or raise Damage.

    Decompression and CRC are mcap's; the records are split here, each Message with one
    struct call: mcap's field-by-field stream reads cost about 5 us per message, most of the
    time it took to read an hour of positions (0.55 of 1.2 s). Schema and Channel records
    (rare in chunks) are parsed by mcap.
    """
    try:
        stream, length = get_chunk_data_stream(chunk, validate_crc=True)
        data = stream.read(length)
    except Exception as error:  # noqa: B902 - bad CRC, bad compression
        raise Damage(offset, f'corrupted chunk ({one_line(error)})') from None
    records = []
    position, end = 0, len(data)
    while position < end:
        if end - position < _RECORD_HEAD.size:
            raise Damage(offset, 'corrupted chunk (a record cut short)')
        opcode, length = _RECORD_HEAD.unpack_from(data, position)
        body = position + _RECORD_HEAD.size
        position = body + length
        if position > end:
            raise Damage(offset, 'corrupted chunk (a record longer than the chunk)')
        if opcode == Opcode.MESSAGE:
            if length < _MESSAGE_FIELDS.size:
                raise Damage(offset, 'corrupted chunk (a message record too short)')
            channel_id, sequence, log_time, publish_time = _MESSAGE_FIELDS.unpack_from(data, body)
            records.append(Message(channel_id=channel_id, log_time=log_time,
                                   data=data[body + _MESSAGE_FIELDS.size:position],
                                   publish_time=publish_time, sequence=sequence))
        elif opcode in (Opcode.SCHEMA, Opcode.CHANNEL):
            records.append(decode_record(opcode, data[body:position], offset))
    return records


class Scan:
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
        self.damage = None  # Damage that stopped the read, if any
        self.skipped = []  # Damage of corrupted chunks skipped (framing intact)
        self.rosbag2 = {}  # the last 'rosbag2' Metadata record's mapping (metadata.parse_record)

    @property
    def message_count(self):
        """Return the number of messages found in intact chunks."""
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


def scan_file(path, on_record=None):
    """Read an MCAP file record by record, stopping cleanly at the first broken record.

    Every chunk is decompressed and CRC-checked; a chunk whose framing is intact but whose
    content is corrupted is skipped (noted in ``skipped``). ``on_record(record)`` receives the
    Schema, Channel and Message records of the data section in file order (messages of intact
    chunks only).
    """
    size = os.path.getsize(path)
    scan = Scan(path, size)
    with open(path, 'rb') as handle:
        if handle.read(8) != MAGIC:
            scan.readable_end = 0
            scan.damage = Damage(0, 'not an MCAP file (bad magic)')
            return scan
        offset = 8
        in_data_section = True
        try:
            while True:
                head = handle.read(_RECORD_HEAD.size)
                if not head:
                    raise Damage(offset, 'file ends without a footer')
                if len(head) < _RECORD_HEAD.size:
                    raise Damage(offset, 'file ends inside a record header')
                opcode, length = _RECORD_HEAD.unpack(head)
                if opcode not in _KNOWN_OPCODES and opcode < 0x80:
                    raise Damage(offset, f'unknown record opcode 0x{opcode:02x}')
                end = offset + _RECORD_HEAD.size + length
                if end > size:
                    raise Damage(offset, f'record of {length} bytes cut off at the end of file')
                body = handle.read(length)
                if opcode in _PARSERS or opcode == Opcode.MESSAGE:
                    record = decode_record(opcode, body, offset)
                    if isinstance(record, Header):
                        scan.header = record
                    elif isinstance(record, DataEnd):
                        in_data_section = False
                    elif isinstance(record, Footer):
                        if handle.read(8) != MAGIC:
                            raise Damage(end, 'missing closing magic after the footer')
                        scan.readable_end = end + 8
                        scan.complete = True
                        return scan
                    elif in_data_section:
                        if isinstance(record, Chunk):
                            try:
                                records = chunk_records(record, offset)
                            except Damage as damage:
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
        except Damage as damage:
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
        if record.name == RECORD_NAME:
            scan.rosbag2 = parse_record(record.metadata)
        return
    else:
        return
    if on_record is not None:
        on_record(record)


class McapFile:
    """One complete MCAP file of a bag, described by its summary (or a full scan)."""

    def __init__(self, path):
        self.path = path
        self.size = os.path.getsize(path)
        self.rosbag2 = {}  # the file's own 'rosbag2' metadata (the last record), parsed
        self.chunk_indexes = None
        with open(path, 'rb') as handle:
            if handle.read(8) != MAGIC:
                raise BagError(f'{path}: not an MCAP file')
            summary = self._read_summary(handle)
        if summary is None:
            # No usable summary (a killed writer, or a writer that leaves it out): read it all.
            scan = scan_file(path)
            if not scan.complete or scan.skipped:
                raise Damage(scan.damage.offset if scan.damage else scan.skipped[0].offset,
                             scan.describe())
            self.header = scan.header
            self.schemas, self.channels, self.counts = scan.schemas, scan.channels, scan.counts
            self.start_ns, self.end_ns = scan.start_ns, scan.end_ns
            self.rosbag2 = scan.rosbag2
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
                if metadata.name == RECORD_NAME:  # rosbag2 applies each in turn: the last wins
                    self.rosbag2 = parse_record(metadata.metadata)
            return summary
        except Exception:  # noqa: B902 - any failure: no trustworthy summary
            return None

    @property
    def ros_distro(self):
        """Return the ROS distro the file's 'rosbag2' record names, or None."""
        return self.rosbag2.get('ros_distro') or None

    def topic_of(self, channel_id):
        """Return the topic of a channel id."""
        return self.channels[channel_id].topic

    def type_of(self, channel_id):
        """Return the message type of a channel id ('' if its schema is missing)."""
        channel = self.channels[channel_id]
        schema = self.schemas.get(channel.schema_id)
        return schema.name if schema is not None else ''

    def iter_messages(self, channel_ids):
        """Yield Message records of the given channels in log-time order (ties: file order)."""
        if self.chunk_indexes is None:
            messages = []
            scan_file(self.path, lambda r: messages.append(r) if isinstance(r, Message)
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
            raise Damage(offset, 'chunk cut off at the end of file')
        opcode, length = _RECORD_HEAD.unpack_from(data)
        if opcode != Opcode.CHUNK:
            raise Damage(offset, 'no chunk where the index says')
        chunk = decode_record(opcode, data[_RECORD_HEAD.size:], offset)
        return chunk_records(chunk, offset)


@contextlib.contextmanager
def file_errors(mcap_file):
    """Turn damage and I/O errors met while reading mcap_file into one-line BagErrors."""
    try:
        yield
    except Damage as damage:
        raise BagError(f'{mcap_file.path}: corrupted at byte {damage.offset} '
                       f'({damage.reason}); run `microball reindex '
                       f'{os.path.dirname(mcap_file.path)}` to keep the intact chunks') from None
    except OSError as error:
        raise BagError(f'{mcap_file.path}: {one_line(error)}') from None


def _natural_key(name):
    return [int(part) if part.isdigit() else part for part in re.split(r'(\d+)', name)]


def mcap_files_in(directory):
    """Return the .mcap files of a directory, in rosbag2's order (name_0, name_1, ..., name_10)."""
    names = [n for n in os.listdir(directory)
             if n.endswith('.mcap') and os.path.isfile(os.path.join(directory, n))]
    return [os.path.join(directory, n) for n in sorted(names, key=_natural_key)]


def damage_report(path):
    """Return how a file is damaged ('truncated or corrupted (...)'), or None if it is intact."""
    try:
        McapFile(path)
        return None
    except Damage:
        scan = scan_file(path)
        return (f'truncated or corrupted ({scan.describe()}; {scan.message_count} messages '
                f'in intact chunks)')
    except BagError as error:
        return str(error).split(': ', 1)[-1]
    except OSError as error:
        return one_line(error)


def open_mcap_file(path, directory):
    """Open one complete file of a bag; BagError saying how far a damaged one is readable."""
    try:
        return McapFile(path)
    except Damage:
        pass
    except OSError as error:
        raise BagError(f'{path}: {one_line(error)}') from None
    scan = scan_file(path)
    raise BagError(f'{path}: truncated or corrupted: {scan.describe()}; '
                   f'{scan.message_count} messages in intact chunks are recoverable with '
                   f'`microball reindex {directory}`')
