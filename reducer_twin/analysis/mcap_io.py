"""
Fast MCAP reading and writing in the layout rosbag2 (Jazzy) uses.

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
into reused buffers while earlier chunks compress on worker threads, and the reader
hands out each decompressed chunk as one buffer plus offset and length arrays, gathered
with numpy from runs of equal-length records or from the Message Index records.

A file without a usable summary (a recording cut short) is scanned record by record;
what is readable is returned and the reader's ``warnings`` say where reading stopped.
"""

import collections
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
import functools
import itertools
import json
import mmap
import os
from pathlib import Path
import re
import struct
import zlib

from msg_adapters import ros_schemas
import numpy as np
from reducer_twin.core.errors import BagError, InvalidInput
import yaml

try:  # Python >= 3.14
    from compression import zstd as _zstd  # pragma: no cover
except ImportError:  # pragma: no cover - depends on the interpreter
    try:
        from backports import zstd as _zstd
    except ImportError:
        _zstd = None
try:
    import lz4.frame as _lz4
except ImportError:  # pragma: no cover - lz4 is optional
    _lz4 = None

MAGIC = b'\x89MCAP0\r\n'
PROFILE = 'ros2'
LIBRARY = 'reducer_twin mcap_io 0.1'
ROS_DISTRO = 'jazzy'
METADATA_VERSION = 9
DEFAULT_CHUNK_SIZE = 768 * 1024  # libmcap's default chunk size, kept by rosbag2
MAX_TIME = 2**63 - 1  # rosbag2's starting_time before the first message

OP_HEADER, OP_FOOTER, OP_SCHEMA, OP_CHANNEL, OP_MESSAGE, OP_CHUNK = 1, 2, 3, 4, 5, 6
OP_MESSAGE_INDEX, OP_CHUNK_INDEX, OP_ATTACHMENT, OP_ATTACHMENT_INDEX = 7, 8, 9, 10
OP_STATISTICS, OP_METADATA, OP_METADATA_INDEX, OP_SUMMARY_OFFSET, OP_DATA_END = 11, 12, 13, 14, 15
RECORD_NAMES = {
    1: 'header', 2: 'footer', 3: 'schema', 4: 'channel', 5: 'message', 6: 'chunk',
    7: 'message index', 8: 'chunk index', 9: 'attachment', 10: 'attachment index',
    11: 'statistics', 12: 'metadata', 13: 'metadata index', 14: 'summary offset',
    15: 'data end'}
MESSAGE_HEADER = 31  # opcode, length, channel, sequence, log time, publish time

_COMPRESSIONS = {'zstd': 'zstd', 'lz4': 'lz4', 'none': '', '': ''}


# --------------------------------------------------------------------------- QoS


_ENUMS = {
    'history': ('system_default', 'keep_last', 'keep_all', 'unknown'),
    'reliability': ('system_default', 'reliable', 'best_effort', 'unknown', 'best_available'),
    'durability': ('system_default', 'transient_local', 'volatile', 'unknown',
                   'best_available'),
    'liveliness': ('system_default', 'automatic', 'manual_by_node', 'manual_by_topic',
                   'unknown', 'best_available'),
}
INFINITE = (9223372036, 854775807)  # RMW_DURATION_INFINITE as rmw_time_t


