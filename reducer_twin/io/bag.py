"""
rosbag2 bags: open any recording the analysis may get, write the ones it produces.

``open_bag`` accepts a bag directory (``metadata.yaml`` of version 1 to 9, possibly split
over several storage files), a bare ``.mcap`` file, an sqlite3 ``.db3`` bag of older
distributions, or a ROS 1 ``.bag`` file (:mod:`reducer_twin.io.rosbag1`); rosbag2's zstd
file and message compression are read too (:mod:`reducer_twin.io.rosbag2_compression`,
the recording left as it is). QoS may be
written with integer or string policies. The returned :class:`Bag` lists topics and reads
joint state topics as vectorised
:class:`~reducer_twin.msg_adapters.jointstate_cdr.JointStateBatch` es
in receive-time order: ``sensor_msgs/msg/JointState`` (CDR or ROS 1) and ros2_control's
``control_msgs/msg/DynamicJointState``, the latter walked by the message definition the
bag stores and turned into ``<joint>`` and ``<joint><motor_suffix>`` entries
(:mod:`reducer_twin.msg_adapters.dynamic_joint_state`).

Problems that leave data readable (a listed file missing, counts that disagree, a
recording cut short, a corrupt chunk) become :class:`~reducer_twin.io.mcap_array_writer.
ReadWarning` s in ``Bag.warnings``; problems that leave nothing to read raise
:class:`~reducer_twin.core.errors.BagError`.

Writing lives in :mod:`reducer_twin.io.bag_writer` (``BagDirWriter`` and
``write_bag_dir`` are importable from here too); the output of the analysis is always MCAP.
"""

from dataclasses import dataclass
import os
from pathlib import Path
import re
import sqlite3
import stat
from typing import NamedTuple

import numpy as np
from reducer_twin.core.errors import BagError, InvalidInput
from reducer_twin.io.bag_writer import BagDirWriter, write_bag_dir  # noqa: F401
from reducer_twin.io.mcap_format import MAGIC
from reducer_twin.io.mcap_reader import McapBagReader, RawBatch, ReadWarning
from reducer_twin.io.rosbag1 import MAGIC as ROS1_MAGIC, Rosbag1File, SERIALIZATION as ROS1
from reducer_twin.io.rosbag1 import VERSION as ROS1_VERSION
from reducer_twin.io.rosbag2_compression import check_compression, DecompressedFiles
from reducer_twin.io.rosbag2_compression import inflate_batch, is_zstd_file
from reducer_twin.io.rosbag2_compression import without_unfinished
from reducer_twin.io.rosbag2_metadata import custom_data_strings, load_yaml
from reducer_twin.io.rosbag2_metadata import parse_qos_profiles
from reducer_twin.msg_adapters import dynamic_joint_state as djs
from reducer_twin.msg_adapters.jointstate_cdr import (
    concat_batches, decode_joint_states, empty_batch)
from reducer_twin.msg_adapters.jointstate_cdr import MSGTYPE as JOINT_STATE
from reducer_twin.msg_adapters.jointstate_ros1 import decode_ros1_joint_states
from reducer_twin.msg_adapters.msgdef_decoder import load_definitions, MessageDecoder
import yaml

SQLITE_MAGIC = b'SQLite format 3\x00'
JOINT_STATE_TYPES = (JOINT_STATE, djs.MSGTYPE)
"""Message types read as joint states: JointState, and ros2_control's DynamicJointState."""
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
    if head.startswith(ROS1_MAGIC):
        version = head[len(ROS1_MAGIC):].split(b'\n')[0]
        if version != ROS1_VERSION:
            raise BagError(f'{path} is a ROS 1 bag of format version '
                           f'{version.decode("ascii", "replace")}; expected version 2.0 '
                           '(ROS 1 since C Turtle)')
        return 'rosbag1'
    if not head:
        raise BagError(f'{path} is empty (0 bytes); expected an MCAP or sqlite3 rosbag2 file '
                       'or a ROS 1 bag')
    raise BagError(f'{path} is neither MCAP nor sqlite3: byte 0 holds {head[:8].hex(" ")}, '
                   f'expected the MCAP magic {MAGIC.hex(" ")}, "SQLite format 3" or a ROS 1 '
                   'bag\'s "#ROSBAG V2.0"')


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

    def definition(self, topic):
        msgtype = next(t['type'] for t in self._topics if t['name'] == topic)
        try:   # rosbag2 Iron and later store definitions; older bags do not
            row = self._db.execute(
                'SELECT encoding, encoded_message_definition FROM message_definitions '
                'WHERE topic_type = ? ORDER BY id LIMIT 1', (msgtype,)).fetchone()
        except sqlite3.Error:
            row = None
        return tuple(row) if row and row[1] else None

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

    def definition(self, topic):
        for channel in self.reader.channels.values():
            schema = self.reader.schemas.get(channel.schema_id)
            if channel.topic == topic and schema is not None and schema.data:
                return schema.encoding, schema.data.decode('utf-8', 'replace')
        return None

    def rosbag2_metadata(self):
        return self.reader.rosbag2_metadata()

    def iter_batches(self, topics):
        return self.reader.iter_batches(topics)

    def close(self):
        self.reader.close()


