"""
Fast MCAP reading of rosbag2 (Jazzy) files.

The format is read with the ``mcap`` library: the footer, the summary (schemas,
channels, statistics, chunk and metadata indexes), Header, Schema, Channel, Metadata
and Chunk records, chunk decompression and the chunk CRC. What stays the project's
own is the measured hot path: each decompressed chunk is handed out as one buffer
plus offset and length arrays, gathered with numpy from runs of equal-length
message records or from the Message Index records, ready for the vectorised
JointState decoder.

Messages come out in log-time order, as rosbag2 and the mcap library's
``log_time_order=True`` read them. In the usual file the chunks already are in that
order (a recorder writes what it receives as it comes) and are handed out as they lie.
A file that stores topics in separate chunks overlapping in time (a writer that
buffers per topic, or one that writes one topic after the other) would hand one topic
out tens of seconds ahead of another; there the chunks are read by the start times of
the chunk index and their messages merged by log time, window by window.

A file without a usable summary (a recording cut short) is scanned record by record;
what is readable is returned and the reader's ``warnings`` say where reading stopped.
"""

import collections
from dataclasses import dataclass, field
import itertools
import mmap
import os
from pathlib import Path
import re
import struct
import zlib

from mcap.data_stream import ReadDataStream
from mcap.exceptions import EndOfFile, McapError
from mcap.reader import SeekingReader
from mcap.records import Channel, Chunk, Footer, Header, Metadata, Schema
from mcap.stream_reader import CRCValidationError, get_chunk_data_stream
import numpy as np
from reducer_twin.core.errors import BagError
from reducer_twin.io.background import Background
from reducer_twin.io.mcap_format import (
    MAGIC, MESSAGE_HEADER, OP_CHANNEL, OP_CHUNK, OP_DATA_END, OP_FOOTER, OP_HEADER, OP_MESSAGE,
    OP_MESSAGE_INDEX, OP_METADATA, OP_SCHEMA, RECORD_NAMES)
from reducer_twin.io.rosbag2_metadata import custom_data_strings, load_yaml
import yaml

_CODECS = ('', 'zstd', 'lz4')
"""Chunk compressions the mcap library decompresses ('' is none)."""


@dataclass(frozen=True)
class ReadWarning:
    """
    A problem met while reading that did not stop the analysis.

    Attributes
    ----------
    path : str
        The file.
    offset : int or None
        Byte offset in the file where the problem is.
    message : str
        What was wrong and what was done about it.

    """

    path: str
    offset: object
    message: str

    def __str__(self):
        """Return ``'<file>: <message>'``."""
        return f'{Path(self.path).name}: {self.message}'


@dataclass(frozen=True)
class TopicInfo:
    """
    What a file holds for one topic.

    Attributes
    ----------
    name, msgtype : str
        Topic name and ROS type.
    count : int
        Messages in the file.
    serialization_format : str
        ``'cdr'``.
    offered_qos_profiles : str
        The channel's QoS YAML as stored.
    type_hash : str
        ``RIHS01_...`` or ``''``.
    channel_ids : tuple of int
        MCAP channels of the topic.

    """

    name: str
    msgtype: str
    count: int
    serialization_format: str
    offered_qos_profiles: str
    type_hash: str
    channel_ids: tuple


@dataclass
class RawBatch:
    """
    Raw messages of one chunk (or one run of unchunked records), as arrays.

    Message i is ``data[offsets[i]:offsets[i] + lengths[i]]``; ``data`` is the
    decompressed chunk, shared, not copied per message.
    """

    channel_id: np.ndarray
    sequence: np.ndarray
    log_time_ns: np.ndarray
    publish_time_ns: np.ndarray
    data: np.ndarray
    offsets: np.ndarray
    lengths: np.ndarray

    def __len__(self):
        """Return the number of messages."""
        return int(self.offsets.shape[0])

    def payload(self, i):
        """
        Return the payload of message ``i`` as bytes.

        Parameters
        ----------
        i : int
            Message index in the batch.

        Returns
        -------
        bytes
            The CDR payload.

        """
        start = int(self.offsets[i])
        return self.data[start:start + int(self.lengths[i])].tobytes()

    def select(self, mask):
        """
        Return the messages selected by a mask or index array.

        Parameters
        ----------
        mask : array_like
            Boolean mask or indices.

        Returns
        -------
        RawBatch
            The selection, sharing ``data``.

        """
        return RawBatch(self.channel_id[mask], self.sequence[mask], self.log_time_ns[mask],
                        self.publish_time_ns[mask], self.data, self.offsets[mask],
                        self.lengths[mask])


@dataclass
class _ChunkRef:
    offset: int  # of the chunk record in the file
    length: int  # of the whole record
    compression: str = ''
    index_offsets: dict = field(default_factory=dict)  # channel -> message index record
    # Log-time range of the chunk's messages from the chunk index; None when the file
    # was scanned (no index: the chunks are read in file order).
    start_ns: object = None
    end_ns: object = None

    @property
    def data_offset(self):
        """Return the file offset of the chunk's (compressed) records."""
        return self.offset + 9 + 28 + len(self.compression.encode('utf-8')) + 8