@dataclass(frozen=True)
class QosProfile:
    """
    One offered QoS profile, as rosbag2 stores it per topic.

    Policies are the strings of metadata version 9 (``'reliable'``, ``'volatile'``, ...);
    durations are ``(sec, nsec)``. The defaults are what ``ros2 bag record`` on Jazzy
    stores for a publisher with rclpy's default profile (DDS does not report the
    history depth of a remote publisher, so history is ``unknown`` with depth 0).
    """

    history: str = 'unknown'
    depth: int = 0
    reliability: str = 'reliable'
    durability: str = 'volatile'
    deadline: tuple = INFINITE
    lifespan: tuple = INFINITE
    liveliness: str = 'automatic'
    liveliness_lease_duration: tuple = INFINITE
    avoid_ros_namespace_conventions: bool = False

    def as_dict(self):
        """
        Return the profile as rosbag2 serialises it (version 9).

        Returns
        -------
        dict
            Keys in rosbag2's order; durations as ``{'sec': .., 'nsec': ..}``.

        """
        def duration(value):
            return {'sec': int(value[0]), 'nsec': int(value[1])}
        return {
            'history': self.history, 'depth': int(self.depth),
            'reliability': self.reliability, 'durability': self.durability,
            'deadline': duration(self.deadline), 'lifespan': duration(self.lifespan),
            'liveliness': self.liveliness,
            'liveliness_lease_duration': duration(self.liveliness_lease_duration),
            'avoid_ros_namespace_conventions': bool(self.avoid_ros_namespace_conventions),
        }


DEFAULT_QOS = (QosProfile(),)


def _policy(name, value):
    choices = _ENUMS[name]
    if isinstance(value, bool):
        raise InvalidInput(f'QoS {name} must be one of {choices} or 0..{len(choices) - 1}, '
                           f'got {value!r}')
    if isinstance(value, int):
        if 0 <= value < len(choices):
            return choices[value]
        return 'unknown'
    text = str(value).strip().lower()
    if text not in choices:
        raise InvalidInput(f'QoS {name} must be one of {choices}, got {value!r}')
    return text


def _duration(name, value):
    if value is None:
        return INFINITE
    if isinstance(value, dict):
        try:
            return int(value['sec']), int(value['nsec'])
        except (KeyError, TypeError, ValueError) as err:
            raise InvalidInput(f'QoS {name} must be {{sec, nsec}}, got {value!r}') from err
    try:
        sec, nsec = value
        return int(sec), int(nsec)
    except (TypeError, ValueError) as err:
        raise InvalidInput(f'QoS {name} must be (sec, nsec), got {value!r}') from err


def qos_from_dict(item):
    """
    Build a QosProfile from a rosbag2 QoS mapping.

    Parameters
    ----------
    item : dict
        One entry of ``offered_qos_profiles``; policies as strings (version 9) or as
        the integers older bags use.

    Returns
    -------
    QosProfile
        The profile; an unknown integer policy becomes ``'unknown'``.

    Raises
    ------
    InvalidInput
        If the mapping lacks keys or holds values of the wrong kind.

    """
    if not isinstance(item, dict):
        raise InvalidInput(f'a QoS profile must be a mapping, got {item!r}')
    try:
        return QosProfile(
            history=_policy('history', item.get('history', 'unknown')),
            depth=int(item.get('depth', 0)),
            reliability=_policy('reliability', item.get('reliability', 'unknown')),
            durability=_policy('durability', item.get('durability', 'unknown')),
            deadline=_duration('deadline', item.get('deadline')),
            lifespan=_duration('lifespan', item.get('lifespan')),
            liveliness=_policy('liveliness', item.get('liveliness', 'unknown')),
            liveliness_lease_duration=_duration(
                'liveliness_lease_duration', item.get('liveliness_lease_duration')),
            avoid_ros_namespace_conventions=bool(
                item.get('avoid_ros_namespace_conventions', False)))
    except (TypeError, ValueError) as err:
        if isinstance(err, InvalidInput):
            raise
        raise InvalidInput(f'QoS profile {item!r} is not understood: {err}') from err


