"""
Vectorised CDR encoding and decoding of ``std_msgs/msg/Float64MultiArray``.

The twin's derived topics are labelled ``Float64MultiArray`` s
(:mod:`reducer_twin.msg_adapters.layouts`).
In CDR (XCDR1, little endian, as rclpy puts it on the wire and rosbag2 stores it), after the
4-byte encapsulation header ``00 01 00 00``::

    uint32 count, then per dimension:          layout.dim
        uint32 n + n bytes (with NUL), aligned to 4   label
        uint32 size, uint32 stride
    uint32 data_offset                          layout.data_offset
    uint32 count, float64[count]                data (aligned to 8 when not empty)

Alignment counts from the end of the encapsulation header. Messages of one layout and one
sample count share every byte but the data, so N of them are one template plus one float
column: :func:`multiarray_columns` returns that form for
``McapBagWriter.write_template_batch``, which builds them in place in its chunk buffers.
Pure Python and numpy: no ROS import.
"""

from dataclasses import dataclass
import functools
import struct

import numpy as np

from reducer_twin.core.errors import InvalidInput
from reducer_twin.msg_adapters.cdr import align, CdrWriter

MSGTYPE = 'std_msgs/msg/Float64MultiArray'
"""ROS type of the derived topics."""

_HEADERS = {b'\x00\x01': '<', b'\x00\x00': '>'}


@dataclass(frozen=True)
class MultiArray:
    """
    A decoded ``Float64MultiArray``.

    Attributes
    ----------
    dims : tuple of tuple
        ``(label, size, stride)`` per dimension.
    data_offset : int
        ``layout.data_offset``.
    data : numpy.ndarray
        float64 values.

    """

    dims: tuple
    data_offset: int
    data: np.ndarray

    def values(self, layout):
        """
        Return the data by the layout's fields, checking the labels.

        Parameters
        ----------
        layout : reducer_twin.msg_adapters.layouts.Layout
            Expected layout.

        Returns
        -------
        numpy.ndarray
            ``(samples, fields)`` for a batch layout, ``(fields,)`` for a record.

        Raises
        ------
        InvalidInput
            If the labels or sizes do not match the layout.

        """
        n_fields = len(layout.fields)
        label = self.dims[-1][0] if self.dims else ''
        if label != layout.label:
            raise InvalidInput(f'expected layout {layout.name!r} with fields {layout.label!r}, '
                               f'got {label!r}')
        if layout.batch:
            if len(self.dims) != 2 or self.dims[1][1] != n_fields or \
                    self.data.size != self.dims[0][1] * n_fields:
                raise InvalidInput(f'{layout.name}: dimensions {list(self.dims)} do not hold '
                                   f'{self.data.size} values of {n_fields} fields')
            return self.data.reshape(-1, n_fields)
        if self.data.size != n_fields:
            raise InvalidInput(f'{layout.name}: expected {n_fields} values, got '
                               f'{self.data.size}')
        return self.data


def _dims(layout, rows):
    n_fields = len(layout.fields)
    if layout.batch:
        return [('samples', rows, rows * n_fields), (layout.label, n_fields, n_fields)]
    return [(layout.label, n_fields, n_fields)]


def multiarray_template(layout, rows=None):
    """
    Serialise one message of a layout with zero data.

    Parameters
    ----------
    layout : reducer_twin.msg_adapters.layouts.Layout
        Layout of the message.
    rows : int, optional
        Samples per message (batch layouts only).

    Returns
    -------
    template : numpy.ndarray
        uint8[L], the message.
    data_offset : int
        Byte offset of the first float64 of ``data`` in the message.

    Raises
    ------
    InvalidInput
        If ``rows`` is missing or negative for a batch layout.

    """
    if layout.batch and (rows is None or int(rows) < 0):
        raise InvalidInput(f'{layout.name} is a batch layout: rows must be >= 0, got {rows!r}')
    return _template(layout, int(rows or 0))


@functools.lru_cache(maxsize=512)
def _template(layout, rows):
    """Build the (read-only) template of a layout and sample count; a few per analysis."""
    dims = _dims(layout, rows)
    msg = CdrWriter()
    msg.u32(len(dims))
    for label, size, stride in dims:
        msg.string(label, 'a dimension label')
        msg.u32(size)
        msg.u32(stride)
    count = dims[0][2] if layout.batch else dims[0][1]
    msg.u32(0)   # data_offset
    msg.u32(count)
    if count:
        msg.align(8)
    data_offset = len(msg)
    msg.zeros(8 * count)
    return np.frombuffer(msg.getvalue(), np.uint8), data_offset


def multiarray_columns(layout, values):
    """
    Describe N messages of one layout as a template and a data column.

    Parameters
    ----------
    layout : reducer_twin.msg_adapters.layouts.Layout
        Layout of the messages.
    values : array_like
        ``(N, fields)`` records for a single-record layout, or ``(N, rows, fields)``
        for a batch layout (every message holds ``rows`` samples).

    Returns
    -------
    template : numpy.ndarray
        uint8[L], one message with zero data.
    columns : list of tuple
        ``[(data_offset, '<f8', values[N, rows * fields])]``, for
        ``McapBagWriter.write_template_batch``.

    Raises
    ------
    InvalidInput
        If ``values`` does not have the layout's shape.

    """
    arr = np.asarray(values, dtype=np.float64)
    n_fields = len(layout.fields)
    ndim = 3 if layout.batch else 2
    if arr.ndim != ndim or arr.shape[-1] != n_fields:
        shape = '(N, rows, fields)' if layout.batch else '(N, fields)'
        raise InvalidInput(f'{layout.name} values must have shape {shape} with {n_fields} '
                           f'fields, got {arr.shape}')
    rows = arr.shape[1] if layout.batch else None
    template, offset = multiarray_template(layout, rows)
    flat = arr.reshape(arr.shape[0], -1)
    return template, ([(offset, '<f8', flat)] if flat.shape[1] else [])


