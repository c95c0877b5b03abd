"""
Conversions between ROS 2 messages and the twin's core values.

The only module that knows both message fields and core types for the live
nodes: JointState entries to encoder samples (the forms robot controllers
publish), labelled ``Float64MultiArray`` layouts, ``DiagnosticArray``
statuses and stamps. Everything is SI; a field that cannot be used raises
:class:`~reducer_twin.core.errors.InvalidInput` with the reason.
"""

from array import array
import math

from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
import numpy as np
from reducer_twin.core.errors import InvalidInput
from reducer_twin.msg_adapters.layouts import parse_values
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray, MultiArrayDimension

LEVELS = {'OK': DiagnosticStatus.OK, 'WARN': DiagnosticStatus.WARN,
          'ERROR': DiagnosticStatus.ERROR, 'STALE': DiagnosticStatus.STALE}
"""Diagnostic level names to the message's byte values."""

LEVEL_NAMES = {v: k for k, v in LEVELS.items()}


def stamp_to_s(stamp):
    """
    Convert a ``builtin_interfaces/Time`` to seconds.

    Parameters
    ----------
    stamp : builtin_interfaces.msg.Time
        Stamp.

    Returns
    -------
    float
        Seconds since the epoch of the stamp's clock.

    """
    return stamp.sec + stamp.nanosec * 1e-9


def stamp_to_ns(stamp):
    """Convert a ``builtin_interfaces/Time`` to integer nanoseconds."""
    return stamp.sec * 1_000_000_000 + stamp.nanosec


def s_to_stamp(t):
    """
    Convert seconds to a ``builtin_interfaces/Time``.

    Parameters
    ----------
    t : float
        Seconds (non-negative).

    Returns
    -------
    builtin_interfaces.msg.Time
        Stamp rounded to the nanosecond.

    """
    return ns_to_stamp(int(round(t * 1e9)))


def ns_to_stamp(ns):
    """Convert integer nanoseconds to a ``builtin_interfaces/Time``."""
    sec, nsec = divmod(int(ns), 1_000_000_000)
    return Time(sec=sec, nanosec=nsec)


def to_multiarray(layout, values):
    """
    Wrap values into a labelled ``Float64MultiArray``.

    Parameters
    ----------
    layout : reducer_twin.msg_adapters.layouts.Layout
        Layout of the message.
    values : sequence of float or ndarray
        One record in field order, or an array (samples, fields) for a batch
        layout.

    Returns
    -------
    std_msgs.msg.Float64MultiArray
        The message.

    """
    msg = Float64MultiArray()
    n_fields = len(layout.fields)
    if layout.batch:
        arr = np.asarray(values, dtype=float).reshape(-1, n_fields)
        msg.layout.dim = [
            MultiArrayDimension(label='samples', size=arr.shape[0], stride=arr.size),
            MultiArrayDimension(label=layout.label, size=n_fields, stride=n_fields)]
        msg.data = _doubles(arr)
    else:
        data = np.asarray(values, dtype=float).ravel()
        if data.size != n_fields:
            raise InvalidInput(f'{layout.name}: expected {n_fields} values, got {data.size}')
        msg.layout.dim = [MultiArrayDimension(label=layout.label, size=n_fields,
                                              stride=n_fields)]
        msg.data = _doubles(data)
    return msg


class BatchPublisherMessage:
    """
    One reusable ``Float64MultiArray`` for a batch layout.

    Building the layout objects costs more than publishing; a publisher
    serialises the message at once, so one message can be refilled for
    every batch.

    Parameters
    ----------
    layout : reducer_twin.msg_adapters.layouts.Layout
        Batch layout.

    """

    def __init__(self, layout):
        self.layout = layout
        n = len(layout.fields)
        self.msg = Float64MultiArray()
        self.msg.layout.dim = [MultiArrayDimension(label='samples', size=0, stride=0),
                               MultiArrayDimension(label=layout.label, size=n, stride=n)]

    def fill(self, rows):
        """
        Put rows (samples, fields) into the message and return it.

        Parameters
        ----------
        rows : ndarray
            Values, one row per sample.

        Returns
        -------
        std_msgs.msg.Float64MultiArray
            The refilled message.

        """
        rows = np.asarray(rows, dtype=np.float64)
        dim = self.msg.layout.dim[0]
        dim.size = rows.shape[0]
        dim.stride = rows.size
        self.msg.data = _doubles(rows)
        return self.msg


def _doubles(values):
    """
    Return values as ``array('d')``, which rosidl takes without checking each element.

    Parameters
    ----------
    values : array_like
        Numbers.

    Returns
    -------
    array.array
        Contiguous float64 values.

    """
    out = array('d')
    out.frombytes(np.ascontiguousarray(values, dtype=np.float64).tobytes())
    return out


def from_multiarray(msg, layout):
    """
    Read a labelled ``Float64MultiArray`` back by field name.

    Parameters
    ----------
    msg : std_msgs.msg.Float64MultiArray
        Received message.
    layout : reducer_twin.msg_adapters.layouts.Layout
        Expected layout.

    Returns
    -------
    dict
        Field name to value (or list of values for a batch).

    """
    labels = [(d.label, d.size) for d in msg.layout.dim]
    return parse_values(layout, labels, list(msg.data))


