"""Repair: ``ros2 bag reindex`` for MCAP bags, plus recovery of what a killed recorder left.

``reindex`` reads every MCAP file of a bag directory front to back. An intact file stays as it
is; a file without summary or with a cut or corrupted chunk is rewritten with every intact
chunk's messages and a full summary. metadata.yaml is then rebuilt as rosbag2's Reindexer
aggregates it (rosbag2_cpp/src/rosbag2_cpp/reindexer.cpp): counts and times from the messages,
topics from the channels, and custom_data and ros_distro from the files' own 'rosbag2' records
(the file that starts last and has them), which a recorder writes when the bag opens; the
records also supply a topic's QoS where its channel lacks it. The bag directory ends holding
only what metadata.yaml lists and metadata.yaml itself: originals of rewritten files go to a
backup directory beside it.
"""

import os
import shutil

from mcap.records import Channel, Message, Schema

from microball_ros.core.errors import BagError
from microball_ros.io.bags.mcap_file import mcap_files_in, scan_file
from microball_ros.io.bags.metadata import (
    bag_metadata,
    custom_data_of,
    load_metadata_yaml,
    topic_qos_of,
    write_metadata_yaml,
)
from microball_ros.io.bags.schema import parse_qos_profiles
from microball_ros.io.bags.writer import McapFileWriter

BACKUP_SUFFIX = '.truncated'
_TEMPORARY_SUFFIX = '.reindex-tmp'


def backup_directory(directory):
    """Return where reindex keeps the originals of a bag's rewritten files: beside the bag.

    ``<bag>.truncated`` next to the bag directory, or ``<bag>.truncated.1``, ``.2``, ... if
    that exists already (one backup directory per repairing run).
    """
    base = os.path.abspath(directory).rstrip(os.sep) + BACKUP_SUFFIX
    candidate, number = base, 1
    while os.path.exists(candidate):
        candidate = f'{base}.{number}'
        number += 1
    return candidate


def reindex(directory, log=None):
    """Rebuild a bag directory's metadata.yaml and repair its MCAP files, like ros2 bag reindex.

    Works without metadata.yaml. A file that needed rewriting is replaced by its repaired copy
    and the original is moved out of the bag, to a backup directory beside it
    (``backup_directory``: ``<bag>.truncated/<name>.mcap``), so that the bag directory holds
    only its .mcap files and metadata.yaml, as rosbag2 lists them. ``log(line)`` receives a
    line per repaired file. Return {topic: message count}; BagError if nothing can be
    recovered, or if the backup cannot be made (then nothing is changed).
    """
    directory = os.fspath(directory)
    if not os.path.isdir(directory):
        raise BagError(f'{directory}: not a directory')
    paths = mcap_files_in(directory)
    if not paths:
        raise BagError(f'{directory}: no .mcap file to reindex')
    try:
        old = load_metadata_yaml(directory)
    except BagError:
        old = {}
    if not isinstance(old, dict):
        old = {}

    rebuilt = []  # (path, temporary path, McapFileWriter, scan)
    entries = []  # per file: (file info dict, topics list, scan)
    try:
        for path in paths:
            scan, writer, temporary = _rebuild(path)
            if writer is None:
                entries.append((*_entry_from_scan(path, scan), scan))
            else:
                rebuilt.append((path, temporary, writer, scan))
                entries.append((writer.file_information(os.path.basename(path)),
                                [dict(t, message_count=writer.counts[t['name']])
                                 for t in writer.topics], scan))
        files = [info for info, _, _ in entries]
        if sum(f['message_count'] for f in files) == 0:
            raise BagError(f'{directory}: no intact message to recover '
                           f'({"; ".join(s.describe() for _, _, _, s in rebuilt) or "empty"})')
        information = _aggregate(entries, old)
        for _, _, writer, _ in rebuilt:
            writer.close(information)
        backup = backup_directory(directory) if rebuilt else None
        if backup is not None:
            try:
                os.makedirs(backup)
            except OSError as error:
                raise BagError(f'{directory}: cannot keep the originals in {backup} '
                               f'({error.strerror or error}); nothing was changed') from None
    except BaseException:
        for _, temporary, writer, _ in rebuilt:
            writer.close()
            os.remove(temporary)
        raise
    for path, temporary, writer, scan in rebuilt:
        kept = os.path.join(backup, os.path.basename(path))
        shutil.move(path, kept)
        os.replace(temporary, path)
        if log is not None:
            log(f'{os.path.basename(path)}: {scan.describe()}; kept {writer.message_count} '
                f'messages; original moved to {kept}')
    write_metadata_yaml(directory, information)
    return {t['topic_metadata']['name']: t['message_count']
            for t in information['topics_with_message_count']}


def _aggregate(entries, old):
    """Return the bag metadata of all files, as rosbag2's Reindexer::aggregate_metadata does."""
    topics, qos_known = {}, {}
    custom_data, distro = custom_data_of(old), old.get('ros_distro') or ''
    latest = None
    for info, file_topics, scan in entries:
        qos_known.update(topic_qos_of(scan.rosbag2))
        # custom_data and ros_distro: from the file that starts last and carries them
        if latest is None or info['start_ns'] > latest:
            latest = info['start_ns']
            custom_data = custom_data_of(scan.rosbag2) or custom_data
            distro = scan.rosbag2.get('ros_distro') or distro
        for topic in file_topics:
            if topic['name'] in topics:
                topics[topic['name']]['message_count'] += topic['message_count']
            else:
                topics[topic['name']] = dict(topic)
    for topic in topics.values():
        if not topic['qos_profiles_yaml'] and topic['name'] in qos_known:
            topic['qos_profiles_yaml'] = qos_known[topic['name']]
            parse_qos_profiles(topic['qos_profiles_yaml'])
    return bag_metadata([info for info, _, _ in entries], list(topics.values()),
                        custom_data=custom_data, ros_distro=distro)


def _rebuild(path):
    """Scan a file; if damaged, copy its intact content to a temporary file (not closed)."""
    scan = scan_file(path)
    if scan.header is not None and scan.header.profile != 'ros2':
        raise BagError(f'{path}: not a ROS 2 MCAP file (profile {scan.header.profile!r})')
    if scan.complete and not scan.skipped:
        return scan, None, None
    temporary = path + _TEMPORARY_SUFFIX
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
        scan = scan_file(path, copy)
    except BaseException:
        writer.close()
        os.remove(temporary)
        raise
    return scan, writer, temporary


def _entry_from_scan(path, scan):
    """Return (file info, topics) of an intact file from its scan."""
    info = {'path': os.path.basename(path), 'start_ns': scan.start_ns or 0,
            'end_ns': scan.end_ns or 0, 'message_count': scan.message_count}
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
    return info, list(topics.values())
