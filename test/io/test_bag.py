"""Tests of rosbag2 bag handling: real rosbag2 bags, bags we write, and damaged bags."""

from pathlib import Path
import shutil

from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
import numpy as np
import pytest
from reducer_twin.core.errors import BagError, InvalidParameter, ReducerTwinError
from reducer_twin.io.bag import BagDirWriter, open_bag, write_bag_dir
from reducer_twin.io.mcap_array_writer import McapBagWriter
from reducer_twin.io.rosbag2_metadata import bag_metadata, dump_yaml
from reducer_twin.msg_adapters.jointstate_cdr import encode_joint_states, JointStateBatch
from rosbags.highlevel import AnyReader
from rosbags.typesys import get_typestore, Stores
from sqlite3_bags import humble_qos, write_joint_states_db3
import yaml

REAL_BAGS = Path(__file__).resolve().parents[2].parent / 'shared' / 'data' / 'rosbag2-jazzy'
JOINT_STATE = 'sensor_msgs/msg/JointState'
T0 = 1_700_000_000_000_000_000

TALKER_TOPICS = {'/topic': ('std_msgs/msg/String', 10), '/rosout': ('rcl_interfaces/msg/Log', 10),
                 '/parameter_events': ('rcl_interfaces/msg/ParameterEvent', 0)}
REAL_TOPICS = {
    'talker': TALKER_TOPICS,
    'sqlite3-talker': TALKER_TOPICS,
    'cdr_test': {'/test_topic': ('test_msgs/msg/BasicTypes', 3),
                 '/array_topic': ('test_msgs/msg/Arrays', 4)},
    'topics_and_service_events': {
        '/test_topic1': ('test_msgs/msg/Strings', 1), '/test_topic2': ('test_msgs/msg/Strings', 1),
        '/test_service1/_service_event': ('test_msgs/srv/BasicTypes_Event', 4),
        '/test_service2/_service_event': ('test_msgs/srv/BasicTypes_Event', 4),
        '/events/write_split': ('rosbag2_interfaces/msg/WriteSplitEvent', 0)},
    'wbag-split': {name: ('std_msgs/msg/String', count) for name, count in (
        ('AAA', 804), ('BBB', 742), ('CCC', 742), ('DDD', 753), ('EEE', 804), ('FFF', 772),
        ('GGG', 731), ('HHH', 726))},
}


def _batch(n, start=0, names=('joint_link', 'motor')):
    k = start + np.arange(n)
    stamps = T0 + k.astype(np.int64) * 1_000_000
    position = np.stack([np.sin(k / 500.0) * (j + 1) for j in range(len(names))], axis=1)
    nan = np.full_like(position, np.nan)
    return JointStateBatch(stamps, tuple(names), position, position * 10.0, nan, 'base')


@pytest.mark.parametrize('name', sorted(REAL_TOPICS))
def test_every_real_rosbag2_bag_lists_its_topics_types_and_counts(name):
    with open_bag(REAL_BAGS / name) as bag:
        assert {t: tuple(s) for t, s in bag.topics.items()} == REAL_TOPICS[name]
        assert not bag.warnings
        assert sum(len(raw) for _, raw in bag.iter_raw()) == sum(
            count for _, count in REAL_TOPICS[name].values())


def test_the_split_bag_is_read_across_its_five_files_in_order():
    with open_bag(REAL_BAGS / 'wbag-split') as bag:
        assert [f.name for f in bag.files] == [f'wbag_{i}.mcap' for i in range(5)]
        times = np.concatenate([raw.log_time_ns for _, raw in bag.iter_raw(['AAA'])])
    assert times.shape == (804,)
    assert (np.diff(times) >= 0).all()


def test_the_sqlite3_bag_holds_the_same_messages_as_the_mcap_talker():
    def messages(path):
        with open_bag(path) as bag:
            return sorted((topic, int(raw.log_time_ns[i]), raw.payload(i))
                          for topic, raw in bag.iter_raw() for i in range(len(raw)))
    assert messages(REAL_BAGS / 'sqlite3-talker') == messages(REAL_BAGS / 'talker')