class _Rosbag1(Rosbag1File):
    """Adapter of Rosbag1File to the storage-file interface of Bag."""

    def topics(self):
        return {name: TopicDetails(name, msgtype, count, ROS1, (), '')
                for name, (msgtype, count) in super().topics().items()}

    def rosbag2_metadata(self):
        return None


_STORAGES = {'mcap': _McapFile, 'sqlite3': _Sqlite3File, 'rosbag1': _Rosbag1}


class Bag:
    """
    An opened recording (use :func:`open_bag`).

    Attributes
    ----------
    path : pathlib.Path
        What was opened.
    files : list of pathlib.Path
        Storage files, in recording order.
    storage : str
        ``'mcap'``, ``'sqlite3'`` or ``'rosbag1'``.
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
    interfaces : InterfaceMap
        DynamicJointState interfaces of the joint and motor entries.
    motor_suffix : str
        Suffix of the motor entries made from DynamicJointState.

    """

    def __init__(self, path, storage, files, info, validate_crc=True, interfaces=None,
                 motor_suffix='_motor', copies=None):
        self.path = Path(path)
        self._copies = copies or DecompressedFiles()
        self._undecompressed = {}
        self.storage = storage
        self.info = info or {}
        self.warnings = []
        self.interfaces = interfaces or djs.InterfaceMap()
        self.motor_suffix = motor_suffix
        self._decoders = {}
        self._files = []
        errors = []
        for file in files:
            try:
                self._files.append(_McapFile(file, validate_crc) if storage == 'mcap'
                                   else _STORAGES[storage](file))
            except BagError as err:
                errors.append(err)
        if errors and not self._files:
            raise errors[0]
        for err in errors:
            self._warn(f'{err}; skipping that file')
        self.files = [Path(self._copies.origin.get(str(f.path), f.path)) for f in self._files]
        self._collect()

    # ----------------------------------------------------------------- public API

    def read_joint_states(self, topics=None, errors='skip'):
        """
        Read joint state topics as arrays, in receive-time order across all files.

        Parameters
        ----------
        topics : str or iterable of str, optional
            Topic names; default every topic of a :data:`JOINT_STATE_TYPES` type.
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
            If a topic is not in the bag or is not a joint state topic.

        """
        names = self._joint_state_topics(topics)
        parts = {name: [] for name in names}
        rejected = {name: [] for name in names}
        for name, decoded, path in self._iter_joint_states(names, errors):
            rejected[name] += [(path, reason) for _, reason in decoded.rejected]
            parts[name].append(decoded)
        for name, problems in rejected.items():
            if problems:
                kind = self.topics[name].msgtype.rsplit('/', 1)[-1]
                self._warn(f'{len(problems)} malformed {kind} message(s) on {name} skipped; '
                           f'the first: {problems[0][1]}', problems[0][0])
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

    def iter_joint_states(self, topics, errors='skip'):
        """
        Decode joint state topics piece by piece (about one storage chunk each), in order.

        Parameters
        ----------
        topics : str or iterable of str
            Topics of a :data:`JOINT_STATE_TYPES` type.
        errors : {'skip', 'raise'}
            Leave malformed messages out (listed in ``rejected`` of the batch) or raise
            InvalidInput.

        Yields
        ------
        tuple
            ``(topic, JointStateBatch)`` with ``log_time_ns`` of the decoded messages;
            DynamicJointState as ``<joint>`` and ``<joint><motor_suffix>`` entries. File
            after file; within a file MCAP and sqlite3 give log-time order across topics
            (MCAP chunks that overlap in time are merged), a ROS 1 bag its file order.

        Raises
        ------
        BagError
            If a topic is not a joint state topic, or its message definition is unusable.

        """
        for name, decoded, _ in self._iter_joint_states(self._joint_state_topics(topics),
                                                        errors):
            yield name, decoded

    def iter_raw(self, topics=None):
        """
        Iterate over raw messages, per storage file and chunk.

        Payloads are CDR: the messages of a ROS 1 bag are converted one by one by their
        connection's definition (``std_msgs/Header`` loses its ``seq``, as in ROS 2);
        :meth:`iter_joint_states` reads joint states of any bag column-wise instead.

        Parameters
        ----------
        topics : str or iterable of str, optional
            Topic names; default all.

        Yields
        ------
        tuple
            ``(topic, RawBatch)``; within a file in the order of :meth:`iter_joint_states`.

        """
        names = self._known_topics(topics)
        for handle in self._files:
            for batch in self._batches(handle, names):
                for name, sub in self._split(handle, batch).items():
                    if self.topic_details[name].serialization_format == ROS1:
                        sub = self._ros1_to_cdr(handle, name, sub)
                    yield name, sub
            self._take_warnings(handle)

    def close(self):
        """Release all files (and delete the decompressed copies of compressed ones)."""
        for handle in self._files:
            handle.close()
        self._files = []
        self._copies.close()

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
        origin = self._copies.origin.get(str(handle.path))
        for warning in handle.warnings:
            if origin is not None:   # said of the recording's file, not of its copy
                warning = ReadWarning(origin, None, f'(decompressed) {warning.message}')
            if warning not in self.warnings:
                self.warnings.append(warning)
        failed = self._undecompressed.pop(str(handle.path), 0)
        if failed:
            self._warn(f'{failed:,} message payload(s) are zstd frames that do not decompress '
                       '(rosbag2 message compression); skipping them',
                       self._copies.origin.get(str(handle.path), handle.path))

    def _batches(self, handle, names):
        """Read raw batches of a file, with payloads of message compression decompressed."""
        for batch in handle.iter_batches(names):
            if self.storage != 'rosbag1':   # a CDR payload starts with 0, a zstd frame not
                batch, failed = inflate_batch(batch)
                if failed:
                    key = str(handle.path)
                    self._undecompressed[key] = self._undecompressed.get(key, 0) + failed
            yield batch

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
            return [n for n, t in self.topics.items() if t.msgtype in JOINT_STATE_TYPES]
        names = self._known_topics(topics)
        for name in names:
            if self.topics[name].msgtype not in JOINT_STATE_TYPES:
                raise BagError(f'topic {name} in {self.path} is {self.topics[name].msgtype}, '
                               f'expected {" or ".join(JOINT_STATE_TYPES)}')
        return names

    def _iter_joint_states(self, names, errors):
        for handle in self._files:
            for batch in self._batches(handle, names):
                for name, sub in self._split(handle, batch).items():
                    decode = self._decoder(handle, name)
                    decoded = decode(sub.data, sub.offsets, sub.lengths, errors)
                    logs = sub.log_time_ns
                    if decoded.rejected:
                        keep = np.ones(len(sub), bool)
                        keep[[i for i, _ in decoded.rejected]] = False
                        logs = logs[keep]
                    decoded.log_time_ns = logs
                    yield name, decoded, handle.path
            self._take_warnings(handle)

    def _decoder(self, handle, topic):
        """Return ``decode(data, offsets, lengths, errors)`` for a joint state topic."""
        key = (id(handle), topic)
        if key in self._decoders:
            return self._decoders[key]
        msgtype = self.topics[topic].msgtype
        ros1 = self.topic_details[topic].serialization_format == ROS1
        if msgtype == JOINT_STATE and not ros1:
            def decode(data, offsets, lengths, errors):
                return decode_joint_states(data, offsets, lengths, errors=errors)
        else:
            decoder = self._definition_decoder(handle, topic, msgtype, ros1)
            if msgtype == JOINT_STATE:
                def decode(data, offsets, lengths, errors):
                    return decode_ros1_joint_states(decoder, data, offsets, lengths, errors)
            else:
                interfaces, suffix = self.interfaces, self.motor_suffix

                def decode(data, offsets, lengths, errors):
                    return djs.decode_dynamic_joint_states(decoder, data, offsets, lengths,
                                                           interfaces, suffix, errors)
        self._decoders[key] = decode
        return decode

    def _definition_decoder(self, handle, topic, msgtype, ros1):
        stored = handle.definition(topic)
        if stored is None and msgtype == djs.MSGTYPE:
            self._warn(f'{topic}: the bag stores no message definition of {msgtype} (rosbag2 '
                       'before Iron does not); reading it with the definition of control_msgs '
                       '4 to 5', handle.path)
            stored = ('ros2msg', djs.DEFINITION)
        if stored is None:
            raise BagError(f'{handle.path}: no message definition of {msgtype} stored for '
                           f'{topic}; cannot read it')
        try:
            types = load_definitions(msgtype, stored[1], stored[0])
            return MessageDecoder(msgtype, types, 'ros1' if ros1 else 'cdr')
        except InvalidInput as err:
            raise BagError(f'{handle.path}: {topic}: {err}') from None

    def _ros1_to_cdr(self, handle, topic, sub):
        """Convert the ROS 1 payloads of one topic to CDR, by the connection's definition."""
        key = (id(handle), topic, 'cdr')
        if key not in self._decoders:
            from rosbags.typesys import get_typestore, Stores
            store = get_typestore(Stores.EMPTY)
            msgtype = self.topics[topic].msgtype
            try:
                types = load_definitions(msgtype, handle.definition(topic)[1], 'ros1msg')
                if 'std_msgs/msg/Header' in types:   # rosbags drops seq itself
                    types['std_msgs/msg/Header'] = get_typestore(
                        Stores.ROS2_JAZZY).fielddefs['std_msgs/msg/Header']
                store.register(types)
            except (InvalidInput, ValueError) as err:
                raise BagError(f'{handle.path}: {topic}: {err}') from None
            self._decoders[key] = (store, msgtype)
        store, msgtype = self._decoders[key]
        payloads, keep = [], np.ones(len(sub), bool)
        for i in range(len(sub)):
            try:
                payloads.append(bytes(store.ros1_to_cdr(sub.payload(i), msgtype)))
            except Exception as err:  # noqa: B902 - rosbags raises several kinds
                keep[i] = False
                self._warn(f'{topic}: a {msgtype} message cannot be converted to CDR '
                           f'({type(err).__name__}: {err}); skipping it', handle.path)
        lengths = np.array([len(p) for p in payloads], np.int64)
        offsets = np.zeros(len(payloads), np.int64)
        np.cumsum(lengths[:-1], out=offsets[1:])
        return RawBatch(sub.channel_id[keep], sub.sequence[keep], sub.log_time_ns[keep],
                        sub.publish_time_ns[keep],
                        np.frombuffer(b''.join(payloads), np.uint8), offsets, lengths)

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
    # Parts of one batch share its buffer: their offsets give the topic's order (file
    # order in a chunk, log-time order where the reader merged overlapping chunks).
    shared = first.data is second.data
    shift = 0 if shared else first.data.shape[0]
    data = first.data if shared else np.concatenate([first.data, second.data])
    order = np.argsort(np.concatenate([first.offsets, second.offsets + shift]), kind='stable')

    def cat(a, b):
        return np.concatenate([a, b])[order]

    return RawBatch(cat(first.channel_id, second.channel_id),
                    cat(first.sequence, second.sequence),
                    cat(first.log_time_ns, second.log_time_ns),
                    cat(first.publish_time_ns, second.publish_time_ns), data,
                    cat(first.offsets, second.offsets + shift),
                    cat(first.lengths, second.lengths))


