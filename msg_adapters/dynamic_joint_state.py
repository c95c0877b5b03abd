"""
``control_msgs/msg/DynamicJointState`` (ros2_control's ``/dynamic_joint_states``) as JointState.

ros2_control's ``joint_state_broadcaster`` publishes every state interface of every joint
on ``/dynamic_joint_states``; a motor-side encoder exported as a joint state interface
(``motor_position``) reaches a bag only there. The message is::

    std_msgs/Header header
    string[] joint_names
    InterfaceValue[] interface_values      # one per joint:
        string[] interface_names           #   e.g. [position, velocity, effort, motor_position]
        float64[] values

The twin does not require ``control_msgs``: payloads are walked by the definition the bag
stores (:mod:`reducer_twin.msg_adapters.msgdef_decoder`; :data:`DEFINITION` only when a bag
of an older distribution stores none). Messages of one layout are read as columns.

Each joint becomes up to two JointState entries, the form ``encoder_ingest`` reads from
one topic: ``<joint>`` with the joint interfaces (position, velocity, effort) and
``<joint><motor_suffix>`` with the motor interfaces, named by :class:`InterfaceMap`.
"""

from dataclasses import dataclass, fields

import numpy as np
from reducer_twin.core.errors import InvalidInput, InvalidParameter
from reducer_twin.msg_adapters.jointstate_cdr import JointStateBatch
from reducer_twin.msg_adapters.jointstate_ros1 import join_groups, stamps_of

MSGTYPE = 'control_msgs/msg/DynamicJointState'

DEFINITION = '\n'.join((
    'std_msgs/Header header',
    'string[] joint_names',
    'InterfaceValue[] interface_values',
    '=' * 80,
    'MSG: control_msgs/InterfaceValue',
    'string[] interface_names',
    'float64[] values',
    '=' * 80,
    'MSG: std_msgs/Header',
    'builtin_interfaces/Time stamp',
    'string frame_id',
    '=' * 80,
    'MSG: builtin_interfaces/Time',
    'int32 sec',
    'uint32 nanosec',
    ''))
"""The fields of the type in control_msgs 4 and 5 (Humble to Kilted), as rosbag2 stores them."""


@dataclass(frozen=True)
class InterfaceMap:
    """
    Which state interfaces are the joint's and the motor's position, velocity and effort.

    Attributes
    ----------
    position, velocity, effort : str
        Joint (output-side) interfaces.
    motor_position, motor_velocity, motor_effort : str
        Motor-side interfaces; the motor angle is read from ``motor_position``.

    """

    position: str = 'position'
    velocity: str = 'velocity'
    effort: str = 'effort'
    motor_position: str = 'motor_position'
    motor_velocity: str = 'motor_velocity'
    motor_effort: str = 'motor_effort'

    def __post_init__(self):
        """Check that every interface is a distinct, non-empty name."""
        names = [getattr(self, f.name) for f in fields(self)]
        for f, name in zip(fields(self), names):
            if not isinstance(name, str) or not name.strip():
                raise InvalidParameter(f'interfaces.{f.name} must be a non-empty interface '
                                       f'name, got {name!r}')
        if len(set(names)) != len(names):
            raise InvalidParameter(f'interfaces must name six distinct interfaces, got '
                                   f'{dict(zip([f.name for f in fields(self)], names))}')

    @classmethod
    def from_mapping(cls, mapping, where='interfaces'):
        """
        Build from a YAML mapping; keys left out keep their defaults.

        Parameters
        ----------
        mapping : dict or None
            ``{position: ..., motor_position: ...}``.
        where : str
            Name of the mapping in error messages.

        Returns
        -------
        InterfaceMap
            The map.

        Raises
        ------
        InvalidParameter
            On unknown keys or values that are not names.

        """
        if mapping is None:
            return cls()
        allowed = [f.name for f in fields(cls)]
        if not isinstance(mapping, dict):
            raise InvalidParameter(f'{where} must be a mapping of {allowed} to interface '
                                   f'names, got {mapping!r}')
        unknown = sorted(set(mapping) - set(allowed))
        if unknown:
            raise InvalidParameter(f'{where}: unknown keys {unknown}; allowed: {allowed}')
        return cls(**mapping)

    def entries(self, motor_suffix):
        """
        Return the JointState entries and the interfaces that fill them.

        Parameters
        ----------
        motor_suffix : str
            Suffix of the motor entry.

        Returns
        -------
        tuple of tuple
            ``(suffix, (position, velocity, effort))`` for the joint and the motor entry.

        """
        return (('', (self.position, self.velocity, self.effort)),
                (motor_suffix, (self.motor_position, self.motor_velocity, self.motor_effort)))


