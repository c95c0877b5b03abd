"""Tests of the MCAP writer and reader: rosbag2 layout, read-backs by other libraries, damage."""

from pathlib import Path

from mcap.reader import make_reader
from mcap.stream_reader import StreamReader
from mcap.writer import Writer as ReferenceMcapWriter
from mcap_ros2.decoder import DecoderFactory
import numpy as np
import pytest
from reducer_twin.core.errors import BagError, InvalidInput, ReducerTwinError
from reducer_twin.io.bag import open_bag
from reducer_twin.io.mcap_array_writer import McapBagWriter
from reducer_twin.io.mcap_reader import McapBagReader
from reducer_twin.io.rosbag2_metadata import dump_yaml, parse_qos_profiles, QosProfile
from reducer_twin.msg_adapters import ros_schemas
from reducer_twin.msg_adapters.jointstate_cdr import decode_joint_states, encode_joint_states
from rosbags.rosbag2 import Reader as RosbagsReader
from rosbags.typesys import get_typestore, Stores
import yaml

REAL_BAGS = Path(__file__).resolve().parents[2].parent / 'shared' / 'data' / 'rosbag2-jazzy'
JOINT_STATE = 'sensor_msgs/msg/JointState'
NAMES = ('joint_link', 'motor')
T0 = 1_700_000_000_000_000_000


def _joint_states(n, start=0):
    stamps = T0 + (start + np.arange(n, dtype=np.int64)) * 1_000_000
    phase = (start + np.arange(n)) / 1000.0
    position = np.stack([np.sin(phase), 81.0 * np.sin(phase)], axis=1)
    return stamps, position


def _write_bag(path, n=3000, compression='zstd', chunk_size=16 * 1024, extra=True):
    stamps, position = _joint_states(n)
    with McapBagWriter(path, compression=compression, chunk_size=chunk_size,
                       custom_data={'aging_factor': '1.25'}) as writer:
        channel = writer.add_topic('/joint_states', JOINT_STATE)
        buffer, offsets = encode_joint_states(stamps, NAMES, position, position * 0.5)
        writer.write_batch(channel, stamps + 20_000, buffer, offsets, publish_times_ns=stamps)
        if extra:
            motor = writer.add_topic('/motor_states', JOINT_STATE)
            buffer, offsets = encode_joint_states(stamps[:5], ['m'], position[:5, :1])
            for i in range(5):
                writer.write(motor, int(stamps[i]) + 7, buffer[offsets[i]:offsets[i + 1]])
    return stamps, position


@pytest.fixture
def small_bag(tmp_path):
    path = tmp_path / 'small.mcap'
    stamps, position = _write_bag(path)
    return path, stamps, position


def test_written_file_passes_the_mcap_library_with_crc_validation(small_bag):
    path, _, _ = small_bag
    with open(path, 'rb') as stream:
        kinds = [type(r).__name__ for r in StreamReader(stream, validate_crcs=True).records]
    assert kinds[0] == 'Header' and kinds[-1] == 'Footer'
    assert kinds.count('Message') == 3005
    with open(path, 'rb') as stream:
        reader = make_reader(stream, validate_crcs=True)
        summary = reader.get_summary()
        assert summary.statistics.message_count == 3005
        assert summary.statistics.channel_message_counts == {1: 3000, 2: 5}
        assert sum(1 for _ in reader.iter_messages()) == 3005


def test_written_file_decodes_with_mcap_ros2_support(small_bag):
    path, stamps, position = small_bag
    with open(path, 'rb') as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        decoded = [(channel.topic, message.log_time, msg) for _, channel, message, msg
                   in reader.iter_decoded_messages(topics=['/joint_states'])]
    assert len(decoded) == 3000
    topic, log_time, msg = decoded[10]
    assert topic == '/joint_states' and log_time == stamps[10] + 20_000
    assert list(msg.name) == list(NAMES)
    np.testing.assert_array_equal(msg.position, position[10])
    np.testing.assert_array_equal(msg.velocity, position[10] * 0.5)
    assert msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec == stamps[10]


