"""
rosbag2 bags: open any recording the analysis may get, write the ones it produces.

``open_bag`` accepts a bag directory (``metadata.yaml`` of version 1 to 9, possibly split
over several storage files), a bare ``.mcap`` file, or an sqlite3 ``.db3`` bag of older
distributions. QoS may be written with integer or string policies. The returned
:class:`Bag` lists topics and reads JointState topics as vectorised
:class:`~msg_adapters.jointstate_cdr.JointStateBatch` es in receive-time order.

Problems that leave data readable (a listed file missing, counts that disagree, a
recording cut short, a corrupt chunk) become :class:`~reducer_twin.analysis.mcap_io.
ReadWarning` s in ``Bag.warnings``; problems that leave nothing to read raise
:class:`~reducer_twin.core.errors.BagError`.

Writing lives in :mod:`reducer_twin.analysis.bag_writer` (``BagDirWriter`` and
``write_bag_dir`` are importable from here too); the output of the analysis is always MCAP.
"""

from dataclasses import dataclass
import os
from pathlib import Path
import re
import sqlite3
import stat
from typing import NamedTuple

from msg_adapters.jointstate_cdr import concat_batches, decode_joint_states, empty_batch
from msg_adapters.jointstate_cdr import MSGTYPE as JOINT_STATE
import numpy as np
from reducer_twin.analysis.bag_writer import BagDirWriter, write_bag_dir  # noqa: F401
from reducer_twin.analysis.mcap_io import (
    custom_data_strings, MAGIC, McapBagReader, parse_qos_profiles, RawBatch, ReadWarning)
from reducer_twin.core.errors import BagError, InvalidInput
import yaml

SQLITE_MAGIC = b'SQLite format 3\x00'
MAX_METADATA_VERSION = 9


class TopicSummary(NamedTuple):
    """``(msgtype, count)`` of one topic."""

    msgtype: str
    count: int


@dataclass(frozen=True)
class TopicDetails:
    """
    Everything a bag says about one topic.

    Attributes
    ----------
    name, msgtype : str
        Topic name and ROS type.
    count : int
        Messages found in the storage files.
    serialization_format : str
        ``'cdr'``.
    qos : tuple of QosProfile
        Offered QoS profiles (empty if the bag stored none or they were unreadable).
    type_hash : str
        ``RIHS01_...`` or ``''``.

    """

    name: str
    msgtype: str
    count: int
    serialization_format: str
    qos: tuple
    type_hash: str


def _natural_key(path):
    return [int(part) if part.isdigit() else part for part in re.split(r'(\d+)', path.name)]


def _sniff(path):
    try:
        mode = os.stat(path).st_mode
    except OSError as err:
        raise BagError(f'cannot read {path}: {err.strerror}') from err
    if not stat.S_ISREG(mode):  # a FIFO would block the open, a device never end
        kind = 'a named pipe (FIFO)' if stat.S_ISFIFO(mode) else 'a socket' \
            if stat.S_ISSOCK(mode) else 'a directory' if stat.S_ISDIR(mode) else 'a device'
        raise BagError(f'{path} is {kind}; expected an MCAP or sqlite3 rosbag2 file')
    try:
        with open(path, 'rb') as stream:
            head = stream.read(16)
    except OSError as err:
        raise BagError(f'cannot read {path}: {err.strerror}') from err
    if head.startswith(MAGIC):
        return 'mcap'
    if head == SQLITE_MAGIC:
        return 'sqlite3'
    if not head:
        raise BagError(f'{path} is empty (0 bytes); expected an MCAP or sqlite3 rosbag2 file')
    raise BagError(f'{path} is neither MCAP nor sqlite3: byte 0 holds {head[:8].hex(" ")}, '
                   f'expected the MCAP magic {MAGIC.hex(" ")} or "SQLite format 3"')