def _group_batch(group, interfaces, motor_suffix):
    """One layout's messages as a JointStateBatch, or a reason why they cannot be read."""
    values = group.template.values
    try:
        joints = list(values['joint_names'])
        per_joint = list(values['interface_values'])
        pairs = [(list(v['interface_names']), v['values']) for v in per_joint]
    except (KeyError, TypeError):
        raise InvalidInput(f'the message definition stored for {MSGTYPE} has no fields '
                           'joint_names and interface_values[].interface_names/values') from None
    if len(per_joint) != len(joints):
        return None, (f'{MSGTYPE} has {len(per_joint)} interface_values for '
                      f'{len(joints)} joint_names')
    n = group.index.shape[0]
    names, columns = [], ([], [], [])
    for joint, (iface_names, block) in zip(joints, pairs):
        if block.count != len(iface_names):
            return None, (f'{MSGTYPE}: joint {joint!r} has {block.count} values for '
                          f'{len(iface_names)} interface_names')
        where = {name: k for k, name in enumerate(iface_names)}
        if not any(i in where for _, wanted in interfaces.entries(motor_suffix)
                   for i in wanted):
            continue
        table = group.template.read(group.rows, block).astype(np.float64) if block.count \
            else np.zeros((n, 0))
        for suffix, wanted in interfaces.entries(motor_suffix):
            if not any(i in where for i in wanted):
                continue
            names.append(joint + suffix)
            for column, interface in zip(columns, wanted):
                column.append(table[:, where[interface]] if interface in where
                              else np.full(n, np.nan))
    arrays = [np.stack(c, axis=1) if c else np.zeros((n, 0)) for c in columns]
    header = values.get('header', {})
    stamps = stamps_of(group.template, group.rows) if isinstance(header, dict) and \
        'stamp' in header else np.zeros(n, np.int64)
    return JointStateBatch(stamps, tuple(names), *arrays,
                           frame_id=str(header.get('frame_id', ''))), None


def decode_dynamic_joint_states(decoder, payloads, starts, lengths, interfaces=None,
                                motor_suffix='_motor', errors='skip'):
    """
    Decode DynamicJointState payloads into JointState arrays.

    Parameters
    ----------
    decoder : MessageDecoder
        Built from the bag's definition of :data:`MSGTYPE`.
    payloads : bytes-like or numpy.ndarray
        One buffer holding the payloads.
    starts, lengths : array_like of int
        int64[N] start and length of each payload.
    interfaces : InterfaceMap, optional
        Interface names; default :class:`InterfaceMap()`.
    motor_suffix : str
        Suffix of each joint's motor entry.
    errors : {'skip', 'raise'}
        Leave malformed payloads out (listed in ``rejected``) or raise.

    Returns
    -------
    JointStateBatch
        ``<joint>`` (joint interfaces) and ``<joint><motor_suffix>`` (motor interfaces)
        entries of the joints that have any of them, NaN where an interface is absent;
        messages in input order.

    Raises
    ------
    InvalidInput
        On a malformed payload with ``errors='raise'``, or a definition without the
        DynamicJointState fields.

    """
    interfaces = interfaces or InterfaceMap()
    groups, rejected = decoder.decode(payloads, starts, lengths, errors)
    parts = []
    for group in groups:
        batch, problem = _group_batch(group, interfaces, motor_suffix)
        if batch is None:
            if errors == 'raise':
                raise InvalidInput(problem)
            rejected += [(int(i), problem) for i in group.index]
        else:
            parts.append((group.index, batch))
    return join_groups(parts, rejected)