def test_written_bare_mcap_reads_with_rosbags(small_bag):
    path, stamps, position = small_bag
    typestore = get_typestore(Stores.ROS2_JAZZY)
    with RosbagsReader(path) as reader:
        connections = {c.topic: c for c in reader.connections}
        assert connections['/joint_states'].msgtype == JOINT_STATE
        qos = connections['/joint_states'].ext.offered_qos_profiles[0]
        assert qos.reliability.name == 'RELIABLE' and qos.durability.name == 'VOLATILE'
        messages = list(reader.messages(connections=[connections['/joint_states']]))
    assert len(messages) == 3000
    _, timestamp, raw = messages[-1]
    msg = typestore.deserialize_cdr(raw, JOINT_STATE)
    assert timestamp == stamps[-1] + 20_000
    np.testing.assert_array_equal(msg.position, position[-1])


def test_layout_matches_what_rosbag2_jazzy_records(small_bag):
    path, _, _ = small_bag
    with open(path, 'rb') as stream:
        reader = make_reader(stream)
        header = reader.get_header()
        summary = reader.get_summary()
        metadata = list(reader.iter_metadata())
    assert header.profile == 'ros2'
    schema = summary.schemas[1]
    assert schema.name == JOINT_STATE and schema.encoding == 'ros2msg'
    assert schema.data.decode() == ros_schemas.message_definition(JOINT_STATE)
    assert '\n' + '=' * 80 + '\nMSG: std_msgs/Header\n' in schema.data.decode()
    channel = summary.channels[1]
    assert channel.message_encoding == 'cdr'
    assert list(channel.metadata) == ['offered_qos_profiles', 'topic_type_hash']
    assert channel.metadata['topic_type_hash'] == ros_schemas.type_hash(JOINT_STATE)
    assert channel.metadata['offered_qos_profiles'].startswith(
        '- history: unknown\n  depth: 0\n  reliability: reliable\n  durability: volatile\n')
    assert len(summary.schemas) == 1, 'both topics share one schema, as in rosbag2'
    assert [m.name for m in metadata] == ['rosbag2', 'rosbag2']
    final = yaml.safe_load(metadata[-1].metadata['serialized_metadata'])
    assert final['version'] == 9 and final['ros_distro'] == 'jazzy'
    assert final['message_count'] == 3005
    assert final['custom_data'] == {'aging_factor': '1.25'}
    assert final['relative_file_paths'] == ['small.mcap']
    assert yaml.safe_load(metadata[0].metadata['serialized_metadata'])['message_count'] == 0


def test_yaml_dump_reproduces_real_rosbag2_metadata_byte_for_byte():
    texts = [(REAL_BAGS / name / 'metadata.yaml').read_text()
             for name in ('topics_and_service_events', 'cdr_test')]
    with McapBagReader(REAL_BAGS / 'topics_and_service_events'
                       / 'bag_with_topics_and_service_events.mcap') as reader:
        texts += [values['serialized_metadata'] for _, values in reader.metadata]
    for text in texts:
        assert dump_yaml(yaml.safe_load(text)) == text


def test_schema_assembly_matches_the_real_rosbag2_cdr_test_bag():
    with McapBagReader(REAL_BAGS / 'cdr_test' / 'cdr_test_0.mcap') as reader:
        schema = next(s for s in reader.schemas.values() if s.name == 'test_msgs/msg/Arrays')
    text = schema.data.decode()
    parts = text.split('\n' + '=' * 80 + '\n')
    texts = {'test_msgs/msg/Arrays': parts[0]}
    for part in parts[1:]:
        header, body = part.split('\n', 1)
        texts[header[len('MSG: '):]] = body
    rebuilt = ros_schemas.assemble_definition('test_msgs/msg/Arrays', texts.__getitem__)
    assert rebuilt == text


@pytest.mark.parametrize('compression', ['zstd', 'lz4', 'none'])
def test_every_compression_round_trips_through_our_reader(tmp_path, compression):
    path = tmp_path / f'{compression}.mcap'
    stamps, position = _write_bag(path, n=2000, compression=compression)
    with McapBagReader(path) as reader:
        assert reader.has_summary and not reader.warnings
        assert {n: t.count for n, t in reader.topics().items()} == {
            '/joint_states': 2000, '/motor_states': 5}
        batches = list(reader.iter_batches(['/joint_states']))
    assert len(batches) > 5, 'the 16 KiB chunk size splits the messages over many chunks'
    decoded = [decode_joint_states(b.data, b.offsets, b.lengths) for b in batches]
    np.testing.assert_array_equal(np.concatenate([d.position for d in decoded]), position)
    np.testing.assert_array_equal(np.concatenate([b.log_time_ns for b in batches]),
                                  stamps + 20_000)
    np.testing.assert_array_equal(np.concatenate([b.publish_time_ns for b in batches]), stamps)


