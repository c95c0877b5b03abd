"""The decoder that walks payloads by a stored message definition, checked against rosbags."""

from hypothesis import given, HealthCheck, settings
from hypothesis import strategies as st
import numpy as np
import pytest
from reducer_twin.core.errors import InvalidInput
from reducer_twin.msg_adapters.msgdef_decoder import Block, load_definitions, MessageDecoder
from rosbags.typesys import get_types_from_msg, get_typestore, Stores

DJS = 'control_msgs/msg/DynamicJointState'
DJS_TEXT = 'std_msgs/Header header\nstring[] joint_names\nInterfaceValue[] interface_values\n'
IV = 'control_msgs/msg/InterfaceValue'
IV_TEXT = 'string[] interface_names\nfloat64[] values\n'
# Every kind of field at unaligned places: scalars of each size, a fixed array, strings,
# a sequence of messages with a bool, a string and a float32 sequence, a trailing int32.
ODD = 'test_msgs/msg/Odd'
ODD_TEXT = '\n'.join((
    'uint8 flag', 'int16 small', 'float64[3] triple', 'string label', 'Inner[] items',
    'int64 big', 'int32 tail', '=' * 80, 'MSG: test_msgs/Inner', 'bool on', 'string name',
    'float32[] values', 'uint16 code', ''))
JOINT_STATE = 'sensor_msgs/msg/JointState'


def _store(ros1=False):
    store = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_JAZZY)
    store.register({**get_types_from_msg(DJS_TEXT, DJS), **get_types_from_msg(IV_TEXT, IV),
                    **get_types_from_msg(ODD_TEXT, ODD)})
    return store


STORE = _store()
STORE1 = _store(ros1=True)


def _decoder(store, msgtype, wire='cdr'):
    """Build a decoder from the definition rosbags writes into a bag for the type."""
    text, _ = store.generate_msgdef(msgtype, ros_version=1 if wire == 'ros1' else 2)
    return MessageDecoder(msgtype, load_definitions(msgtype, text,
                                                    'ros1msg' if wire == 'ros1' else 'ros2msg'),
                          wire)


def _plain(template, node=None):
    """Return the template's values with every Block replaced by its numbers."""
    node = template.values if node is None else node
    if isinstance(node, Block):
        values = template.value(node)
        return values.tolist()
    if isinstance(node, dict):
        return {k: _plain(template, v) for k, v in node.items()}
    if isinstance(node, list):
        return [_plain(template, v) for v in node]
    return node


def _rosbags_plain(msg):
    """Return a rosbags message as nested dicts and lists, in the same form as ``_plain``."""
    if hasattr(msg, '__dataclass_fields__'):
        return {k: _rosbags_plain(getattr(msg, k)) for k in msg.__dataclass_fields__
                if k != '__msgtype__'}
    if isinstance(msg, np.ndarray):
        return msg.tolist()
    if isinstance(msg, list):
        return [_rosbags_plain(v) for v in msg]
    if isinstance(msg, (bool, np.bool_)):
        return [int(msg)]
    if isinstance(msg, (int, float, np.integer, np.floating)):
        return [msg.item() if hasattr(msg, 'item') else msg]
    return msg


def _odd(store, k):
    types = store.types
    inner = [types['test_msgs/msg/Inner'](bool(i % 2), f'item{i}' * (i + 1),
                                          np.arange(i, dtype=np.float32) * 0.5, 7 + i)
             for i in range(k)]
    return types[ODD](3, -2, np.array([1.5, -2.5, 3.25]), 'x' * k, inner, -(2 ** 40), 99)


def _djs(store, stamp_s, joints, interfaces, values):
    types = store.types
    header = types['std_msgs/msg/Header'](
        types['builtin_interfaces/msg/Time'](int(stamp_s), 250_000_000), 'base_link')
    ivs = [types[IV](list(names), np.asarray(vals, np.float64))
           for names, vals in zip(interfaces, values)]
    return types[DJS](header, list(joints), ivs)


def _batch(payloads):
    lengths = np.array([len(p) for p in payloads], np.int64)
    starts = np.zeros(len(payloads), np.int64)
    np.cumsum(lengths[:-1], out=starts[1:])
    return np.frombuffer(b''.join(payloads), np.uint8), starts, lengths


