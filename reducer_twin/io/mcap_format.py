"""
MCAP record opcodes and framing shared by the project's array writer and its reader.

Records are framed and parsed by the ``mcap`` library (:func:`record_bytes` writes
them); what is here besides is the layout the numpy hot path needs (opcodes, the message
record header, the chunk record header) and the chunk compression of the array writer.
"""

import struct

from mcap.data_stream import RecordBuilder

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
DEFAULT_CHUNK_SIZE = 768 * 1024  # libmcap's default chunk size, kept by rosbag2

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


def record_bytes(*records):
    """
    Serialise records with the mcap library's record writer.

    Parameters
    ----------
    *records : mcap.records.McapRecord
        Header, Schema, Channel, Metadata, Statistics, index records...

    Returns
    -------
    bytes
        The records, framed (opcode, length, body) one after the other.

    """
    builder = RecordBuilder()
    for record in records:
        record.write(builder)
    return builder.end()


def _string(text):
    raw = text.encode('utf-8')
    return struct.pack('<I', len(raw)) + raw


def _compress(compression, data, level):
    if compression == 'zstd':
        return _zstd.compress(data, level=level)
    if compression == 'lz4':
        return _lz4.compress(data)
    return bytes(data)