def parse_qos_profiles(value):
    """
    Parse ``offered_qos_profiles`` as found in a bag.

    Parameters
    ----------
    value : str, list, QosProfile or None
        A YAML string (channel metadata, metadata.yaml up to version 8), a list of
        mappings (metadata.yaml version 9), or profiles.

    Returns
    -------
    tuple of QosProfile
        Empty for ``''`` or None.

    Raises
    ------
    InvalidInput
        If the text is not YAML or the entries are not QoS mappings.

    """
    if value is None or value == '':
        return ()
    if isinstance(value, QosProfile):
        return (value,)
    if isinstance(value, str):
        try:
            value = yaml.safe_load(value)
        except yaml.YAMLError as err:
            raise InvalidInput(f'offered_qos_profiles is not YAML: {err}') from err
        if value is None:
            return ()
    if isinstance(value, dict):
        value = [value]
    if not isinstance(value, (list, tuple)):
        raise InvalidInput(f'offered_qos_profiles must be a list of profiles, got {value!r}')
    return tuple(v if isinstance(v, QosProfile) else qos_from_dict(v) for v in value)


# --------------------------------------------------------------------------- YAML


_PLAIN = re.compile(r'[A-Za-z0-9_./][A-Za-z0-9_./\-]*')


@functools.lru_cache(maxsize=4096)
def _reads_back(text):
    """Whether YAML reads the plain scalar ``text`` as that string (cached: 0.3 ms a call)."""
    return yaml.safe_load(text) == text


def _scalar(value):
    if value is None:
        return '~'
    if isinstance(value, bool):
        return 'true' if value else 'false'
    if isinstance(value, (int, np.integer)):
        return str(int(value))
    text = str(value)
    if _PLAIN.fullmatch(text) and _reads_back(text):
        return text
    return json.dumps(text, ensure_ascii=False)


def dump_yaml(node, indent=0):
    """
    Serialise nested dicts and lists the way yaml-cpp (and so rosbag2) writes them.

    Block style; a sequence under a key is indented by two spaces; empty sequences
    are written as ``[]`` and empty or missing mappings as ``~``; strings that YAML
    would read as something else are double-quoted.

    Parameters
    ----------
    node : dict, list or scalar
        The document.
    indent : int
        Indentation of the top level, in spaces.

    Returns
    -------
    str
        The YAML text, without a trailing newline.

    """
    pad = ' ' * indent
    if isinstance(node, dict):
        if not node:
            return pad + '{}'
        lines = []
        for key, value in node.items():
            head = f'{pad}{_scalar(key)}:'
            if isinstance(value, dict) and value:
                lines.append(head + '\n' + dump_yaml(value, indent + 2))
            elif isinstance(value, (list, tuple)):
                lines.append(head + '\n' + dump_yaml(list(value), indent + 2))
            elif isinstance(value, dict):
                lines.append(head + ' ~')
            else:
                lines.append(f'{head} {_scalar(value)}')
        return '\n'.join(lines)
    if isinstance(node, (list, tuple)):
        if not node:
            return pad + '[]'
        lines = []
        for item in node:
            if isinstance(item, (dict, list, tuple)) and item:
                body = dump_yaml(item, indent + 2)
                lines.append(pad + '- ' + body[indent + 2:])
            else:
                lines.append(f'{pad}- {_scalar(item) if not isinstance(item, dict) else "{}"}')
        return '\n'.join(lines)
    return pad + _scalar(node)


