"""
Derived bags framed by the mcap library: rosbag2's layout, read back by three readers.

The file :class:`~reducer_twin.io.mcap_writer.LibraryMcapWriter` writes must carry
what ``ros2 bag record -s mcap`` writes (profile ``ros2``, ``ros2msg`` schemas, ``cdr``
channels with ``offered_qos_profiles`` and ``topic_type_hash``, the ``rosbag2`` metadata
record) with the library's own identifier in the Header, and hold the same messages as
the project's array writer for the same input, for every chunk compression.
"""

from mcap.reader import make_reader
from mcap.writer import LIBRARY_IDENTIFIER
from mcap_ros2.decoder import DecoderFactory
import numpy as np
import pytest
from reducer_twin.core.errors import InvalidInput
from reducer_twin.io.bag import open_bag
from reducer_twin.io.bag_writer import BagDirWriter
from reducer_twin.io.mcap_writer import LibraryMcapWriter
from reducer_twin.io.rosbag2_metadata import QosProfile
from reducer_twin.msg_adapters import ros_schemas
from reducer_twin.msg_adapters.layouts import TE_BATCH
from reducer_twin.msg_adapters.multiarray_cdr import encode_multiarrays, MSGTYPE as MULTIARRAY
from rosbags.highlevel import AnyReader
from rosbags.typesys import get_typestore, Stores
import yaml

T0 = 1_700_000_000_000_000_000
LATEST = (QosProfile(durability='transient_local'),)


def _write(root, framing, compression, writeback=False):
    rng = np.random.default_rng(4)
    te = rng.normal(size=(40, 25, len(TE_BATCH.fields)))
    logs = T0 + np.arange(40, dtype=np.int64) * 100_000_000
    with BagDirWriter(root, compression=compression, framing=framing,
                      custom_data={'reducer_twin.joints': 'joint_1'}) as writer:
        te_ch = writer.add_topic('/reducer_twin/joint_1/te', MULTIARRAY)
        life_ch = writer.add_topic('/reducer_twin/joint_1/remaining_life', MULTIARRAY, LATEST)
        writer.write_batch(te_ch, logs[:30], *encode_multiarrays(TE_BATCH, te[:30]))
        if writeback:
            writer.start_writeback()
        writer.write(life_ch, int(logs[5]), b'\x00\x01\x00\x00' + bytes(28))
        writer.write_batch(te_ch, logs[30:], *encode_multiarrays(TE_BATCH, te[30:]))
        if writeback:
            writer.start_writeback()
    return root, te, logs


@pytest.mark.parametrize('compression', ['none', 'zstd', 'lz4'])
def test_the_library_framed_file_has_rosbag2s_layout_and_the_librarys_header(
        tmp_path, compression):
    root, _, _ = _write(tmp_path / 'd', 'library', compression)
    with open(root / 'd_0.mcap', 'rb') as stream:
        reader = make_reader(stream, validate_crcs=True)
        header, summary = reader.get_header(), reader.get_summary()
        metadata = list(reader.iter_metadata())
        messages = list(reader.iter_messages())
    assert (header.profile, header.library) == ('ros2', LIBRARY_IDENTIFIER)
    assert header.library.startswith('mcap-python/')
    (schema,) = summary.schemas.values()
    assert (schema.name, schema.encoding) == (MULTIARRAY, 'ros2msg')
    assert schema.data.decode() == ros_schemas.message_definition(MULTIARRAY)
    channels = {c.topic: c for c in summary.channels.values()}
    life = channels['/reducer_twin/joint_1/remaining_life']
    assert life.message_encoding == 'cdr'
    assert list(life.metadata) == ['offered_qos_profiles', 'topic_type_hash']
    assert life.metadata['topic_type_hash'] == ros_schemas.type_hash(MULTIARRAY)
    assert 'durability: transient_local' in life.metadata['offered_qos_profiles']
    assert {c.compression for c in summary.chunk_indexes} == {
        '' if compression == 'none' else compression}
    (record,) = metadata
    assert record.name == 'rosbag2'
    info = yaml.safe_load(record.metadata['serialized_metadata'])
    assert info['message_count'] == 41 and info['custom_data'] == {
        'reducer_twin.joints': 'joint_1'}
    assert info == yaml.safe_load((root / 'metadata.yaml').read_text())[
        'rosbag2_bagfile_information']
    assert len(messages) == 41


@pytest.mark.parametrize('compression', ['none', 'zstd'])
def test_both_framings_hold_the_same_messages_read_by_rosbags_and_by_our_reader(
        tmp_path, compression):
    lib, te, logs = _write(tmp_path / 'lib', 'library', compression)
    fast, _, _ = _write(tmp_path / 'fast', 'fast', compression)

    def rosbags(root):
        with AnyReader([root], default_typestore=get_typestore(Stores.ROS2_JAZZY)) as reader:
            return [(c.topic, t, bytes(raw)) for c, t, raw in reader.messages()]

    def ours(root):
        with open_bag(root) as bag:
            assert bag.metadata == {'reducer_twin.joints': 'joint_1'} and not bag.warnings
            return sorted((topic, int(raw.log_time_ns[i]), bytes(raw.payload(i)))
                          for topic, raw in bag.iter_raw() for i in range(len(raw)))
    assert rosbags(lib) == rosbags(fast)
    assert ours(lib) == ours(fast)
    assert (lib / 'metadata.yaml').read_text() == (fast / 'metadata.yaml').read_text().replace(
        'fast_0.mcap', 'lib_0.mcap')
    with open(lib / 'lib_0.mcap', 'rb') as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        rows = [msg for _, channel, _, msg in reader.iter_decoded_messages()
                if channel.topic.endswith('/te')]
    np.testing.assert_array_equal(np.array([m.data for m in rows]).reshape(te.shape), te)


@pytest.mark.parametrize('framing', ['library', 'fast'])
def test_write_back_started_while_writing_leaves_the_bag_byte_for_byte_the_same(
        tmp_path, framing):
    # The hint lets the kernel write out early what the final fsync would wait for.
    plain, _, _ = _write(tmp_path / 'plain' / 'd', framing, 'zstd')
    hinted, _, _ = _write(tmp_path / 'hinted' / 'd', framing, 'zstd', writeback=True)
    for name in ('d_0.mcap', 'metadata.yaml'):
        assert (hinted / name).read_bytes() == (plain / name).read_bytes()


def test_the_library_writer_refuses_bad_arguments(tmp_path):
    with pytest.raises(InvalidInput, match='compression'):
        LibraryMcapWriter(tmp_path / 'a.mcap', compression='bz2')
    with pytest.raises(InvalidInput, match='chunk_size'):
        LibraryMcapWriter(tmp_path / 'b.mcap', chunk_size=10)
    writer = LibraryMcapWriter(tmp_path / 'c.mcap')
    channel = writer.add_topic('/t', MULTIARRAY)
    with pytest.raises(InvalidInput, match='N \\+ 1 offsets'):
        writer.write_batch(channel, np.array([T0]), b'abcd', np.array([0, 2, 4]))
    with pytest.raises(InvalidInput, match='>= 0 ns'):
        writer.write(channel, -1, b'x')
    with pytest.raises(InvalidInput, match='channel id 9'):
        writer.write(9, T0, b'x')
    writer.close()
    with pytest.raises(FileExistsError):
        LibraryMcapWriter(tmp_path / 'c.mcap')
