"""
ROS 1 ``.bag`` files (format 2.0), read chunk by chunk into arrays.

rosbags' rosbag1 reader opens the file: the bag header, the connections (topic, type and
each connection's message definition) and the chunk infos. Its per-message index objects
are replaced by arrays (one ``INDEX_DATA`` record becomes one structured array), and the
messages are not taken one by one through ``Reader.messages``: each chunk that holds a
wanted connection is decompressed once, and the message data records the index points
at are located in it with vectorised reads of their record headers. A chunk becomes one
:class:`~reducer_twin.io.mcap_array_writer.RawBatch` whose payloads are ROS 1 serialised, in
file order (the order rosbag recorded them), with the index's receive times as log times.

A bag that is not indexed, is encrypted or uses a compression rosbags does not know is
refused with the reader's reason; a chunk that cannot be read or decompressed is skipped
with a warning, and the rest is read.
"""

import os
from pathlib import Path

import numpy as np
from reducer_twin.core.errors import BagError
from reducer_twin.io.mcap_reader import RawBatch, ReadWarning

MAGIC = b'#ROSBAG V'
VERSION = b'2.0'
SERIALIZATION = 'ros1'
INDEX_ENTRY = np.dtype([('sec', '<u4'), ('nsec', '<u4'), ('offset', '<u4')])
_OP_MSGDATA, _OP_CONNECTION = 2, 7


def _reader_class():
    """Return rosbags' rosbag1 Reader, keeping each chunk's index as arrays."""
    from rosbags.rosbag1.reader import Header, read_bytes, read_uint32, Reader, ReaderError
    from rosbags.rosbag1.reader import RecordType

    class ArrayIndexReader(Reader):
        """rosbags' Reader with ``INDEX_DATA`` records kept as arrays per chunk."""

        def __init__(self, path):
            super().__init__(path)
            self.chunk_index = {}   # chunk position -> {connection id: INDEX_ENTRY array}

        def read_index_data(self, pos, indexes):
            """Read one INDEX_DATA record after a chunk as an array (not per message)."""
            header = Header.read(self.bio, RecordType.IDXDATA)
            version = header.get_uint32('ver')
            if version != 1:
                raise ReaderError(f'IDXDATA version {version} is not supported.')
            conn, count = header.get_uint32('conn'), header.get_uint32('count')
            size = read_uint32(self.bio)
            if size != count * INDEX_ENTRY.itemsize:
                raise ReaderError(f'IDXDATA of connection {conn} holds {size} bytes for '
                                  f'{count} entries')
            entries = np.frombuffer(read_bytes(self.bio, size), INDEX_ENTRY)
            self.chunk_index.setdefault(pos, {})[conn] = entries

    return ArrayIndexReader


def _u32(buf, at):
    """Little-endian uint32 at each offset of ``at`` (all inside ``buf``)."""
    return buf[at[:, None] + np.arange(4)].copy().view('<u4')[:, 0].astype(np.int64)


def _header_fields(buf, start, length):
    """Parse a record header: ``{name: (value start, value length)}``; None if malformed."""
    fields, pos, end = {}, start, start + length
    while pos < end:
        if pos + 4 > end:
            return None
        size = int.from_bytes(bytes(buf[pos:pos + 4]), 'little')
        item = bytes(buf[pos + 4:pos + 4 + size])
        if pos + 4 + size > end or b'=' not in item:
            return None
        name = item.split(b'=', 1)[0]
        fields[name] = (pos + 4 + len(name) + 1, size - len(name) - 1)
        pos += 4 + size
    return fields


