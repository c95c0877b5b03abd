"""
The CDR primitives the message encoders share (XCDR1 little endian, as rmw_fastrtps writes).

A serialised ROS 2 message starts with the 4-byte encapsulation header ``00 01 00 00``;
alignment counts from its end (a uint32 sits at a multiple of 4 after it, a float64 at
a multiple of 8). A string is ``uint32 n`` (aligned to 4) and ``n`` bytes ending in NUL.
:class:`CdrWriter` builds one message from these; the JointState, Float64MultiArray and
DiagnosticArray encoders and decoders use them.

Pure Python: no ROS import.
"""

import struct

from reducer_twin.core.errors import InvalidInput

ENCAPSULATION = b'\x00\x01\x00\x00'
"""CDR little endian, no options: the first 4 bytes of every message the encoders write."""

_ZEROS = tuple(bytes(n) for n in range(8))
_U32 = struct.Struct('<I').pack


def align(pos, size):
    """
    Align an absolute offset to ``size``, counting from the encapsulation header's end.

    Parameters
    ----------
    pos : int
        Offset in the message, header included.
    size : int
        Alignment of the next primitive (4 or 8).

    Returns
    -------
    int
        The first offset >= ``pos`` where the primitive may start.

    """
    return 4 + ((pos - 4 + size - 1) // size) * size


def cdr_string(text, what):
    """
    Serialise a string: ``uint32 n`` and ``n`` bytes of UTF-8 ending in NUL (unaligned).

    Parameters
    ----------
    text : str
        The string.
    what : str
        Its name, for messages.

    Returns
    -------
    bytes
        The length field and the bytes; the caller aligns the length to 4.

    Raises
    ------
    InvalidInput
        If ``text`` is not a str or holds a NUL character.

    """
    try:
        raw = text.encode('utf-8')
    except (AttributeError, UnicodeEncodeError) as err:
        raise InvalidInput(f'{what} must be a str, got {text!r}') from err
    if b'\x00' in raw:
        raise InvalidInput(f'{what} must not contain NUL characters, got {text!r}')
    return _U32(len(raw) + 1) + raw + b'\x00'


class CdrWriter:
    """
    One CDR message under construction, starting with the encapsulation header.

    Attributes
    ----------
    out : bytearray
        The bytes so far.

    """

    def __init__(self):
        self.out = bytearray(ENCAPSULATION)

    def align(self, size):
        """Pad with zero bytes to the alignment ``size`` (4 or 8)."""
        self.out += _ZEROS[(4 - len(self.out)) % size]

    def u32(self, value):
        """Append a uint32 (aligned to 4)."""
        out = self.out
        out += _ZEROS[-len(out) % 4]
        out += _U32(value)

    def string(self, text, what):
        """Append a CDR string, its length aligned to 4 (see :func:`cdr_string`)."""
        out = self.out
        out += _ZEROS[-len(out) % 4]
        out += cdr_string(text, what)

    def raw(self, data):
        """Append bytes as they are (a byte, a stamp already packed)."""
        self.out += data

    def zeros(self, count, size=1):
        """Append ``count`` zero elements of ``size`` bytes, aligned to ``size`` when any."""
        if count and size > 1:
            self.align(size)
        self.out += bytes(count * size)

    def __len__(self):
        """Return the length so far, header included."""
        return len(self.out)

    def getvalue(self):
        """Return the message as bytes."""
        return bytes(self.out)