def bag_metadata(topics, files, custom_data=None, storage_identifier='mcap'):
    """
    Build rosbag2's BagMetadata (version 9) as a dict in rosbag2's key order.

    Parameters
    ----------
    topics : list of dict
        Per topic: ``name``, ``type``, ``qos`` (sequence of QosProfile), ``type_hash``
        and ``count``.
    files : list of dict
        Per file: ``path`` (relative), ``start`` and ``end`` (ns, None if empty) and
        ``count``.
    custom_data : dict of str to str, optional
        User key/values (rosbag2's ``custom_data``).
    storage_identifier : str
        ``'mcap'``.

    Returns
    -------
    dict
        The content of ``rosbag2_bagfile_information``.

    """
    starts = [f['start'] for f in files if f['start'] is not None]
    ends = [f['end'] for f in files if f['end'] is not None]
    start = min(starts) if starts else MAX_TIME
    duration = max(ends) - start if ends else 0

    def file_entry(f):
        f_start = MAX_TIME if f['start'] is None else f['start']
        f_duration = 0 if f['start'] is None else f['end'] - f['start']
        return {'path': f['path'], 'starting_time': {'nanoseconds_since_epoch': f_start},
                'duration': {'nanoseconds': f_duration}, 'message_count': f['count']}

    return {
        'version': METADATA_VERSION,
        'storage_identifier': storage_identifier,
        'duration': {'nanoseconds': duration},
        'starting_time': {'nanoseconds_since_epoch': start},
        'message_count': sum(f['count'] for f in files),
        'topics_with_message_count': [
            {'topic_metadata': {
                'name': t['name'], 'type': t['type'], 'serialization_format': 'cdr',
                'offered_qos_profiles': [q.as_dict() for q in t['qos']],
                'type_description_hash': t['type_hash']},
             'message_count': t['count']} for t in topics],
        'compression_format': '',
        'compression_mode': '',
        'relative_file_paths': [f['path'] for f in files],
        'files': [file_entry(f) for f in files],
        'custom_data': dict(custom_data) if custom_data else None,
        'ros_distro': ROS_DISTRO,
    }


# --------------------------------------------------------------------------- records


def _string(text):
    raw = text.encode('utf-8')
    return struct.pack('<I', len(raw)) + raw


def _kv_map(mapping):
    body = b''.join(_string(str(k)) + _string(str(v)) for k, v in mapping.items())
    return struct.pack('<I', len(body)) + body


def _record(opcode, body):
    return struct.pack('<BQ', opcode, len(body)) + body


def _int_map(mapping, key_fmt):
    body = b''.join(struct.pack('<' + key_fmt + 'Q', k, v) for k, v in sorted(mapping.items()))
    return struct.pack('<I', len(body)) + body


def _compress(compression, data, level):
    if compression == 'zstd':
        return _zstd.compress(data, level=level)
    if compression == 'lz4':
        return _lz4.compress(data)
    return bytes(data)