def encode_multiarrays(layout, values):
    """
    Serialise N messages of one layout back to back.

    Parameters
    ----------
    layout : reducer_twin.msg_adapters.layouts.Layout
        Layout of the messages.
    values : array_like
        As for :func:`multiarray_columns`.

    Returns
    -------
    buffer : numpy.ndarray
        uint8[N * L], the payloads.
    offsets : numpy.ndarray
        int64[N + 1] boundaries (for ``write_batch``).

    Raises
    ------
    InvalidInput
        If ``values`` does not have the layout's shape.

    """
    template, columns = multiarray_columns(layout, values)
    n = np.asarray(values).shape[0]
    rows = np.empty((n, template.size), np.uint8)
    rows[:] = template
    for offset, dtype, column in columns:
        rows[:, offset:offset + 8 * column.shape[1]].view(dtype)[...] = column
    return rows.reshape(-1), np.arange(n + 1, dtype=np.int64) * template.size


def encode_multiarray(layout, values):
    """
    Serialise one message.

    Parameters
    ----------
    layout : reducer_twin.msg_adapters.layouts.Layout
        Layout of the message.
    values : array_like
        ``(rows, fields)`` for a batch layout, ``(fields,)`` for a record.

    Returns
    -------
    bytes
        The CDR payload.

    Raises
    ------
    InvalidInput
        If ``values`` does not have the layout's shape.

    """
    arr = np.asarray(values, dtype=np.float64)
    n_fields = len(layout.fields)
    expected = 2 if layout.batch else 1
    if arr.ndim != expected or arr.shape[-1] != n_fields:
        shape = '(rows, fields)' if layout.batch else '(fields,)'
        raise InvalidInput(f'{layout.name} values must have shape {shape} with {n_fields} '
                           f'fields, got {arr.shape}')
    template, offset = multiarray_template(layout, arr.shape[0] if layout.batch else None)
    out = bytearray(template.tobytes())
    out[offset:offset + arr.nbytes] = arr.astype('<f8').tobytes()
    return bytes(out)


class _Reader:
    def __init__(self, payload):
        self.buf = memoryview(payload).cast('B')
        head = bytes(self.buf[:2])
        if len(self.buf) < 4 or head not in _HEADERS:
            raise InvalidInput(f'Float64MultiArray payload must start with a CDR encapsulation '
                               f'header 00 01 or 00 00, got {bytes(self.buf[:4]).hex(" ")}')
        self.order = _HEADERS[head]
        self.pos = 4

    def need(self, count, what):
        if self.pos + count > len(self.buf):
            raise InvalidInput(f'Float64MultiArray payload of {len(self.buf)} bytes ends inside '
                               f'{what} at byte {self.pos}')

    def u32(self, what):
        self.pos = align(self.pos, 4)
        self.need(4, what)
        value = struct.unpack_from(self.order + 'I', self.buf, self.pos)[0]
        self.pos += 4
        return value

    def string(self, what):
        size = self.u32(what)
        self.need(size, what)
        raw = bytes(self.buf[self.pos:self.pos + size])
        self.pos += size
        return raw[:-1].decode('utf-8', errors='replace') if size else ''


def decode_multiarray(payload):
    """
    Decode one ``Float64MultiArray``.

    Parameters
    ----------
    payload : bytes-like
        CDR payload with its encapsulation header.

    Returns
    -------
    MultiArray
        Dimensions, data offset and data.

    Raises
    ------
    InvalidInput
        If the payload is truncated or not CDR.

    """
    reader = _Reader(payload)
    n_dims = reader.u32('the dimension count')
    if n_dims > 64:
        raise InvalidInput(f'Float64MultiArray claims {n_dims} dimensions; expected at most 64')
    dims = []
    for k in range(n_dims):
        label = reader.string(f'the label of dimension {k}')
        size = reader.u32(f'the size of dimension {k}')
        stride = reader.u32(f'the stride of dimension {k}')
        dims.append((label, size, stride))
    data_offset = reader.u32('layout.data_offset')
    count = reader.u32('the data count')
    if count:
        reader.pos = align(reader.pos, 8)
    reader.need(8 * count, 'the data')
    data = np.frombuffer(reader.buf, reader.order + 'f8', count, reader.pos).astype(np.float64)
    return MultiArray(tuple(dims), data_offset, data)


def decode_layout_batch(layout, payloads):
    """
    Decode messages of one layout into one array.

    Parameters
    ----------
    layout : reducer_twin.msg_adapters.layouts.Layout
        Expected layout.
    payloads : iterable of bytes-like
        CDR payloads.

    Returns
    -------
    numpy.ndarray
        Records stacked ``(N, fields)`` for a single-record layout; samples of all
        messages concatenated ``(samples, fields)`` for a batch layout.

    Raises
    ------
    InvalidInput
        If a message does not decode or does not have the layout.

    """
    parts = [decode_multiarray(p).values(layout) for p in payloads]
    n_fields = len(layout.fields)
    if not parts:
        return np.zeros((0, n_fields))
    return np.concatenate(parts) if layout.batch else np.stack(parts)
