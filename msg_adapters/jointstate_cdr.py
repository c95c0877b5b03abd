"""
Vectorised CDR encoding and decoding of ``sensor_msgs/msg/JointState``.

A JointState in CDR (XCDR1, plain, as Fast DDS puts it on the wire and rosbag2 stores
it) is, after the 4-byte encapsulation header ``00 01 00 00`` (little endian) or
``00 00 00 00`` (big endian)::

    int32 sec, uint32 nanosec              header.stamp
    uint32 n + n bytes (with NUL)          header.frame_id
    uint32 count, then per name: uint32 n + n bytes (each aligned to 4)
    uint32 count, float64[count]           position, velocity, effort

Alignment is counted from the end of the encapsulation header; a float64 array is
aligned to 8 only when it is not empty. Padding bytes carry no meaning (rclpy's
``serialize_message`` leaves them uninitialised), so the decoder never looks at them.

A controller publishes the same joints every tick, so the messages of one topic share
one length and one byte layout except for the stamp and the numbers. Both directions
exploit that: the encoder writes one template row per message and fills the stamp and
float columns through strided numpy views; the decoder groups payloads of equal length,
checks that their structural bytes equal those of a template message, and reads the
columns of the whole group at once. Messages that do not fit a template take a per-
message path that handles any layout.
"""

from dataclasses import dataclass, replace
import struct

import numpy as np

from reducer_twin.core.errors import InvalidInput
from reducer_twin.msg_adapters.cdr import align, CdrWriter

MSGTYPE = 'sensor_msgs/msg/JointState'
FIELDS = ('position', 'velocity', 'effort')

_NS_PER_S = 1_000_000_000
_MAX_TEMPLATES_PER_LENGTH = 8
_INT32_MIN, _INT32_MAX = -2**31, 2**31 - 1


@dataclass(eq=False)
class JointStateBatch:
    """
    A batch of N JointState messages, as arrays over messages and joints.

    Attributes
    ----------
    stamps_ns : numpy.ndarray
        int64[N], ``header.stamp`` in ns since the epoch.
    names : tuple of str
        The J joint names, the columns of the arrays. A batch decoded from messages
        with different name sets holds the union, in order of first appearance.
    position, velocity, effort : numpy.ndarray
        float64[N, J] in rad (or m), rad/s (or m/s), N m (or N). NaN where a message
        left the field empty, gave its velocity or effort a length other than its name
        count, or did not name the joint (a position of another length than the names
        rejects the message: no entry can be told its value).
    frame_id : str
        ``header.frame_id`` of the first message.
    log_time_ns : numpy.ndarray or None
        int64[N] receive times (MCAP ``log_time``) when the batch came from a bag.
    rejected : tuple
        ``(index, reason)`` of malformed messages left out (decode with
        ``errors='skip'``); the index counts in the input batch.
    repeated_names : int
        Entries left out because their message named the joint before (the first entry
        of a name counts).
    named : numpy.ndarray or None
        int64[J], per column, the messages that named it; None when every message
        named every column (a column of a name a message lacks is NaN in its row: it
        is absent, not a bad value).
    effort_faults : tuple
        ``(messages, first problem)``: messages whose ``effort[]`` was neither empty nor
        one per name (their efforts are NaN: which entry a value belongs to cannot be
        known), and the first one's problem (None when there was none).

    """

    stamps_ns: np.ndarray
    names: tuple
    position: np.ndarray
    velocity: np.ndarray
    effort: np.ndarray
    frame_id: str = ''
    log_time_ns: object = None
    rejected: tuple = ()
    repeated_names: int = 0
    named: object = None
    effort_faults: tuple = (0, None)

    def __len__(self):
        """Return the number of messages N."""
        return int(self.stamps_ns.shape[0])

    def joint_index(self, name):
        """
        Return the column of a joint.

        Parameters
        ----------
        name : str
            Joint name.

        Returns
        -------
        int
            Column index into ``position``, ``velocity`` and ``effort``.

        Raises
        ------
        InvalidInput
            If no message of the batch names the joint.

        """
        try:
            return self.names.index(name)
        except ValueError:
            raise InvalidInput(
                f'joint {name!r} is not in this JointState batch; it has {list(self.names)}'
            ) from None

    def take(self, index):
        """
        Return the messages selected by an index array or mask, as a new batch.

        Parameters
        ----------
        index : array_like
            Integer indices or a boolean mask over the N messages.

        Returns
        -------
        JointStateBatch
            The selected messages with the same joint columns (``named`` kept when
            they are all of them, reordered).

        """
        log = None if self.log_time_ns is None else self.log_time_ns[index]
        stamps = self.stamps_ns[index]
        return JointStateBatch(
            stamps, self.names, self.position[index], self.velocity[index],
            self.effort[index], self.frame_id, log, (),
            named=self.named if stamps.shape[0] == len(self) else None)


