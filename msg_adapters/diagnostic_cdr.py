"""
CDR encoding of ``diagnostic_msgs/msg/DiagnosticArray`` without ROS.

The bag analysis writes ``/diagnostics`` as the live nodes publish it (one array per
window and joint). The layout, XCDR1 little endian after the encapsulation header
``00 01 00 00`` (alignment counted from its end)::

    int32 sec, uint32 nanosec, string frame_id               header
    uint32 count, then per status:                          status[]
        uint8 level, string name, string message, string hardware_id,
        uint32 count, then per value: string key, string value

A string is ``uint32 n`` (aligned to 4) and ``n`` bytes ending in NUL. Values are
formatted as :func:`reducer_twin.msg_adapters.ros.diagnostic_status` formats them (floats with six
significant digits), so an offline analysis and a live recording read alike.
"""

import math
import struct
from typing import NamedTuple

from reducer_twin.core.errors import InvalidInput
from reducer_twin.msg_adapters.cdr import CdrWriter

MSGTYPE = 'diagnostic_msgs/msg/DiagnosticArray'
"""ROS type of ``/diagnostics``."""

LEVELS = {'OK': 0, 'WARN': 1, 'ERROR': 2, 'STALE': 3}
"""Level names to the message's byte values (``DiagnosticStatus.OK`` ...)."""


class Status(NamedTuple):
    """
    One ``DiagnosticStatus``.

    Attributes
    ----------
    level : str
        ``'OK'``, ``'WARN'``, ``'ERROR'`` or ``'STALE'``.
    name, message, hardware_id : str
        As in the message.
    values : mapping
        Key to value; formatted with :func:`format_value`.

    """

    level: str
    name: str
    message: str
    hardware_id: str
    values: dict


def format_value(value):
    """
    Format a key/value value as the live nodes do.

    Parameters
    ----------
    value : object
        A number, bool or string.

    Returns
    -------
    str
        Floats with six significant digits (``nan``/``inf`` as such), others by ``str``.

    """
    if isinstance(value, float):
        return f'{value:.6g}' if math.isfinite(value) else str(value)
    return str(value)


def encode_diagnostic_array(stamp_ns, statuses, frame_id=''):
    """
    Serialise a ``DiagnosticArray``.

    Parameters
    ----------
    stamp_ns : int
        ``header.stamp`` [ns] (>= 0).
    statuses : sequence of Status
        The statuses.
    frame_id : str
        ``header.frame_id``.

    Returns
    -------
    bytes
        The CDR payload.

    Raises
    ------
    InvalidInput
        On an unknown level, a negative stamp or a string with NUL.

    """
    sec, nanosec = divmod(int(stamp_ns), 1_000_000_000)
    if not 0 <= sec < 2**31:
        raise InvalidInput(f'stamp_ns must be in [0, 2^31) s, got {stamp_ns!r} ns')
    msg = CdrWriter()
    msg.raw(struct.pack('<iI', sec, nanosec))
    msg.string(frame_id, 'frame_id')
    msg.u32(len(statuses))
    for status in statuses:
        if status.level not in LEVELS:
            raise InvalidInput(f'diagnostic level must be one of {sorted(LEVELS)}, got '
                               f'{status.level!r}')
        msg.raw(bytes((LEVELS[status.level],)))
        msg.string(str(status.name), 'status name')
        msg.string(str(status.message), 'status message')
        msg.string(str(status.hardware_id), 'hardware_id')
        msg.u32(len(status.values))
        for key, value in status.values.items():
            msg.string(str(key), 'key')
            msg.string(format_value(value), f'value of {key}')
    return msg.getvalue()