def test_bare_storage_files_and_metadata_paths_open():
    with open_bag(REAL_BAGS / 'talker' / 'talker.mcap') as bag:
        assert bag.storage == 'mcap' and bag.topics['/topic'].count == 10
    with open_bag(REAL_BAGS / 'sqlite3-talker' / 'talker.db3') as bag:
        assert bag.storage == 'sqlite3' and bag.topics['/rosout'].count == 10
    with open_bag(REAL_BAGS / 'cdr_test' / 'metadata.yaml') as bag:
        assert bag.files == [REAL_BAGS / 'cdr_test' / 'cdr_test_0.mcap']


def test_qos_written_as_integers_and_as_strings_are_both_understood(tmp_path):
    with open_bag(REAL_BAGS / 'talker') as bag:
        (old,) = bag.topic_details['/rosout'].qos
    assert (old.reliability, old.durability) == ('reliable', 'transient_local')
    assert old.lifespan == (10, 0)
    write_bag_dir(tmp_path / 'new', {'/joint_states': _batch(10)})
    with open_bag(tmp_path / 'new') as bag:
        (new,) = bag.topic_details['/joint_states'].qos
    assert (new.history, new.reliability, new.durability) == ('unknown', 'reliable', 'volatile')


def test_a_written_bag_reads_back_with_our_reader(tmp_path):
    batch = _batch(5000)
    out = write_bag_dir(tmp_path / 'sim', {'/joint_states': batch},
                        custom_data={'aging_factor': '1.5', 'seed': '42'})
    assert sorted(p.name for p in out.iterdir()) == ['metadata.yaml', 'sim_0.mcap']
    with open_bag(out) as bag:
        assert bag.topics == {'/joint_states': (JOINT_STATE, 5000)}
        assert bag.metadata == {'aging_factor': '1.5', 'seed': '42'}
        assert not bag.warnings
        got = bag.read_joint_states()['/joint_states']
    assert got.names == batch.names and got.frame_id == 'base'
    np.testing.assert_array_equal(got.stamps_ns, batch.stamps_ns)
    np.testing.assert_array_equal(got.log_time_ns, batch.stamps_ns)
    np.testing.assert_array_equal(got.position, batch.position)
    np.testing.assert_array_equal(got.velocity, batch.velocity)
    assert np.isnan(got.effort).all()
    with open_bag(out / 'sim_0.mcap') as bare:
        assert bare.metadata == {'aging_factor': '1.5', 'seed': '42'}, 'the .mcap carries it'


def test_a_written_bag_reads_back_with_rosbags_anyreader(tmp_path):
    batch = _batch(300)
    out = write_bag_dir(tmp_path / 'sim', {'/joint_states': batch}, custom_data={'k': 'v'})
    with AnyReader([out], default_typestore=get_typestore(Stores.ROS2_JAZZY)) as reader:
        assert reader.message_count == 300
        assert [c.msgtype for c in reader.connections] == [JOINT_STATE]
        rows = [(t, reader.deserialize(raw, c.msgtype)) for c, t, raw in reader.messages()]
    assert [t for t, _ in rows] == batch.stamps_ns.tolist()
    np.testing.assert_array_equal(np.array([m.position for _, m in rows]), batch.position)
    assert list(rows[0][1].name) == list(batch.names)


def test_a_written_bag_reads_back_with_mcap_and_mcap_ros2(tmp_path):
    batch = _batch(300)
    out = write_bag_dir(tmp_path / 'sim', {'/joint_states': batch}, compression='lz4')
    with open(out / 'sim_0.mcap', 'rb') as stream:
        reader = make_reader(stream, validate_crcs=True, decoder_factories=[DecoderFactory()])
        decoded = [msg for _, _, _, msg in reader.iter_decoded_messages()]
    assert len(decoded) == 300
    np.testing.assert_array_equal(np.array([m.velocity for m in decoded]), batch.velocity)