def _safe_qos(value):
    try:
        return parse_qos_profiles(value)
    except InvalidInput:
        return ()


def _read_metadata_yaml(path):
    try:
        text = path.read_text(encoding='utf-8')
        document = load_yaml(text)
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


def open_bag(path, validate_crc=True, interfaces=None, motor_suffix='_motor'):
    """
    Open a rosbag2 recording or a ROS 1 bag.

    Parameters
    ----------
    path : str or os.PathLike
        A bag directory, a ``metadata.yaml``, a ``.mcap`` file, a ``.db3`` file or a
        ROS 1 ``.bag`` file.
    validate_crc : bool
        Check MCAP chunk CRCs where stored.
    interfaces : InterfaceMap, optional
        DynamicJointState interfaces of the joint and motor entries (default names
        ``position``, ``velocity``, ``effort``, ``motor_position``, ...).
    motor_suffix : str
        Suffix of the motor entries made from DynamicJointState.

    Returns
    -------
    Bag
        The opened bag; close it (or use it as a context manager) when done.

    Raises
    ------
    BagError
        If the path does not exist, holds no storage file, is neither MCAP, sqlite3 nor
        an indexed ROS 1 bag, uses a rosbag2 compression other than zstd, or its
        metadata.yaml is unreadable or lists only missing files.

    """
    path = Path(path)
    if not path.exists():
        raise BagError(f'{path} does not exist; expected a rosbag2 bag directory, a .mcap, '
                       'a .db3 or a ROS 1 .bag file')
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
            files, unfinished = without_unfinished(sorted(
                [*path.glob('*.mcap'), *path.glob('*.db3'), *path.glob('*.mcap.zstd'),
                 *path.glob('*.db3.zstd')], key=_natural_key))
            for file in unfinished:
                warnings.append(ReadWarning(str(file), None, f'{file.name[:-5]} is there too '
                                            '(a compression that did not finish): reading that'))
            if not files:
                ros1 = sorted(p.name for p in path.glob('*.bag'))
                hint = f'; ROS 1 bags are given as files: {ros1[:3]}' if ros1 else ''
                raise BagError(f'{path} has no metadata.yaml and no .mcap or .db3 file; '
                               f'expected a rosbag2 bag directory{hint}')
            warnings.append(ReadWarning(str(path), None, f'no metadata.yaml in {path}; reading '
                                        f'the {len(files)} storage file(s) found'))
    else:
        files = [path]
    copies = DecompressedFiles()   # of files rosbag2 compressed whole (file mode)
    try:    # whatever stops the opening (an error, Ctrl-C while decompressing) removes them
        bag = _open_storage(path, files, info, warnings, copies, validate_crc, interfaces,
                            motor_suffix)
    except BaseException:
        copies.close()
        raise
    bag.warnings[:0] = warnings
    return bag