def test_mixed_length_batches_and_single_writes_round_trip(tmp_path):
    path = tmp_path / 'mixed.mcap'
    payloads = [bytes([i % 251]) * (i % 37) for i in range(500)]
    offsets = np.concatenate([[0], np.cumsum([len(p) for p in payloads])])
    times = T0 + np.arange(500, dtype=np.int64)
    with McapBagWriter(path, chunk_size=2048) as writer:
        channel = writer.add_topic('/raw', 'std_msgs/msg/String')
        writer.write_batch(channel, times[:400], b''.join(payloads[:400]), offsets[:401])
        for i in range(400, 500):
            writer.write(channel, int(times[i]), payloads[i])
    with McapBagReader(path) as reader:
        got = [(t, p) for _, t, _, p in reader.iter_messages()]
    assert got == list(zip(times.tolist(), payloads))
    with open(path, 'rb') as stream:
        assert [m.data for _, _, m in make_reader(stream, validate_crcs=True).iter_messages()] \
            == payloads


def test_reader_agrees_with_the_mcap_library_on_real_rosbag2_files():
    files = [REAL_BAGS / 'talker' / 'talker.mcap', REAL_BAGS / 'cdr_test' / 'cdr_test_0.mcap',
             *sorted((REAL_BAGS / 'wbag-split').glob('*.mcap')),
             REAL_BAGS / 'topics_and_service_events' / 'bag_with_topics_and_service_events.mcap']
    for path in files:
        with open(path, 'rb') as stream:
            expected = [(c.topic, m.log_time, m.publish_time, m.data)
                        for _, c, m in make_reader(stream).iter_messages(log_time_order=False)]
        with McapBagReader(path) as reader:
            got = list(reader.iter_messages())
            assert not reader.warnings
        assert sorted(got) == sorted(expected), path.name


def test_unchunked_messages_are_read(tmp_path):
    path = tmp_path / 'unchunked.mcap'
    stamps, position = _joint_states(300)
    buffer, offsets = encode_joint_states(stamps, NAMES, position)
    with open(path, 'wb') as stream:
        writer = ReferenceMcapWriter(stream, use_chunking=False)
        writer.start(profile='ros2', library='test')
        schema = writer.register_schema(JOINT_STATE, 'ros2msg',
                                        ros_schemas.message_definition(JOINT_STATE).encode())
        channel = writer.register_channel('/joint_states', 'cdr', schema,
                                          {'offered_qos_profiles': ''})
        for i in range(300):
            writer.add_message(channel, int(stamps[i]), buffer[offsets[i]:offsets[i + 1]]
                               .tobytes(), int(stamps[i]))
        writer.finish()
    with McapBagReader(path) as reader:
        assert reader.topics()['/joint_states'].count == 300
        batches = list(reader.iter_batches())
    assert len(batches) == 1, 'consecutive unchunked messages are handed over as one batch'
    decoded = decode_joint_states(batches[0].data, batches[0].offsets, batches[0].lengths)
    np.testing.assert_array_equal(decoded.position, position)