def empty_batch(names=()):
    """
    Return a batch of no messages.

    Parameters
    ----------
    names : sequence of str
        Joint names (columns).

    Returns
    -------
    JointStateBatch
        N = 0, J = ``len(names)``.

    """
    names = tuple(names)
    shape = (0, len(names))
    return JointStateBatch(
        np.zeros(0, np.int64), names, np.zeros(shape), np.zeros(shape), np.zeros(shape), '',
        np.zeros(0, np.int64))


# --------------------------------------------------------------------------- encoding


def _template(frame_id, names, counts):
    """Build the bytes of one message and the offsets of its stamp and float fields."""
    msg = CdrWriter()
    msg.raw(bytes(8))
    msg.string(frame_id, 'frame_id')
    msg.u32(len(names))
    for i, name in enumerate(names):
        msg.string(name, f'names[{i}]')
    offsets = []
    for count in counts:
        msg.u32(count)
        if count:
            msg.align(8)
        offsets.append(len(msg))
        msg.zeros(8 * count)
    return np.frombuffer(msg.getvalue(), np.uint8), offsets


def _field_array(values, what, n, n_joints):
    if values is None:
        return None
    try:
        arr = np.asarray(values, dtype=np.float64)
    except (TypeError, ValueError) as err:
        raise InvalidInput(f'{what} must be numeric [N, J] values: {err}') from err
    if arr.ndim == 1 and n_joints == 1 and arr.shape[0] == n:
        arr = arr[:, None]
    if arr.shape == (n, 0) or arr.size == 0 and arr.shape[0] in (0, n):
        return None
    if arr.shape != (n, n_joints):
        raise InvalidInput(
            f'{what} must have shape (N, J) = ({n}, {n_joints}), got {arr.shape}')
    return arr


def fill_columns(rows, columns):
    """
    Write per-message fields into rows of serialised messages, in place.

    Parameters
    ----------
    rows : numpy.ndarray
        uint8[N, R] (any row stride, last axis contiguous) holding N message templates.
    columns : sequence of tuple
        ``(offset, dtype, values)``: values of shape [N] or [N, k] written at byte
        ``offset`` of every row with numpy dtype ``dtype`` (e.g. ``'<f8'``).

    """
    for offset, dtype, values in columns:
        values = np.asarray(values)
        width = np.dtype(dtype).itemsize * (values.shape[1] if values.ndim == 2 else 1)
        view = rows[:, offset:offset + width].view(dtype)
        view[...] = values if values.ndim == 2 else values[:, None]


def joint_state_columns(stamps_ns, names, position, velocity=None, effort=None, frame_id=''):
    """
    Describe N JointState messages that share their names as a template and columns.

    This is the form in which a writer can build messages in place (see
    ``McapBagWriter.write_template_batch``): every message is the template with the
    columns written into it.

    Parameters
    ----------
    stamps_ns, names, position, velocity, effort, frame_id
        As for :func:`encode_joint_states`.

    Returns
    -------
    template : numpy.ndarray
        uint8[L], one serialised message with zero stamp and values.
    columns : list of tuple
        ``(offset, dtype, values)`` for header.stamp sec and nanosec and for each
        non-empty float field.

    Raises
    ------
    InvalidInput
        As for :func:`encode_joint_states`.

    """
    stamps = np.asarray(stamps_ns)
    if stamps.ndim != 1 or not np.issubdtype(stamps.dtype, np.integer):
        raise InvalidInput(
            f'stamps_ns must be a 1-D integer array in ns, got dtype {stamps.dtype} '
            f'and shape {stamps.shape}')
    if isinstance(names, str):
        raise InvalidInput(f'names must be a sequence of str, got the str {names!r}')
    names = tuple(names)
    n, n_joints = stamps.shape[0], len(names)
    fields = [_field_array(v, w, n, n_joints)
              for v, w in zip((position, velocity, effort), FIELDS)]
    counts = [0 if f is None else n_joints for f in fields]
    template, offsets = _template(frame_id, names, counts)
    sec, nsec = np.divmod(stamps.astype(np.int64), _NS_PER_S)
    if n and (sec.min() < _INT32_MIN or sec.max() > _INT32_MAX):
        bad = stamps[(sec < _INT32_MIN) | (sec > _INT32_MAX)][0]
        raise InvalidInput(
            f'stamps_ns must lie within the int32 seconds range of builtin_interfaces/Time '
            f'({_INT32_MIN} .. {_INT32_MAX} s), got {bad} ns')
    columns = [(4, '<i4', sec), (8, '<u4', nsec)]
    columns += [(offset, '<f8', values) for values, offset in zip(fields, offsets)
                if values is not None and n_joints]
    return template, columns