@pytest.mark.parametrize('little_endian', [True, False])
def test_every_field_kind_decodes_as_rosbags_deserialises_it_in_cdr(little_endian):
    decoder = _decoder(STORE, ODD)
    for k in range(4):
        payload = bytes(STORE.serialize_cdr(_odd(STORE, k), ODD, little_endian=little_endian))
        got = _plain(decoder.parse(payload))
        assert got == _rosbags_plain(STORE.deserialize_cdr(payload, ODD))


def test_every_field_kind_decodes_as_rosbags_deserialises_it_in_ros1():
    decoder = _decoder(STORE1, ODD, 'ros1')
    for k in range(4):
        payload = bytes(STORE1.serialize_ros1(_odd(STORE1, k), ODD))
        got = _plain(decoder.parse(payload))
        assert got == _rosbags_plain(STORE1.deserialize_ros1(payload, ODD))


def test_a_ros1_header_keeps_its_seq_and_an_unsigned_stamp():
    decoder = _decoder(STORE1, JOINT_STATE, 'ros1')
    types = STORE1.types
    msg = types[JOINT_STATE](
        types['std_msgs/msg/Header'](7, types['builtin_interfaces/msg/Time'](1, 5), 'f'),
        ['a'], np.array([1.0]), np.array([]), np.array([]))
    payload = bytearray(STORE1.serialize_ros1(msg, JOINT_STATE))
    payload[4:8] = (3_000_000_000).to_bytes(4, 'little')   # roscpp writes time as uint32
    template = decoder.parse(bytes(payload))
    header = template.values['header']
    assert template.value(header['seq']).tolist() == [7]
    # Beyond 2038 a ROS 1 time stays positive: its seconds are unsigned.
    assert template.value(header['stamp']['sec']).tolist() == [3_000_000_000]


interface_lists = st.lists(st.sampled_from(['position', 'velocity', 'effort', 'motor_position',
                                            'temperature']),
                           min_size=0, max_size=5, unique=True)


@settings(max_examples=40, suppress_health_check=[HealthCheck.too_slow])
@given(joints=st.lists(st.text('abcdefgh_', min_size=1, max_size=9), min_size=1, max_size=4,
                       unique=True),
       data=st.data())
def test_dynamic_joint_states_of_any_layout_decode_as_rosbags_deserialises_them(joints, data):
    interfaces = [data.draw(interface_lists) for _ in joints]
    rng = np.random.default_rng(len(joints))
    payloads = [bytes(STORE.serialize_cdr(_djs(STORE, 1_700_000_000 + i, joints, interfaces,
                                               [rng.normal(size=len(n)) for n in interfaces]),
                                          DJS)) for i in range(5)]
    decoder = _decoder(STORE, DJS)
    groups, rejected = decoder.decode(*_batch(payloads))
    assert rejected == []
    # One layout: one group, read as columns.
    (group,) = groups
    assert group.index.tolist() == list(range(5))
    for k, iv in enumerate(group.template.values['interface_values']):
        got = group.template.read(group.rows, iv['values'])
        want = np.array([STORE.deserialize_cdr(p, DJS).interface_values[k].values
                         for p in payloads]).reshape(5, -1)
        np.testing.assert_array_equal(got, want)
    assert group.template.values['joint_names'] == joints


def test_payloads_of_several_layouts_fall_into_one_group_each():
    joints = ['j1', 'j2']
    small = [['position'], ['position']]
    large = [['position', 'motor_position'], ['position', 'motor_position']]
    payloads = []
    for i in range(12):
        names = large if i % 3 == 0 else small
        values = [np.full(len(n), float(i)) for n in names]
        payloads.append(bytes(STORE.serialize_cdr(_djs(STORE, i, joints, names, values), DJS)))
    groups, rejected = _decoder(STORE, DJS).decode(*_batch(payloads))
    assert rejected == [] and len(groups) == 2
    seen = np.sort(np.concatenate([g.index for g in groups]))
    assert seen.tolist() == list(range(12))
    for group in groups:
        first = group.template.values['interface_values'][0]['values']
        np.testing.assert_array_equal(group.template.read(group.rows, first)[:, 0],
                                      group.index.astype(float))