def _open_storage(path, files, info, warnings, copies, validate_crc, interfaces, motor_suffix):
    """Sniff the storage files (decompressing compressed ones into ``copies``); open the bag."""
    kinds, readable, errors = set(), [], []
    for file in files:
        try:
            if is_zstd_file(file):
                file = copies.decompress(file)
            kinds.add(_sniff(file))
            readable.append(file)
        except BagError as err:
            errors.append(err)
    warnings += copies.warnings
    if not readable:
        raise errors[0]
    for err in errors:  # a split bag with one damaged file: read the others
        warnings.append(ReadWarning(str(path), None, f'{err}; skipping that file'))
    files = readable
    if len(kinds) > 1:
        raise BagError(f'{path} mixes {" and ".join(sorted(kinds))} files; expected one '
                       'storage format')
    storage = kinds.pop()
    declared = info.get('storage_identifier')
    if declared and declared != storage:
        warnings.append(ReadWarning(str(path), None, f'metadata.yaml says storage '
                                    f'{declared!r} but the files are {storage}; reading them '
                                    f'as {storage}'))
    return Bag(path, storage, files, info, validate_crc, interfaces, motor_suffix, copies)


def _check_metadata(meta, info, warnings):
    version = info.get('version')
    if not isinstance(version, int) or version < 1:
        raise BagError(f'{meta}: version must be a positive integer, got {version!r}')
    if version > MAX_METADATA_VERSION:
        warnings.append(ReadWarning(str(meta), None, f'metadata version {version} is newer than '
                                    f'{MAX_METADATA_VERSION}; reading it as version '
                                    f'{MAX_METADATA_VERSION}'))
    check_compression(meta, info)
    storage = info.get('storage_identifier')
    if storage not in ('mcap', 'sqlite3'):
        raise BagError(f"{meta}: storage_identifier must be 'mcap' or 'sqlite3', "
                       f'got {storage!r}')