def encode_joint_states(stamps_ns, names, position, velocity=None, effort=None, frame_id=''):
    """
    Serialise N JointState messages that share their joint names into one CDR buffer.

    Parameters
    ----------
    stamps_ns : array_like of int
        int64[N], ``header.stamp`` in ns since the epoch (seconds must fit int32).
    names : sequence of str
        The J joint names, shared by all messages.
    position : array_like or None
        float64[N, J] in rad or m; None (or zero columns) leaves the field empty.
    velocity, effort : array_like or None
        float64[N, J] in rad/s (m/s) and N m (N); None leaves the field empty, as
        ros2_control does for interfaces it does not have.
    frame_id : str
        ``header.frame_id``.

    Returns
    -------
    buffer : numpy.ndarray
        uint8, all messages back to back, each with its encapsulation header.
    offsets : numpy.ndarray
        int64[N + 1]; message i is ``buffer[offsets[i]:offsets[i + 1]]``.

    Raises
    ------
    InvalidInput
        On arrays of the wrong shape, stamps outside the int32 seconds range or names
        that are not strings.

    """
    template, columns = joint_state_columns(stamps_ns, names, position, velocity, effort,
                                            frame_id)
    n = columns[0][2].shape[0]
    row = template.shape[0]
    out = np.empty((n, row), np.uint8)
    if n:
        out.view(f'V{row}')[:, 0] = template.view(f'V{row}')[0]
        fill_columns(out, columns)
    return out.reshape(-1), np.arange(n + 1, dtype=np.int64) * row


# --------------------------------------------------------------------------- decoding


@dataclass(frozen=True)
class _Layout:
    """Byte layout of one JointState payload, shared by every message that matches it."""

    length: int
    byte_order: str
    frame_id: str
    names: tuple
    fields: tuple  # ((offset, count), ...) for position, velocity, effort
    spans: tuple  # ((start, stop), ...) bytes that must equal the template
    coarse: tuple  # fewer, wider spans: ``spans`` plus the padding between them


def _reject(where, offset, problem):
    return InvalidInput(f'malformed JointState CDR in {where}, byte {offset}: {problem}')