def test_metadata_yaml_is_version_9_as_rosbag2_jazzy_writes_it(tmp_path):
    out = write_bag_dir(tmp_path / 'sim', {'/joint_states': _batch(100)},
                        custom_data={'aging_factor': '2'})
    text = (out / 'metadata.yaml').read_text()
    info = yaml.safe_load(text)['rosbag2_bagfile_information']
    assert list(info) == ['version', 'storage_identifier', 'duration', 'starting_time',
                          'message_count', 'topics_with_message_count', 'compression_format',
                          'compression_mode', 'relative_file_paths', 'files', 'custom_data',
                          'ros_distro']
    assert (info['version'], info['storage_identifier'], info['ros_distro']) == (
        9, 'mcap', 'jazzy')
    assert info['duration'] == {'nanoseconds': 99_000_000}
    assert info['starting_time'] == {'nanoseconds_since_epoch': T0}
    (topic,) = info['topics_with_message_count']
    assert topic['message_count'] == 100
    meta = topic['topic_metadata']
    assert list(meta) == ['name', 'type', 'serialization_format', 'offered_qos_profiles',
                          'type_description_hash']
    assert meta['offered_qos_profiles'][0]['reliability'] == 'reliable'
    assert meta['type_description_hash'].startswith('RIHS01_')
    assert info['files'] == [{'path': 'sim_0.mcap', 'starting_time':
                              {'nanoseconds_since_epoch': T0},
                              'duration': {'nanoseconds': 99_000_000}, 'message_count': 100}]
    assert info['custom_data'] == {'aging_factor': '2'}, 'kept a string, quoted'
    assert dump_yaml(yaml.safe_load(text)) == text


def test_a_non_empty_output_directory_is_refused_unless_overwrite(tmp_path):
    own = {'reducer_twin.run': '1'}
    out = write_bag_dir(tmp_path / 'sim', {'/joint_states': _batch(10)}, custom_data=own)
    with pytest.raises(InvalidParameter, match='not empty.*--overwrite'):
        write_bag_dir(out, {'/joint_states': _batch(10)}, custom_data=own)
    write_bag_dir(out, {'/joint_states': _batch(20)}, custom_data=own, overwrite=True)
    with open_bag(out) as bag:
        assert bag.topics['/joint_states'].count == 20
    (out / 'notes.txt').write_text('mine')
    with pytest.raises(InvalidParameter, match='did not write.*notes.txt'):
        write_bag_dir(out, {'/joint_states': _batch(10)}, overwrite=True)
    assert (out / 'notes.txt').read_text() == 'mine'


def test_overwrite_never_replaces_a_bag_that_reducer_twin_did_not_write(tmp_path):
    theirs = write_bag_dir(tmp_path / 'theirs', {'/joint_states': _batch(10)},
                           custom_data={'k': 'v'})
    before = {p.name: p.read_bytes() for p in theirs.iterdir()}
    with pytest.raises(InvalidParameter, match='did not write'):
        write_bag_dir(theirs, {'/joint_states': _batch(20)}, overwrite=True)
    assert {p.name: p.read_bytes() for p in theirs.iterdir()} == before


def test_a_failed_write_leaves_nothing_at_the_bag_directory(tmp_path):
    with pytest.raises(RuntimeError):
        with BagDirWriter(tmp_path / 'crash', custom_data={'run': '1'}) as writer:
            channel = writer.add_topic('/joint_states', JOINT_STATE)
            writer.write_joint_states(channel, _batch(50))
            raise RuntimeError('simulator failed')
    assert list(tmp_path.iterdir()) == [], 'no bag, no temporary, no lock'