class _Corrupt(Exception):
    """Internal: a record or chunk cannot be used."""


def _u64(buf, pos):
    return struct.unpack_from('<Q', buf, pos)[0]


class _View:
    """A read-only stream over a buffer that hands out slices without copying them."""

    def __init__(self, body):
        self._body = memoryview(body)
        self._pos = 0

    def read(self, length):
        out = self._body[self._pos:self._pos + length]
        self._pos += len(out)
        return out


class _RecordBody(ReadDataStream):
    """The mcap library's field reader over one record body; a field past its end is an error."""

    def __init__(self, body):
        super().__init__(_View(body))

    def read(self, length):
        data = super().read(length)
        if len(data) != length:
            raise EndOfFile()
        return data


def _parse(record_type, body, what):
    """
    Parse a record body with the mcap library's record type.

    Raises _Corrupt, naming ``what``, when a field runs past the body or a
    string is not UTF-8.
    """
    try:
        return record_type.read(_RecordBody(body))
    except EndOfFile:
        raise _Corrupt(f'{what} ends inside a field ({len(body)} bytes)') from None
    except UnicodeDecodeError as err:
        raise _Corrupt(f'{what}: a string is not UTF-8 ({err.reason})') from None
    except (struct.error, ValueError, McapError) as err:
        raise _Corrupt(f'{what} is malformed ({err})') from None


def _gather_messages(arr, starts, end):
    """Read the message record fields at ``starts`` of ``arr`` (records end by ``end``)."""
    n = starts.shape[0]
    if n == 0:
        empty = np.zeros(0, np.int64)
        return empty.astype(np.uint16), empty.astype(np.uint32), empty, empty, empty, empty
    if starts.min() < 0 or starts.max() + MESSAGE_HEADER > end:
        raise _Corrupt('a message record offset lies outside the chunk')
    step = int(starts[1] - starts[0]) if n > 1 else 0
    if n > 1 and step >= MESSAGE_HEADER and (np.diff(starts) == step).all():
        head = np.lib.stride_tricks.as_strided(arr[int(starts[0]):], (n, MESSAGE_HEADER),
                                               (step, 1), writeable=False)
    else:
        head = np.lib.stride_tricks.sliding_window_view(arr[:end], MESSAGE_HEADER)[starts]
    if (head[:, 0] != OP_MESSAGE).any():
        bad = int(starts[np.argmax(head[:, 0] != OP_MESSAGE)])
        raise _Corrupt(f'the record at chunk byte {bad} is not a message record')

    def column(a, b, dtype):
        return head[:, a:b].view(f'V{b - a}')[:, 0].copy().view(dtype)

    body = column(1, 9, '<u8').astype(np.int64)
    if (body < 22).any() or (starts + 9 + body > end).any():
        raise _Corrupt('a message record length runs past the end of its chunk')
    return (column(9, 11, '<u2'), column(11, 15, '<u4'), column(15, 23, '<u8').astype(np.int64),
            column(23, 31, '<u8').astype(np.int64), starts + MESSAGE_HEADER, body - 22)


def _walk(buf, start, end, arr=None):
    """
    Yield ``(opcode, starts, body_length)`` for the records in ``buf[start:end]``.

    Runs of records with equal opcode and length are detected with numpy and yielded
    as one array of starts. Raises _Corrupt at a record that does not fit.
    """
    pos = start
    previous = None
    while pos < end:
        if pos + 9 > end:
            raise _Corrupt(f'truncated record header at byte {pos} ({end - pos} of 9 bytes)')
        opcode, length = struct.unpack_from('<BQ', buf, pos)
        stride = 9 + length
        if length > end - pos - 9:
            raise _Corrupt(f'truncated {RECORD_NAMES.get(opcode, f"opcode {opcode}")} record at '
                           f'byte {pos} (needs {stride} bytes, {end - pos} remain)')
        room = (end - pos) // stride
        if arr is not None and previous == (opcode, length) and room > 8:
            run = _run_length(arr, pos, opcode, length, stride, room)
            yield opcode, pos + stride * np.arange(run, dtype=np.int64), length
            pos += run * stride
            previous = None
            continue
        yield opcode, np.array([pos], np.int64), length
        previous = (opcode, length)
        pos += stride


def _run_length(arr, pos, opcode, length, stride, room):
    """Count the records from ``pos`` on that have this opcode and length (probing 16, 512...)."""
    expected = np.frombuffer(struct.pack('<BQ', opcode, length), 'V9')[0]
    checked, limit = 1, 16
    while checked < room:
        upto = min(room, limit)
        first = pos + stride * checked
        heads = np.lib.stride_tricks.as_strided(arr[first:], (upto - checked, 9), (stride, 1),
                                                writeable=False)
        good = heads.view('V9')[:, 0] == expected
        if not good.all():
            return checked + int(np.argmin(good))
        checked, limit = upto, limit * 32
    return room


