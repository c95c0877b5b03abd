"""ROS 1 .bag files read chunk by chunk, checked against rosbags' own rosbag1 reader."""

import struct

import numpy as np
import pytest
from reducer_twin.core.errors import BagError
from reducer_twin.io.bag import open_bag
from reducer_twin.io.rosbag1 import Rosbag1File
from reducer_twin.msg_adapters.jointstate_cdr import decode_joint_states, MSGTYPE as JOINT_STATE
from rosbags.rosbag1 import Reader, Writer
from rosbags.typesys import get_typestore, Stores

STORE = get_typestore(Stores.ROS1_NOETIC)
TYPES = STORE.types
T0 = 1_700_000_000_000_000_000
NAMES = ['joint_1', 'joint_1_motor', 'joint_2', 'joint_2_motor']


def _joint_state(i, names=NAMES):
    header = TYPES['std_msgs/msg/Header'](
        i, TYPES['builtin_interfaces/msg/Time']((T0 + i * 2_000_000) // 10**9,
                                                (T0 + i * 2_000_000) % 10**9), 'base')
    n = len(names)
    return bytes(STORE.serialize_ros1(TYPES[JOINT_STATE](
        header, list(names), np.arange(n) + 0.001 * i, np.full(n, -1.0 * i),
        np.array([]) if i % 5 == 0 else np.arange(n) * 10.0), JOINT_STATE))


def _write(path, count=600, compression=None, chunk=16_384):
    """Write a bag as rosbag writes one: JointState from two publishers, a string topic between."""
    writer = Writer(path)
    if compression:
        writer.set_compression(getattr(Writer.CompressionFormat, compression))
    writer.chunk_threshold = chunk
    with writer:
        a = writer.add_connection('/joint_states', JOINT_STATE, typestore=STORE,
                                  callerid='/driver_a')
        b = writer.add_connection('/joint_states', JOINT_STATE, typestore=STORE,
                                  callerid='/driver_b')
        log = writer.add_connection('/log', 'std_msgs/msg/String', typestore=STORE)
        for i in range(count):
            writer.write(a if i % 7 else b, T0 + i * 2_000_000 + 40_000, _joint_state(i))
            if i % 11 == 0:
                writer.write(log, T0 + i * 2_000_000 + 50_000, bytes(STORE.serialize_ros1(
                    TYPES['std_msgs/msg/String'](f'tick {i}'), 'std_msgs/msg/String')))
    return path


def _rosbags_messages(path, topic):
    with Reader(path) as reader:
        conns = [c for c in reader.connections if c.topic == topic]
        return [(t, bytes(d)) for _, t, d in reader.messages(conns)]


def _ours(path, topic):
    bag = Rosbag1File(path)
    try:
        out = []
        for batch in bag.iter_batches([topic]):
            assert {bag.topic_of(int(c)) for c in np.unique(batch.channel_id)} == {topic}
            out += [(int(t), batch.payload(i)) for i, t in enumerate(batch.log_time_ns)]
        return out, bag.warnings
    finally:
        bag.close()


@pytest.mark.parametrize('compression', [None, 'BZ2', 'LZ4'])
def test_every_message_of_a_topic_is_read_as_rosbags_reads_it(tmp_path, compression):
    path = _write(tmp_path / 'robot.bag', compression=compression)
    for topic in ('/joint_states', '/log'):
        got, warnings = _ours(path, topic)
        assert got == _rosbags_messages(path, topic) and warnings == []
    bag = Rosbag1File(path)
    try:
        assert bag.topics() == {'/joint_states': (JOINT_STATE, 600),
                                '/log': ('std_msgs/msg/String', 55)}
        encoding, text = bag.definition('/joint_states')
        assert encoding == 'ros1msg' and 'MSG: std_msgs/Header\nuint32 seq' in text
    finally:
        bag.close()


def test_the_joint_states_decode_like_rosbags_deserialises_them(tmp_path):
    path = _write(tmp_path / 'robot.bag', count=300)
    with open_bag(path) as bag:
        assert bag.storage == 'rosbag1' and bag.metadata == {}
        got = bag.read_joint_states()['/joint_states']
    want = [STORE.deserialize_ros1(d, JOINT_STATE) for _, d in
            _rosbags_messages(path, '/joint_states')]
    assert got.names == tuple(NAMES) and len(got) == len(want) == 300
    np.testing.assert_array_equal(
        got.stamps_ns, [m.header.stamp.sec * 10**9 + m.header.stamp.nanosec for m in want])
    np.testing.assert_array_equal(got.position, [m.position for m in want])
    np.testing.assert_array_equal(got.velocity, [m.velocity for m in want])
    for row, m in zip(got.effort, want):   # an empty effort field reads as NaN
        np.testing.assert_array_equal(row, m.effort if len(m.effort) else np.nan)