class _Sqlite3File:
    """A rosbag2 sqlite3 storage file, read with the standard library."""

    def __init__(self, path):
        self.path = Path(path)
        self.warnings = []
        # immutable=1 reads files in read-only directories without lock files; a bag
        # recorded in WAL mode and not checkpointed keeps messages in its -wal file,
        # which only a normal read-only connection sees.
        wal = Path(f'{self.path}-wal')
        options = 'mode=ro' if wal.is_file() and wal.stat().st_size else 'mode=ro&immutable=1'
        try:
            self._db = sqlite3.connect(f'file:{self.path}?{options}', uri=True)
            cursor = self._db.execute('SELECT * FROM topics')
            columns = [c[0] for c in cursor.description]
            self._topics = [dict(zip(columns, row)) for row in cursor.fetchall()]
            self._counts = dict(self._db.execute(
                'SELECT topic_id, COUNT(*) FROM messages GROUP BY topic_id').fetchall())
        except sqlite3.Error as err:
            raise BagError(f'{self.path} is not a readable rosbag2 sqlite3 file: {err}; expected '
                           "tables 'topics' and 'messages'") from err
        self.channels = {t['id']: t for t in self._topics}

    def topics(self):
        return {t['name']: TopicDetails(
            t['name'], t['type'], int(self._counts.get(t['id'], 0)),
            t.get('serialization_format', 'cdr'), t.get('offered_qos_profiles') or '',
            t.get('type_description_hash') or '') for t in self._topics}

    def topic_of(self, channel_id):
        return self.channels[channel_id]['name']

    def rosbag2_metadata(self):
        return None

    def iter_batches(self, topics, page=200_000):
        ids = [t['id'] for t in self._topics if t['name'] in topics]
        if not ids:
            return
        marks = ','.join('?' * len(ids))
        try:
            cursor = self._db.execute(
                f'SELECT topic_id, timestamp, data FROM messages WHERE topic_id IN ({marks}) '
                'ORDER BY timestamp, id', ids)
            while True:
                rows = cursor.fetchmany(page)
                if not rows:
                    return
                topic_ids, stamps, blobs = zip(*rows)
                lengths = np.fromiter((len(b) for b in blobs), np.int64, len(blobs))
                offsets = np.zeros(len(blobs), np.int64)
                np.cumsum(lengths[:-1], out=offsets[1:])
                stamps = np.array(stamps, np.int64)
                yield RawBatch(np.array(topic_ids, np.uint16), np.zeros(len(blobs), np.uint32),
                               stamps, stamps, np.frombuffer(b''.join(blobs), np.uint8),
                               offsets, lengths)
        except sqlite3.Error as err:
            self.warnings.append(ReadWarning(str(self.path), None,
                                             f'reading stopped: sqlite3 error {err}'))

    def close(self):
        self._db.close()


class _McapFile:
    """Adapter of McapBagReader to the storage-file interface of Bag."""

    def __init__(self, path, validate_crc):
        self.reader = McapBagReader(path, validate_crc=validate_crc)
        self.path = self.reader.path
        self.warnings = self.reader.warnings

    def topics(self):
        out = {}
        for name, info in self.reader.topics().items():
            out[name] = TopicDetails(name, info.msgtype, info.count, info.serialization_format,
                                     info.offered_qos_profiles, info.type_hash)
        return out

    def topic_of(self, channel_id):
        return self.reader.channels[channel_id].topic

    def rosbag2_metadata(self):
        return self.reader.rosbag2_metadata()

    def iter_batches(self, topics):
        return self.reader.iter_batches(topics)

    def close(self):
        self.reader.close()


