"""
Vectorised decoding of messages of any ROS type, from the message definition a bag stores.

The twin reads two kinds of messages it has no dedicated codec for: ``control_msgs/msg/
DynamicJointState`` (whose package it does not require; a rosbag2 bag stores the type's
``.msg`` text as the MCAP schema or in the sqlite3 ``message_definitions`` table) and the
messages of a ROS 1 ``.bag`` file (each connection stores its definition). The text is
parsed with rosbags' typesys (:func:`load_definitions`); :class:`MessageDecoder` walks
payloads by it.

Both wire formats are supported:

* ``'cdr'`` (rosbag2): a 4-byte encapsulation header (``00 01`` little, ``00 00`` big
  endian), primitives aligned to their size counted from the end of that header,
  strings as ``uint32`` length with the NUL, sequences as a ``uint32`` count; an empty
  sequence of primitives is not aligned (as Fast DDS writes it).
* ``'ros1'``: no header, no alignment, little endian, strings without the NUL,
  ``time`` as ``uint32`` seconds and nanoseconds.

A recorder stores messages of one layout (same strings, same sequence lengths) again
and again: they have one length, and every number sits at the same byte offset. The
decoder therefore parses one message of a length completely (a :class:`Template`:
its strings, and a :class:`Block` for every number or run of numbers), checks with a
few vectorised byte comparisons which other payloads of that length share its
structural bytes (encapsulation, string lengths and texts, sequence counts; never
padding), and hands those over as one group whose numbers are read as columns
(:meth:`Template.read`). Payloads that match no template are parsed one by one.
"""

from dataclasses import dataclass
import struct

import numpy as np

from reducer_twin.core.errors import InvalidInput

WIRES = ('cdr', 'ros1')
SEPARATOR = '=' * 80

# Nodetype values of rosbags' typesys (rosbags.interfaces.Nodetype).
_BASE, _NAME, _ARRAY, _SEQUENCE = 1, 2, 3, 4
_PRIMITIVES = {
    'bool': 'u1', 'byte': 'u1', 'char': 'u1', 'uint8': 'u1', 'int8': 'i1',
    'int16': 'i2', 'uint16': 'u2', 'int32': 'i4', 'uint32': 'u4', 'float32': 'f4',
    'int64': 'i8', 'uint64': 'u8', 'float64': 'f8',
}
_TIME = 'builtin_interfaces/msg/Time'
_DURATION = 'builtin_interfaces/msg/Duration'
_CDR_BUILTINS = {
    _TIME: ([], [('sec', (_BASE, ('int32', 0))), ('nanosec', (_BASE, ('uint32', 0)))]),
    _DURATION: ([], [('sec', (_BASE, ('int32', 0))), ('nanosec', (_BASE, ('uint32', 0)))]),
}
# ROS 1 ``time`` is unsigned, ``duration`` signed in both parts (roscpp's serializers).
_ROS1_BUILTINS = {
    _TIME: ([], [('sec', (_BASE, ('uint32', 0))), ('nanosec', (_BASE, ('uint32', 0)))]),
    _DURATION: ([], [('sec', (_BASE, ('int32', 0))), ('nanosec', (_BASE, ('int32', 0)))]),
}
_MAX_TEMPLATES_PER_LENGTH = 8
_MAX_DEPTH = 32


def load_definitions(msgtype, text, encoding='ros2msg'):
    """
    Parse a stored message definition into rosbags field definitions.

    Parameters
    ----------
    msgtype : str
        The type the text defines, e.g. ``'control_msgs/msg/DynamicJointState'``.
    text : str
        The definition: the type's ``.msg`` text followed by the types it uses, each
        after a line of 80 ``=`` and ``MSG: pkg/Name`` (rosbag2's ``ros2msg`` and a ROS 1
        connection's ``message_definition``), or ``ros2idl`` text.
    encoding : {'ros2msg', 'ros1msg', 'ros2idl'}
        How the text is written.

    Returns
    -------
    dict
        Type name to ``(constants, fields)`` as rosbags' ``get_types_from_msg`` gives.

    Raises
    ------
    InvalidInput
        If the text cannot be parsed or does not define ``msgtype``.

    """
    from rosbags.typesys import get_types_from_idl, get_types_from_msg
    try:
        if encoding == 'ros2idl':
            types = {}
            for part in text.split(f'{SEPARATOR}\n'):
                if part.startswith('IDL: '):
                    part = part.split('\n', 1)[1] if '\n' in part else ''
                if part.strip():
                    types.update(get_types_from_idl(part))
        elif encoding in ('ros2msg', 'ros1msg'):
            types = get_types_from_msg(text, msgtype)
        else:
            raise InvalidInput(f'the message definition of {msgtype} has encoding '
                               f"{encoding!r}; expected 'ros2msg', 'ros1msg' or 'ros2idl'")
    except InvalidInput:
        raise
    except Exception as err:  # noqa: B902 - rosbags' parser raises several kinds
        detail = ' '.join(str(err).split())[:300]
        raise InvalidInput(f'the message definition of {msgtype} stored in the bag cannot be '
                           f'parsed: {type(err).__name__}: {detail}') from None
    if msgtype not in types:
        raise InvalidInput(f'the message definition stored for {msgtype} defines '
                           f'{sorted(types)} but not {msgtype}')
    return types