def test_iter_raw_gives_every_topic_as_ros2_cdr(tmp_path):
    path = _write(tmp_path / 'robot.bag', count=100)
    cdr = get_typestore(Stores.ROS2_JAZZY)
    with open_bag(path) as bag:
        texts = [cdr.deserialize_cdr(raw.payload(i), 'std_msgs/msg/String').data
                 for _, raw in bag.iter_raw(['/log']) for i in range(len(raw))]
        # A Header loses its ROS 1 seq: the CDR is a ROS 2 JointState.
        states = decode_joint_states([raw.payload(i) for _, raw in
                                      bag.iter_raw(['/joint_states']) for i in range(len(raw))])
        direct = bag.read_joint_states()['/joint_states']
    assert texts == [f'tick {i}' for i in range(0, 100, 11)]
    assert states.names == direct.names and len(states) == 100
    for field in ('stamps_ns', 'position', 'velocity', 'effort'):
        np.testing.assert_array_equal(getattr(states, field), getattr(direct, field))


def test_an_index_entry_at_a_connection_record_is_followed_to_its_message(tmp_path):
    # rosbag may point an index entry at the connection record written just before the
    # connection's first message; the reader then steps over that record.
    path = tmp_path / 'robot.bag'
    with Writer(path) as writer:
        states = writer.add_connection('/joint_states', JOINT_STATE, typestore=STORE)
        for i in range(10):
            writer.write(states, T0 + i, _joint_state(i))
        log = writer.add_connection('/log', 'std_msgs/msg/String', typestore=STORE)
        writer.write(log, T0 + 10, bytes(STORE.serialize_ros1(
            TYPES['std_msgs/msg/String']('late'), 'std_msgs/msg/String')))
        writer.write(states, T0 + 11, _joint_state(11))
    want = _rosbags_messages(path, '/log')
    data = bytearray(path.read_bytes())
    at = data.rindex(struct.pack('<II', (T0 + 10) // 10**9, (T0 + 10) % 10**9))
    offset = struct.unpack_from('<I', data, at + 8)[0]
    with Reader(path) as reader:
        conn_record = _connection_record_offset(reader, reader.chunk_infos[0].pos, offset)
    struct.pack_into('<I', data, at + 8, conn_record)
    path.write_bytes(bytes(data))
    got, warnings = _ours(path, '/log')
    assert got == want and warnings == []


def _connection_record_offset(reader, pos, message_offset):
    """Offset in the chunk of the last connection record before ``message_offset``."""
    chunk = reader.chunks[pos]
    with open(reader.path, 'rb') as stream:
        stream.seek(chunk.datapos)
        data = chunk.decompressor(stream.read(chunk.datasize))
    at, last = 0, None
    while at < message_offset:
        header = struct.unpack_from('<I', data, at)[0]
        is_connection = b'op=\x07' in data[at + 4:at + 4 + header]
        body = struct.unpack_from('<I', data, at + 4 + header)[0]
        if is_connection:
            last = at
        at += 8 + header + body
    assert last is not None
    return last


def test_a_corrupt_chunk_is_skipped_with_a_warning_and_the_rest_is_read(tmp_path):
    path = _write(tmp_path / 'robot.bag', compression='BZ2')
    want = _rosbags_messages(path, '/joint_states')
    with Reader(path) as reader:
        second = reader.chunks[sorted(reader.chunks)[1]]
    data = bytearray(path.read_bytes())
    data[second.datapos + 20:second.datapos + 60] = bytes(40)
    path.write_bytes(bytes(data))
    got, warnings = _ours(path, '/joint_states')
    assert 0 < len(got) < len(want) and set(got) <= set(want)
    (warning,) = warnings
    assert 'corrupt chunk' in warning.message and warning.offset == second.datapos


def _unindexed(path):
    data = bytearray(path.read_bytes())
    at = data.index(b'index_pos=') + len(b'index_pos=')
    data[at:at + 8] = bytes(8)
    path.write_bytes(bytes(data))


BAD_BAGS = [
    ('a bag cut short before its index', lambda p: p.write_bytes(p.read_bytes()[:30_000]),
     'is not a readable ROS 1 bag'),
    ('an unindexed bag', _unindexed, 'not indexed.*rosbag reindex'),
    ('a bag of format 1.2', lambda p: p.write_bytes(b'#ROSBAG V1.2\n' + p.read_bytes()[13:]),
     'format version 1.2; expected version 2.0'),
]


@pytest.mark.parametrize('what, damage, reason', BAD_BAGS, ids=[b[0] for b in BAD_BAGS])
def test_a_bag_that_cannot_be_read_is_refused_with_the_reason(tmp_path, what, damage, reason):
    path = _write(tmp_path / 'robot.bag', count=200)
    damage(path)
    with pytest.raises(BagError, match=reason) as err:
        open_bag(path)
    assert '\n' not in str(err.value)


def test_a_directory_of_ros1_bags_is_refused_naming_them(tmp_path):
    _write(tmp_path / 'robot.bag', count=10)
    with pytest.raises(BagError, match=r"ROS 1 bags are given as files: \['robot.bag'\]"):
        open_bag(tmp_path)