class McapBagReader:
    """
    Read a rosbag2 MCAP file, fast, tolerating truncation.

    Parameters
    ----------
    path : str or os.PathLike
        The ``.mcap`` file.
    validate_crc : bool
        Check chunk CRCs (and the summary CRC) where the file stores them.

    Attributes
    ----------
    header : tuple of str
        ``(profile, library)``.
    schemas, channels : dict
        ``mcap.records.Schema`` and ``mcap.records.Channel`` records by id.
    warnings : list of ReadWarning
        Problems met; reading goes on after them.
    has_summary : bool
        Whether the summary section was used (otherwise the file was scanned).

    Raises
    ------
    BagError
        If the file is missing, empty, or does not start with the MCAP magic.

    """

    def __init__(self, path, validate_crc=True):
        self.path = Path(path)
        self.validate_crc = bool(validate_crc)
        self.warnings = []
        self.header = ('', '')
        self.schemas = {}
        self.channels = {}
        self.statistics = None
        self.metadata = []  # (name, dict) of Metadata records
        self.has_summary = False
        self._chunks = []
        self._loose = []  # arrays of message record starts outside chunks
        self._loose_parts = []
        self._counts = {}
        try:
            self._file = open(self.path, 'rb')
        except OSError as err:
            raise BagError(f'cannot open {self.path}: {err.strerror}') from err
        self.size = os.fstat(self._file.fileno()).st_size
        if self.size == 0:
            self._file.close()
            raise BagError(f'{self.path} is empty (0 bytes); expected an MCAP file starting '
                           f'with the magic {MAGIC.hex(" ")}')
        self._mm = mmap.mmap(self._file.fileno(), 0, access=mmap.ACCESS_READ)
        head = self._mm[:8]
        if head != MAGIC:
            self.close()
            raise BagError(f'{self.path} is not an MCAP file: byte 0 holds {head.hex(" ")}, '
                           f'expected the magic {MAGIC.hex(" ")}')
        self._read_header()
        try:
            self._read_summary()
            self.has_summary = True
        except _Corrupt as err:
            if str(err):
                self._warn(None, f'{err}; scanning the records instead')
            self._scan()

    # ----------------------------------------------------------------- public API

    def topics(self):
        """
        List the topics of the file.

        Returns
        -------
        dict of str to TopicInfo
            By topic name, in channel id order.

        """
        out = {}
        for cid in sorted(self.channels):
            channel = self.channels[cid]
            schema = self.schemas.get(channel.schema_id)
            count = int(self._counts.get(cid, 0))
            if channel.topic in out:
                old = out[channel.topic]
                out[channel.topic] = TopicInfo(
                    old.name, old.msgtype, old.count + count, old.serialization_format,
                    old.offered_qos_profiles, old.type_hash, old.channel_ids + (cid,))
                continue
            out[channel.topic] = TopicInfo(
                channel.topic, schema.name if schema else '', count,
                channel.message_encoding, channel.metadata.get('offered_qos_profiles', ''),
                channel.metadata.get('topic_type_hash', ''), (cid,))
        return out

    def rosbag2_metadata(self):
        """
        Return the bag metadata rosbag2 stored in the file, if any.

        Returns
        -------
        dict or None
            The last ``rosbag2`` Metadata record's ``serialized_metadata``, parsed.

        """
        for name, values in reversed(self.metadata):
            if name == 'rosbag2' and 'serialized_metadata' in values:
                try:
                    info = load_yaml(values['serialized_metadata'])
                except yaml.YAMLError as err:
                    self._warn(None, f'the rosbag2 metadata record is not YAML: {err}')
                    return None
                if isinstance(info, dict):
                    custom = custom_data_strings(values['serialized_metadata'])
                    if custom is not None:
                        info['custom_data'] = custom
                    return info
        return None

    def iter_batches(self, topics=None):
        """
        Iterate over the messages of the selected topics, about one chunk at a time.

        Parameters
        ----------
        topics : iterable of str, optional
            Topic names; default all.

        Yields
        ------
        RawBatch
            Selected messages in log-time order across batches. Where the chunks do not
            overlap in time, one batch per chunk, its messages in file order; where they
            do, the messages of the overlapping chunks merged by log time (ties in file
            order), so that no topic runs ahead of another. Messages outside chunks
            come last.

        """
        wanted = self._channel_ids(topics)
        if not wanted:
            return
        wanted_arr = np.array(sorted(wanted), np.uint16)
        chunks = [c for c in self._chunks
                  if not c.index_offsets or wanted.intersection(c.index_offsets)]
        plan = self._log_time_plan(chunks, wanted)
        if plan is None:
            for _, batch in self._loaded_batches(chunks, wanted, wanted_arr):
                if batch is not None:
                    yield batch
        else:
            yield from self._merged_batches(*plan, wanted, wanted_arr)
        for starts in self._loose:
            batch = self._loose_batch(starts)
            batch = batch.select(np.isin(batch.channel_id, wanted_arr))
            if len(batch):
                yield batch

    def iter_messages(self, topics=None):
        """
        Iterate over single messages (convenient, not fast).

        Parameters
        ----------
        topics : iterable of str, optional
            Topic names; default all.

        Yields
        ------
        tuple
            ``(topic, log_time_ns, publish_time_ns, payload bytes)``.

        """
        for batch in self.iter_batches(topics):
            for i in range(len(batch)):
                channel = self.channels[int(batch.channel_id[i])]
                yield (channel.topic, int(batch.log_time_ns[i]), int(batch.publish_time_ns[i]),
                       batch.payload(i))

    def close(self):
        """Release the file."""
        if getattr(self, '_mm', None) is not None:
            try:
                self._mm.close()
            except BufferError:  # a numpy view is still alive; the GC closes the map
                pass
            self._mm = None
        self._file.close()

    def __enter__(self):
        """Return the reader."""
        return self

    def __exit__(self, *exc):
        """Release the file."""
        self.close()

    # ----------------------------------------------------------------- internals

    def _warn(self, offset, message):
        self.warnings.append(ReadWarning(str(self.path), offset, message))

    def _pread(self, offset, size):
        data = os.pread(self._file.fileno(), size, offset)
        if len(data) != size:
            raise _Corrupt(f'{size} bytes at byte {offset} run past the end of the file')
        return data

    def _channel_ids(self, topics):
        if topics is None:
            return set(self.channels)
        names = {topics} if isinstance(topics, str) else set(topics)
        return {cid for cid, ch in self.channels.items() if ch.topic in names}

    def _loaded_batches(self, chunks, wanted, wanted_arr):
        """Yield ``(chunk, batch of the wanted messages or None)`` for each chunk, in order."""
        # Decompression (and the CRC check) of the next chunks runs on a worker thread
        # while this one is handed out; zstd and zlib release the GIL.
        with Background(1, 'mcap-read') as pool:
            queue = collections.deque()
            upcoming = iter(chunks)
            for chunk in itertools.islice(upcoming, 2):
                queue.append((chunk, pool.submit(self._load_chunk, chunk)))
            while queue:
                chunk, future = queue.popleft()
                following = next(upcoming, None)
                if following is not None:
                    queue.append((following, pool.submit(self._load_chunk, following)))
                batch = self._chunk_batch(chunk, wanted, future.result())
                if batch is not None and len(batch):
                    ids = batch.channel_id
                    if not (ids.min() == ids.max() and int(ids[0]) in wanted) and \
                            not np.isin(ids, wanted_arr).all():
                        batch = batch.select(np.isin(batch.channel_id, wanted_arr))
                yield chunk, batch if batch is not None and len(batch) else None

    def _log_time_plan(self, chunks, wanted):
        """
        Return ``(chunks, first log times)`` in log-time order, or None for file order.

        None when file order already is log-time order (each chunk starts no earlier
        than every chunk before it ends: the usual recording) or when the file has no
        chunk index to tell (a scanned file keeps its file order).
        """
        if len(chunks) < 2 or any(c.start_ns is None for c in chunks):
            return None
        starts = np.array([c.start_ns for c in chunks], np.int64)
        ends = np.array([c.end_ns for c in chunks], np.int64)
        if _ranges_in_order(starts, ends):
            return None
        # The index gives a chunk's range over all its channels: the chunk that holds a
        # 1 Hz topic spans the whole recording although its joint states span seconds.
        # The message indexes of the wanted channels give their own range.
        for i, chunk in enumerate(chunks):
            if chunk.index_offsets and not wanted.issuperset(chunk.index_offsets):
                try:
                    times = np.concatenate([pairs[0::2] for pairs in
                                            self._index_entries(chunk, wanted)])
                except (_Corrupt, struct.error, ValueError):
                    continue   # the chunk's own range is still a valid (wider) bound
                if times.size:
                    starts[i], ends[i] = times.min(), times.max()
        if _ranges_in_order(starts, ends):
            return None
        order = np.lexsort((np.array([c.offset for c in chunks]), starts))
        return [chunks[i] for i in order.tolist()], starts[order]

    def _merged_batches(self, chunks, starts, wanted, wanted_arr):
        """
        Yield the messages of time-overlapping chunks merged by log time.

        The chunks come by first log time. Once chunk k is read, no message of a later
        chunk is older than the first log time of chunk k + 1 (the chunk index says
        so), so every message held before that time is handed out; the rest waits.
        What is held at a time is the chunks that overlap: about one per topic.
        """
        topic_rank = self._topic_ranks()
        held = []   # (chunk offset, batch sorted by log time, not yet handed out)
        loaded = self._loaded_batches(chunks, wanted, wanted_arr)
        for k, (chunk, batch) in enumerate(loaded):
            if batch is not None:
                held.append((chunk.offset, _sorted_by_log_time(batch)))
            limit = int(starts[k + 1]) if k + 1 < len(chunks) else None
            ready, held = _split_held(held, limit)
            yield from _merge_by_log_time(ready, topic_rank)

    def _topic_ranks(self):
        """Return an array: channel id -> rank of its topic (channels of a topic share it)."""
        names = sorted({ch.topic for ch in self.channels.values()})
        rank = np.zeros(max(self.channels, default=0) + 1, np.int64)
        for cid, channel in self.channels.items():
            rank[cid] = names.index(channel.topic)
        return rank

    def _read_header(self):
        try:
            opcode, length = struct.unpack_from('<BQ', self._mm, 8)
            if opcode != OP_HEADER or 17 + length > self.size:
                raise _Corrupt('no header record')
            header = _parse(Header, self._mm[17:17 + length], 'the header record')
            self.header = (header.profile, header.library)
        except (struct.error, _Corrupt):
            self._warn(8, f'no valid header record at byte 8 of {self.size}')

    def _read_summary(self):
        mm, size = self._mm, self.size
        at = size - 8 - 29
        if size < 8 + 29 + 8 or mm[size - 8:] != MAGIC or mm[at] != OP_FOOTER \
                or _u64(mm, at + 1) != 20:
            raise _Corrupt(f'no footer at the end of the file ({size} bytes; a recording '
                           'that was cut short?)')
        footer = _parse(Footer, mm[at + 9:at + 29], 'the footer')
        start = footer.summary_start
        if start == 0:
            raise _Corrupt('')  # a valid file without summary: scan quietly
        if not 8 <= start <= at or (footer.summary_offset_start and not
                                    start <= footer.summary_offset_start <= at):
            raise _Corrupt(f'the footer points to a summary at byte {start}, outside the file')
        if self.validate_crc and footer.summary_crc and \
                zlib.crc32(mm[start:at + 25]) != footer.summary_crc:
            raise _Corrupt(f'the summary CRC does not match (summary at byte {start})')
        try:
            self._file.seek(0)
            summary = SeekingReader(self._file).get_summary()
        except Exception as err:  # noqa: B902 - any damage means: scan the records instead
            raise _Corrupt(f'the summary at byte {start} cannot be read ({err})') from None
        if summary is None or summary.statistics is None:
            raise _Corrupt('')  # valid, but message counts need a scan: scan quietly
        self.schemas = dict(summary.schemas)
        self.channels = dict(summary.channels)
        self.statistics = summary.statistics
        self._counts = dict(summary.statistics.channel_message_counts)
        self._chunks = sorted((self._chunk_from_index(index, start)
                               for index in summary.chunk_indexes), key=lambda c: c.offset)
        for index in summary.metadata_indexes:
            self._read_metadata_record(index.offset, index.length)
        if self.statistics.message_count and not self._chunks:
            self._loose = self._scan_loose(start)

    def _chunk_from_index(self, index, limit):
        offset, length = index.chunk_start_offset, index.chunk_length
        if offset + length > limit or length < 9:
            raise _Corrupt(f'a chunk index points to bytes {offset} .. {offset + length}, '
                           'past the data section')
        opcode, body = struct.unpack_from('<BQ', self._mm, offset)
        if opcode != OP_CHUNK or 9 + body != length:
            raise _Corrupt(f'no chunk record of {length} bytes at byte {offset}')
        return _ChunkRef(offset, length, index.compression, dict(index.message_index_offsets),
                         index.message_start_time, index.message_end_time)

    def _chunk_at(self, offset):
        opcode, length = struct.unpack_from('<BQ', self._mm, offset)
        if opcode != OP_CHUNK or offset + 9 + length > self.size:
            raise _Corrupt(f'no chunk record at byte {offset}')
        return _ChunkRef(offset, 9 + length)

    def _read_metadata_record(self, offset, length):
        try:
            opcode, body = struct.unpack_from('<BQ', self._mm, offset)
            if opcode != OP_METADATA or offset + 9 + body > self.size:
                raise _Corrupt(f'no metadata record at byte {offset}')
            record = _parse(Metadata, self._mm[offset + 9:offset + 9 + body],
                            f'the metadata record at byte {offset}')
            self.metadata.append((record.name, record.metadata))
        except (struct.error, _Corrupt) as err:
            self._warn(offset, f'metadata record skipped: {err}')

    def _add_schema(self, body, what):
        record = _parse(Schema, body, what)
        self.schemas[record.id] = Schema(id=record.id, name=record.name,
                                         encoding=record.encoding, data=bytes(record.data))

    def _add_channel(self, body, what):
        record = _parse(Channel, body, what)
        self.channels[record.id] = record

    def _load_chunk(self, chunk):
        """Read, decompress and check a chunk; return (uint8 array, None) or (None, problem)."""
        what = f'chunk at byte {chunk.offset}'
        try:
            # pread, not the map: a copy into reused heap memory costs far less than a
            # page fault per 4 KiB of the file.
            record = _parse(Chunk, self._pread(chunk.offset + 9, chunk.length - 9), what)
        except _Corrupt as err:
            return None, f'{err}; its messages are skipped'
        chunk.compression = record.compression
        if record.compression not in _CODECS:
            return None, (f'{what} has the unsupported compression {record.compression!r} '
                          '(expected zstd, lz4 or none); its messages are skipped')
        try:
            if record.compression:
                records, size = get_chunk_data_stream(record, validate_crc=self.validate_crc)
                data = records.read(size)
            else:   # used in place; its CRC is checked as the library checks it
                data = record.data
                if self.validate_crc and record.uncompressed_crc and \
                        zlib.crc32(data) != record.uncompressed_crc:
                    raise CRCValidationError(record.uncompressed_crc, zlib.crc32(data), record)
        except CRCValidationError:
            return None, f'{what} fails its CRC check (corrupted file); its messages are skipped'
        except Exception as err:  # noqa: B902 - every codec raises its own error type
            return None, (f'{what} cannot be decompressed ({record.compression}: {err}); its '
                          'messages are skipped')
        if len(data) != record.uncompressed_size:
            return None, (f'{what} decompressed to {len(data)} bytes, expected '
                          f'{record.uncompressed_size}; its messages are skipped')
        return np.frombuffer(data, np.uint8), None

    def _chunk_data(self, chunk, loaded=None):
        """Return the decompressed records of a chunk (uint8 array) or None after a warning."""
        data, problem = self._load_chunk(chunk) if loaded is None else loaded
        if problem is not None:
            self._warn(chunk.offset, problem)
        return data

    def _index_entries(self, chunk, wanted):
        """Return the (log time, offset) uint64 pairs of the wanted channels' message indexes."""
        parts = []
        for channel_id in wanted:
            offset = chunk.index_offsets.get(channel_id)
            if offset is None:
                continue
            opcode, length = struct.unpack_from('<BQ', self._mm, offset)
            if opcode != OP_MESSAGE_INDEX or offset + 9 + length > self.size:
                raise _Corrupt(f'no message index record at byte {offset}')
            index_channel, size = struct.unpack_from('<HI', self._mm, offset + 9)
            if index_channel != channel_id or size % 16 or 6 + size > length:
                raise _Corrupt(f'the message index at byte {offset} is malformed')
            parts.append(np.frombuffer(self._pread(offset + 15, size), '<u8'))
        return parts

    def _index_starts(self, chunk, wanted):
        parts = [pairs[1::2].astype(np.int64) for pairs in self._index_entries(chunk, wanted)]
        if not parts:
            return np.zeros(0, np.int64)
        return np.sort(np.concatenate(parts)) if len(parts) > 1 else parts[0]

    def _chunk_batch(self, chunk, wanted, loaded=None):
        data = self._chunk_data(chunk, loaded)
        if data is None:
            return None
        if len(chunk.index_offsets) > 1:
            # Several channels share the chunk: their records interleave, so the message
            # indexes give the offsets in one vectorised step. A single-channel chunk is
            # faster to scan (its records form runs of equal length).
            try:
                starts = self._index_starts(chunk, wanted)
                fields = _gather_messages(data, starts, data.shape[0])
                if starts.shape[0] > 1 and (np.diff(starts) <= 0).any():
                    raise _Corrupt('it lists a message twice')
                if not np.isin(fields[0], list(wanted)).all():
                    raise _Corrupt('it points to a message of another channel')
                return RawBatch(*fields[:4], data, *fields[4:])
            except (_Corrupt, struct.error) as err:
                self._warn(chunk.offset, f'message index of the chunk at byte {chunk.offset} '
                           f'is unusable ({err}); scanning the chunk')
        try:
            starts = self._chunk_message_starts(data)
            fields = _gather_messages(data, starts, data.shape[0])
        except _Corrupt as err:
            self._warn(chunk.offset, f'chunk at byte {chunk.offset} is corrupt ({err}); '
                       'its messages are skipped')
            return None
        return RawBatch(*fields[:4], data, *fields[4:])

    def _chunk_message_starts(self, data, collect=False):
        """Return starts of the message records in a chunk; optionally add schemas/channels."""
        runs = []
        for opcode, starts, length in _walk(data, 0, data.shape[0], data):
            if opcode == OP_MESSAGE:
                runs.append(starts)
            elif collect and opcode in (OP_SCHEMA, OP_CHANNEL):
                pos = int(starts[0])
                (self._add_schema if opcode == OP_SCHEMA else self._add_channel)(
                    data[pos + 9:pos + 9 + length].tobytes(),
                    f'a {RECORD_NAMES[opcode]} record inside a chunk')
        return np.concatenate(runs) if runs else np.zeros(0, np.int64)

    def _loose_batch(self, starts):
        first = int(starts[0])
        last = int(starts[-1])
        end = last + 9 + _u64(self._mm, last + 1)
        data = np.frombuffer(self._pread(first, end - first), np.uint8)
        fields = _gather_messages(data, starts - first, data.shape[0])
        return RawBatch(*fields[:4], data, *fields[4:])

    def _add_loose(self, starts):
        """Collect message records outside chunks into groups of bounded size."""
        if self._loose_parts:
            first = int(self._loose_parts[0][0])
            count = sum(part.shape[0] for part in self._loose_parts)
            if count < 65536 and int(starts[-1]) - first < 16 * 2**20:
                self._loose_parts.append(starts)
                return
            self._loose.append(np.concatenate(self._loose_parts))
        self._loose_parts = [starts]

    def _end_loose(self):
        if self._loose_parts:
            self._loose.append(np.concatenate(self._loose_parts))
        self._loose_parts = []

    def _scan_loose(self, stop):
        """Find message records outside chunks in the data section of a summarised file."""
        self._loose, self._loose_parts = [], []
        arr = np.frombuffer(self._mm, np.uint8)
        try:
            for opcode, starts, _ in _walk(self._mm, 8, stop, arr):
                if opcode == OP_MESSAGE:
                    self._add_loose(starts)
                elif opcode == OP_DATA_END:
                    break
        except _Corrupt as err:
            self._warn(None, f'data section: {err}')
        finally:
            del arr
        self._end_loose()
        return self._loose

    def _scan(self):
        """Read the data section record by record (no summary, or an unusable one)."""
        self.schemas, self.channels, self._chunks, self._loose = {}, {}, [], []
        self.metadata, self._counts, self.statistics = [], {}, None
        self._loose_parts = []
        mm, size = self._mm, self.size
        arr = np.frombuffer(mm, np.uint8)
        pos = 8
        stopped = False
        try:
            for opcode, starts, length in _walk(mm, 8, size, arr):
                pos = int(starts[0])
                if opcode == OP_MESSAGE:
                    self._add_loose(starts)
                    continue
                what = f'the {RECORD_NAMES.get(opcode, "unknown")} record at byte {pos}'
                try:
                    if opcode == OP_SCHEMA:
                        self._add_schema(mm[pos + 9:pos + 9 + length], what)
                    elif opcode == OP_CHANNEL:
                        self._add_channel(mm[pos + 9:pos + 9 + length], what)
                    elif opcode == OP_CHUNK:
                        self._scan_chunk(pos)
                    elif opcode == OP_MESSAGE_INDEX and self._chunks:
                        if length < 2:
                            raise _Corrupt(f'{what} has no channel id')
                        (channel_id,) = struct.unpack_from('<H', mm, pos + 9)
                        self._chunks[-1].index_offsets[channel_id] = pos
                    elif opcode == OP_METADATA:
                        record = _parse(Metadata, mm[pos + 9:pos + 9 + length], what)
                        self.metadata.append((record.name, record.metadata))
                    elif opcode in (OP_DATA_END, OP_FOOTER):
                        return
                except _Corrupt as err:
                    self._warn(pos, f'record skipped: {err}')
        except _Corrupt as err:
            stopped = True
            self._warn(pos, f'reading stopped at byte {_stop_offset(err, pos)} of {size}: {err}')
        finally:
            del arr
            self._end_loose()
            for starts in self._loose:
                ids, counts = np.unique(self._loose_batch(starts).channel_id,
                                        return_counts=True)
                for cid, count in zip(ids.tolist(), counts.tolist()):
                    self._counts[cid] = self._counts.get(cid, 0) + count
        if not stopped:
            self._warn(size, f'the file ends at byte {size} without a data end record '
                       '(a recording that was cut short?)')

    def _scan_chunk(self, pos):
        chunk = self._chunk_at(pos)
        data = self._chunk_data(chunk)
        if data is None:
            return
        try:
            starts = self._chunk_message_starts(data, collect=True)
            channel_ids = _gather_messages(data, starts, data.shape[0])[0]
        except _Corrupt as err:
            self._warn(pos, f'chunk at byte {pos} is corrupt ({err}); its messages are skipped')
            return
        self._chunks.append(chunk)
        ids, counts = np.unique(channel_ids, return_counts=True)
        for cid, count in zip(ids.tolist(), counts.tolist()):
            self._counts[cid] = self._counts.get(cid, 0) + count