def _split_bag(root, reverse=False):
    """Two MCAP files and a metadata.yaml listing them, as ros2 bag record splits."""
    root.mkdir()
    summaries, topics = [], {}
    for index, start in enumerate((0, 100)):
        path = root / f'split_{index}.mcap'
        with McapBagWriter(path) as writer:
            channel = writer.add_topic('/joint_states', JOINT_STATE)
            batch = _batch(100, start)
            buffer, offsets = encode_joint_states(batch.stamps_ns, batch.names, batch.position)
            writer.write_batch(channel, batch.stamps_ns, buffer, offsets)
        summaries.append(writer.file_summary())
        for topic in writer.topic_summaries():
            topics.setdefault(topic['name'], dict(topic, count=0))['count'] += topic['count']
    if reverse:
        summaries.reverse()
    info = bag_metadata(list(topics.values()), summaries)
    (root / 'metadata.yaml').write_text(dump_yaml({'rosbag2_bagfile_information': info}))
    return root


def test_joint_states_come_in_time_order_across_split_files(tmp_path):
    bag_dir = _split_bag(tmp_path / 'split', reverse=True)
    with open_bag(bag_dir) as bag:
        assert [f.name for f in bag.files] == ['split_1.mcap', 'split_0.mcap']
        got = bag.read_joint_states(['/joint_states'])['/joint_states']
        assert not bag.warnings
    np.testing.assert_array_equal(got.stamps_ns, _batch(200).stamps_ns)
    np.testing.assert_array_equal(got.position, _batch(200).position)


def test_metadata_that_disagrees_with_its_files_gives_warnings_and_reads_what_exists(tmp_path):
    bag_dir = _split_bag(tmp_path / 'split')
    (bag_dir / 'split_1.mcap').unlink()
    with open_bag(bag_dir) as bag:
        text = ' '.join(str(w) for w in bag.warnings)
        assert "lists 1 file(s) that do not exist: ['split_1.mcap']" in text
        assert 'lists 200 messages on /joint_states, but the storage files hold 100' in text
        assert len(bag.read_joint_states()['/joint_states']) == 100
    (bag_dir / 'split_0.mcap').unlink()
    with pytest.raises(BagError, match='none of the storage files listed'):
        open_bag(bag_dir)