def test_padding_bytes_do_not_split_a_layout():
    # A string of 3 bytes + NUL ends at an offset that needs 4 bytes of padding before the
    # float64 array; writers may leave garbage there.
    msgs = [bytearray(STORE.serialize_cdr(_djs(STORE, i, ['abc'], [['abc']], [[float(i)]]),
                                          DJS)) for i in range(4)]
    decoder = _decoder(STORE, DJS)
    template = decoder.parse(bytes(msgs[0]))
    block = template.values['interface_values'][0]['values']
    covered = np.zeros(len(msgs[0]), bool)
    for start, stop in template.spans:
        covered[start:stop] = True
    covered[block.offset:block.stop] = True
    covered[4:12] = True
    padding = np.flatnonzero(~covered)
    assert padding.size   # the layout has padding
    for i, msg in enumerate(msgs):
        for at in padding:
            msg[at] = 0xA5 ^ i
    groups, rejected = decoder.decode(*_batch([bytes(m) for m in msgs]))
    assert rejected == [] and len(groups) == 1
    np.testing.assert_array_equal(groups[0].template.read(groups[0].rows, block)[:, 0],
                                  [0.0, 1.0, 2.0, 3.0])


def _good():
    return bytes(STORE.serialize_cdr(_djs(STORE, 1, ['j'], [['position']], [[1.0]]), DJS))


MALFORMED = [
    ('a truncated payload', lambda p: p[:30], 'needs'),
    ('an unknown encapsulation', lambda p: b'\x00\x07' + p[2:], 'is not plain CDR'),
    ('a string without its NUL', lambda p: p[:25] + b'X' + p[26:], 'does not end with NUL'),
    ('a count that runs past the end', lambda p: p[:28] + b'\xff\xff\x00\x00' + p[32:],
     'runs past'),
    ('bytes after the message', lambda p: p + bytes(16), 'the message ends there'),
    ('fewer than 4 bytes', lambda p: p[:3], 'at least the 4-byte'),
]


@pytest.mark.parametrize('what, corrupt, reason', MALFORMED, ids=[m[0] for m in MALFORMED])
def test_a_malformed_payload_is_rejected_with_the_byte_and_the_problem(what, corrupt, reason):
    good = _good()
    bad = corrupt(good)
    decoder = _decoder(STORE, DJS)
    groups, rejected = decoder.decode(*_batch([good, bad, good]))
    assert [i for i, _ in rejected] == [1]
    assert reason in rejected[0][1] and 'byte' in rejected[0][1]
    assert sorted(np.concatenate([g.index for g in groups]).tolist()) == [0, 2]
    with pytest.raises(InvalidInput, match=reason):
        decoder.decode(*_batch([good, bad]), errors='raise')


BAD_DEFINITIONS = [
    ('text that is not a message definition', '@@@ ###', 'ros2msg', 'cannot be parsed: '),
    ('an IDL text of another type', 'module pkg { module msg { struct Other { int32 x; }; }; };',
     'ros2idl', r"defines \['pkg/msg/Other'\] but not"),
    ('an unknown encoding', 'int32 x', 'json', "encoding 'json'"),
]


@pytest.mark.parametrize('what, text, encoding, reason', BAD_DEFINITIONS,
                         ids=[b[0] for b in BAD_DEFINITIONS])
def test_an_unusable_definition_is_refused_with_a_reason_on_one_line(
        what, text, encoding, reason):
    with pytest.raises(InvalidInput, match=reason) as err:
        load_definitions(DJS, text, encoding)
    assert '\n' not in str(err.value)


def test_a_type_the_definition_does_not_define_is_a_malformed_message():
    types = load_definitions(DJS, DJS_TEXT)   # InterfaceValue is missing
    decoder = MessageDecoder(DJS, types)
    with pytest.raises(InvalidInput, match='does not define'):
        decoder.parse(bytes(STORE.serialize_cdr(_djs(STORE, 1, ['j'], [['p']], [[1.0]]), DJS)))