def _ranges_in_order(starts, ends):
    """Whether each [start, end] log-time range begins no earlier than all before it end."""
    return bool((starts[1:] >= np.maximum.accumulate(ends[:-1])).all())


def _sorted_by_log_time(batch):
    """Return the batch stably sorted by log time (a chunk's file order is kept for ties)."""
    logs = batch.log_time_ns
    if logs.shape[0] > 1 and (logs[1:] < logs[:-1]).any():
        return batch.select(np.argsort(logs, kind='stable'))
    return batch


def _split_held(held, limit):
    """Split held batches into the messages before ``limit`` (None: all) and the rest."""
    ready, rest = [], []
    for offset, batch in held:
        cut = len(batch) if limit is None else int(
            np.searchsorted(batch.log_time_ns, limit, 'left'))
        if cut:
            ready.append((offset, batch.select(slice(0, cut))))
        if cut < len(batch):
            rest.append((offset, batch.select(slice(cut, None))))
    return ready, rest


def _merge_by_log_time(parts, topic_rank):
    """
    Yield the messages of sorted batches in log-time order (ties in file order).

    The leading messages of the batch that starts first and the trailing ones of the
    batch that ends last overlap no other batch: they are handed out as they are, and
    only the overlap is merged (a recording whose chunks overlap by a few messages
    costs next to nothing).
    """
    parts = [batch for _, batch in sorted(parts, key=lambda part: part[0])]
    if len(parts) < 2:
        yield from parts
        return
    firsts = [int(b.log_time_ns[0]) for b in parts]
    lasts = [int(b.log_time_ns[-1]) for b in parts]
    head = int(np.argmin(firsts))
    tail = int(np.argmax(lasts))
    # Before every other batch's first message (ties stay in the merge, for file order).
    cut = int(np.searchsorted(parts[head].log_time_ns,
                              min(f for i, f in enumerate(firsts) if i != head), 'left'))
    # After every other batch's last message.
    keep = int(np.searchsorted(parts[tail].log_time_ns,
                               max(v for i, v in enumerate(lasts) if i != tail), 'right'))
    prefix = parts[head].select(slice(0, cut))
    suffix = parts[tail].select(slice(keep, None))
    if head == tail:   # cut <= keep: the others' first message is not after their last
        parts[head] = parts[head].select(slice(cut, keep))
    else:
        parts[head] = parts[head].select(slice(cut, None))
        parts[tail] = parts[tail].select(slice(0, keep))
    middle = [b for b in parts if len(b)]
    if len(middle) > 1:
        middle = [_interleave(middle, topic_rank)]
    for piece in (prefix, *middle, suffix):
        if len(piece):
            yield piece