@dataclass(frozen=True)
class Block:
    """
    Numbers at one place of every message of a template's layout.

    Attributes
    ----------
    offset : int
        Byte offset of the first number in the payload.
    dtype : str
        numpy dtype with byte order, e.g. ``'<f8'``.
    count : int
        Numbers in the run (1 for a scalar field, the length of a sequence).

    """

    offset: int
    dtype: str
    count: int

    @property
    def stop(self):
        """Return the byte offset after the run."""
        return self.offset + np.dtype(self.dtype).itemsize * self.count


@dataclass(frozen=True)
class Template:
    """
    One payload parsed completely: its layout, shared by the payloads that match it.

    Attributes
    ----------
    length : int
        Payload length in bytes.
    values : dict
        The message as nested dicts (messages), lists (sequences and arrays of strings
        or messages), str (strings) and :class:`Block` (numbers and runs of numbers).
    spans : tuple of tuple
        ``(start, stop)`` byte ranges a payload must equal to share this layout.
    payload : bytes
        The parsed payload.

    """

    length: int
    values: dict
    spans: tuple
    payload: bytes

    def read(self, rows, block):
        """
        Read a block from the rows of a group.

        Parameters
        ----------
        rows : numpy.ndarray
            uint8[N, length], payloads that match this template.
        block : Block
            Where the numbers are (from ``values``).

        Returns
        -------
        numpy.ndarray
            [N, count] of the block's dtype, in native byte order.

        """
        n = rows.shape[0]
        if block.count == 0 or n == 0:
            return np.zeros((n, block.count), np.dtype(block.dtype).newbyteorder('='))
        raw = _bytes_column(rows, block.offset, block.stop).copy()
        out = raw.view(block.dtype).reshape(n, block.count)
        return out.astype(out.dtype.newbyteorder('='), copy=False)

    def value(self, block):
        """
        Return the numbers of a block in this template's own payload.

        Parameters
        ----------
        block : Block
            From ``values``.

        Returns
        -------
        numpy.ndarray
            [count] numbers.

        """
        return np.frombuffer(self.payload, block.dtype, block.count, block.offset)


@dataclass
class Group:
    """Payloads of one layout: ``index`` into the input, their ``template`` and ``rows``."""

    index: np.ndarray
    template: Template
    rows: np.ndarray


class _Malformed(Exception):
    pass


