"""
rosbag2 MCAP files framed by the mcap library's ``mcap.writer.Writer``.

The derived bags of ``reducer-twin analyze`` are small (about 12 k messages per million
input messages), so their framing (Header, Schema and Channel records, chunks, Message
Index records, the summary, CRCs and chunk compression) is left to the library. What is
rosbag2's is added here, as ``ros2 bag record -s mcap`` writes it: profile ``ros2``,
``ros2msg`` schemas, ``cdr`` channels whose metadata hold ``offered_qos_profiles`` (YAML,
metadata version 9) and ``topic_type_hash``, and the ``rosbag2`` Metadata record (the
serialised bag metadata with ``custom_data``), written through ``add_metadata`` when the
file is closed. The Header names the library (``mcap-python/<version>``). Chunk CRCs are
written (readers detect corruption with them); the data-section CRC is not, as neither
rosbag2 nor the library writes it by default.

The interface is the one of :class:`~reducer_twin.io.mcap_array_writer.McapBagWriter`, whose
own framing stays for ``simulate`` (about a million messages per bag, where building
chunks as arrays is several times faster).
"""

from pathlib import Path

from mcap.writer import CompressionType, Writer
import numpy as np
from reducer_twin.core.errors import BagError, InvalidInput
from reducer_twin.io.mcap_array_writer import _Topic, message_times, TopicBook
from reducer_twin.io.mcap_format import DEFAULT_CHUNK_SIZE, PROFILE
from reducer_twin.io.outputs import start_writeback
from reducer_twin.io.rosbag2_metadata import (
    bag_metadata, DEFAULT_QOS, dump_yaml, parse_qos_profiles)
from reducer_twin.msg_adapters import ros_schemas
from reducer_twin.msg_adapters.jointstate_cdr import fill_columns

_COMPRESSION = {'none': CompressionType.NONE, '': CompressionType.NONE,
                'zstd': CompressionType.ZSTD, 'lz4': CompressionType.LZ4}