def _decompress(compression, data, size):
    """Decompress chunk records, never producing more than the declared ``size`` bytes."""
    if compression == '':
        return bytes(data)
    if compression == 'zstd':
        if _zstd is None:  # pragma: no cover
            raise ValueError('no zstd module is installed')
        make = _zstd.ZstdDecompressor
    elif compression == 'lz4':
        if _lz4 is None:  # pragma: no cover
            raise ValueError('no lz4 module is installed')
        make = _lz4.LZ4FrameDecompressor
    else:
        raise ValueError(f'unsupported chunk compression {compression!r}; expected zstd, lz4 '
                         'or none')
    parts, total = [], 0
    while data:  # one frame after the other; a damaged size field cannot exhaust memory
        decompressor = make()
        part = decompressor.decompress(data, max_length=size + 1 - total)
        parts.append(part)
        total += len(part)
        if total > size:
            raise ValueError(f'the records are longer than the declared {size} bytes')
        if not decompressor.eof:
            raise ValueError('the compressed data end inside a frame')
        data = decompressor.unused_data
    return parts[0] if len(parts) == 1 else b''.join(parts)


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
    :mod:`reducer_twin.analysis.mcap_writer`; both keep ``_topics`` (objects with ``name``,
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
        self._schemas = {}  # msgtype -> (id, record body)
        self._topics = {}  # name -> _Topic
        self._channels = []  # (id, record body)
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
        self._pool = ThreadPoolExecutor(threads) if threads > 1 else None
        self._pending = []
        self._write(MAGIC)
        self._write(_record(OP_HEADER, _string(PROFILE) + _string(LIBRARY)))
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
            body = (struct.pack('<H', schema_id) + _string(msgtype) + _string('ros2msg')
                    + struct.pack('<I', len(schema_text.encode('utf-8')))
                    + schema_text.encode('utf-8'))
            self._schemas[msgtype] = (schema_id, body)
            self._append_bytes(_record(OP_SCHEMA, body))
        schema_id = self._schemas[msgtype][0]
        channel_id = len(self._topics) + 1
        qos_text = dump_yaml([p.as_dict() for p in profiles]) if profiles else ''
        body = (struct.pack('<HH', channel_id, schema_id) + _string(name) + _string('cdr')
                + _kv_map({'offered_qos_profiles': qos_text, 'topic_type_hash': type_hash}))
        self._channels.append((channel_id, body))
        self._append_bytes(_record(OP_CHANNEL, body))
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
            self._file.write(_record(OP_DATA_END, struct.pack('<I', self._crc)))
            self._pos += 9 + 4
            self._write_summary()
        finally:
            self._closed = True
            self._file.close()
            if self._pool is not None:
                self._pool.shutdown()
        return self.file_summary()

    def discard(self):
        """Close the file without finishing it (after an error; the caller removes it)."""
        self._closed = True
        try:
            self._file.close()
        except OSError:
            pass  # a full disk fails the flush again: the file is removed anyway
        if self._pool is not None:
            self._pool.shutdown(cancel_futures=True)

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
        body = _string('rosbag2') + _kv_map({'serialized_metadata': dump_yaml(info)})
        record = _record(OP_METADATA, body)
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
            self._write(_record(OP_MESSAGE_INDEX, body))
        self._chunk_indexes.append(
            struct.pack('<QQQQ', start, end, chunk_start, chunk_length)
            + _int_map(index_offsets, 'H')
            + struct.pack('<Q', self._pos - index_start) + _string(self.compression)
            + struct.pack('<QQ', len(compressed), len(data)))

    def _write_summary(self):
        summary_start = self._pos
        groups = []
        out = bytearray()

        def group(opcode, bodies):
            if not bodies:
                return
            start = summary_start + len(out)
            for body in bodies:
                out.extend(_record(opcode, body))
            groups.append((opcode, start, summary_start + len(out) - start))

        counts = {t.channel_id: t.count for t in self._topics.values() if t.count}
        starts = [t.start for t in self._topics.values() if t.start is not None]
        ends = [t.end for t in self._topics.values() if t.end is not None]
        statistics = (struct.pack('<QHIIII', sum(counts.values()), len(self._schemas),
                                  len(self._channels), 0, len(self._metadata_indexes),
                                  len(self._chunk_indexes))
                      + struct.pack('<QQ', min(starts) if starts else 0,
                                    max(ends) if ends else 0)
                      + _int_map(counts, 'H'))
        group(OP_SCHEMA, [body for _, body in sorted(self._schemas.values())])
        group(OP_CHANNEL, [body for _, body in self._channels])
        group(OP_STATISTICS, [statistics])
        group(OP_CHUNK_INDEX, self._chunk_indexes)
        group(OP_METADATA_INDEX, [struct.pack('<QQ', off, length) + _string(name)
                                  for off, length, name in self._metadata_indexes])
        offsets_start = summary_start + len(out)
        for opcode, start, length in groups:
            out.extend(_record(OP_SUMMARY_OFFSET, struct.pack('<BQQ', opcode, start, length)))
        footer_head = struct.pack('<BQQQ', OP_FOOTER, 20, summary_start, offsets_start)
        crc = zlib.crc32(footer_head, zlib.crc32(bytes(out)))
        self._file.write(bytes(out) + footer_head + struct.pack('<I', crc) + MAGIC)
        self._pos += len(out) + len(footer_head) + 4 + len(MAGIC)


# --------------------------------------------------------------------------- reading


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
class SchemaInfo:
    """An MCAP Schema record: ``id``, ``name`` (ROS type), ``encoding`` and ``data``."""

    id: int  # noqa: A003 - the MCAP field name
    name: str
    encoding: str
    data: bytes


@dataclass(frozen=True)
class ChannelInfo:
    """An MCAP Channel record: ids, ``topic``, ``message_encoding`` and ``metadata``."""

    id: int  # noqa: A003 - the MCAP field name
    schema_id: int
    topic: str
    message_encoding: str
    metadata: dict


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
    compressed_size: int = 0
    uncompressed_size: int = 0
    crc: int = 0
    data_offset: int = 0  # of the compressed records in the file
    index_offsets: dict = field(default_factory=dict)  # channel -> message index record


class _Corrupt(Exception):
    """Internal: a record or chunk cannot be used."""


def _u64(buf, pos):
    return struct.unpack_from('<Q', buf, pos)[0]


class _Cursor:
    """Bounds-checked reading of MCAP primitive fields from a record body."""

    def __init__(self, buf, start, end, what):
        self.buf, self.pos, self.end, self.what = buf, start, end, what

    def take(self, fmt):
        size = struct.calcsize(fmt)
        if self.pos + size > self.end:
            raise _Corrupt(f'{self.what} ends at byte {self.end} but needs {size} more '
                           f'bytes at byte {self.pos}')
        values = struct.unpack_from(fmt, self.buf, self.pos)
        self.pos += size
        return values if len(values) > 1 else values[0]

    def raw(self, size_fmt='<I'):
        size = self.take(size_fmt)
        if self.pos + size > self.end:
            raise _Corrupt(f'{self.what}: a field of {size} bytes at byte {self.pos} runs past '
                           f'the record end at byte {self.end}')
        data = bytes(self.buf[self.pos:self.pos + size])
        self.pos += size
        return data

    def string(self):
        try:
            return self.raw().decode('utf-8')
        except UnicodeDecodeError as err:
            raise _Corrupt(f'{self.what}: a string is not UTF-8 ({err.reason})') from None

    def kv_map(self):
        size = self.take('<I')
        stop = self.pos + size
        if stop > self.end:
            raise _Corrupt(f'{self.what}: a map of {size} bytes runs past the record end')
        out = {}
        while self.pos < stop:
            key = self.string()
            out[key] = self.string()
        return out

    def int_map(self, key_fmt):
        size = self.take('<I')
        stop = self.pos + size
        if stop > self.end:
            raise _Corrupt(f'{self.what}: a map of {size} bytes runs past the record end')
        out = {}
        while self.pos < stop:
            key, value = self.take('<' + key_fmt + 'Q')
            out[key] = value
        return out


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
        By id.
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
                    info = yaml.safe_load(values['serialized_metadata'])
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
        Iterate over the messages of the selected topics, one chunk at a time.

        Parameters
        ----------
        topics : iterable of str, optional
            Topic names; default all.

        Yields
        ------
        RawBatch
            The selected messages of one chunk, in file order.

        """
        wanted = self._channel_ids(topics)
        if not wanted:
            return
        wanted_arr = np.array(sorted(wanted), np.uint16)
        chunks = [c for c in self._chunks
                  if not c.index_offsets or wanted.intersection(c.index_offsets)]
        # Decompression (and the CRC check) of the next chunks runs on a worker thread
        # while this one is handed out; zstd and zlib release the GIL.
        with ThreadPoolExecutor(1) as pool:
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
                    if len(batch):
                        yield batch
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

    def _read_header(self):
        try:
            opcode, length = struct.unpack_from('<BQ', self._mm, 8)
            if opcode != OP_HEADER or 17 + length > self.size:
                raise _Corrupt('no header record')
            cursor = _Cursor(self._mm, 17, 17 + length, 'the header record')
            self.header = (cursor.string(), cursor.string())
        except (struct.error, _Corrupt):
            self._warn(8, f'no valid header record at byte 8 of {self.size}')

    def _read_summary(self):
        mm, size = self._mm, self.size
        footer = size - 8 - 29
        if size < 8 + 29 + 8 or mm[size - 8:] != MAGIC or mm[footer] != OP_FOOTER \
                or _u64(mm, footer + 1) != 20:
            raise _Corrupt(f'no footer at the end of the file ({size} bytes; a recording '
                           'that was cut short?)')
        summary_start, offsets_start, crc = struct.unpack_from('<QQI', mm, footer + 9)
        if summary_start == 0:
            raise _Corrupt('')  # a valid file without summary: scan quietly
        if not 8 <= summary_start <= footer or (offsets_start and not
                                                summary_start <= offsets_start <= footer):
            raise _Corrupt(f'the footer points to a summary at byte {summary_start}, outside '
                           f'the file')
        if self.validate_crc and crc and zlib.crc32(mm[summary_start:footer + 25]) != crc:
            raise _Corrupt(f'the summary CRC does not match (summary at byte {summary_start})')
        stop = offsets_start or footer
        chunks = []
        metadata_at = []
        arr = None
        for opcode, starts, length in _walk(mm, summary_start, stop, arr):
            pos = int(starts[0])
            cursor = _Cursor(mm, pos + 9, pos + 9 + length,
                             f'the {RECORD_NAMES.get(opcode, "unknown")} record at byte {pos}')
            if opcode == OP_SCHEMA:
                self._add_schema(cursor)
            elif opcode == OP_CHANNEL:
                self._add_channel(cursor)
            elif opcode == OP_STATISTICS:
                stats = cursor.take('<QHIIIIQQ')
                self.statistics = stats
                self._counts = cursor.int_map('H')
            elif opcode == OP_CHUNK_INDEX:
                chunks.append(self._chunk_from_index(cursor, summary_start))
            elif opcode == OP_METADATA_INDEX:
                offset, rec_len = cursor.take('<QQ')
                metadata_at.append((offset, rec_len))
        if self.statistics is None:
            raise _Corrupt('')  # valid, but message counts need a scan: scan quietly
        self._chunks = sorted(chunks, key=lambda c: c.offset)
        for offset, rec_len in metadata_at:
            self._read_metadata_record(offset, rec_len)
        if self.statistics[0] and not self._chunks:
            self._loose = self._scan_loose(summary_start)

    def _chunk_from_index(self, cursor, limit):
        start, end, offset, length = cursor.take('<QQQQ')
        index_offsets = cursor.int_map('H')
        if offset + length > limit or length < 9:
            raise _Corrupt(f'a chunk index points to bytes {offset} .. {offset + length}, '
                           'past the data section')
        return self._chunk_at(offset, index_offsets)

    def _chunk_at(self, offset, index_offsets=None):
        mm = self._mm
        opcode, length = struct.unpack_from('<BQ', mm, offset)
        if opcode != OP_CHUNK or offset + 9 + length > self.size:
            raise _Corrupt(f'no chunk record at byte {offset}')
        cursor = _Cursor(mm, offset + 9, offset + 9 + length, f'the chunk at byte {offset}')
        _, _, uncompressed, crc = cursor.take('<QQQI')
        compression = cursor.string()
        compressed = cursor.take('<Q')
        if cursor.pos + compressed > cursor.end:
            raise _Corrupt(f'the chunk at byte {offset} holds {compressed} bytes of records, '
                           'more than its record length')
        return _ChunkRef(offset, 9 + length, compression, compressed, uncompressed, crc,
                         cursor.pos, dict(index_offsets or {}))

    def _read_metadata_record(self, offset, length):
        try:
            opcode, body = struct.unpack_from('<BQ', self._mm, offset)
            if opcode != OP_METADATA or offset + 9 + body > self.size:
                raise _Corrupt(f'no metadata record at byte {offset}')
            cursor = _Cursor(self._mm, offset + 9, offset + 9 + body,
                             f'the metadata record at byte {offset}')
            self.metadata.append((cursor.string(), cursor.kv_map()))
        except (struct.error, _Corrupt) as err:
            self._warn(offset, f'metadata record skipped: {err}')

    def _add_schema(self, cursor):
        schema_id = cursor.take('<H')
        name = cursor.string()
        encoding = cursor.string()
        self.schemas[schema_id] = SchemaInfo(schema_id, name, encoding, cursor.raw())

    def _add_channel(self, cursor):
        channel_id, schema_id = cursor.take('<HH')
        topic = cursor.string()
        encoding = cursor.string()
        self.channels[channel_id] = ChannelInfo(channel_id, schema_id, topic, encoding,
                                                cursor.kv_map())

    def _load_chunk(self, chunk):
        """Decompress and check a chunk; return (uint8 array, None) or (None, problem)."""
        try:
            # pread, not the map: a copy into reused heap memory costs far less than a
            # page fault per 4 KiB of the file.
            raw = self._pread(chunk.data_offset, chunk.compressed_size)
            data = _decompress(chunk.compression, raw, chunk.uncompressed_size)
        except Exception as err:  # noqa: B902 - every codec raises its own error type
            return None, (f'chunk at byte {chunk.offset} cannot be decompressed '
                          f'({chunk.compression}: {err}); its messages are skipped')
        if len(data) != chunk.uncompressed_size:
            return None, (f'chunk at byte {chunk.offset} decompressed to {len(data)} bytes, '
                          f'expected {chunk.uncompressed_size}; its messages are skipped')
        if self.validate_crc and chunk.crc and zlib.crc32(data) != chunk.crc:
            return None, (f'chunk at byte {chunk.offset} fails its CRC check (corrupted '
                          'file); its messages are skipped')
        return np.frombuffer(data, np.uint8), None

    def _chunk_data(self, chunk, loaded=None):
        """Return the decompressed records of a chunk (uint8 array) or None after a warning."""
        data, problem = self._load_chunk(chunk) if loaded is None else loaded
        if problem is not None:
            self._warn(chunk.offset, problem)
        return data

    def _index_starts(self, chunk, wanted):
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
            pairs = np.frombuffer(self._pread(offset + 15, size), '<u8')
            parts.append(pairs[1::2].astype(np.int64))
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
                cursor = _Cursor(data, pos + 9, pos + 9 + length,
                                 f'a {RECORD_NAMES[opcode]} record inside a chunk')
                (self._add_schema if opcode == OP_SCHEMA else self._add_channel)(cursor)
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
                cursor = _Cursor(mm, pos + 9, pos + 9 + length,
                                 f'the {RECORD_NAMES.get(opcode, "unknown")} record at byte '
                                 f'{pos}')
                try:
                    if opcode == OP_SCHEMA:
                        self._add_schema(cursor)
                    elif opcode == OP_CHANNEL:
                        self._add_channel(cursor)
                    elif opcode == OP_CHUNK:
                        self._scan_chunk(pos)
                    elif opcode == OP_MESSAGE_INDEX and self._chunks:
                        channel_id = cursor.take('<H')
                        self._chunks[-1].index_offsets[channel_id] = pos
                    elif opcode == OP_METADATA:
                        self.metadata.append((cursor.string(), cursor.kv_map()))
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


def _stop_offset(err, default):
    match = re.search(r'at byte (\d+)', str(err))
    return int(match.group(1)) if match else default


def custom_data_strings(text):
    """
    Read rosbag2 ``custom_data`` from metadata YAML, every value as the string written.

    yaml-cpp writes a value such as ``1.5`` unquoted; rosbag2 reads it back as a string,
    and so does this function (a plain YAML load would turn it into a float).

    Parameters
    ----------
    text : str
        A metadata.yaml document or a ``serialized_metadata`` value.

    Returns
    -------
    dict of str to str or None
        None when the text holds no ``custom_data`` mapping.

    """
    try:
        raw = yaml.load(text, Loader=yaml.BaseLoader)
    except yaml.YAMLError:
        return None
    if isinstance(raw, dict) and 'rosbag2_bagfile_information' in raw:
        raw = raw['rosbag2_bagfile_information']
    if not isinstance(raw, dict):
        return None
    custom = raw.get('custom_data')
    if not isinstance(custom, dict):
        return None
    return {str(k): str(v) for k, v in custom.items()}