class _Walk:
    """Parse one payload by the definitions; collect values, blocks and structural spans."""

    def __init__(self, types, payload, wire):
        self.types = types
        self.buf = payload
        self.size = len(payload)
        self.ros1 = wire == 'ros1'
        self.spans = []
        if self.ros1:
            self.order, self.base, self.pos = '<', 0, 0
            return
        if self.size < 4:
            raise _Malformed(0, f'payload has {self.size} bytes, expected at least the 4-byte '
                             'CDR encapsulation header')
        kind = payload[0:2]
        if kind not in (b'\x00\x01', b'\x00\x00'):
            raise _Malformed(0, f'encapsulation header {payload[:4].hex(" ")} is not plain CDR; '
                             'expected 00 01 00 00 (little endian) or 00 00 00 00 (big endian)')
        self.order = '<' if kind == b'\x00\x01' else '>'
        self.base, self.pos = 4, 4
        self.spans.append((0, 2))

    def align(self, size):
        if not self.ros1 and size > 1:
            self.pos = self.base + ((self.pos - self.base + size - 1) // size) * size

    def need(self, count, what):
        if self.pos + count > self.size:
            raise _Malformed(self.pos, f'{what} needs {count} bytes but the payload ends at '
                             f'byte {self.size}')

    def count(self, what):
        self.align(4)
        self.need(4, what)
        value = struct.unpack_from(self.order + 'I', self.buf, self.pos)[0]
        self.spans.append((self.pos, self.pos + 4))
        self.pos += 4
        return value

    def string(self, what):
        length = self.count(f'the length of {what}')
        start = self.pos
        if length > self.size - start:
            raise _Malformed(start - 4, f'{what} has length {length}, which runs past the '
                             f'payload end at byte {self.size}')
        raw = self.buf[start:start + length]
        if not self.ros1:
            if length and raw[-1:] != b'\x00':
                raise _Malformed(start + length - 1, f'{what} does not end with NUL')
            raw = raw[:-1]
        try:
            text = raw.decode('utf-8')
        except UnicodeDecodeError as err:
            raise _Malformed(start, f'{what} is not UTF-8: {err.reason}') from None
        self.spans[-1] = (start - 4, start + length)
        self.pos = start + length
        return text

    def numbers(self, kind, count, what):
        code = _PRIMITIVES[kind]
        size = int(code[1])
        if count:
            self.align(size)
        if count > (self.size - self.pos) // size:
            raise _Malformed(self.pos, f'{what} holds {count} {kind} values ({count * size} '
                             f'bytes) but the payload ends at byte {self.size}')
        block = Block(self.pos, self.order + code, count)
        self.pos += size * count
        return block

    def element(self, node, what, depth):
        kind, detail = node
        if kind == _BASE:
            name = detail[0]
            if name == 'string':
                return self.string(what)
            if name in _PRIMITIVES:
                return self.numbers(name, 1, what)
            raise _Malformed(self.pos, f'{what} has type {name}, which this reader does not '
                             'support')
        if kind == _NAME:
            return self.message(detail, what, depth + 1)
        raise _Malformed(self.pos, f'{what} nests arrays, which ROS messages cannot')

    def field(self, node, what, depth):
        kind, detail = node
        if kind not in (_ARRAY, _SEQUENCE):
            return self.element(node, what, depth)
        inner, length = detail
        if kind == _SEQUENCE:
            length = self.count(f'the count of {what}[]')
            if length > self.size - self.pos:
                raise _Malformed(self.pos - 4, f'{what}[] count {length} runs past the payload '
                                 f'end at byte {self.size}')
        if inner[0] == _BASE and inner[1][0] in _PRIMITIVES:
            return self.numbers(inner[1][0], length, f'{what}[]')
        return [self.element(inner, f'{what}[{i}]', depth) for i in range(length)]

    def message(self, msgtype, what, depth=0):
        if depth > _MAX_DEPTH:
            raise _Malformed(self.pos, f'{what} nests messages deeper than {_MAX_DEPTH} levels')
        try:
            _, fields = self.types[msgtype]
        except KeyError:
            raise _Malformed(self.pos, f'{what} has type {msgtype}, which the message '
                             'definition does not define') from None
        out = {}
        for name, node in fields:
            out[name] = self.field(node, f'{what}.{name}' if what else name, depth)
        return out


def _merge(spans):
    merged = []
    for start, stop in spans:
        if stop <= start:
            continue
        if merged and merged[-1][1] == start:
            merged[-1] = (merged[-1][0], stop)
        else:
            merged.append((start, stop))
    return tuple(merged)


def _bytes_column(rows, start, stop):
    """Return the bytes ``start:stop`` of every row as one opaque (void) value per row."""
    return rows[:, start:stop].view(f'V{stop - start}')[:, 0]


def _rows(buf, starts, length):
    """Return an (n, length) uint8 array of the payloads at ``starts`` (a view if regular)."""
    n = starts.shape[0]
    if n and length:
        step = int(starts[1] - starts[0]) if n > 1 else length
        if step >= length and (n == 1 or np.all(np.diff(starts) == step)):
            return np.lib.stride_tricks.as_strided(
                buf[int(starts[0]):], shape=(n, length), strides=(step, 1), writeable=False)
        return np.lib.stride_tricks.sliding_window_view(buf, length)[starts]
    return np.zeros((n, length), np.uint8)


def _matches(rows, template, spans):
    ok = np.ones(rows.shape[0], bool)
    for start, stop in spans:
        ok &= _bytes_column(rows, start, stop) == _bytes_column(template[None, :], start, stop)
    return ok


class MessageDecoder:
    """
    Decode payloads of one ROS type by its message definition.

    Parameters
    ----------
    msgtype : str
        The type, e.g. ``'control_msgs/msg/DynamicJointState'``.
    types : dict
        Field definitions from :func:`load_definitions` (builtin ``Time`` and
        ``Duration`` are added when missing; a ROS 1 ``time`` is always unsigned).
    wire : {'cdr', 'ros1'}
        Serialization of the payloads.

    """

    def __init__(self, msgtype, types, wire='cdr'):
        if wire not in WIRES:
            raise InvalidInput(f'wire must be one of {WIRES}, got {wire!r}')
        self.msgtype = msgtype
        self.wire = wire
        builtins = _ROS1_BUILTINS if wire == 'ros1' else _CDR_BUILTINS
        self.types = {**builtins, **types} if wire == 'cdr' else {**types, **builtins}

    def parse(self, payload):
        """
        Parse one payload completely.

        Parameters
        ----------
        payload : bytes
            One serialised message.

        Returns
        -------
        Template
            Its values and layout.

        Raises
        ------
        InvalidInput
            If the payload is not a well-formed message of the type.

        """
        payload = bytes(payload)
        try:
            walk = _Walk(self.types, payload, self.wire)
            values = walk.message(self.msgtype, '')
        except _Malformed as err:
            offset, problem = err.args
            raise InvalidInput(f'malformed {self.msgtype} ({self.wire}), byte {offset}: '
                               f'{problem}') from None
        if walk.pos != walk.size and (self.wire == 'ros1' or walk.size - walk.pos >= 8):
            # CDR writers may pad the end up to 8 bytes; anything else is not this type.
            raise InvalidInput(f'malformed {self.msgtype} ({self.wire}), byte {walk.pos}: the '
                               f'message ends there but the payload has {walk.size} bytes')
        return Template(len(payload), values, _merge(walk.spans), payload)

    def decode(self, payloads, starts, lengths, errors='skip'):
        """
        Parse a batch of payloads into groups of one layout each.

        Parameters
        ----------
        payloads : bytes-like or numpy.ndarray
            One buffer holding the payloads.
        starts, lengths : array_like of int
            int64[N] start and length of each payload in the buffer.
        errors : {'skip', 'raise'}
            Leave malformed payloads out (listing them) or raise.

        Returns
        -------
        groups : list of Group
            Every well-formed payload in exactly one group.
        rejected : list of tuple
            ``(index, reason)`` of the malformed payloads.

        Raises
        ------
        InvalidInput
            On a malformed payload when ``errors='raise'``, or offsets outside the buffer.

        """
        if errors not in ('skip', 'raise'):
            raise InvalidInput(f"errors must be 'skip' or 'raise', got {errors!r}")
        buf = payloads.reshape(-1).view(np.uint8) if isinstance(payloads, np.ndarray) \
            else np.frombuffer(payloads, np.uint8)
        starts = np.asarray(starts, np.int64).reshape(-1)
        lengths = np.asarray(lengths, np.int64).reshape(-1)
        if starts.shape != lengths.shape:
            raise InvalidInput(f'starts and lengths must have the same length, got '
                               f'{starts.shape[0]} and {lengths.shape[0]}')
        if starts.size and ((starts < 0) | (lengths < 0)
                            | (starts + lengths > buf.shape[0])).any():
            raise InvalidInput(f'payload offsets run outside the buffer of {buf.shape[0]} '
                               'bytes')
        groups, rejected = [], []
        if starts.size == 0:
            return groups, rejected
        unique, inverse = np.unique(lengths, return_inverse=True)
        if unique.shape[0] == 1:
            by_length = [(int(unique[0]), np.arange(starts.shape[0]))]
        else:
            order = np.argsort(inverse, kind='stable')
            bounds = np.searchsorted(inverse[order], np.arange(unique.shape[0] + 1))
            by_length = [(int(unique[k]), order[bounds[k]:bounds[k + 1]])
                         for k in range(unique.shape[0])]
        for length, index in by_length:
            self._length_group(buf, starts, index, length, groups, rejected, errors)
        return groups, rejected

    def _parse_at(self, buf, start, length, i, rejected, errors):
        try:
            return self.parse(buf[start:start + length].tobytes())
        except InvalidInput as err:
            if errors == 'raise':
                raise
            rejected.append((int(i), str(err)))
            return None

    def _length_group(self, buf, starts, index, length, groups, rejected, errors):
        remaining, k, passes = index, 0, 0
        while k < remaining.shape[0] and passes < _MAX_TEMPLATES_PER_LENGTH:
            i = remaining[k]
            template = self._parse_at(buf, int(starts[i]), length, i, rejected, errors)
            if template is None:
                k += 1
                continue
            passes += 1
            candidates = remaining[k:]
            rows = _rows(buf, starts[candidates], length)
            ok = _matches(rows, rows[0], template.spans)
            groups.append(Group(candidates[ok], template, rows if ok.all() else rows[ok]))
            remaining, k = candidates[~ok], 0
        for i in remaining[k:]:   # irregular traffic: one by one
            template = self._parse_at(buf, int(starts[i]), length, i, rejected, errors)
            if template is not None:
                groups.append(Group(np.array([i]), template,
                                    _rows(buf, starts[[i]], length)))