def _interleave(parts, topic_rank):
    """
    Merge sorted batches of different chunks into one batch in log-time order.

    Within each topic the offsets keep the order the messages are handed out in (as
    in a chunk, where they give the file order). When each topic comes from one chunk
    in file order (a topic stored in chunks of its own), copying each chunk's bytes
    keeps it; otherwise the payloads are gathered topic by topic in log-time order.
    """
    logs = np.concatenate([b.log_time_ns for b in parts])
    order = np.argsort(logs, kind='stable')   # parts come in file order: ties keep it
    part = np.repeat(np.arange(len(parts)), [len(b) for b in parts])[order]
    source = np.concatenate([b.offsets for b in parts])[order]
    length = np.concatenate([b.lengths for b in parts])[order]
    channel = np.concatenate([b.channel_id for b in parts])[order]
    topics = [_topics_of(topic_rank[b.channel_id]) for b in parts]
    if sum(t.shape[0] for t in topics) == np.unique(np.concatenate(topics)).shape[0] and \
            all((b.offsets[1:] > b.offsets[:-1]).all() for b in parts):
        # Only the bytes the messages occupy, each once: a chunk held for long is not
        # copied whole each time a few of its messages are handed out.
        spans, shift, base = [], np.zeros(len(parts), np.int64), 0
        for i, b in enumerate(parts):
            low, high = int(b.offsets[0]), int(b.offsets[-1] + b.lengths[-1])
            spans.append(b.data[low:high])
            shift[i] = base - low
            base += high - low
        data, offsets = np.concatenate(spans), source + shift[part]
    else:
        data, offsets = _gather_by_topic(parts, part, source, length, topic_rank[channel])
    return RawBatch(channel, np.concatenate([b.sequence for b in parts])[order], logs[order],
                    np.concatenate([b.publish_time_ns for b in parts])[order], data, offsets,
                    length)


def _topics_of(ranks):
    """Return the distinct topic ranks (a chunk of one topic is the usual case)."""
    low, high = ranks.min(), ranks.max()
    return np.array([low]) if low == high else np.unique(ranks)


def _gather_by_topic(parts, part, source, length, topic):
    """Copy the payloads into one buffer topic by topic, in log-time order; return it, offsets."""
    layout = np.argsort(topic, kind='stable')
    part, source, size = part[layout], source[layout], length[layout]
    placed = np.zeros(layout.shape[0], np.int64)
    np.cumsum(size[:-1], out=placed[1:])
    offsets = np.empty_like(placed)
    offsets[layout] = placed
    data = np.empty(int(placed[-1] + size[-1]), np.uint8)
    for i, b in enumerate(parts):
        mine = part == i
        # Byte k of a message lands at its place + k, from its offset + k in the chunk.
        count = size[mine]
        step = np.arange(int(count.sum())) - np.repeat(np.cumsum(count) - count, count)
        data[np.repeat(placed[mine], count) + step] = b.data[np.repeat(source[mine], count) + step]
    return data, offsets


def _stop_offset(err, default):
    match = re.search(r'at byte (\d+)', str(err))
    return int(match.group(1)) if match else default