def _parse_layout(payload, where):
    """Parse one payload (bytes) completely; raise InvalidInput on any inconsistency."""
    size = len(payload)
    if size < 4:
        raise _reject(where, 0, f'payload has {size} bytes, expected at least the 4-byte '
                      'CDR encapsulation header')
    kind = payload[0:2]
    if kind == b'\x00\x01':
        order = '<'
    elif kind == b'\x00\x00':
        order = '>'
    else:
        raise _reject(where, 0, f'encapsulation header {payload[:4].hex(" ")} is not plain '
                      'CDR; expected 00 01 00 00 (little endian) or 00 00 00 00 (big endian)')
    u32 = struct.Struct(order + 'I')
    spans = [(0, 2)]

    def need(pos, count, what):
        if pos + count > size:
            raise _reject(where, pos, f'{what} needs {count} bytes but the payload ends at '
                          f'byte {size}')

    def read_u32(pos, what):
        pos = align(pos, 4)
        need(pos, 4, what)
        return u32.unpack_from(payload, pos)[0], pos

    def read_string(pos, what):
        length, pos = read_u32(pos, f'the length of {what}')
        if length > size - pos - 4:
            raise _reject(where, pos, f'{what} has length {length}, which runs past the '
                          f'payload end at byte {size}')
        raw = payload[pos + 4:pos + 4 + length]
        if length and raw[-1:] != b'\x00':
            raise _reject(where, pos + 3 + length, f'{what} does not end with NUL')
        inner = raw.find(b'\x00', 0, max(length - 1, 0))
        if inner >= 0:
            raise _reject(where, pos + 4 + inner, f'{what} has a NUL inside (a C reader would '
                          'cut it there)')
        try:
            text = raw[:-1].decode('utf-8') if length else ''
        except UnicodeDecodeError as err:
            raise _reject(where, pos + 4, f'{what} is not UTF-8: {err.reason}') from None
        spans.append((pos, pos + 4 + length))
        return text, pos + 4 + length

    need(4, 8, 'header.stamp')
    frame_id, pos = read_string(12, 'header.frame_id')
    n_names, pos = read_u32(pos, 'the count of name[]')
    spans.append((pos, pos + 4))
    pos += 4
    if n_names > (size - pos) // 5:
        raise _reject(where, pos - 4, f'name[] count {n_names} needs at least {5 * n_names} '
                      f'bytes but only {size - pos} remain')
    names = []
    for i in range(n_names):
        name, pos = read_string(pos, f'name[{i}]')
        names.append(name)
    fields = []
    for field in FIELDS:
        count, pos = read_u32(pos, f'the count of {field}[]')
        spans.append((pos, pos + 4))
        pos += 4
        if count:
            pos = align(pos, 8)
            if count > (size - pos) // 8:
                raise _reject(where, pos - 4, f'{field}[] count {count} needs {8 * count} '
                              f'bytes but the payload ends at byte {size}')
        fields.append((pos, count))
        pos += 8 * count
    if fields[0][1] and fields[0][1] != n_names:
        # Which name lacks its value cannot be known: no position of it is read.
        raise _reject(where, fields[0][0], f'position[] has {fields[0][1]} entries for '
                      f'{n_names} names (a JointState has one per name)')
    merged = []
    for start, stop in spans:
        if merged and merged[-1][1] == start:
            merged[-1] = (merged[-1][0], stop)
        else:
            merged.append((start, stop))
    variable = [(2, 12)] + [(offset, offset + 8 * count) for offset, count in fields if count]
    coarse = []
    begin = 0
    for start, stop in variable:
        if start > begin:
            coarse.append((begin, start))
        begin = stop
    if pos > begin:
        coarse.append((begin, pos))
    return _Layout(size, order, frame_id, tuple(names), tuple(fields), tuple(merged),
                   tuple(coarse))


class JointStateReader:
    """
    Decode JointState payloads one message at a time, as a live subscription gets them.

    A controller sends the same names every tick, so the layout of the last
    message is kept: a payload of the same length whose structural bytes
    (encapsulation, frame, names, array counts) equal the last one's is read
    without parsing, the stamp and the three float arrays straight out of the
    bytes. Any other payload is parsed and checked completely and its layout
    kept in turn. The result is what the typed message would hold; no
    ``sensor_msgs.msg.JointState`` (twelve strings, three arrays) is built.
    """

    def __init__(self):
        self._known = {}    # payload length -> (layout, template bytes, stamp struct, dtype)

    def read(self, payload):
        """
        Decode one payload.

        Parameters
        ----------
        payload : bytes
            One serialised ``sensor_msgs/msg/JointState`` (CDR, with its
            encapsulation header), as a raw subscription delivers it.

        Returns
        -------
        tuple
            ``(stamp_ns, names, position, velocity, effort)``: int, tuple of
            str and three read-only float64 arrays as long as the message's
            fields (empty where the message left a field empty).

        Raises
        ------
        InvalidInput
            If the payload is not a well-formed JointState.

        """
        known = self._known.get(len(payload))
        if known is None or not _same_layout(payload, known[0], known[1]):
            layout = _parse_layout(bytes(payload), 'a JointState message')
            if len(self._known) >= _MAX_TEMPLATES_PER_LENGTH and known is None:
                self._known.clear()     # traffic of ever new lengths: start again
            known = (layout, bytes(payload), struct.Struct(layout.byte_order + 'iI'),
                     np.dtype(layout.byte_order + 'f8'))
            self._known[len(payload)] = known
        layout, _, stamp, dtype = known
        sec, nsec = stamp.unpack_from(payload, 4)
        position, velocity, effort = (np.frombuffer(payload, dtype, count, offset)
                                      for offset, count in layout.fields)
        return sec * _NS_PER_S + nsec, layout.names, position, velocity, effort