class Bag:
    """
    An opened rosbag2 recording (use :func:`open_bag`).

    Attributes
    ----------
    path : pathlib.Path
        What was opened.
    files : list of pathlib.Path
        Storage files, in recording order.
    storage : str
        ``'mcap'`` or ``'sqlite3'``.
    topics : dict of str to TopicSummary
        ``name -> (msgtype, count)``.
    topic_details : dict of str to TopicDetails
        Types, counts, QoS and type hashes.
    metadata : dict of str to str
        rosbag2 ``custom_data`` (empty if none).
    info : dict
        The parsed ``rosbag2_bagfile_information`` (from metadata.yaml or the MCAP
        ``rosbag2`` record), or an empty dict.
    warnings : list of ReadWarning
        Problems met while opening and reading.

    """

    def __init__(self, path, storage, files, info, validate_crc=True):
        self.path = Path(path)
        self.storage = storage
        self.info = info or {}
        self.warnings = []
        self._files = []
        errors = []
        for file in files:
            try:
                self._files.append(_McapFile(file, validate_crc) if storage == 'mcap'
                                   else _Sqlite3File(file))
            except BagError as err:
                errors.append(err)
        if errors and not self._files:
            raise errors[0]
        for err in errors:
            self._warn(f'{err}; skipping that file')
        self.files = [f.path for f in self._files]
        self._collect()

    # ----------------------------------------------------------------- public API

    def read_joint_states(self, topics=None, errors='skip'):
        """
        Read JointState topics as arrays, in receive-time order across all files.

        Parameters
        ----------
        topics : str or iterable of str, optional
            Topic names; default every ``sensor_msgs/msg/JointState`` topic.
        errors : {'skip', 'raise'}
            Malformed messages are left out with a warning (``'skip'``) or raise
            InvalidInput.

        Returns
        -------
        dict of str to JointStateBatch
            Per topic, with ``log_time_ns`` set; stably sorted by log time.

        Raises
        ------
        BagError
            If a topic is not in the bag or is not a JointState topic.

        """
        names = self._joint_state_topics(topics)
        parts = {name: [] for name in names}
        rejected = {name: [] for name in names}
        for handle in self._files:
            for batch in handle.iter_batches(names):
                by_topic = self._split(handle, batch)
                for name, sub in by_topic.items():
                    decoded = decode_joint_states(sub.data, sub.offsets, sub.lengths,
                                                  errors=errors)
                    if decoded.rejected:
                        keep = np.ones(len(sub), bool)
                        keep[[i for i, _ in decoded.rejected]] = False
                        rejected[name] += [(handle.path, reason) for _, reason
                                           in decoded.rejected]
                        decoded.log_time_ns = sub.log_time_ns[keep]
                    else:
                        decoded.log_time_ns = sub.log_time_ns
                    parts[name].append(decoded)
            self._take_warnings(handle)
        for name, problems in rejected.items():
            if problems:
                self._warn(f'{len(problems)} malformed JointState message(s) on {name} '
                           f'skipped; the first: {problems[0][1]}', problems[0][0])
        out = {}
        for name in names:
            batch = concat_batches(parts[name]) if parts[name] else empty_batch()
            if batch.log_time_ns is None:
                batch.log_time_ns = np.zeros(len(batch), np.int64)
            batch.rejected = ()
            logs = batch.log_time_ns
            if logs.shape[0] > 1 and (np.diff(logs) < 0).any():
                batch = batch.take(np.argsort(logs, kind='stable'))
            out[name] = batch
        return out

    def iter_raw(self, topics=None):
        """
        Iterate over raw messages, per storage file and chunk.

        Parameters
        ----------
        topics : str or iterable of str, optional
            Topic names; default all.

        Yields
        ------
        tuple
            ``(topic, RawBatch)``; within a file in file order.

        """
        names = self._known_topics(topics)
        for handle in self._files:
            for batch in handle.iter_batches(names):
                yield from self._split(handle, batch).items()
            self._take_warnings(handle)

    def close(self):
        """Release all files."""
        for handle in self._files:
            handle.close()
        self._files = []

    def __enter__(self):
        """Return the bag."""
        return self

    def __exit__(self, *exc):
        """Release all files."""
        self.close()

    # ----------------------------------------------------------------- internals

    def _warn(self, message, path=None, offset=None):
        self.warnings.append(ReadWarning(str(path or self.path), offset, message))

    def _take_warnings(self, handle):
        for warning in handle.warnings:
            if warning not in self.warnings:
                self.warnings.append(warning)

    def _collect(self):
        details = {}
        for handle in self._files:
            self._take_warnings(handle)
            for name, topic in handle.topics().items():
                qos = topic.qos
                if isinstance(qos, str):
                    try:
                        qos = parse_qos_profiles(qos)
                    except InvalidInput as err:
                        self._warn(f'QoS of {name} unreadable: {err}', handle.path)
                        qos = ()
                if name in details:
                    old = details[name]
                    details[name] = TopicDetails(name, old.msgtype, old.count + topic.count,
                                                 old.serialization_format, old.qos or qos,
                                                 old.type_hash or topic.type_hash)
                else:
                    details[name] = TopicDetails(name, topic.msgtype, topic.count,
                                                 topic.serialization_format, qos,
                                                 topic.type_hash)
        if self.info:
            # metadata.yaml describes the whole bag: hold the files against it.
            for entry in self.info.get('topics_with_message_count') or []:
                self._compare_topic(entry, details)
        elif self._files:
            # Without metadata.yaml, the rosbag2 record inside the (last) MCAP file still
            # carries custom_data; its counts may describe a whole split bag, so they are
            # not compared with this file's.
            self.info = self._files[-1].rosbag2_metadata() or {}
        self.topic_details = details
        self.topics = {name: TopicSummary(d.msgtype, d.count) for name, d in details.items()}
        custom = self.info.get('custom_data') if isinstance(self.info, dict) else None
        self.metadata = {str(k): str(v) for k, v in custom.items()} \
            if isinstance(custom, dict) else {}

    def _compare_topic(self, entry, details):
        try:
            meta = entry['topic_metadata']
            name, msgtype, count = meta['name'], meta['type'], int(entry['message_count'])
        except (KeyError, TypeError, ValueError):
            self._warn(f'metadata lists a topic entry it does not describe fully: {entry!r}')
            return
        found = details.get(name)
        if found is None:
            if count:
                self._warn(f'metadata lists {count} messages on {name} ({msgtype}), but no '
                           'storage file holds that topic')
            details[name] = TopicDetails(
                name, msgtype, 0, meta.get('serialization_format', 'cdr'),
                _safe_qos(meta.get('offered_qos_profiles')),
                meta.get('type_description_hash') or '')
            return
        if found.count != count:
            self._warn(f'metadata lists {count} messages on {name}, but the storage files hold '
                       f'{found.count}; using what the files hold')
        if not found.qos:
            qos = _safe_qos(meta.get('offered_qos_profiles'))
            details[name] = TopicDetails(name, found.msgtype, found.count,
                                         found.serialization_format, qos,
                                         found.type_hash or meta.get('type_description_hash')
                                         or '')

    def _known_topics(self, topics):
        if topics is None:
            return list(self.topics)
        names = [topics] if isinstance(topics, str) else list(topics)
        missing = [n for n in names if n not in self.topics]
        if missing:
            raise BagError(f'{self.path} has no topic {missing[0]!r}; it has '
                           f'{sorted(self.topics)}')
        return names

    def _joint_state_topics(self, topics):
        if topics is None:
            return [n for n, t in self.topics.items() if t.msgtype == JOINT_STATE]
        names = self._known_topics(topics)
        for name in names:
            if self.topics[name].msgtype != JOINT_STATE:
                raise BagError(f'topic {name} in {self.path} is {self.topics[name].msgtype}, '
                               f'expected {JOINT_STATE}')
        return names

    def _split(self, handle, batch):
        if len(batch) == 0:
            return {}
        if batch.channel_id.min() == batch.channel_id.max():
            return {handle.topic_of(int(batch.channel_id[0])): batch}
        ids = np.unique(batch.channel_id)
        out = {}
        for cid in ids.tolist():
            name = handle.topic_of(cid)
            sub = batch.select(batch.channel_id == cid)
            if name in out:  # two channels of one topic: keep file order
                sub = _merge_raw(out[name], sub)
            out[name] = sub
        return out