def batch_array(msg, layout):
    """
    Return a batch ``Float64MultiArray`` as an array (samples, fields).

    Parameters
    ----------
    msg : std_msgs.msg.Float64MultiArray
        Received batch message.
    layout : reducer_twin.msg_adapters.layouts.Layout
        Expected batch layout.

    Returns
    -------
    ndarray
        Values, one row per sample.

    Raises
    ------
    InvalidInput
        If the layout does not match.

    """
    dims = msg.layout.dim
    n_fields = len(layout.fields)
    if (len(dims) != 2 or dims[1].label != layout.label or dims[1].size != n_fields
            or len(msg.data) != dims[0].size * n_fields):
        raise InvalidInput(f'expected a {layout.name!r} batch with fields {layout.label!r}')
    return np.frombuffer(msg.data, dtype=np.float64).reshape(dims[0].size, n_fields)


def diagnostic_status(name, hardware_id, level, message, values):
    """
    Build one ``DiagnosticStatus`` with key/values.

    Parameters
    ----------
    name : str
        Status name, e.g. ``'reducer_twin: joint_1 reducer'``.
    hardware_id : str
        Identifier of the reducer.
    level : str
        ``'OK'``, ``'WARN'``, ``'ERROR'`` or ``'STALE'``.
    message : str
        Short human-readable summary.
    values : mapping
        Key to value; floats are formatted with 6 significant digits.

    Returns
    -------
    diagnostic_msgs.msg.DiagnosticStatus
        The status.

    """
    status = DiagnosticStatus(level=LEVELS[level], name=name, message=message,
                              hardware_id=hardware_id)
    status.values = [KeyValue(key=str(k), value=_fmt(v)) for k, v in values.items()]
    return status


def diagnostic_array(stamp_ns, statuses):
    """
    Wrap statuses into a ``DiagnosticArray`` stamped at ``stamp_ns``.

    Parameters
    ----------
    stamp_ns : int
        Stamp [ns].
    statuses : list of DiagnosticStatus
        Statuses.

    Returns
    -------
    diagnostic_msgs.msg.DiagnosticArray
        The array.

    """
    arr = DiagnosticArray()
    arr.header.stamp = ns_to_stamp(stamp_ns)
    arr.status = list(statuses)
    return arr


def _fmt(value):
    if isinstance(value, float):
        return f'{value:.6g}' if math.isfinite(value) else str(value)
    return str(value)


def make_joint_state(stamp_ns, names, position, velocity=None, effort=None, frame_id=''):
    """
    Build a ``JointState`` as ros2_control's joint_state_broadcaster does.

    Parameters
    ----------
    stamp_ns : int
        Header stamp [ns].
    names : sequence of str
        Joint (interface) names.
    position, velocity, effort : sequence of float
        Values per name [rad, rad/s, N·m]; None leaves the field empty.
    frame_id : str
        Header frame.

    Returns
    -------
    sensor_msgs.msg.JointState
        The message.

    """
    msg = JointState()
    msg.header.stamp = ns_to_stamp(stamp_ns)
    msg.header.frame_id = frame_id
    msg.name = list(names)
    msg.position = _doubles(position)
    msg.velocity = array('d') if velocity is None else _doubles(velocity)
    msg.effort = array('d') if effort is None else _doubles(effort)
    return msg


class JointStatePicker:
    """
    Pick named entries out of ``JointState`` messages.

    The index of each name is cached per name list, so a controller that
    publishes the same joints every tick costs one dict lookup per message.

    Parameters
    ----------
    names : sequence of str
        Entries to pick, in order.

    """

    def __init__(self, names):
        self.names = tuple(names)
        self._cache_key = None
        self._index = None

    def pick(self, msg):
        """
        Return position, velocity and effort of the wanted entries.

        Parameters
        ----------
        msg : sensor_msgs.msg.JointState
            Received message.

        Returns
        -------
        tuple of ndarray
            ``(position, velocity, effort)``, one value per wanted name; NaN
            where a field is empty (ros2_control leaves unavailable
            interfaces empty or NaN).

        Raises
        ------
        InvalidInput
            If a wanted name is missing or the arrays are inconsistent.

        """
        return self.pick_fields(tuple(msg.name), msg.position, msg.velocity, msg.effort)

    def pick_fields(self, names, position, velocity, effort):
        """
        Return the wanted entries of a message given as its fields.

        Parameters
        ----------
        names : tuple of str
            The message's ``name``.
        position, velocity, effort : array.array or ndarray
            Its float fields (as rclpy or
            :class:`~reducer_twin.msg_adapters.jointstate_cdr.JointStateReader` gives them).

        Returns
        -------
        tuple of ndarray
            As :meth:`pick`.

        Raises
        ------
        InvalidInput
            If a wanted name is missing or the arrays are inconsistent.

        """
        n = len(names)
        fields = (position, velocity, effort)
        for field, arr in zip(('position', 'velocity', 'effort'), fields):
            if len(arr) not in (0, n):
                raise InvalidInput(f'JointState {field} has {len(arr)} values for {n} names')
        if names is not self._cache_key and names != self._cache_key:
            lookup = {name: k for k, name in enumerate(names)}
            missing = [name for name in self.names if name not in lookup]
            if missing:
                raise InvalidInput(f'JointState lacks {missing}; it has {list(names)[:12]}')
            self._index = np.array([lookup[name] for name in self.names], dtype=np.intp)
            self._cache_key = names
        out = []
        for arr in fields:
            if len(arr):
                out.append(np.frombuffer(arr, dtype=np.float64)[self._index]
                           if isinstance(arr, array) else
                           np.asarray(arr, dtype=float)[self._index])
            else:
                out.append(np.full(len(self.names), np.nan))
        return tuple(out)