def _same_layout(payload, layout, template):
    """Whether ``payload`` (of the template's length) has the template's structure."""
    for start, stop in layout.coarse:
        if payload[start:stop] != template[start:stop]:
            # Padding may differ between writers: compare the meaningful bytes only.
            return all(payload[a:b] == template[a:b] for a, b in layout.spans)
    return True


def _as_buffer(payloads, offsets, lengths):
    """Normalise the accepted input forms to (uint8 buffer, starts, lengths)."""
    if offsets is None:
        if isinstance(payloads, (bytes, bytearray, memoryview, np.ndarray)):
            raise InvalidInput('a single buffer needs offsets; pass a list of payloads or '
                               'decode_joint_states(buffer, offsets, lengths)')
        try:
            parts = [bytes(p) for p in payloads]
        except TypeError as err:
            raise InvalidInput(f'payloads must be bytes-like objects: {err}') from err
        lens = np.fromiter((len(p) for p in parts), np.int64, len(parts))
        starts = np.zeros(len(parts), np.int64)
        if len(parts) > 1:
            np.cumsum(lens[:-1], out=starts[1:])
        return np.frombuffer(b''.join(parts), np.uint8), starts, lens
    try:
        buf = np.frombuffer(payloads, np.uint8) if not isinstance(payloads, np.ndarray) \
            else payloads.reshape(-1).view(np.uint8)
    except (TypeError, ValueError) as err:
        raise InvalidInput(f'buffer must be a bytes-like object or uint8 array: {err}') from err
    starts = np.asarray(offsets, dtype=np.int64).reshape(-1)
    if lengths is None:
        if starts.shape[0] == 0:
            raise InvalidInput('offsets must hold N + 1 boundaries, got an empty array')
        lens = np.diff(starts)
        starts = starts[:-1]
    else:
        lens = np.asarray(lengths, dtype=np.int64).reshape(-1)
        if lens.shape != starts.shape:
            raise InvalidInput(f'offsets and lengths must have the same length, got '
                               f'{starts.shape[0]} and {lens.shape[0]}')
    if starts.size:
        bad = (starts < 0) | (lens < 0) | (starts + lens > buf.shape[0])
        if bad.any():
            i = int(np.argmax(bad))
            raise InvalidInput(
                f'payload {i} spans bytes {starts[i]} .. {starts[i] + lens[i]} of a buffer of '
                f'{buf.shape[0]} bytes; expected offsets and lengths inside the buffer')
    return buf, starts, lens


def _rows(buf, starts, length):
    """Return an (n, length) uint8 array of the payloads at ``starts`` (a view if regular)."""
    n = starts.shape[0]
    if n == 1 or (n > 1 and length > 0):
        step = int(starts[1] - starts[0]) if n > 1 else length
        if step >= length and (n == 1 or np.all(np.diff(starts) == step)):
            return np.lib.stride_tricks.as_strided(
                buf[int(starts[0]):], shape=(n, length), strides=(step, 1), writeable=False)
    if length == 0:
        return np.zeros((n, 0), np.uint8)
    return np.lib.stride_tricks.sliding_window_view(buf, length)[starts]


def _bytes_column(rows, start, stop):
    """Return the bytes ``start:stop`` of every row as one opaque (void) value per row."""
    return rows[:, start:stop].view(f'V{stop - start}')[:, 0]


def _matches(rows, template, spans):
    ok = None
    for start, stop in spans:
        same = _bytes_column(rows, start, stop) == _bytes_column(template[None, :], start, stop)
        ok = same if ok is None else ok & same
    return np.ones(rows.shape[0], bool) if ok is None else ok


def _read_group(rows, layout):
    """Read stamps and float fields of rows that all follow ``layout``."""
    order = layout.byte_order
    stamp = _bytes_column(rows, 4, 12).copy().view(np.uint8).reshape(-1, 8)
    sec = stamp[:, :4].copy().view(order + 'i4')[:, 0].astype(np.int64)
    nsec = stamp[:, 4:].copy().view(order + 'u4')[:, 0].astype(np.int64)
    values = []
    n_joints = len(layout.names)
    for offset, count in layout.fields:
        if count == n_joints and count:
            raw = _bytes_column(rows, offset, offset + 8 * count).copy()
            floats = raw.view(order + 'f8').reshape(-1, count)
            values.append(floats.astype(np.float64, copy=False))
        else:
            values.append(None)
    return sec * _NS_PER_S + nsec, values