def _merge_raw(first, second):
    data = np.concatenate([first.data, second.data])
    order = np.argsort(np.concatenate([first.offsets, second.offsets + first.data.shape[0]]),
                       kind='stable')

    def cat(a, b):
        return np.concatenate([a, b])[order]

    return RawBatch(cat(first.channel_id, second.channel_id),
                    cat(first.sequence, second.sequence),
                    cat(first.log_time_ns, second.log_time_ns),
                    cat(first.publish_time_ns, second.publish_time_ns), data,
                    cat(first.offsets, second.offsets + first.data.shape[0]),
                    cat(first.lengths, second.lengths))


def _safe_qos(value):
    try:
        return parse_qos_profiles(value)
    except InvalidInput:
        return ()


def _read_metadata_yaml(path):
    try:
        text = path.read_text(encoding='utf-8')
        document = yaml.safe_load(text)
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as err:
        raise BagError(f'{path} cannot be read as YAML: {err}') from err
    if not isinstance(document, dict) or not isinstance(
            document.get('rosbag2_bagfile_information'), dict):
        raise BagError(f'{path} has no rosbag2_bagfile_information mapping; expected a rosbag2 '
                       'metadata.yaml')
    info = document['rosbag2_bagfile_information']
    custom = custom_data_strings(text)
    if custom is not None:
        info['custom_data'] = custom
    return info