class LibraryMcapWriter(TopicBook):
    """
    Write one rosbag2 MCAP file with ``mcap.writer.Writer``.

    Parameters
    ----------
    path : str or os.PathLike
        File to create (``.mcap``); it must not exist.
    compression : {'none', 'zstd', 'lz4'}
        Chunk compression (rosbag2's default is none).
    chunk_size : int
        Uncompressed bytes per chunk (libmcap's default, 768 KiB).
    custom_data : dict of str to str, optional
        rosbag2 ``custom_data``, stored in the ``rosbag2`` metadata record.

    Raises
    ------
    InvalidInput
        On an unknown compression or a chunk size below 1 KiB.
    OSError
        If the file exists or cannot be created (the caller names the output).

    """

    def __init__(self, path, compression='none', chunk_size=DEFAULT_CHUNK_SIZE,
                 custom_data=None):
        if compression is None:
            compression = 'none'
        if compression not in _COMPRESSION:
            raise InvalidInput(f"compression must be 'zstd', 'lz4' or 'none', "
                               f'got {compression!r}')
        if int(chunk_size) < 1024:
            raise InvalidInput(f'chunk_size must be >= 1024 bytes, got {chunk_size!r}')
        self.path = Path(path)
        self.custom_data = {str(k): str(v) for k, v in (custom_data or {}).items()}
        self._file = open(self.path, 'xb')
        self._writer = Writer(self._file, chunk_size=int(chunk_size),
                              compression=_COMPRESSION[compression], enable_crcs=True,
                              enable_data_crcs=False)
        self._writer.start(profile=PROFILE)
        self._schemas = {}  # msgtype -> schema id
        self._topics = {}  # name -> _Topic
        self._by_channel = {}  # channel id -> _Topic
        self._closed = False

    # ----------------------------------------------------------------- public API

    def add_topic(self, name, msgtype, qos=DEFAULT_QOS, schema_text=None, type_hash=None):
        """
        Declare a topic: a Schema (once per type) and a Channel with rosbag2's metadata.

        Parameters
        ----------
        name : str
            Topic name.
        msgtype : str
            ROS type, e.g. ``'std_msgs/msg/Float64MultiArray'``.
        qos : sequence of QosProfile, str or list of dict
            Offered QoS profiles.
        schema_text : str, optional
            ``ros2msg`` definition; default: read from the installed ROS packages.
        type_hash : str, optional
            ``RIHS01_...``; default: read from the installed ROS packages.

        Returns
        -------
        int
            Channel id for the write methods.

        Raises
        ------
        BagError
            If the topic exists already or the writer is closed.

        """
        self._check_open()
        if name in self._topics:
            raise BagError(f'topic {name!r} was already added to {self.path}')
        if schema_text is None:
            schema_text = ros_schemas.message_definition(msgtype)
        if type_hash is None:
            type_hash = ros_schemas.type_hash(msgtype)
        profiles = parse_qos_profiles(qos)
        if msgtype not in self._schemas:
            self._schemas[msgtype] = self._writer.register_schema(
                name=msgtype, encoding='ros2msg', data=schema_text.encode('utf-8'))
        qos_text = dump_yaml([p.as_dict() for p in profiles]) if profiles else ''
        channel_id = self._writer.register_channel(
            topic=name, message_encoding='cdr', schema_id=self._schemas[msgtype],
            metadata={'offered_qos_profiles': qos_text, 'topic_type_hash': type_hash})
        topic = _Topic(channel_id, name, msgtype, profiles, type_hash)
        self._topics[name] = self._by_channel[channel_id] = topic
        return channel_id

    def write(self, channel_id, log_time_ns, data, publish_time_ns=None, sequence=0):
        """
        Write one message.

        Parameters
        ----------
        channel_id : int
            From ``add_topic``.
        log_time_ns : int
            Receive time in ns.
        data : bytes-like
            CDR payload.
        publish_time_ns : int, optional
            Send time in ns; default ``log_time_ns``.
        sequence : int
            MCAP sequence number (rosbag2 on Jazzy writes 0).

        """
        publish = log_time_ns if publish_time_ns is None else publish_time_ns
        logs, pubs = message_times(np.array([log_time_ns], np.int64),
                                   np.array([publish], np.int64))
        topic = self._topic_of(channel_id)
        self._writer.add_message(channel_id, int(logs[0]), bytes(data), int(pubs[0]),
                                 int(sequence))
        self._note(topic, logs)

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
            int64[N + 1] boundaries.
        publish_times_ns : array_like of int, optional
            int64[N] send times; default the log times.

        Raises
        ------
        InvalidInput
            On shapes that disagree, offsets outside the buffer or negative times.

        """
        topic = self._topic_of(channel_id)
        logs, pubs = message_times(log_times_ns, publish_times_ns)
        bounds = np.asarray(offsets, dtype=np.int64).reshape(-1)
        n = logs.shape[0]
        if bounds.shape[0] != n + 1:
            raise InvalidInput(f'write_batch needs N log times and N + 1 offsets, got shapes '
                               f'{logs.shape} and {bounds.shape}')
        if n == 0:
            return
        raw = buffer if isinstance(buffer, np.ndarray) else np.frombuffer(buffer, np.uint8)
        raw = raw.reshape(-1).view(np.uint8)
        if bounds[0] < 0 or bounds[-1] > raw.shape[0] or (np.diff(bounds) < 0).any():
            raise InvalidInput(f'offsets must rise from >= 0 to <= {raw.shape[0]} (the buffer '
                               f'size), got {bounds[0]} .. {bounds[-1]}')
        data = memoryview(np.ascontiguousarray(raw))   # slices are views: one copy less
        add = self._writer.add_message
        for log, pub, start, end in zip(logs.tolist(), pubs.tolist(), bounds[:-1].tolist(),
                                        bounds[1:].tolist()):
            add(channel_id, log, data[start:end], pub, 0)
        self._note(topic, logs)

    def write_template_batch(self, channel_id, log_times_ns, template, columns,
                             publish_times_ns=None):
        """
        Write N messages that are one template with per-message columns written in.

        Parameters
        ----------
        channel_id : int
            From ``add_topic``.
        log_times_ns : array_like of int
            int64[N] receive times in ns.
        template : bytes-like or numpy.ndarray
            One serialised message (uint8[L]).
        columns : sequence of tuple
            ``(offset, dtype, values)``: values of shape [N] or [N, k] written at byte
            ``offset`` of each payload with numpy dtype ``dtype``.
        publish_times_ns : array_like of int, optional
            int64[N] send times; default the log times.

        Raises
        ------
        InvalidInput
            On shapes that disagree or columns outside the template.

        """
        logs = np.asarray(log_times_ns)
        template = np.frombuffer(bytes(template), np.uint8) \
            if not isinstance(template, np.ndarray) else template.reshape(-1).view(np.uint8)
        n, length = logs.shape[0] if logs.ndim == 1 else 0, template.shape[0]
        for offset, dtype, values in columns:
            values = np.asarray(values)
            width = np.dtype(dtype).itemsize * (values.shape[1] if values.ndim == 2 else 1)
            if values.shape[0] != n or values.ndim > 2 or offset < 0 \
                    or offset + width > length:
                raise InvalidInput(
                    f'column at byte {offset} ({dtype}, shape {values.shape}) must hold N = '
                    f'{n} rows and fit the {length}-byte template')
        rows = np.empty((n, length), np.uint8)
        rows[...] = template
        fill_columns(rows, columns)
        self.write_batch(channel_id, log_times_ns, rows.reshape(-1),
                         np.arange(n + 1, dtype=np.int64) * length, publish_times_ns)

    def close(self):
        """
        Write the ``rosbag2`` metadata record, let the library finish the file, close it.

        Returns
        -------
        dict
            ``file_summary()`` of the finished file.

        Raises
        ------
        OSError
            If the file cannot be finished (the caller names the output).

        """
        if self._closed:
            return self.file_summary()
        self._closed = True
        try:
            info = bag_metadata(self.topic_summaries(), [self.file_summary()], self.custom_data)
            self._writer.add_metadata('rosbag2', {'serialized_metadata': dump_yaml(info)})
            self._writer.finish()
            self._file.flush()
        finally:
            self.discard()
        return self.file_summary()

    def start_writeback(self):
        """Hand what was written so far to the kernel and let it start writing it out."""
        self._check_open()
        self._file.flush()
        start_writeback(self._file.fileno())

    def discard(self):
        """Close the file without finishing it (after an error; the caller removes it)."""
        self._closed = True
        try:
            self._file.close()
        except OSError:
            pass  # a full disk fails the flush again: the file is removed anyway

    def __enter__(self):
        """Return the writer."""
        return self

    def __exit__(self, *exc):
        """Close the file."""
        self.close()

    # ----------------------------------------------------------------- internals

    def _check_open(self):
        if self._closed:
            raise BagError(f'{self.path} is closed; open a new writer to write more')

    def _topic_of(self, channel_id):
        self._check_open()
        topic = self._by_channel.get(channel_id)
        if topic is None:
            raise InvalidInput(f'channel id {channel_id!r} was not returned by add_topic; '
                               f'known channels: {sorted(self._by_channel)}')
        return topic

    @staticmethod
    def _note(topic, logs):
        lo, hi = int(logs.min()), int(logs.max())
        topic.count += logs.shape[0]
        topic.start = lo if topic.start is None else min(topic.start, lo)
        topic.end = hi if topic.end is None else max(topic.end, hi)