def _write_with_the_mcap_library(path, steps, chunk_size=4096, use_statistics=True):
    """
    Write JointState messages with the mcap library, in the order the steps give.

    Parameters
    ----------
    path : pathlib.Path
        The file.
    steps : list of tuple
        ``(channel, log times)``: written one step after the other, so that a channel
        written in one step fills chunks of its own. A channel is named by its topic,
        ``'/topic#2'`` for a second publisher of the topic.
    chunk_size : int
        Bytes per chunk (4 KiB: about 40 messages).
    use_statistics : bool
        Write the statistics record (without it the reader scans the file).

    """
    with open(path, 'wb') as stream:
        writer = ReferenceMcapWriter(stream, chunk_size=chunk_size,
                                     use_statistics=use_statistics)
        writer.start(profile='ros2', library='test')
        schema = writer.register_schema(JOINT_STATE, 'ros2msg',
                                        ros_schemas.message_definition(JOINT_STATE).encode())
        channels = {}
        for name, times in steps:
            if name not in channels:
                channels[name] = writer.register_channel(name.split('#')[0], 'cdr', schema,
                                                         {'offered_qos_profiles': ''})
            phase = (times - T0) / 1e9
            buffer, offsets = encode_joint_states(times, [name.strip('/')],
                                                  np.sin(phase)[:, None])
            for i, t in enumerate(times.tolist()):
                writer.add_message(channels[name], t, buffer[offsets[i]:offsets[i + 1]]
                                   .tobytes(), t)
        writer.finish()


def _ticks(start, stop):
    return T0 + np.arange(start, stop, dtype=np.int64) * 1_000_000


# Layouts whose chunks overlap in log time: 1 kHz joint states, the same tick stamped alike
# on every topic (ties in log time).
OVERLAPPING_LAYOUTS = {
    # rosbags, or a converter, writing one topic after the other; a 1 Hz topic last.
    'topic after topic': [('/joint_states', _ticks(0, 1200)), ('/motor_states', _ticks(0, 1200)),
                          ('/slow', _ticks(0, 1200)[::500])],
    # A writer buffering each topic on its own (simulate --layout split over long runs).
    'per-topic blocks': [(topic, _ticks(k, k + 300)) for k in range(0, 1200, 300)
                         for topic in ('/joint_states', '/motor_states')],
    # Two publishers of one topic, 0.5 ms apart, stored one after the other.
    'two publishers of a topic': [('/joint_states', _ticks(0, 1200)),
                                  ('/joint_states#2', _ticks(0, 1200) + 500_000)],
    # A message written 60 ms late, in a later chunk than its log time: that chunk
    # overlaps the ones before it by one message.
    'a late message': [('/joint_states', np.concatenate(
        [_ticks(0, 499), _ticks(500, 560), _ticks(499, 500), _ticks(560, 1200)]))],
}


@pytest.mark.parametrize('layout', list(OVERLAPPING_LAYOUTS))
def test_chunks_overlapping_in_time_are_read_in_log_time_order_as_the_mcap_library_reads_them(
        tmp_path, layout):
    path = tmp_path / 'overlap.mcap'
    _write_with_the_mcap_library(path, OVERLAPPING_LAYOUTS[layout])
    with open(path, 'rb') as stream:
        expected = [(c.topic, m.log_time, m.publish_time, m.data)
                    for _, c, m in make_reader(stream).iter_messages(log_time_order=True)]
    with McapBagReader(path) as reader:
        got = list(reader.iter_messages())
        batches = list(reader.iter_batches(['/joint_states', '/motor_states']))
        topic_of = {cid: channel.topic for cid, channel in reader.channels.items()}
        assert not reader.warnings
    # Same messages, same order: by log time, ties in file order (payloads copied right).
    assert got == expected
    times = np.concatenate([b.log_time_ns for b in batches])
    assert (np.diff(times) >= 0).all(), 'no topic runs ahead of another'
    for batch in batches:
        topics = np.array([topic_of[int(cid)] for cid in batch.channel_id])
        for topic in set(topics):   # within a topic, offsets follow the order handed out
            assert (np.diff(batch.offsets[topics == topic]) > 0).all()
        decoded = decode_joint_states(batch.data, batch.offsets, batch.lengths)
        np.testing.assert_array_equal(decoded.stamps_ns, batch.log_time_ns)
    # What the analysis reads: each topic's pieces follow each other in time.
    with open_bag(path) as bag:
        pieces = list(bag.iter_joint_states(list(bag.topics)))
    for topic in {name for name, _ in pieces}:
        times = np.concatenate([js.log_time_ns for name, js in pieces if name == topic])
        assert (np.diff(times) >= 0).all(), topic


