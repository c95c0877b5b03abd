"""ros2_control's DynamicJointState read as the joint and motor entries encoder_ingest pairs."""

import numpy as np
import pytest
from reducer_twin.core.errors import InvalidInput, InvalidParameter
from reducer_twin.msg_adapters.dynamic_joint_state import (
    decode_dynamic_joint_states, DEFINITION, InterfaceMap, MSGTYPE)
from reducer_twin.msg_adapters.msgdef_decoder import load_definitions, MessageDecoder
from rosbags.typesys import get_types_from_msg, get_typestore, Stores

IV = 'control_msgs/msg/InterfaceValue'
STORE = get_typestore(Stores.ROS2_JAZZY)
STORE.register({
    **get_types_from_msg('std_msgs/Header header\nstring[] joint_names\n'
                         'InterfaceValue[] interface_values\n', MSGTYPE),
    **get_types_from_msg('string[] interface_names\nfloat64[] values\n', IV)})
TYPES = STORE.types


def _message(stamp_ns, joints):
    """``joints``: list of (name, {interface: value}) in the order the hardware exports."""
    header = TYPES['std_msgs/msg/Header'](
        TYPES['builtin_interfaces/msg/Time'](stamp_ns // 10**9, stamp_ns % 10**9), 'world')
    ivs = [TYPES[IV](list(values), np.array(list(values.values()), float))
           for _, values in joints]
    return bytes(STORE.serialize_cdr(TYPES[MSGTYPE](header, [n for n, _ in joints], ivs),
                                     MSGTYPE))


def _decode(payloads, interfaces=None, suffix='_motor', errors='skip', definition=None):
    text = definition or STORE.generate_msgdef(MSGTYPE, ros_version=2)[0]
    decoder = MessageDecoder(MSGTYPE, load_definitions(MSGTYPE, text))
    lengths = np.array([len(p) for p in payloads], np.int64)
    starts = np.concatenate([[0], np.cumsum(lengths)[:-1]]).astype(np.int64)
    return decode_dynamic_joint_states(decoder, b''.join(payloads), starts, lengths,
                                       interfaces, suffix, errors)


def test_each_joint_becomes_a_joint_entry_and_a_motor_entry_by_interface_name():
    payloads = [_message(1_000_000_000 + i, [
        ('j1', {'position': 0.1 * i, 'velocity': 1.0, 'effort': 5.0, 'motor_position': 12.1}),
        # Another export order, and a custom interface the twin does not use.
        ('j2', {'motor_position': -3.0, 'temperature': 40.0, 'effort': -2.0,
                'position': 0.2 * i})]) for i in range(6)]
    batch = _decode(payloads)
    assert batch.names == ('j1', 'j1_motor', 'j2', 'j2_motor') and batch.rejected == ()
    np.testing.assert_array_equal(batch.stamps_ns, 1_000_000_000 + np.arange(6))
    np.testing.assert_allclose(batch.position[:, 0], 0.1 * np.arange(6))
    np.testing.assert_allclose(batch.position[:, 2], 0.2 * np.arange(6))
    np.testing.assert_array_equal(batch.position[:, [1, 3]], [[12.1, -3.0]] * 6)
    np.testing.assert_array_equal(batch.effort[:, [0, 2]], [[5.0, -2.0]] * 6)
    # What a joint does not export is NaN: j2's velocity, every motor velocity and effort.
    assert np.isnan(batch.velocity[:, 1:]).all() and np.isnan(batch.effort[:, [1, 3]]).all()
    assert batch.frame_id == 'world'


def test_configured_interface_names_and_suffix_pick_other_interfaces():
    payloads = [_message(5, [('arm', {'position': 1.0, 'encoder2/position': 161.0,
                                      'current_torque': 3.5})])]
    interfaces = InterfaceMap(effort='current_torque', motor_position='encoder2/position')
    batch = _decode(payloads, interfaces, suffix='/motor')
    assert batch.names == ('arm', 'arm/motor')
    np.testing.assert_array_equal(batch.position, [[1.0, 161.0]])
    np.testing.assert_array_equal(batch.effort[:, 0], [3.5])


def test_a_joint_with_none_of_the_interfaces_is_left_out():
    batch = _decode([_message(5, [('gripper', {'width': 0.02}),
                                  ('j1', {'position': 1.0})])])
    assert batch.names == ('j1',)


def test_layouts_that_change_mid_stream_keep_the_message_order_and_the_union_of_entries():
    small = {'position': 1.0}
    full = {'position': 2.0, 'motor_position': 20.0}
    payloads = [_message(i, [('j', full if i % 2 else small)]) for i in range(6)]
    batch = _decode(payloads)
    assert batch.names == ('j', 'j_motor')
    np.testing.assert_array_equal(batch.stamps_ns, np.arange(6))
    np.testing.assert_array_equal(batch.position[:, 0], [1.0, 2.0] * 3)
    np.testing.assert_array_equal(batch.position[1::2, 1], [20.0] * 3)
    assert np.isnan(batch.position[0::2, 1]).all()


def _mismatched_values():
    header = TYPES['std_msgs/msg/Header'](TYPES['builtin_interfaces/msg/Time'](1, 0), '')
    iv = TYPES[IV](['position', 'motor_position'], np.array([1.0]))
    return bytes(STORE.serialize_cdr(TYPES[MSGTYPE](header, ['j'], [iv]), MSGTYPE))


def _mismatched_joints():
    header = TYPES['std_msgs/msg/Header'](TYPES['builtin_interfaces/msg/Time'](1, 0), '')
    iv = TYPES[IV](['position'], np.array([1.0]))
    return bytes(STORE.serialize_cdr(TYPES[MSGTYPE](header, ['j', 'k'], [iv]), MSGTYPE))


@pytest.mark.parametrize('payload, reason', [
    (_mismatched_values(), "joint 'j' has 1 values for 2 interface_names"),
    (_mismatched_joints(), 'has 1 interface_values for 2 joint_names'),
], ids=['values shorter than the interface names', 'fewer interface values than joints'])
def test_a_message_whose_lists_disagree_is_rejected_with_the_reason(payload, reason):
    good = _message(2, [('j', {'position': 1.0})])
    batch = _decode([good, payload, good])
    assert len(batch) == 2 and [i for i, _ in batch.rejected] == [1]
    assert reason in batch.rejected[0][1]
    with pytest.raises(InvalidInput, match=reason):
        _decode([payload], errors='raise')


def test_the_builtin_definition_reads_what_control_msgs_writes():
    payloads = [_message(7, [('j', {'position': 1.0, 'motor_position': 2.0})])]
    a = _decode(payloads)
    b = _decode(payloads, definition=DEFINITION)
    assert a.names == b.names
    np.testing.assert_array_equal(a.position, b.position)


BAD_MAPPINGS = [
    ('an unknown key', {'motor_angle': 'x'}, r"unknown keys \['motor_angle'\]"),
    ('an empty name', {'position': ''}, 'interfaces.position must be a non-empty'),
    ('a number for a name', {'effort': 3}, 'interfaces.effort must be a non-empty'),
    ('one interface for two entries', {'motor_position': 'position'}, 'six distinct'),
    ('a list instead of a mapping', ['position'], 'must be a mapping'),
]


@pytest.mark.parametrize('what, mapping, reason', BAD_MAPPINGS, ids=[b[0] for b in BAD_MAPPINGS])
def test_a_bad_interface_mapping_is_refused_naming_the_key_and_value(what, mapping, reason):
    with pytest.raises(InvalidParameter, match=reason):
        InterfaceMap.from_mapping(mapping)


def test_keys_left_out_of_the_mapping_keep_their_defaults():
    got = InterfaceMap.from_mapping({'motor_position': 'encoder2'})
    assert got == InterfaceMap(motor_position='encoder2')
    assert got.position == 'position' and InterfaceMap.from_mapping(None) == InterfaceMap()
