"""
Fast MCAP writing in the layout rosbag2 (Jazzy) uses.

The writer produces what ``ros2 bag record -s mcap`` writes: the MCAP magic, a Header
of profile ``ros2``, Schema records of encoding ``ros2msg`` and Channel records of
message encoding ``cdr`` (inside the first chunk that follows ``add_topic``, as libmcap
does), chunks with their Message Index records, a ``rosbag2`` Metadata record holding
the serialised bag metadata (written when the file is opened and again when it is
closed), Data End, and a summary of schemas, channels, statistics, chunk indexes and
metadata indexes with summary offsets and a footer. Channel metadata holds
``offered_qos_profiles`` (YAML, metadata version 9: policies as strings) and
``topic_type_hash`` (``RIHS01_...``).

Where this writer differs from ``ros2 bag record``, on purpose: the Header names this
library, not libmcap; chunk CRCs (rosbag2 sets ``noChunkCRC``) and the data-section CRC
are written, so corruption is detected; chunks are zstd-compressed by default (rosbag2's
default is none; level 1 is libmcap's ``Zstd`` default) and ``compression='none'`` gives
rosbag2's plain chunks. Message sequence numbers are 0, as rosbag2 on Jazzy writes them.

Speed comes from treating messages as arrays: ``write_batch`` and
``write_template_batch`` fill whole chunks of message records with numpy column writes
into reused buffers while earlier chunks compress on worker threads.
"""

from dataclasses import dataclass
from pathlib import Path
import struct
import zlib

from mcap.records import (
    Channel, ChunkIndex, DataEnd, Footer, Header, Metadata, MetadataIndex, Schema, Statistics,
    SummaryOffset)
import numpy as np
from reducer_twin.core.errors import BagError, InvalidInput
from reducer_twin.io.background import Background
from reducer_twin.io.mcap_format import (
    _compress, _COMPRESSIONS, _lz4, _string, _zstd, DEFAULT_CHUNK_SIZE, LIBRARY, MAGIC,
    MESSAGE_HEADER, OP_CHANNEL, OP_CHUNK, OP_CHUNK_INDEX, OP_MESSAGE, OP_MESSAGE_INDEX,
    OP_METADATA_INDEX, OP_SCHEMA, OP_STATISTICS, PROFILE, record_bytes)
from reducer_twin.io.rosbag2_metadata import (
    bag_metadata, DEFAULT_QOS, dump_yaml, parse_qos_profiles)
from reducer_twin.msg_adapters import ros_schemas


def message_times(log_times_ns, publish_times_ns=None):
    """
    Check the log and publish times of N messages.

    Parameters
    ----------
    log_times_ns : array_like of int
        int64[N] receive times in ns.
    publish_times_ns : array_like of int, optional
        int64[N] send times in ns; default the log times.

    Returns
    -------
    tuple of numpy.ndarray
        ``(log, publish)`` as uint64[N].

    Raises
    ------
    InvalidInput
        On arrays that are not 1-D integers of one shape, or negative times.

    """
    logs = np.asarray(log_times_ns)
    if logs.ndim != 1 or not np.issubdtype(logs.dtype, np.integer):
        raise InvalidInput(f'log_times_ns must be a 1-D integer array in ns, got dtype '
                           f'{logs.dtype} and shape {logs.shape}')
    pubs = logs if publish_times_ns is None else np.asarray(publish_times_ns)
    if pubs.shape != logs.shape or not np.issubdtype(pubs.dtype, np.integer):
        raise InvalidInput(f'publish_times_ns must be integers of shape {logs.shape}, got '
                           f'{pubs.dtype} {pubs.shape}')
    if logs.shape[0] and (logs.min() < 0 or pubs.min() < 0):
        raise InvalidInput('log_times_ns and publish_times_ns must be >= 0 ns')
    return logs.astype(np.uint64), pubs.astype(np.uint64)


@dataclass
class _Topic:
    channel_id: int
    name: str
    msgtype: str
    qos: tuple
    type_hash: str
    count: int = 0
    start: int = None
    end: int = None