def _files_of_directory(directory, info, warnings):
    """Resolve the storage files a metadata.yaml lists (rosbag2 <= v3 prefixed the bag dir)."""
    listed = info.get('relative_file_paths') or []
    if not isinstance(listed, list):
        raise BagError(f'{directory / "metadata.yaml"}: relative_file_paths must be a list, got '
                       f'{listed!r}')
    files, missing = [], []
    for rel in listed:
        rel = Path(str(rel))
        for candidate in (directory / rel, directory / rel.name):
            if candidate.is_file():
                files.append(candidate)
                break
        else:
            missing.append(str(rel))
    if missing:
        warnings.append(ReadWarning(
            str(directory), None, f'metadata.yaml lists {len(missing)} file(s) that do not '
            f'exist: {missing}; reading the {len(files)} that do'))
    if not files:
        raise BagError(f'none of the storage files listed in {directory / "metadata.yaml"} '
                       f'exist: {missing or "(the list is empty)"}')
    return files


def open_bag(path, validate_crc=True):
    """
    Open a rosbag2 recording.

    Parameters
    ----------
    path : str or os.PathLike
        A bag directory, a ``metadata.yaml``, a ``.mcap`` file or a ``.db3`` file.
    validate_crc : bool
        Check MCAP chunk CRCs where stored.

    Returns
    -------
    Bag
        The opened bag; close it (or use it as a context manager) when done.

    Raises
    ------
    BagError
        If the path does not exist, holds no storage file, is neither MCAP nor sqlite3,
        uses rosbag2 file or message compression, or its metadata.yaml is unreadable or
        lists only missing files.

    """
    path = Path(path)
    if not path.exists():
        raise BagError(f'{path} does not exist; expected a rosbag2 bag directory, a .mcap or '
                       'a .db3 file')
    warnings = []
    info = {}
    if path.is_file() and path.name == 'metadata.yaml':
        path = path.parent
    if path.is_dir():
        meta = path / 'metadata.yaml'
        if meta.is_file():
            info = _read_metadata_yaml(meta)
            _check_metadata(meta, info, warnings)
            files = _files_of_directory(path, info, warnings)
        else:
            files = sorted([*path.glob('*.mcap'), *path.glob('*.db3')], key=_natural_key)
            if not files:
                raise BagError(f'{path} has no metadata.yaml and no .mcap or .db3 file; '
                               'expected a rosbag2 bag directory')
            warnings.append(ReadWarning(str(path), None, f'no metadata.yaml in {path}; reading '
                                        f'the {len(files)} storage file(s) found'))
    else:
        files = [path]
    kinds, readable, errors = set(), [], []
    for file in files:
        try:
            kinds.add(_sniff(file))
            readable.append(file)
        except BagError as err:
            errors.append(err)
    if not readable:
        raise errors[0]
    for err in errors:  # a split bag with one damaged file: read the others
        warnings.append(ReadWarning(str(path), None, f'{err}; skipping that file'))
    files = readable
    if len(kinds) > 1:
        raise BagError(f'{path} mixes MCAP and sqlite3 files; expected one storage format')
    storage = kinds.pop()
    declared = info.get('storage_identifier')
    if declared and declared != storage:
        warnings.append(ReadWarning(str(path), None, f'metadata.yaml says storage '
                                    f'{declared!r} but the files are {storage}; reading them '
                                    f'as {storage}'))
    bag = Bag(path, storage, files, info, validate_crc)
    bag.warnings[:0] = warnings
    return bag


def _check_metadata(meta, info, warnings):
    version = info.get('version')
    if not isinstance(version, int) or version < 1:
        raise BagError(f'{meta}: version must be a positive integer, got {version!r}')
    if version > MAX_METADATA_VERSION:
        warnings.append(ReadWarning(str(meta), None, f'metadata version {version} is newer than '
                                    f'{MAX_METADATA_VERSION}; reading it as version '
                                    f'{MAX_METADATA_VERSION}'))
    mode = str(info.get('compression_mode') or '').lower()
    if mode in ('file', 'message'):
        raise BagError(f'{meta}: rosbag2 {mode} compression '
                       f'({info.get("compression_format")!r}) is not supported; expected '
                       "compression_mode '' (MCAP chunk compression is supported)")
    storage = info.get('storage_identifier')
    if storage not in ('mcap', 'sqlite3'):
        raise BagError(f"{meta}: storage_identifier must be 'mcap' or 'sqlite3', "
                       f'got {storage!r}')