class Rosbag1File:
    """
    A ROS 1 bag, opened with rosbags' rosbag1 reader.

    Parameters
    ----------
    path : str or os.PathLike
        The ``.bag`` file.

    Raises
    ------
    BagError
        If the file cannot be opened as an indexed, unencrypted ROS 1 bag.

    """

    def __init__(self, path):
        self.path = Path(path)
        self.warnings = []
        reader = _reader_class()(self.path)
        try:
            reader.open()
        except Exception as err:  # noqa: B902 - rosbags raises several kinds on bad files
            text = str(err) or type(err).__name__
            raise BagError(f'{self.path} is not a readable ROS 1 bag: {text}; expected an '
                           'indexed rosbag format 2.0 file (run "rosbag reindex" on a bag '
                           'whose recording was cut short)') from None
        self._reader = reader
        self._fd = reader.bio.fileno()
        self.connections = {c.id: c for c in reader.connections}
        self._counts = {}
        for info in reader.chunk_infos:
            for cid, count in info.connection_counts.items():
                self._counts[cid] = self._counts.get(cid, 0) + int(count)

    def topics(self):
        """
        List the topics.

        Returns
        -------
        dict of str to tuple
            ``name -> (msgtype, count)``, the type in ROS 2 form (``pkg/msg/Name``).

        """
        out = {}
        for cid in sorted(self.connections):
            conn = self.connections[cid]
            msgtype, count = out.get(conn.topic, (conn.msgtype, 0))
            out[conn.topic] = (msgtype, count + self._counts.get(cid, 0))
        return out

    def topic_of(self, channel_id):
        """Return the topic of a connection id."""
        return self.connections[channel_id].topic

    def definition(self, topic):
        """
        Return the message definition of a topic's (first) connection.

        Parameters
        ----------
        topic : str
            Topic name.

        Returns
        -------
        tuple of str
            ``('ros1msg', text)``.

        """
        texts = {c.msgdef.data for c in self.connections.values() if c.topic == topic}
        first = next(c for c in self.connections.values() if c.topic == topic)
        if len(texts) > 1:
            self._warn(None, f'{topic} has connections with {len(texts)} different message '
                       'definitions; reading all of them with the first')
        return 'ros1msg', first.msgdef.data

    def iter_batches(self, topics):
        """
        Yield the messages of some topics, one chunk at a time.

        Parameters
        ----------
        topics : iterable of str
            Topic names.

        Yields
        ------
        RawBatch
            ROS 1 payloads of one chunk in file order; ``channel_id`` is the connection.

        """
        wanted = {cid for cid, c in self.connections.items() if c.topic in set(topics)}
        if not wanted:
            return
        for info in sorted(self._reader.chunk_infos, key=lambda x: x.pos):
            index = self._reader.chunk_index.get(info.pos, {})
            parts = [(cid, index[cid]) for cid in sorted(wanted & set(index))
                     if index[cid].shape[0]]
            if not parts:
                continue
            data = self._chunk_data(info.pos)
            if data is None:
                continue
            batch = self._locate(info.pos, data, parts)
            if batch is not None and len(batch):
                yield batch

    def close(self):
        """Release the file."""
        if self._reader is not None:
            self._reader.close()
            self._reader = None

    # ----------------------------------------------------------------- internals

    def _warn(self, offset, message):
        warning = ReadWarning(str(self.path), offset, message)
        if warning not in self.warnings:
            self.warnings.append(warning)

    def _chunk_data(self, pos):
        chunk = self._reader.chunks[pos]
        try:
            raw = os.pread(self._fd, chunk.datasize, chunk.datapos)
        except OSError as err:
            self._warn(chunk.datapos, f'chunk unreadable: {err.strerror}; skipping it')
            return None
        if len(raw) < chunk.datasize:
            self._warn(chunk.datapos, f'chunk cut short: {len(raw)} of {chunk.datasize} bytes '
                       'in the file; skipping it')
            return None
        try:
            return np.frombuffer(chunk.decompressor(raw), np.uint8)
        except Exception as err:  # noqa: B902 - bz2, lz4 and others raise their own kinds
            self._warn(chunk.datapos, f'corrupt chunk: {type(err).__name__}: {err}; skipping '
                       'it')
            return None

    def _locate(self, pos, buf, parts):
        """Message payloads of the index entries ``parts`` in a decompressed chunk."""
        conn = np.concatenate([np.full(e.shape[0], cid, np.uint32) for cid, e in parts])
        entries = np.concatenate([e for _, e in parts])
        order = np.argsort(entries['offset'], kind='stable')
        conn, entries = conn[order], entries[order]
        record = entries['offset'].astype(np.int64)
        size = buf.shape[0]
        start = np.zeros(record.shape[0], np.int64)
        length = np.full(record.shape[0], -1, np.int64)
        inside = record + 4 <= size
        header = np.zeros(record.shape[0], np.int64)
        header[inside] = _u32(buf, record[inside])
        fits = inside & (record + 8 + header <= size)
        # The records rosbag writes share one header layout: check it once, read all.
        lengths, counts = np.unique(header[fits], return_counts=True)
        if lengths.size:
            common = int(lengths[np.argmax(counts)])
            same = fits & (header == common)
            first = record[same][0]
            fields = _header_fields(buf, int(first) + 4, common)
            fast = self._fast_records(buf, record, same, common, fields, conn)
            start[fast] = record[fast] + 8 + common
            length[fast] = _u32(buf, record[fast] + 4 + common)
        for i in np.flatnonzero(length < 0):   # unusual records: one by one
            start[i], length[i] = self._slow_record(buf, int(record[i]), int(conn[i]))
        ok = (length >= 0) & (start + length <= size)
        if not ok.all():
            self._warn(pos, f'{int((~ok).sum())} message record(s) of the chunk at byte {pos} '
                       'are not where its index says or run past it; skipping them')
        times = entries['sec'].astype(np.int64) * 1_000_000_000 + entries['nsec']
        return RawBatch(conn[ok], np.zeros(int(ok.sum()), np.uint32), times[ok], times[ok],
                        buf, start[ok], length[ok])

    @staticmethod
    def _fast_records(buf, record, same, length, fields, conn):
        """Mask of records whose header has the layout ``fields`` with op 2 and the right conn."""
        if fields is None or b'op' not in fields or b'conn' not in fields:
            return np.zeros(record.shape[0], bool)
        op_at, op_len = fields[b'op']
        conn_at, conn_len = fields[b'conn']
        if op_len != 1 or conn_len != 4:
            return np.zeros(record.shape[0], bool)
        mask = same.copy()
        rows = record[mask] + 4
        template = buf[int(record[mask][0]) + 4:int(record[mask][0]) + 4 + length]
        values = np.zeros(length, bool)   # value bytes may differ; names and sizes may not
        for at, size in fields.values():
            values[at - int(record[mask][0]) - 4:at - int(record[mask][0]) - 4 + size] = True
        fixed = np.flatnonzero(~values)
        good = (buf[rows[:, None] + fixed] == template[fixed]).all(axis=1)
        base = int(record[mask][0]) + 4
        good &= buf[rows + (op_at - base)] == _OP_MSGDATA
        good &= _u32(buf, rows + (conn_at - base)) == conn[mask]
        mask[mask] = good
        return mask

    def _slow_record(self, buf, record, conn):
        """Follow a record the fast path did not take (e.g. after a connection record)."""
        size = buf.shape[0]
        while record + 4 <= size:
            header = int.from_bytes(bytes(buf[record:record + 4]), 'little')
            fields = _header_fields(buf, record + 4, header)
            data_at = record + 4 + header
            if fields is None or b'op' not in fields or data_at + 4 > size:
                break
            data_len = int.from_bytes(bytes(buf[data_at:data_at + 4]), 'little')
            at, _ = fields[b'op']
            if buf[at] == _OP_CONNECTION:
                record = data_at + 4 + data_len
                continue
            if buf[at] == _OP_MSGDATA and b'conn' in fields:
                c_at, _ = fields[b'conn']
                if int.from_bytes(bytes(buf[c_at:c_at + 4]), 'little') == conn:
                    return data_at + 4, data_len
            break
        return 0, -1
