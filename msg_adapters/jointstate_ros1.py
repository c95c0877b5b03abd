"""
``sensor_msgs/JointState`` of ROS 1 bags, decoded column-wise into a JointStateBatch.

A ROS 1 JointState is, with no alignment and little endian::

    uint32 seq, uint32 secs, uint32 nsecs       header
    uint32 n + n bytes (no NUL)                 header.frame_id
    uint32 count, then per name: uint32 n + n bytes
    uint32 count, float64[count]                position, velocity, effort

The payloads are walked by the connection's own message definition with
:class:`~reducer_twin.msg_adapters.msgdef_decoder.MessageDecoder`; messages of one layout (the same
names every tick) are read as columns, as :func:`~reducer_twin.msg_adapters.jointstate_cdr.
decode_joint_states` reads CDR. The result follows the same rules: NaN where a field is
empty or not as long as the names, the union of names across layouts.
"""

import numpy as np
from reducer_twin.core.errors import InvalidInput
from reducer_twin.msg_adapters.jointstate_cdr import (
    concat_batches, empty_batch, FIELDS, JointStateBatch)

MSGTYPE = 'sensor_msgs/msg/JointState'
_NS_PER_S = 1_000_000_000


def stamps_of(template, rows, header='header'):
    """
    Read ``<header>.stamp`` of a group as int64 ns.

    Parameters
    ----------
    template : Template
        The group's template.
    rows : numpy.ndarray
        The group's payload rows.
    header : str
        Name of the header field.

    Returns
    -------
    numpy.ndarray
        int64[N] stamps in ns since the epoch.

    """
    stamp = template.values[header]['stamp']
    sec = template.read(rows, stamp['sec'])[:, 0].astype(np.int64)
    nsec = template.read(rows, stamp['nanosec'])[:, 0].astype(np.int64)
    return sec * _NS_PER_S + nsec


def join_groups(parts, rejected):
    """
    Join per-layout batches into one batch in input order.

    Parameters
    ----------
    parts : list of tuple
        ``(index, JointStateBatch)``: input indices of each group's messages.
    rejected : list of tuple
        ``(index, reason)`` of the payloads left out.

    Returns
    -------
    JointStateBatch
        All decoded messages in input order, with ``rejected`` set; ``log_time_ns`` None.

    """
    rejected = tuple(sorted(rejected))
    if not parts:
        batch = empty_batch()
        batch.log_time_ns = None
        batch.rejected = rejected
        return batch
    if len(parts) == 1:
        batch = parts[0][1]
    else:
        index = np.concatenate([p[0] for p in parts])
        batch = concat_batches([p[1] for p in parts])
        batch = batch.take(np.argsort(index, kind='stable'))
    batch.log_time_ns = None
    batch.rejected = rejected
    return batch


def decode_ros1_joint_states(decoder, payloads, starts, lengths, errors='skip'):
    """
    Decode ROS 1 JointState payloads into arrays.

    Parameters
    ----------
    decoder : MessageDecoder
        Built from the connection's definition of ``sensor_msgs/msg/JointState`` with
        ``wire='ros1'``.
    payloads : bytes-like or numpy.ndarray
        One buffer holding the payloads (a decompressed chunk).
    starts, lengths : array_like of int
        int64[N] start and length of each payload.
    errors : {'skip', 'raise'}
        Leave malformed payloads out (listed in ``rejected``) or raise.

    Returns
    -------
    JointStateBatch
        Messages in input order, without the malformed ones.

    Raises
    ------
    InvalidInput
        On a malformed payload with ``errors='raise'``, or a definition that lacks the
        JointState fields.

    """
    groups, rejected = decoder.decode(payloads, starts, lengths, errors)
    parts = []
    for group in groups:
        values = group.template.values
        try:
            names = tuple(values['name'])
            header = values['header']
            blocks = [values[field] for field in FIELDS]
        except (KeyError, TypeError):
            raise InvalidInput(f'the message definition of {decoder.msgtype} has no JointState '
                               'fields header, name, position, velocity, effort') from None
        n, j = group.index.shape[0], len(names)
        columns = []
        for block in blocks:
            if j and block.count == j:
                columns.append(group.template.read(group.rows, block).astype(np.float64))
            else:
                columns.append(np.full((n, j), np.nan))
        parts.append((group.index, JointStateBatch(
            stamps_of(group.template, group.rows), names, *columns,
            frame_id=str(header.get('frame_id', '')))))
    return join_groups(parts, rejected)
