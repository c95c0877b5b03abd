"""Tests of the vectorised JointState CDR codec against rclpy's and rosbags' serializers."""

from hypothesis import given, HealthCheck, settings
from hypothesis import strategies as st
import numpy as np
import pytest
from rclpy.serialization import deserialize_message, serialize_message
from reducer_twin.core.errors import InvalidInput, ReducerTwinError
from reducer_twin.msg_adapters.jointstate_cdr import (
    concat_batches, decode_joint_states, encode_joint_states, JointStateBatch, JointStateReader)
from rosbags.typesys import get_typestore, Stores
from sensor_msgs.msg import JointState

STAMPS = np.array([5_000_000_007, -1_500_000_000, 1_700_000_000_123_456_789], np.int64)
NAMES = ['joint_link', 'motor']
POSITION = np.array([[1.0, 2.0], [3.0, -4.5], [np.nan, -0.0]])
TYPESTORE = get_typestore(Stores.ROS2_JAZZY)


def _rclpy_message(stamp, names, position, velocity, effort, frame_id):
    msg = JointState()
    msg.header.stamp.sec = int(stamp // 1_000_000_000)
    msg.header.stamp.nanosec = int(stamp % 1_000_000_000)
    msg.header.frame_id = frame_id
    msg.name = list(names)
    msg.position = [] if position is None else [float(v) for v in position]
    msg.velocity = [] if velocity is None else [float(v) for v in velocity]
    msg.effort = [] if effort is None else [float(v) for v in effort]
    return msg


def _rosbags_bytes(stamp, names, position, velocity, effort, frame_id, little_endian=True):
    types = TYPESTORE.types
    empty = np.zeros(0)
    msg = types['sensor_msgs/msg/JointState'](
        types['std_msgs/msg/Header'](
            types['builtin_interfaces/msg/Time'](int(stamp // 1_000_000_000),
                                                 int(stamp % 1_000_000_000)), frame_id),
        list(names), empty if position is None else position,
        empty if velocity is None else velocity, empty if effort is None else effort)
    return bytes(TYPESTORE.serialize_cdr(msg, 'sensor_msgs/msg/JointState',
                                         little_endian=little_endian))


def _meaningful_bytes(payload):
    """Positions of all bytes of a payload that are not alignment padding."""
    keep = np.ones(len(payload), bool)
    pos = 4

    def pad(to, size):
        aligned = 4 + ((to - 4 + size - 1) // size) * size
        keep[to:aligned] = False
        return aligned

    def u32(at):
        return int.from_bytes(payload[at:at + 4], 'little')

    pos = 12
    pos = pos + 4 + u32(pos)
    pos = pad(pos, 4)
    count = u32(pos)
    pos += 4
    for _ in range(count):
        pos = pad(pos, 4)
        pos = pos + 4 + u32(pos)
    for _ in range(3):
        pos = pad(pos, 4)
        count = u32(pos)
        pos += 4
        if count:
            pos = pad(pos, 8)
        pos += 8 * count
    return keep[:pos], pos


CASES = [
    (None, None, 'ab'),
    (POSITION * 2, None, ''),
    (None, POSITION * 3, 'base_link'),
    (POSITION, POSITION, 'x'),
]


@pytest.mark.parametrize('velocity, effort, frame_id', CASES)
def test_encoded_bytes_equal_rclpy_serialization_in_every_defined_byte(
        velocity, effort, frame_id):
    buffer, offsets = encode_joint_states(STAMPS, NAMES, POSITION, velocity, effort, frame_id)
    for i, stamp in enumerate(STAMPS):
        ours = buffer[offsets[i]:offsets[i + 1]].tobytes()
        ref = serialize_message(_rclpy_message(
            stamp, NAMES, POSITION[i], None if velocity is None else velocity[i],
            None if effort is None else effort[i], frame_id))
        # rclpy (rmw_serialize) sizes its buffer with Fast-CDR's conservative estimate
        # and leaves padding bytes uninitialised; every byte that carries meaning, and
        # the real message length, must match ours exactly.
        keep, used = _meaningful_bytes(ref)
        assert used == len(ours)
        assert len(ref) >= len(ours)
        ref_meaning = np.frombuffer(ref[:used], np.uint8)[keep]
        our_meaning = np.frombuffer(ours, np.uint8)[keep]
        assert ref_meaning.tobytes() == our_meaning.tobytes()
        assert not np.frombuffer(ours, np.uint8)[~keep].any(), 'our padding is zero'


@pytest.mark.parametrize('velocity, effort, frame_id', CASES)
def test_encoded_bytes_equal_rosbags_serialize_cdr_byte_for_byte(velocity, effort, frame_id):
    buffer, offsets = encode_joint_states(STAMPS, NAMES, POSITION, velocity, effort, frame_id)
    for i, stamp in enumerate(STAMPS):
        ref = _rosbags_bytes(stamp, NAMES, POSITION[i],
                             None if velocity is None else velocity[i],
                             None if effort is None else effort[i], frame_id)
        assert buffer[offsets[i]:offsets[i + 1]].tobytes() == ref


def test_rclpy_deserializes_our_bytes():
    buffer, offsets = encode_joint_states(STAMPS, NAMES, POSITION, POSITION * 2, None, 'base')
    for i, stamp in enumerate(STAMPS):
        msg = deserialize_message(buffer[offsets[i]:offsets[i + 1]].tobytes(), JointState)
        assert list(msg.name) == NAMES
        assert msg.header.frame_id == 'base'
        assert msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec == stamp
        np.testing.assert_array_equal(np.array(msg.position), POSITION[i])
        np.testing.assert_array_equal(np.array(msg.velocity), POSITION[i] * 2)
        assert len(msg.effort) == 0


def test_decoder_reads_rclpy_serialized_messages_with_slack_and_garbage_padding():
    payloads = [serialize_message(_rclpy_message(s, NAMES, POSITION[i], None, POSITION[i],
                                                 'frame'))
                for i, s in enumerate(STAMPS)]
    batch = decode_joint_states(payloads)
    np.testing.assert_array_equal(batch.stamps_ns, STAMPS)
    np.testing.assert_array_equal(batch.position, POSITION)
    np.testing.assert_array_equal(batch.effort, POSITION)
    assert np.isnan(batch.velocity).all()
    assert batch.names == tuple(NAMES)
    assert batch.frame_id == 'frame'


def test_round_trip_keeps_nan_infinities_and_negative_zero():
    values = np.array([[np.nan, np.inf], [-np.inf, -0.0], [1e308, 5e-324]])
    buffer, offsets = encode_joint_states(STAMPS, NAMES, values, values, values)
    batch = decode_joint_states(buffer, offsets)
    for field in (batch.position, batch.velocity, batch.effort):
        assert field.tobytes() == values.tobytes()


def test_empty_velocity_and_effort_decode_as_nan():
    buffer, offsets = encode_joint_states(STAMPS, NAMES, POSITION)
    batch = decode_joint_states(buffer, offsets)
    assert batch.velocity.shape == (3, 2) and np.isnan(batch.velocity).all()
    assert batch.effort.shape == (3, 2) and np.isnan(batch.effort).all()
    np.testing.assert_array_equal(batch.position, POSITION)


def test_a_field_shorter_than_the_name_list_decodes_as_nan():
    payload = _rosbags_bytes(10, ['a', 'b', 'c'], np.array([1.0, 2.0, 3.0]),
                             np.array([4.0]), None, '')
    batch = decode_joint_states([payload])
    np.testing.assert_array_equal(batch.position, [[1.0, 2.0, 3.0]])
    assert np.isnan(batch.velocity).all()


def test_a_position_list_of_another_length_than_the_names_rejects_the_message():
    # Which name lacks its position cannot be known (the names were one longer: every
    # message decoded as no position at all, and nothing said why).
    payload = _rosbags_bytes(10, ['a', 'b', 'c'], np.array([1.0, 2.0]), None, None, '')
    with pytest.raises(InvalidInput, match=r'position\[\] has 2 entries for 3 names'):
        decode_joint_states([payload])
    batch = decode_joint_states([payload, _rosbags_bytes(11, ['a', 'b'], np.array([1.0, 2.0]),
                                                         None, None, '')], errors='skip')
    assert len(batch) == 1 and [i for i, _ in batch.rejected] == [0]


def test_irregular_batch_decodes_to_the_union_of_names_in_input_order():
    payloads = [
        _rosbags_bytes(1, ['a', 'b'], np.array([1.0, 2.0]), None, None, 'f'),
        _rosbags_bytes(2, ['b', 'c', 'd'], np.array([3.0, 4.0, 5.0]), None, None, 'f'),
        _rosbags_bytes(3, ['a', 'b'], np.array([6.0, 7.0]), None, None, 'f'),
        _rosbags_bytes(4, [], None, None, None, ''),
        _rosbags_bytes(5, ['aa', 'b'], np.array([8.0, 9.0]), None, None, 'f'),
    ]
    batch = decode_joint_states(payloads)
    assert batch.names == ('a', 'b', 'c', 'd', 'aa')
    np.testing.assert_array_equal(batch.stamps_ns, [1, 2, 3, 4, 5])
    expected = np.full((5, 5), np.nan)
    expected[0, :2] = [1, 2]
    expected[1, 1:4] = [3, 4, 5]
    expected[2, :2] = [6, 7]
    expected[4, [4, 1]] = [8, 9]
    np.testing.assert_array_equal(batch.position, expected)


def test_many_layouts_of_one_length_are_all_decoded_correctly():
    frames = [f'frame{i:02d}' for i in range(20)]
    payloads = [_rosbags_bytes(i, ['j'], np.array([float(i)]), None, None, frames[i % 20])
                for i in range(60)]
    batch = decode_joint_states(payloads)
    np.testing.assert_array_equal(batch.position[:, 0], np.arange(60.0))
    np.testing.assert_array_equal(batch.stamps_ns, np.arange(60))


def test_big_endian_payloads_decode():
    payload = _rosbags_bytes(7_000_000_001, NAMES, POSITION[0], POSITION[0] * 2, None, 'be',
                             little_endian=False)
    batch = decode_joint_states([payload, payload])
    np.testing.assert_array_equal(batch.position, [POSITION[0]] * 2)
    np.testing.assert_array_equal(batch.stamps_ns, [7_000_000_001] * 2)
    assert batch.frame_id == 'be'


def test_decoder_reads_payloads_inside_a_larger_buffer_without_copying_them_first():
    buffer, offsets = encode_joint_states(STAMPS, NAMES, POSITION)
    length = int(offsets[1])
    records = np.zeros((3, length + 31), np.uint8)
    records[:, 31:] = buffer.reshape(3, length)
    starts = np.arange(3) * (length + 31) + 31
    batch = decode_joint_states(records.reshape(-1), starts, np.full(3, length))
    np.testing.assert_array_equal(batch.position, POSITION)
    picked = decode_joint_states(records.reshape(-1), starts[[0, 2]], np.full(2, length))
    np.testing.assert_array_equal(picked.stamps_ns, STAMPS[[0, 2]])


def _valid_payload():
    return _rosbags_bytes(5, NAMES, POSITION[0], POSITION[0], None, 'frame')


BAD_PAYLOADS = [
    ('empty', b''),
    ('shorter than the encapsulation', b'\x00\x01'),
    ('unknown encapsulation', b'\x00\x07\x00\x00' + bytes(40)),
    ('truncated stamp', _valid_payload()[:9]),
    ('truncated name list', _valid_payload()[:30]),
    ('truncated position array', _valid_payload()[:60]),
    ('frame_id length overflows', _valid_payload()[:12] + b'\xff\xff\xff\xff'
     + _valid_payload()[16:]),
    ('name count overflows', _valid_payload()[:24] + b'\xff\xff\xff\x7f'
     + _valid_payload()[28:]),
    ('string without NUL', _valid_payload()[:21] + b'X' + _valid_payload()[22:]),
    ('NUL inside a name', _valid_payload()[:33] + b'\x00' + _valid_payload()[34:]),
]


@pytest.mark.parametrize('label, payload', BAD_PAYLOADS, ids=[b[0] for b in BAD_PAYLOADS])
def test_malformed_payloads_raise_invalid_input_naming_message_and_byte(label, payload):
    with pytest.raises(InvalidInput, match=r'malformed JointState CDR in message 0 .*byte \d+'):
        decode_joint_states([payload])


def test_a_position_count_past_the_payload_end_is_rejected():
    payload = bytearray(_valid_payload())
    keep, _ = _meaningful_bytes(payload)
    count_at = 56  # position count of this payload (frame 'frame', names joint_link, motor)
    assert int.from_bytes(payload[count_at:count_at + 4], 'little') == 2
    payload[count_at:count_at + 4] = (10_000).to_bytes(4, 'little')
    with pytest.raises(InvalidInput, match='position'):
        decode_joint_states([bytes(payload)])


def test_skip_mode_leaves_out_and_lists_malformed_messages():
    good = _valid_payload()
    batch = decode_joint_states([good, good[:20], good], errors='skip')
    assert len(batch) == 2
    assert [index for index, _ in batch.rejected] == [1]
    np.testing.assert_array_equal(batch.position, [POSITION[0]] * 2)


BAD_ENCODE_ARGS = [
    ('stamps not integers', {'stamps_ns': np.array([1.5]), 'position': [[1.0, 2.0]]}),
    ('position of the wrong shape', {'stamps_ns': [1], 'position': [[1.0, 2.0, 3.0]]}),
    ('velocity of the wrong shape', {'stamps_ns': [1, 2], 'position': np.zeros((2, 2)),
                                     'velocity': np.zeros((1, 2))}),
    ('seconds beyond int32', {'stamps_ns': [2**31 * 1_000_000_000], 'position': [[1.0, 2.0]]}),
    ('names as one string', {'stamps_ns': [1], 'names': 'ab', 'position': [[1.0, 2.0]]}),
    ('name with NUL', {'stamps_ns': [1], 'names': ['a\x00', 'b'], 'position': [[1.0, 2.0]]}),
]


@pytest.mark.parametrize('label, kwargs', BAD_ENCODE_ARGS, ids=[b[0] for b in BAD_ENCODE_ARGS])
def test_encoder_rejects_bad_input_with_invalid_input(label, kwargs):
    kwargs = dict(kwargs)
    kwargs.setdefault('names', NAMES)
    with pytest.raises(InvalidInput):
        encode_joint_states(**kwargs)


def test_offsets_outside_the_buffer_are_rejected():
    buffer, offsets = encode_joint_states(STAMPS, NAMES, POSITION)
    with pytest.raises(InvalidInput, match='outside|inside'):
        decode_joint_states(buffer, offsets + 5)


def test_concatenated_batches_keep_order_and_union_names():
    first = decode_joint_states([_rosbags_bytes(1, ['a'], np.array([1.0]), None, None, '')])
    second = decode_joint_states([_rosbags_bytes(2, ['b'], np.array([2.0]), None, None, '')])
    joined = concat_batches([first, second])
    assert isinstance(joined, JointStateBatch)
    assert joined.names == ('a', 'b')
    np.testing.assert_array_equal(joined.position, [[1.0, np.nan], [np.nan, 2.0]])


CDR_LIKE = st.binary(max_size=200).map(lambda b: b'\x00\x01\x00\x00' + b)


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(st.one_of(st.binary(max_size=200), CDR_LIKE), min_size=1, max_size=4))
def test_random_bytes_raise_only_project_errors(payloads):
    try:
        decode_joint_states(payloads)
    except ReducerTwinError:
        pass


@settings(max_examples=300, deadline=None)
@given(st.integers(0, 10_000), st.integers(0, 255), st.integers(0, 100))
def test_corrupted_valid_messages_raise_only_project_errors(where, value, cut):
    payload = bytearray(_valid_payload())
    payload[where % len(payload)] = value
    payload = bytes(payload[:len(payload) - cut % 8])
    try:
        batch = decode_joint_states([payload, _valid_payload()], errors='skip')
    except ReducerTwinError:
        return
    assert len(batch) + len(batch.rejected) == 2


# -- one message at a time (a raw live subscription) ------------------------------------------


def _read_like_rclpy(reader, payload):
    """Read ``payload`` with the reader and check it against rclpy's own deserialisation."""
    stamp, names, position, velocity, effort = reader.read(payload)
    msg = deserialize_message(payload, JointState)
    assert stamp == msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
    assert names == tuple(msg.name)
    for got, field in ((position, msg.position), (velocity, msg.velocity),
                       (effort, msg.effort)):
        np.testing.assert_array_equal(got, np.array(field, dtype=float))
    return stamp, names, position, velocity, effort


def test_the_reader_gives_what_rclpy_deserializes_as_layouts_come_and_go():
    reader = JointStateReader()
    rng = np.random.default_rng(3)
    messages = []
    for i in range(40):
        # A controller's steady layout, interleaved with others: another joint set of
        # the same length, empty fields, a short field, another frame, big endian.
        names = NAMES if i % 5 else ['joint_lonk', 'rotom']
        position = rng.normal(size=2)
        velocity = None if i % 7 == 3 else rng.normal(size=2)
        effort = position[:1] if i % 11 == 4 else rng.normal(size=2)
        frame = 'base' if i % 13 else 'tool0'
        if i % 17 == 9:
            messages.append(_rosbags_bytes(STAMPS[i % 3], names, position, velocity, effort,
                                           frame, little_endian=False))
        else:
            messages.append(serialize_message(_rclpy_message(
                STAMPS[i % 3] + i, names, position, velocity, effort, frame)))
    for payload in messages:
        _read_like_rclpy(reader, payload)


def test_the_reader_reads_a_steady_stream_with_other_padding_bytes():
    reader = JointStateReader()
    payload = bytearray(_valid_payload())
    _read_like_rclpy(reader, bytes(payload))
    meaningful, end = _meaningful_bytes(payload)
    padding = np.flatnonzero(~meaningful)
    assert padding.size and end == len(payload)
    for at in padding:
        payload[at] = 0xA5          # padding carries no meaning: same layout, same values
    stamp, names, position, velocity, effort = reader.read(bytes(payload))
    assert stamp == 5 and names == tuple(NAMES)
    np.testing.assert_array_equal(position, POSITION[0])
    assert effort.size == 0


@pytest.mark.parametrize('label, payload', BAD_PAYLOADS, ids=[b[0] for b in BAD_PAYLOADS])
def test_the_reader_refuses_malformed_payloads_and_keeps_reading_good_ones(label, payload):
    reader = JointStateReader()
    reader.read(_valid_payload())
    with pytest.raises(InvalidInput, match=r'malformed JointState CDR in a JointState message'):
        reader.read(payload)
    assert reader.read(_valid_payload())[0] == 5


@settings(max_examples=300, deadline=None)
@given(st.integers(0, 10_000), st.integers(0, 255), st.integers(0, 100))
def test_the_reader_on_corrupted_messages_raises_only_project_errors(where, value, cut):
    reader = JointStateReader()
    reader.read(_valid_payload())           # the template a corrupted message is held to
    payload = bytearray(_valid_payload())
    payload[where % len(payload)] = value
    payload = bytes(payload[:len(payload) - cut % 8])
    try:
        stamp, names, position, velocity, effort = reader.read(payload)
    except ReducerTwinError:
        return
    msg = deserialize_message(payload, JointState)     # accepted: it is a JointState
    assert names == tuple(msg.name)
    np.testing.assert_array_equal(position, np.array(msg.position, dtype=float))