def test_chunks_that_follow_each_other_in_time_are_handed_out_one_per_chunk(tmp_path):
    # The 1 Hz topic shares the last chunk with /joint_states' tail: that chunk's index
    # spans the whole file, but /joint_states alone is in order and read as it lies.
    path = tmp_path / 'ordered.mcap'
    _write_with_the_mcap_library(path, [('/joint_states', _ticks(0, 1200)),
                                        ('/slow', _ticks(0, 1200)[::500])])
    with McapBagReader(path) as reader:
        (cid,) = reader.topics()['/joint_states'].channel_ids
        holding = [c for c in reader._chunks if cid in c.index_offsets]
        batches = list(reader.iter_batches(['/joint_states']))
    assert len(batches) == len(holding) > 20
    np.testing.assert_array_equal(np.concatenate([b.log_time_ns for b in batches]),
                                  _ticks(0, 1200))


def test_a_file_without_statistics_is_scanned_and_read_in_file_order(tmp_path):
    path = tmp_path / 'scanned.mcap'
    steps = OVERLAPPING_LAYOUTS['topic after topic'][:2]
    _write_with_the_mcap_library(path, steps, use_statistics=False)
    with McapBagReader(path) as reader:
        got = [(topic, t) for topic, t, _, _ in reader.iter_messages()]
        assert not reader.has_summary
    assert got == [(topic, t) for topic, times in steps for t in times.tolist()]


@pytest.mark.parametrize('keep', [0.97, 0.6, 0.3, 0.05])
def test_a_truncated_file_reads_what_is_left_and_says_where_it_stopped(
        small_bag, tmp_path, keep):
    path, _, position = small_bag
    data = path.read_bytes()
    size = int(len(data) * keep)
    cut = tmp_path / 'cut.mcap'
    cut.write_bytes(data[:size])
    with McapBagReader(cut) as reader:
        assert not reader.has_summary
        text = ' '.join(str(w) for w in reader.warnings)
        assert f'no footer at the end of the file ({size} bytes' in text
        if keep < 0.9:  # cut inside the data section, not in the summary
            assert 'reading stopped at byte' in text or 'without a data end' in text
            assert f'of {size}' in text
        topics = reader.topics()
        count = topics['/joint_states'].count if '/joint_states' in topics else 0
        batches = list(reader.iter_batches(['/joint_states']))
    assert sum(len(b) for b in batches) == count
    assert count == 3000 if keep > 0.9 else count < 3000
    if batches:
        decoded = decode_joint_states(batches[0].data, batches[0].offsets, batches[0].lengths)
        np.testing.assert_array_equal(decoded.position, position[:len(decoded)])


def test_empty_and_foreign_files_raise_bag_error(tmp_path):
    empty = tmp_path / 'empty.mcap'
    empty.write_bytes(b'')
    with pytest.raises(BagError, match='empty'):
        McapBagReader(empty)
    foreign = tmp_path / 'foreign.mcap'
    foreign.write_bytes(b'PK\x03\x04 not an mcap at all')
    with pytest.raises(BagError, match='not an MCAP file: byte 0'):
        McapBagReader(foreign)
    with pytest.raises(BagError, match='cannot open'):
        McapBagReader(tmp_path / 'missing.mcap')


def test_bit_flips_anywhere_give_warnings_or_bag_errors_never_tracebacks(tmp_path):
    path = tmp_path / 'flip.mcap'
    _write_bag(path, n=400, chunk_size=4096)
    data = path.read_bytes()
    rng = np.random.default_rng(7)
    flipped = tmp_path / 'flipped.mcap'
    for where in np.concatenate([np.arange(0, 80), rng.integers(0, len(data), 150),
                                 np.arange(len(data) - 80, len(data))]):
        damaged = bytearray(data)
        damaged[int(where)] ^= 1 << int(rng.integers(0, 8))
        flipped.write_bytes(bytes(damaged))
        try:
            with McapBagReader(flipped) as reader:
                reader.topics()
                for batch in reader.iter_batches():
                    decode_joint_states(batch.data, batch.offsets, batch.lengths,
                                        errors='skip')
        except ReducerTwinError:
            pass


def test_a_flipped_payload_byte_is_caught_by_the_chunk_crc(tmp_path):
    path = tmp_path / 'crc.mcap'
    _write_bag(path, n=400, compression='none', chunk_size=4096, extra=False)
    data = bytearray(path.read_bytes())
    with McapBagReader(path) as reader:
        chunk = reader._chunks[1]
    data[chunk.data_offset + 200] ^= 0x10
    path.write_bytes(bytes(data))
    with McapBagReader(path) as reader:
        total = sum(len(b) for b in reader.iter_batches())
        assert any('CRC' in str(w) for w in reader.warnings)
    assert 0 < total < 400