class TopicBook:
    """
    What a bag writer tells about its file: ``custom_data``, per-topic and per-file summaries.

    Shared by :class:`McapBagWriter` and the library-framed writer of
    :mod:`reducer_twin.io.mcap_writer`; both keep ``_topics`` (objects with ``name``,
    ``msgtype``, ``qos``, ``type_hash``, ``count``, ``start``, ``end``) and ``path``.
    """

    def set_custom_data(self, mapping):
        """
        Set rosbag2 ``custom_data`` (str to str) to store when the file is closed.

        Parameters
        ----------
        mapping : dict
            Keys and values, converted to str.

        """
        self.custom_data = {str(k): str(v) for k, v in mapping.items()}

    def topic_summaries(self):
        """
        Return what was written per topic.

        Returns
        -------
        list of dict
            ``name``, ``type``, ``qos``, ``type_hash``, ``count``, ``start``, ``end``.

        """
        return [{'name': t.name, 'type': t.msgtype, 'qos': t.qos, 'type_hash': t.type_hash,
                 'count': t.count, 'start': t.start, 'end': t.end}
                for t in self._topics.values()]

    def file_summary(self):
        """
        Return the per-file entry of the bag metadata.

        Returns
        -------
        dict
            ``path`` (file name), ``start``, ``end`` (ns or None) and ``count``.

        """
        starts = [t.start for t in self._topics.values() if t.start is not None]
        ends = [t.end for t in self._topics.values() if t.end is not None]
        return {'path': self.path.name, 'start': min(starts) if starts else None,
                'end': max(ends) if ends else None,
                'count': sum(t.count for t in self._topics.values())}