def test_a_truncated_bag_file_is_read_up_to_the_damage_with_a_warning(tmp_path):
    out = write_bag_dir(tmp_path / 'sim', {'/joint_states': _batch(20000)})
    mcap = out / 'sim_0.mcap'
    data = mcap.read_bytes()
    mcap.write_bytes(data[:len(data) // 2])
    with open_bag(out) as bag:
        got = bag.read_joint_states()['/joint_states']
        text = ' '.join(str(w) for w in bag.warnings)
    assert 'reading stopped at byte' in text and f'of {len(data) // 2}' in text
    assert 0 < len(got) < 20000
    np.testing.assert_array_equal(got.position, _batch(len(got)).position)


def test_a_bit_flipped_bag_gives_warnings_or_bag_errors_only(tmp_path):
    out = write_bag_dir(tmp_path / 'sim', {'/joint_states': _batch(2000)})
    data = (out / 'sim_0.mcap').read_bytes()
    rng = np.random.default_rng(3)
    for where in rng.integers(0, len(data), 40):
        damaged = bytearray(data)
        damaged[int(where)] ^= 0xFF
        (out / 'sim_0.mcap').write_bytes(bytes(damaged))
        try:
            with open_bag(out) as bag:
                bag.read_joint_states()
        except ReducerTwinError:
            pass


def _bag_dir_with(tmp_path, name, files=None, metadata=None):
    root = tmp_path / name
    root.mkdir()
    for file_name, content in (files or {}).items():
        (root / file_name).write_bytes(content)
    if metadata is not None:
        (root / 'metadata.yaml').write_text(metadata)
    return root


BAD_BAGS = [
    ('missing path', lambda tmp: tmp / 'nope', 'does not exist'),
    ('directory without bag files', lambda tmp: _bag_dir_with(tmp, 'empty_dir'),
     'no metadata.yaml and no .mcap or .db3'),
    ('zero-length mcap', lambda tmp: _bag_dir_with(tmp, 'zero', {'a.mcap': b''}) / 'a.mcap',
     'empty'),
    ('wrong magic', lambda tmp: _bag_dir_with(tmp, 'magic', {'a.mcap': b'GIF89a' * 4})
     / 'a.mcap', 'neither MCAP nor sqlite3: byte 0'),
    ('not a sqlite database', lambda tmp: _bag_dir_with(
        tmp, 'db', {'a.db3': b'SQLite format 3\x00' + bytes(100)}) / 'a.db3', 'sqlite3'),
    ('metadata.yaml not YAML', lambda tmp: _bag_dir_with(tmp, 'yaml', metadata=': : ['),
     'cannot be read as YAML'),
    ('metadata.yaml of something else', lambda tmp: _bag_dir_with(tmp, 'other',
                                                                  metadata='a: 1'),
     'no rosbag2_bagfile_information'),
    ('file compression other than zstd', lambda tmp: _bag_dir_with(
        tmp, 'compressed', metadata='rosbag2_bagfile_information:\n  version: 5\n'
        '  storage_identifier: sqlite3\n  compression_mode: FILE\n'
        '  compression_format: bz2\n  relative_file_paths: [a.db3.bz2]\n'),
     "compression 'bz2' cannot be read; expected compression_format zstd"),
    ('unknown storage', lambda tmp: _bag_dir_with(
        tmp, 'storage', metadata='rosbag2_bagfile_information:\n  version: 9\n'
        '  storage_identifier: hdf5\n  relative_file_paths: [a.h5]\n'), 'storage_identifier'),
]


@pytest.mark.parametrize('label, make, message', BAD_BAGS, ids=[b[0] for b in BAD_BAGS])
def test_unreadable_bags_raise_bag_error_saying_what_is_wrong(tmp_path, label, make, message):
    path = make(tmp_path)
    with pytest.raises(BagError, match=message):
        open_bag(path)


def test_a_directory_of_mcap_files_without_metadata_yaml_is_read_with_a_warning(tmp_path):
    out = write_bag_dir(tmp_path / 'sim', {'/joint_states': _batch(10)},
                        custom_data={'aging_factor': '3'})
    (out / 'metadata.yaml').unlink()
    with open_bag(out) as bag:
        assert bag.topics['/joint_states'].count == 10
        assert 'no metadata.yaml' in str(bag.warnings[0])
        assert bag.metadata == {'aging_factor': '3'}, 'from the rosbag2 record in the .mcap'


def test_asking_for_a_missing_or_non_jointstate_topic_raises_bag_error():
    with open_bag(REAL_BAGS / 'talker') as bag:
        with pytest.raises(BagError, match="no topic '/joint_states'"):
            bag.read_joint_states(['/joint_states'])
        with pytest.raises(BagError, match='is std_msgs/msg/String, expected'):
            bag.read_joint_states('/topic')
        assert bag.read_joint_states() == {}


def test_a_copied_real_bag_with_a_cut_file_still_lists_its_topics(tmp_path):
    bag_dir = tmp_path / 'wbag'
    shutil.copytree(REAL_BAGS / 'wbag-split', bag_dir)
    for path in bag_dir.iterdir():
        path.chmod(0o644)
    last = bag_dir / 'wbag_4.mcap'
    last.write_bytes(last.read_bytes()[:5000])
    with open_bag(bag_dir) as bag:
        assert set(bag.topics) == set(REAL_TOPICS['wbag-split'])
        assert sum(len(raw) for _, raw in bag.iter_raw()) < 6074
        assert any('wbag_4.mcap' in str(w) for w in bag.warnings)


def test_a_sqlite3_jointstate_bag_of_an_older_distribution_reads_like_mcap(tmp_path):
    batch = _batch(500)
    buffer, offsets = encode_joint_states(batch.stamps_ns, batch.names, batch.position)
    root = tmp_path / 'humble'
    root.mkdir()
    qos = humble_qos(reliability=2)
    write_joint_states_db3(root / 'humble_0.db3', batch.stamps_ns, buffer, offsets, qos,
                           order=range(499, -1, -1))
    info = {'version': 5, 'storage_identifier': 'sqlite3', 'relative_file_paths':
            ['humble/humble_0.db3'], 'duration': {'nanoseconds': 499_000_000},
            'starting_time': {'nanoseconds_since_epoch': T0}, 'message_count': 500,
            'topics_with_message_count': [{'topic_metadata': {
                'name': '/joint_states', 'type': JOINT_STATE, 'serialization_format': 'cdr',
                'offered_qos_profiles': qos}, 'message_count': 500}],
            'compression_format': '', 'compression_mode': '', 'files': []}
    (root / 'metadata.yaml').write_text(yaml.safe_dump({'rosbag2_bagfile_information': info}))
    with open_bag(root) as bag:
        assert bag.storage == 'sqlite3' and not bag.warnings
        assert bag.topic_details['/joint_states'].qos[0].reliability == 'best_effort'
        got = bag.read_joint_states()['/joint_states']
    np.testing.assert_array_equal(got.stamps_ns, batch.stamps_ns)
    np.testing.assert_array_equal(got.position, batch.position)


def test_a_split_bag_with_one_unreadable_file_reads_the_others_with_a_warning(tmp_path):
    bag_dir = _split_bag(tmp_path / 'split')
    (bag_dir / 'split_0.mcap').write_bytes(b'\x00' * 64)
    with open_bag(bag_dir) as bag:
        assert [f.name for f in bag.files] == ['split_1.mcap']
        assert any('split_0.mcap is neither MCAP nor sqlite3' in str(w) for w in bag.warnings)
        np.testing.assert_array_equal(bag.read_joint_states()['/joint_states'].stamps_ns,
                                      _batch(100, 100).stamps_ns)


def test_malformed_jointstate_messages_in_a_bag_are_skipped_with_one_warning(tmp_path):
    batch = _batch(100)
    buffer, offsets = encode_joint_states(batch.stamps_ns, batch.names, batch.position)
    with McapBagWriter(tmp_path / 'bad.mcap') as writer:
        channel = writer.add_topic('/joint_states', JOINT_STATE)
        for i in range(100):
            payload = buffer[offsets[i]:offsets[i + 1]].tobytes()
            writer.write(channel, int(batch.stamps_ns[i]), payload[:30] if i % 10 == 3
                         else payload)
    with open_bag(tmp_path / 'bad.mcap') as bag:
        got = bag.read_joint_states()['/joint_states']
        (warning,) = bag.warnings
    assert len(got) == 90
    assert '10 malformed JointState message(s) on /joint_states skipped' in str(warning)
    np.testing.assert_array_equal(got.position, np.delete(batch.position, np.arange(3, 100, 10),
                                                          axis=0))


def test_two_publishers_of_one_topic_in_one_chunk_keep_their_file_order(tmp_path):
    from mcap.writer import Writer as McapWriter
    from reducer_twin.msg_adapters.ros_schemas import message_definition
    stamps = T0 + np.arange(40, dtype=np.int64) * 1_000_000
    buf, bounds = encode_joint_states(stamps, ['j'], np.arange(40.0)[:, None])
    with open(tmp_path / 'two.mcap', 'wb') as stream:
        writer = McapWriter(stream)
        writer.start('ros2', 'test')
        schema = writer.register_schema(JOINT_STATE, 'ros2msg',
                                        message_definition(JOINT_STATE).encode())
        channels = [writer.register_channel('/joint_states', 'cdr', schema, {'n': str(k)})
                    for k in range(2)]
        for i in range(40):   # the publishers take turns, as two drivers on one topic do
            writer.add_message(channels[i % 3 == 0], int(stamps[i]), bytes(
                buf[bounds[i]:bounds[i + 1]]), int(stamps[i]))
        writer.finish()
    with open_bag(tmp_path / 'two.mcap') as bag:
        order = [int(t) for _, raw in bag.iter_raw(['/joint_states']) for t in raw.log_time_ns]
        (_, batch), = bag.iter_joint_states(['/joint_states'])
    assert order == stamps.tolist()
    np.testing.assert_array_equal(batch.position[:, 0], np.arange(40.0))