class _Pieces:
    """Decoded groups, collected before they are placed into the output arrays."""

    def __init__(self):
        self.items = []  # (message indices, layout, stamps, [pos, vel, eff])
        self.rejected = []

    def add(self, index, layout, stamps, values):
        self.items.append((index, layout, stamps, values))


def _parse_at(buf, starts, i, length, pieces, errors):
    """Parse message ``i`` fully; return its layout, or None after rejecting it."""
    start = int(starts[i])
    try:
        return _parse_layout(buf[start:start + length].tobytes(),
                             f'message {i} (buffer byte {start})')
    except InvalidInput as err:
        if errors == 'raise':
            raise
        pieces.rejected.append((int(i), str(err)))
        return None


def _decode_length_group(buf, starts, index, length, pieces, errors):
    """Decode messages of one length: a few vectorised template passes, then one by one."""
    remaining = index
    k = 0  # position in ``remaining`` of the next template candidate
    passes = 0
    while k < remaining.shape[0] and passes < _MAX_TEMPLATES_PER_LENGTH:
        layout = _parse_at(buf, starts, remaining[k], length, pieces, errors)
        if layout is None:
            k += 1
            continue
        passes += 1
        candidates = remaining[k:]
        rows = _rows(buf, starts[candidates], length)
        # Padding included, one comparison per gap between stamp and float arrays; rows
        # that differ there (padding may hold garbage) get the exact check.
        ok = _matches(rows, rows[0], layout.coarse)
        if not ok.all():
            ok[~ok] = _matches(rows[~ok], rows[0], layout.spans)
            rows = rows[ok]
        pieces.add(candidates[ok], layout, *_read_group(rows, layout))
        remaining, k = candidates[~ok], 0
    # Irregular traffic: no template repeats enough to pay for another vectorised pass.
    for i in remaining[k:]:
        layout = _parse_at(buf, starts, i, length, pieces, errors)
        if layout is not None:
            rows = _rows(buf, starts[[i]], length)
            pieces.add(np.array([i]), layout, *_read_group(rows, layout))


def decode_joint_states(payloads, offsets=None, lengths=None, errors='raise'):
    """
    Decode a batch of JointState CDR payloads into arrays.

    Parameters
    ----------
    payloads : sequence of bytes-like, or bytes-like / uint8 array
        Either a list of payloads, or one buffer that holds them all (for instance a
        decompressed MCAP chunk, which is then read without copying per message).
    offsets : array_like of int, optional
        With a single buffer: int64[N] start of each payload (with ``lengths``), or
        int64[N + 1] boundaries (without ``lengths``, as ``encode_joint_states`` returns).
    lengths : array_like of int, optional
        int64[N] payload lengths.
    errors : {'raise', 'skip'}
        ``'raise'`` stops at the first malformed payload; ``'skip'`` leaves it out and
        lists it in ``JointStateBatch.rejected``.

    Returns
    -------
    JointStateBatch
        Messages in input order (without the skipped ones).

    Raises
    ------
    InvalidInput
        On a malformed payload (truncated, a length or count that runs past the payload,
        an unknown encapsulation, a string that is not NUL-terminated UTF-8) when
        ``errors='raise'``, or on offsets outside the buffer.

    """
    if errors not in ('raise', 'skip'):
        raise InvalidInput(f"errors must be 'raise' or 'skip', got {errors!r}")
    buf, starts, lens = _as_buffer(payloads, offsets, lengths)
    n = starts.shape[0]
    pieces = _Pieces()
    if n:
        if lens.min() == lens.max():
            groups = [(int(lens[0]), np.arange(n))]
        else:
            unique, inverse = np.unique(lens, return_inverse=True)
            order = np.argsort(inverse, kind='stable')
            bounds = np.searchsorted(inverse[order], np.arange(unique.shape[0] + 1))
            groups = [(int(unique[k]), order[bounds[k]:bounds[k + 1]])
                      for k in range(unique.shape[0])]
        for length, index in groups:
            _decode_length_group(buf, starts, index, length, pieces, errors)
    return _assemble(n, pieces)


