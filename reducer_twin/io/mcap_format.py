"""
MCAP record opcodes and framing shared by the project's array writer and its reader.

Reading parses records with the ``mcap`` library; what is here is the record layout the
numpy hot path needs (opcodes, the message record header) and the chunk compression of
the array writer.
"""

import struct

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
LIBRARY = 'reducer_twin mcap_array_writer 0.1'
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