def test_qos_is_read_from_integers_and_strings():
    old = ('- history: 3\n  depth: 0\n  reliability: 1\n  durability: 2\n  deadline:\n'
           '    sec: 0\n    nsec: 0\n  lifespan:\n    sec: 0\n    nsec: 0\n  liveliness: 1\n'
           '  liveliness_lease_duration:\n    sec: 0\n    nsec: 0\n'
           '  avoid_ros_namespace_conventions: false')
    new = dump_yaml([QosProfile(history='keep_last', depth=100,
                                reliability='best_effort').as_dict()])
    (profile_old,) = parse_qos_profiles(old)
    (profile_new,) = parse_qos_profiles(new)
    assert (profile_old.history, profile_old.reliability, profile_old.durability) == (
        'unknown', 'reliable', 'volatile')
    assert (profile_new.history, profile_new.depth, profile_new.reliability) == (
        'keep_last', 100, 'best_effort')
    assert parse_qos_profiles('') == ()
    with pytest.raises(InvalidInput):
        parse_qos_profiles('- history: sometimes')


def test_writer_refuses_bad_arguments(tmp_path):
    with pytest.raises(InvalidInput, match='compression'):
        McapBagWriter(tmp_path / 'a.mcap', compression='bz2')
    with McapBagWriter(tmp_path / 'b.mcap') as writer:
        channel = writer.add_topic('/x', JOINT_STATE)
        with pytest.raises(BagError, match='already'):
            writer.add_topic('/x', JOINT_STATE)
        with pytest.raises(InvalidInput, match='channel id'):
            writer.write(99, 0, b'')
        with pytest.raises(InvalidInput, match='offsets'):
            writer.write_batch(channel, [1, 2], b'abc', [0, 1])
        with pytest.raises(InvalidInput, match='>= 0'):
            writer.write(channel, -5, b'')
    with pytest.raises(BagError, match='already exists'):
        McapBagWriter(tmp_path / 'b.mcap')
    with pytest.raises(BagError, match='definition'):
        with McapBagWriter(tmp_path / 'c.mcap') as writer:
            writer.add_topic('/y', 'no_such_msgs/msg/Thing')


SCHEMA_TYPES = ['sensor_msgs/msg/JointState', 'std_msgs/msg/Float64MultiArray',
                'diagnostic_msgs/msg/DiagnosticArray', 'std_msgs/msg/String',
                'builtin_interfaces/msg/Time']


@pytest.mark.parametrize('msgtype', SCHEMA_TYPES)
def test_schemas_and_type_hashes_come_from_the_installed_ros_packages(msgtype):
    text = ros_schemas.message_definition(msgtype)
    own = ros_schemas.interface_file(msgtype, '.msg').read_text()
    assert text.startswith(own)
    for block in text.split('\n' + '=' * 80 + '\n')[1:]:
        assert block.startswith('MSG: ') and block.split('\n', 1)[0].count('/') == 1
    digest = ros_schemas.type_hash(msgtype)
    assert digest.startswith('RIHS01_') and len(digest) == 7 + 64
    int(digest[7:], 16)


def test_the_jointstate_schema_lists_header_then_time_as_rosbag2_does():
    text = ros_schemas.message_definition(JOINT_STATE)
    separator = '\n' + '=' * 80 + '\n'
    assert [b.split('\n', 1)[0] for b in text.split(separator)[1:]] == [
        'MSG: std_msgs/Header', 'MSG: builtin_interfaces/Time']
    assert ros_schemas.type_hash('sensor_msgs/JointState') == ros_schemas.type_hash(JOINT_STATE)


def test_a_type_that_is_not_installed_raises_bag_error_naming_what_was_searched():
    with pytest.raises(BagError, match=r'share/no_such_msgs/msg/Thing.msg under the searched '
                                       r'prefixes \['):
        ros_schemas.message_definition('no_such_msgs/msg/Thing')
    with pytest.raises(BagError, match='not understood'):
        ros_schemas.type_hash('JointState')