def _assemble(n, pieces):
    if not pieces.items:
        batch = empty_batch()
        batch.log_time_ns = None
        batch.rejected = tuple(sorted(pieces.rejected))
        return batch
    items = sorted(pieces.items, key=lambda item: int(item[0][0]) if item[0].size else n)
    first_layout = items[0][1]
    repeated = 0
    faults = _effort_faults(items)
    for k, (index, layout, stamps, values) in enumerate(items):
        names = tuple(dict.fromkeys(layout.names))
        if len(names) != len(layout.names):  # a name given twice: its first entry counts
            keep = [layout.names.index(name) for name in names]
            repeated += (len(layout.names) - len(names)) * len(index)
            items[k] = (index, replace(layout, names=names), stamps,
                        [None if v is None else v[:, keep] for v in values])
    if len(items) == 1 and not pieces.rejected:
        index, layout, stamps, values = items[0]
        shape = (n, len(layout.names))
        out = [v if v is not None else np.full(shape, np.nan) for v in values]
        return JointStateBatch(stamps, layout.names, *out, frame_id=layout.frame_id,
                               repeated_names=repeated, effort_faults=faults)
    columns = {}
    for _, layout, _, _ in items:
        for name in layout.names:
            columns.setdefault(name, len(columns))
    keep = np.ones(n, bool)
    if pieces.rejected:
        keep[[i for i, _ in pieces.rejected]] = False
    row_of = np.cumsum(keep) - 1
    n_out = int(keep.sum())
    stamps_out = np.zeros(n_out, np.int64)
    out = [np.full((n_out, len(columns)), np.nan) for _ in FIELDS]
    named = np.zeros(len(columns), np.int64)
    for index, layout, stamps, values in items:
        rows = row_of[index]
        stamps_out[rows] = stamps
        cols = np.array([columns[name] for name in layout.names], np.int64)
        named[cols] += index.shape[0]
        for target, value in zip(out, values):
            if value is not None:
                target[rows[:, None], cols[None, :]] = value
    return JointStateBatch(stamps_out, tuple(columns), *out, frame_id=first_layout.frame_id,
                           rejected=tuple(sorted(pieces.rejected)), repeated_names=repeated,
                           named=None if (named == n_out).all() else named,
                           effort_faults=faults)


def _effort_faults(items):
    """Count the messages whose effort[] is neither empty nor one per name; the first's."""
    count, first, first_index = 0, None, None
    for index, layout, _, _ in items:
        entries = layout.fields[2][1]
        if entries and entries != len(layout.names) and index.size:
            count += int(index.size)
            if first_index is None or int(index[0]) < first_index:
                first_index = int(index[0])
                first = (f'effort[] has {entries} entries for {len(layout.names)} names (a '
                         'JointState has one per name)')
    return count, first


def concat_batches(batches):
    """
    Join batches in the given order, taking the union of their joint names.

    Parameters
    ----------
    batches : sequence of JointStateBatch
        Batches to join.

    Returns
    -------
    JointStateBatch
        All messages; NaN where a batch did not have a joint. ``log_time_ns`` is kept
        only when every batch has it.

    """
    batches = [b for b in batches if b is not None]
    if not batches:
        return empty_batch()
    names = {}
    for batch in batches:
        for name in batch.names:
            names.setdefault(name, len(names))
    names = tuple(names)
    same = all(batch.names == names for batch in batches)
    named = None
    if not same or any(b.named is not None for b in batches):
        named = np.zeros(len(names), np.int64)
        for batch in batches:
            cols = [names.index(name) for name in batch.names]
            named[cols] += batch.named if batch.named is not None else len(batch)
        if (named == sum(len(b) for b in batches)).all():
            named = None
    faults = sum(b.effort_faults[0] for b in batches)
    first = next((b.effort_faults[1] for b in batches if b.effort_faults[0]), None)
    if same:
        fields = [np.concatenate([getattr(b, f) for b in batches]) for f in FIELDS]
    else:
        total = sum(len(b) for b in batches)
        fields = [np.full((total, len(names)), np.nan) for _ in FIELDS]
        row = 0
        for batch in batches:
            cols = [names.index(name) for name in batch.names]
            for target, field in zip(fields, FIELDS):
                target[row:row + len(batch), cols] = getattr(batch, field)
            row += len(batch)
    logs = None
    if all(b.log_time_ns is not None for b in batches):
        logs = np.concatenate([np.asarray(b.log_time_ns, np.int64) for b in batches])
    frame_id = next((b.frame_id for b in batches if len(b)), batches[0].frame_id)
    return JointStateBatch(np.concatenate([b.stamps_ns for b in batches]), names, *fields,
                           frame_id=frame_id, log_time_ns=logs,
                           rejected=tuple(r for b in batches for r in b.rejected),
                           repeated_names=sum(b.repeated_names for b in batches),
                           named=named, effort_faults=(faults, first))