class McapBagWriter(TopicBook):
    """
    Write one rosbag2 MCAP file.

    Parameters
    ----------
    path : str or os.PathLike
        File to create (``.mcap``).
    compression : {'zstd', 'lz4', 'none'}
        Chunk compression. rosbag2's own default is ``none``; zstd makes files about
        seven times smaller at little cost.
    chunk_size : int
        Uncompressed bytes per chunk (libmcap's default, 768 KiB).
    compression_level : int
        zstd level; 1 is what libmcap (and so rosbag2) uses for ``Zstd``.
    chunk_crc : bool
        Store the CRC-32 of each uncompressed chunk (rosbag2 turns it off; readers use
        it to detect corruption).
    data_crc : bool
        Store the CRC-32 of the data section in the Data End record.
    custom_data : dict of str to str, optional
        rosbag2 ``custom_data``, stored in the ``rosbag2`` metadata record.
    overwrite : bool
        Replace an existing file.
    threads : int
        Chunks compressed in parallel when a batch fills several chunks.

    Raises
    ------
    BagError
        If the file exists (and ``overwrite`` is false) or cannot be created.
    InvalidInput
        On an unknown compression or a chunk size below 1 KiB.

    """

    def __init__(self, path, compression='zstd', chunk_size=DEFAULT_CHUNK_SIZE,
                 compression_level=1, chunk_crc=True, data_crc=True, custom_data=None,
                 overwrite=False, threads=2):
        if compression is None:
            compression = 'none'
        if compression not in _COMPRESSIONS:
            raise InvalidInput(f"compression must be 'zstd', 'lz4' or 'none', "
                               f'got {compression!r}')
        self.compression = _COMPRESSIONS[compression]
        if self.compression == 'zstd' and _zstd is None:  # pragma: no cover
            raise BagError('zstd compression needs backports.zstd (pip install backports.zstd)')
        if self.compression == 'lz4' and _lz4 is None:  # pragma: no cover
            raise BagError('lz4 compression needs the lz4 package (pip install lz4)')
        if int(chunk_size) < 1024:
            raise InvalidInput(f'chunk_size must be >= 1024 bytes, got {chunk_size!r}')
        self.path = Path(path)
        self.chunk_size = int(chunk_size)
        self.compression_level = int(compression_level)
        self.chunk_crc = bool(chunk_crc)
        self.data_crc = bool(data_crc)
        self.custom_data = {str(k): str(v) for k, v in (custom_data or {}).items()}
        if self.path.exists() and not overwrite:
            raise BagError(f'{self.path} already exists; pass overwrite=True to replace it')
        try:
            self._file = open(self.path, 'wb')
        except OSError as err:
            raise BagError(f'cannot create {self.path}: {err.strerror}') from err
        self._closed = False
        self._pos = 0
        self._crc = 0
        self._schemas = {}  # msgtype -> mcap.records.Schema
        self._topics = {}  # name -> _Topic
        self._channels = []  # mcap.records.Channel
        # Chunks are built in a ring of reused buffers (no page faults, no copies) while
        # earlier chunks are compressed on the thread pool.
        self._ring = [np.empty(self.chunk_size + 65536, np.uint8)
                      for _ in range(3 if threads > 1 else 1)]
        self._ring_index = 0
        self._chunk = self._ring[0]
        self._chunk_len = 0
        self._chunk_start = None
        self._chunk_end = None
        self._index = {}  # channel id -> list of uint64 (k, 2) arrays (log time, offset)
        self._chunk_indexes = []
        self._metadata_indexes = []
        self._pool = Background(threads, 'mcap-write') if threads > 1 else None
        self._pending = []
        self._write(MAGIC)
        self._write(record_bytes(Header(profile=PROFILE, library=LIBRARY)))
        self._write_rosbag2_metadata()

    # ----------------------------------------------------------------- public API

    def add_topic(self, name, msgtype, qos=DEFAULT_QOS, schema_text=None, type_hash=None):
        """
        Declare a topic: a Schema record (once per type) and a Channel record.

        Parameters
        ----------
        name : str
            Topic name, e.g. ``'/joint_states'``.
        msgtype : str
            ROS type, e.g. ``'sensor_msgs/msg/JointState'``.
        qos : sequence of QosProfile, str or list of dict
            Offered QoS profiles; default: what rosbag2 records for an rclpy publisher.
        schema_text : str, optional
            ``ros2msg`` definition; default: read from the installed ROS packages.
        type_hash : str, optional
            ``RIHS01_...``; default: read from the installed ROS packages.

        Returns
        -------
        int
            The channel id to pass to ``write`` and ``write_batch``.

        Raises
        ------
        BagError
            If the topic exists already, the writer is closed, or the type's definition
            is not installed.

        """
        self._check_open()
        if name in self._topics:
            raise BagError(f'topic {name!r} was already added to {self.path}')
        if schema_text is None or type_hash is None:
            schema_text = ros_schemas.message_definition(msgtype) if schema_text is None \
                else schema_text
            type_hash = ros_schemas.type_hash(msgtype) if type_hash is None else type_hash
        profiles = parse_qos_profiles(qos)
        if msgtype not in self._schemas:
            schema_id = len(self._schemas) + 1
            schema = Schema(id=schema_id, name=msgtype, encoding='ros2msg',
                            data=schema_text.encode('utf-8'))
            self._schemas[msgtype] = schema
            self._append_bytes(record_bytes(schema))
        schema_id = self._schemas[msgtype].id
        channel_id = len(self._topics) + 1
        qos_text = dump_yaml([p.as_dict() for p in profiles]) if profiles else ''
        channel = Channel(id=channel_id, schema_id=schema_id, topic=name, message_encoding='cdr',
                          metadata={'offered_qos_profiles': qos_text,
                                    'topic_type_hash': type_hash})
        self._channels.append(channel)
        self._append_bytes(record_bytes(channel))
        self._topics[name] = _Topic(channel_id, name, msgtype, profiles, type_hash)
        return channel_id

    def write(self, channel_id, log_time_ns, data, publish_time_ns=None, sequence=0):
        """
        Write one message.

        Parameters
        ----------
        channel_id : int
            From ``add_topic``.
        log_time_ns : int
            Receive time in ns (what rosbag2 plays back by).
        data : bytes-like
            Serialised CDR payload.
        publish_time_ns : int, optional
            Send time in ns; default ``log_time_ns``.
        sequence : int
            MCAP sequence number (rosbag2 on Jazzy writes 0).

        Raises
        ------
        InvalidInput
            On an unknown channel or a negative time.

        """
        topic = self._topic_of(channel_id)
        log_time = int(log_time_ns)
        publish = log_time if publish_time_ns is None else int(publish_time_ns)
        if log_time < 0 or publish < 0:
            raise InvalidInput(f'log_time_ns and publish_time_ns must be >= 0 ns, got '
                               f'{log_time} and {publish}')
        payload = bytes(data)
        if self._chunk_len and self._chunk_len + MESSAGE_HEADER + len(payload) > \
                self.chunk_size:
            self._finish_chunk()
        offset = self._chunk_len
        self._append_bytes(struct.pack('<BQHIQQ', OP_MESSAGE, 22 + len(payload), channel_id,
                                       sequence, log_time, publish) + payload)
        self._note_messages(topic, np.array([log_time], np.uint64),
                            np.array([offset], np.uint64))

    def write_batch(self, channel_id, log_times_ns, buffer, offsets, publish_times_ns=None):
        """
        Write N messages of one channel held back to back in one buffer.

        Parameters
        ----------
        channel_id : int
            From ``add_topic``.
        log_times_ns : array_like of int
            int64[N] receive times in ns.
        buffer : bytes-like or numpy.ndarray
            The payloads, message i at ``buffer[offsets[i]:offsets[i + 1]]``.
        offsets : array_like of int
            int64[N + 1] boundaries, as ``encode_joint_states`` returns them.
        publish_times_ns : array_like of int, optional
            int64[N] send times; default the log times.

        Raises
        ------
        InvalidInput
            On shapes that disagree, offsets outside the buffer or negative times.

        """
        topic = self._topic_of(channel_id)
        logs, pubs = self._times(log_times_ns, publish_times_ns)
        bounds = np.asarray(offsets, dtype=np.int64).reshape(-1)
        n = logs.shape[0]
        if bounds.shape[0] != n + 1:
            raise InvalidInput(f'write_batch needs N log times and N + 1 offsets, got shapes '
                               f'{logs.shape} and {bounds.shape}')
        if n == 0:
            return
        raw = buffer if isinstance(buffer, np.ndarray) else np.frombuffer(buffer, np.uint8)
        raw = raw.reshape(-1).view(np.uint8)
        lengths = np.diff(bounds)
        if bounds[0] < 0 or bounds[-1] > raw.shape[0] or (lengths < 0).any():
            raise InvalidInput(f'offsets must rise from >= 0 to <= {raw.shape[0]} (the buffer '
                               f'size), got {bounds[0]} .. {bounds[-1]}')
        if (lengths == lengths[0]).all():
            length = int(lengths[0])
            payloads = raw[bounds[0]:bounds[-1]].reshape(n, length)
            self._write_uniform(topic, logs, pubs, payloads, length, ())
        else:
            self._write_mixed(topic, logs, pubs, raw, bounds, lengths)

    def write_template_batch(self, channel_id, log_times_ns, template, columns,
                             publish_times_ns=None):
        """
        Write N messages that are one payload template with per-message fields.

        The messages are built in place in the chunk buffer: the template is copied into
        every record, then the columns are written through strided numpy views. This is
        the fastest way to write sampled signals (see ``joint_state_columns``).

        Parameters
        ----------
        channel_id : int
            From ``add_topic``.
        log_times_ns : array_like of int
            int64[N] receive times in ns.
        template : bytes-like or numpy.ndarray
            One serialised payload (uint8[L]).
        columns : sequence of tuple
            ``(offset, dtype, values)``: values of shape [N] or [N, k] written at byte
            ``offset`` of each payload with numpy dtype ``dtype``.
        publish_times_ns : array_like of int, optional
            int64[N] send times; default the log times.

        Raises
        ------
        InvalidInput
            On shapes that disagree, columns outside the template or negative times.

        """
        topic = self._topic_of(channel_id)
        logs, pubs = self._times(log_times_ns, publish_times_ns)
        template = np.frombuffer(bytes(template), np.uint8) \
            if not isinstance(template, np.ndarray) else template.reshape(-1).view(np.uint8)
        length = template.shape[0]
        checked = []
        for offset, dtype, values in columns:
            values = np.asarray(values)
            width = np.dtype(dtype).itemsize * (values.shape[1] if values.ndim == 2 else 1)
            if values.shape[0] != logs.shape[0] or values.ndim > 2 or offset < 0 \
                    or offset + width > length:
                raise InvalidInput(
                    f'column at byte {offset} ({dtype}, shape {values.shape}) must hold N = '
                    f'{logs.shape[0]} rows and fit the {length}-byte template')
            checked.append((offset, dtype, values))
        if logs.shape[0]:
            self._write_uniform(topic, logs, pubs, template, length, checked)

    def close(self):
        """
        Flush the last chunk and write metadata, Data End, summary and footer.

        Returns
        -------
        dict
            ``file_summary()`` of the finished file.

        """
        if self._closed:
            return self.file_summary()
        try:
            if self._chunk_len:
                self._finish_chunk()
            self._drain()
            self._write_rosbag2_metadata()
            data_end = record_bytes(DataEnd(data_section_crc=self._crc))
            self._file.write(data_end)
            self._pos += len(data_end)
            self._write_summary()
        finally:
            self._closed = True
            self._file.close()
            if self._pool is not None:
                self._pool.close()
        return self.file_summary()

    def discard(self):
        """Close the file without finishing it (after an error; the caller removes it)."""
        self._closed = True
        try:
            self._file.close()
        except OSError:
            pass  # a full disk fails the flush again: the file is removed anyway
        if self._pool is not None:
            self._pool.close()  # a chunk in flight is compressed for nobody, never awaited

    def __enter__(self):
        """Return the writer."""
        return self

    def __exit__(self, *exc):
        """Close the file, also after an error, so what was written stays readable."""
        self.close()

    # ----------------------------------------------------------------- internals

    def _check_open(self):
        if self._closed:
            raise BagError(f'{self.path} is closed; open a new writer to write more')

    def _topic_of(self, channel_id):
        self._check_open()
        for topic in self._topics.values():
            if topic.channel_id == channel_id:
                return topic
        raise InvalidInput(f'channel id {channel_id!r} was not returned by add_topic; known '
                           f'channels: {[t.channel_id for t in self._topics.values()]}')

    def _times(self, log_times_ns, publish_times_ns):
        return message_times(log_times_ns, publish_times_ns)

    def _write(self, data):
        self._file.write(data)
        self._pos += len(data)
        if self.data_crc:
            self._crc = zlib.crc32(data, self._crc)

    def _write_rosbag2_metadata(self):
        info = bag_metadata(self.topic_summaries(), [self.file_summary()], self.custom_data)
        record = record_bytes(Metadata(name='rosbag2',
                                       metadata={'serialized_metadata': dump_yaml(info)}))
        self._metadata_indexes.append((self._pos, len(record), 'rosbag2'))
        self._write(record)

    def _reserve(self, size):
        need = self._chunk_len + size
        if need > self._chunk.shape[0]:
            grown = np.empty(max(need, 2 * self._chunk.shape[0]), np.uint8)
            grown[:self._chunk_len] = self._chunk[:self._chunk_len]
            self._chunk = self._ring[self._ring_index] = grown

    def _append_bytes(self, data):
        self._reserve(len(data))
        self._chunk[self._chunk_len:self._chunk_len + len(data)] = np.frombuffer(data, np.uint8)
        self._chunk_len += len(data)

    def _note_messages(self, topic, logs, rel_offsets):
        self._index.setdefault(topic.channel_id, []).append(
            np.stack([logs, rel_offsets], axis=1))
        lo, hi = int(logs.min()), int(logs.max())
        topic.count += logs.shape[0]
        topic.start = lo if topic.start is None else min(topic.start, lo)
        topic.end = hi if topic.end is None else max(topic.end, hi)
        self._chunk_start = lo if self._chunk_start is None else min(self._chunk_start, lo)
        self._chunk_end = hi if self._chunk_end is None else max(self._chunk_end, hi)

    def _write_uniform(self, topic, logs, pubs, payloads, length, columns):
        """Write equal-length records: ``payloads`` is uint8[N, L] or one template uint8[L]."""
        record = MESSAGE_HEADER + length
        n = logs.shape[0]
        head = np.frombuffer(struct.pack('<BQHIQQ', OP_MESSAGE, 22 + length, topic.channel_id,
                                         0, 0, 0), f'V{MESSAGE_HEADER}')[0]
        if length:
            payloads = payloads.view(f'V{length}')
            payloads = payloads[0] if payloads.ndim == 1 else payloads[:, 0]
        done = 0
        while done < n:
            room = self.chunk_size - self._chunk_len
            k = min(n - done, max(room // record, 0 if self._chunk_len else 1))
            if k == 0:
                self._finish_chunk()
                continue
            self._reserve(k * record)
            start = self._chunk_len
            part = slice(done, done + k)
            rows = self._chunk[start:start + k * record].reshape(k, record)
            rows[:, :MESSAGE_HEADER].view(f'V{MESSAGE_HEADER}')[:, 0] = head
            rows[:, 15:23].view('<u8')[:, 0] = logs[part]
            rows[:, 23:31].view('<u8')[:, 0] = pubs[part]
            if length:
                rows[:, MESSAGE_HEADER:].view(f'V{length}')[:, 0] = \
                    payloads if payloads.ndim == 0 else payloads[part]
            for offset, dtype, values in columns:
                width = np.dtype(dtype).itemsize * (values.shape[1] if values.ndim == 2 else 1)
                at = MESSAGE_HEADER + offset
                view = rows[:, at:at + width].view(dtype)
                view[...] = values[part] if values.ndim == 2 else values[part, None]
            self._chunk_len += k * record
            rel = start + np.arange(k, dtype=np.uint64) * record
            self._note_messages(topic, logs[part], rel)
            done += k
            if self._chunk_len >= self.chunk_size:
                self._finish_chunk()

    def _write_mixed(self, topic, logs, pubs, raw, bounds, lengths):
        sizes = MESSAGE_HEADER + lengths
        ends = np.cumsum(sizes)
        n = logs.shape[0]
        done = 0
        while done < n:
            room = self.chunk_size - self._chunk_len
            used = ends[done - 1] if done else 0
            k = int(np.searchsorted(ends, used + room, side='right')) - done
            k = min(n - done, max(k, 0 if self._chunk_len else 1))
            if k == 0:
                self._finish_chunk()
                continue
            part = slice(done, done + k)
            total = int(sizes[part].sum())
            self._reserve(total)
            start = self._chunk_len
            rel = start + np.concatenate(([0], np.cumsum(sizes[part])[:-1])).astype(np.int64)
            header = np.empty((k, MESSAGE_HEADER), np.uint8)
            header[:, 0] = OP_MESSAGE
            header[:, 1:9] = (22 + lengths[part]).astype('<u8').view(np.uint8).reshape(k, 8)
            header[:, 9:11] = np.frombuffer(struct.pack('<H', topic.channel_id), np.uint8)
            header[:, 11:15] = 0
            header[:, 15:23] = logs[part].astype('<u8').view(np.uint8).reshape(k, 8)
            header[:, 23:31] = pubs[part].astype('<u8').view(np.uint8).reshape(k, 8)
            self._chunk[rel[:, None] + np.arange(MESSAGE_HEADER)] = header
            src_start = bounds[done]
            n_bytes = int(bounds[done + k] - src_start)
            shift = np.repeat(rel + MESSAGE_HEADER - (bounds[part] - src_start), lengths[part])
            self._chunk[np.arange(n_bytes) + shift] = raw[src_start:src_start + n_bytes]
            self._chunk_len += total
            self._note_messages(topic, logs[part], rel.astype(np.uint64))
            done += k
            if self._chunk_len >= self.chunk_size:
                self._finish_chunk()

    def _finish_chunk(self):
        """Hand the current chunk to compression and continue in the next ring buffer."""
        data = self._chunk[:self._chunk_len]
        job = (data, self._chunk_start or 0, self._chunk_end or 0, self._index)
        self._chunk_len = 0
        self._chunk_start = self._chunk_end = None
        self._index = {}
        if self._pool is None:
            self._emit_chunk(job, self._pack(data))
            return
        self._pending.append((job, self._pool.submit(self._pack, data)))
        # A ring buffer is reused only after its chunk was written out.
        while len(self._pending) > len(self._ring) - 1:
            job, future = self._pending.pop(0)
            self._emit_chunk(job, future.result())
        self._ring_index = (self._ring_index + 1) % len(self._ring)
        self._chunk = self._ring[self._ring_index]

    def _drain(self):
        while self._pending:
            job, future = self._pending.pop(0)
            self._emit_chunk(job, future.result())

    def _pack(self, data):
        crc = zlib.crc32(data) if self.chunk_crc else 0
        return crc, _compress(self.compression, data, self.compression_level)

    def _emit_chunk(self, job, packed):
        data, start, end, index = job
        crc, compressed = packed
        chunk_start = self._pos
        head = (struct.pack('<QQQI', start, end, len(data), crc) + _string(self.compression)
                + struct.pack('<Q', len(compressed)))
        body_len = len(head) + len(compressed)
        self._write(struct.pack('<BQ', OP_CHUNK, body_len) + head)
        self._write(compressed)
        chunk_length = 9 + body_len
        index_offsets = {}
        index_start = self._pos
        for channel_id in sorted(index):
            pairs = np.concatenate(index[channel_id]).astype('<u8')
            body = struct.pack('<HI', channel_id, pairs.nbytes) + pairs.tobytes()
            index_offsets[channel_id] = self._pos
            self._write(struct.pack('<BQ', OP_MESSAGE_INDEX, len(body)) + body)
        self._chunk_indexes.append(ChunkIndex(
            message_start_time=start, message_end_time=end, chunk_start_offset=chunk_start,
            chunk_length=chunk_length, message_index_offsets=index_offsets,
            message_index_length=self._pos - index_start, compression=self.compression,
            compressed_size=len(compressed), uncompressed_size=len(data)))

    def _write_summary(self):
        summary_start = self._pos
        groups = []
        out = bytearray()

        def group(opcode, records):
            if not records:
                return
            start = summary_start + len(out)
            out.extend(record_bytes(*records))
            groups.append((opcode, start, summary_start + len(out) - start))

        counts = {t.channel_id: t.count for t in self._topics.values() if t.count}
        starts = [t.start for t in self._topics.values() if t.start is not None]
        ends = [t.end for t in self._topics.values() if t.end is not None]
        statistics = Statistics(
            message_count=sum(counts.values()), schema_count=len(self._schemas),
            channel_count=len(self._channels), attachment_count=0,
            metadata_count=len(self._metadata_indexes), chunk_count=len(self._chunk_indexes),
            message_start_time=min(starts) if starts else 0,
            message_end_time=max(ends) if ends else 0, channel_message_counts=counts)
        group(OP_SCHEMA, sorted(self._schemas.values(), key=lambda schema: schema.id))
        group(OP_CHANNEL, self._channels)
        group(OP_STATISTICS, [statistics])
        group(OP_CHUNK_INDEX, self._chunk_indexes)
        group(OP_METADATA_INDEX, [MetadataIndex(offset=offset, length=length, name=name)
                                  for offset, length, name in self._metadata_indexes])
        offsets_start = summary_start + len(out)
        out.extend(record_bytes(*(SummaryOffset(group_opcode=opcode, group_start=start,
                                                group_length=length)
                                  for opcode, start, length in groups)))
        # The summary CRC covers the summary and the footer up to the CRC field itself.
        footer = record_bytes(Footer(summary_start=summary_start,
                                     summary_offset_start=offsets_start, summary_crc=0))
        crc = zlib.crc32(footer[:-4], zlib.crc32(out))
        tail = bytes(out) + footer[:-4] + struct.pack('<I', crc) + MAGIC
        self._file.write(tail)
        self._pos += len(tail)
