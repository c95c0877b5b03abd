"""
Tests of rosbag2 file and message compression (zstd), on bags compressed by rosbags.

A recording made with ``ros2 bag record --compression-mode file|message
--compression-format zstd`` reads exactly like the same recording uncompressed; the
recording is left byte for byte as it was and no decompressed copy outlives the bag.
"""

import hashlib
from pathlib import Path
import tempfile

import numpy as np
import pytest
from reducer_twin.core.errors import BagError
from reducer_twin.io.bag import open_bag, write_bag_dir
from reducer_twin.io.mcap_reader import RawBatch
from reducer_twin.io.rosbag2_compression import _zstd, DecompressedFiles, inflate_batch
from reducer_twin.io.rosbag2_compression import ZSTD_MAGIC
from reducer_twin.msg_adapters.jointstate_cdr import JointStateBatch
from rosbags.rosbag2 import Reader, StoragePlugin, Writer
from rosbags.rosbag2.enums import CompressionFormat, CompressionMode

T0 = 1_700_000_000_000_000_000


def _plain_bag(root, n=3000):
    k = np.arange(n)
    position = np.stack([np.sin(k / 300.0), 40.0 * np.sin(k / 300.0)], axis=1)
    batch = JointStateBatch(T0 + k.astype(np.int64) * 1_000_000, ('joint_1', 'joint_1_motor'),
                            position, position * 2.0, np.cos(k / 50.0)[:, None] * [100.0, 1.0],
                            'base')
    return write_bag_dir(root, {'/joint_states': batch}, custom_data={'note': 'plain'})


def _compressed_copy(plain, root, mode, storage):
    """Rewrite a bag with rosbags' writer in rosbag2 compression ``mode`` (zstd)."""
    writer = Writer(root, version=9, storage_plugin=StoragePlugin[storage.upper()])
    writer.set_compression(CompressionMode[mode.upper()], CompressionFormat.ZSTD)
    with Reader(plain) as reader, writer:
        out = {c.id: writer.add_connection(c.topic, c.msgtype, msgdef=c.msgdef.data,
                                           rihs01=c.digest)
               for c in reader.connections}
        for connection, stamp, raw in reader.messages():
            writer.write(out[connection.id], stamp, raw)
    return root


def _digests(root):
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(root.iterdir())}


def _joint_states(path):
    with open_bag(path) as bag:
        batch = bag.read_joint_states()['/joint_states']
        return batch, list(bag.warnings), list(bag.files)


@pytest.fixture
def private_tmp(tmp_path, monkeypatch):
    """Send the decompressed copies to a directory the test can look into."""
    scratch = tmp_path / 'scratch'
    scratch.mkdir()
    monkeypatch.setattr(tempfile, 'tempdir', str(scratch))
    return scratch


@pytest.mark.parametrize('storage', ['mcap', 'sqlite3'])
@pytest.mark.parametrize('mode', ['file', 'message'])
def test_a_compressed_recording_reads_exactly_like_the_plain_one(
        tmp_path, private_tmp, mode, storage):
    plain = _plain_bag(tmp_path / 'plain')
    packed = _compressed_copy(plain, tmp_path / 'packed', mode, storage)
    suffix = {'mcap': '.mcap', 'sqlite3': '.db3'}[storage] + ('.zstd' if mode == 'file' else '')
    assert [p.name for p in packed.iterdir() if p.name != 'metadata.yaml'] == \
        [f'packed{suffix}'], 'rosbags wrote what rosbag2 writes'
    before = _digests(packed)
    expected, _, _ = _joint_states(plain)
    got, warnings, files = _joint_states(packed)
    assert not warnings
    assert files == [packed / f'packed{suffix}'], "the recording's file, not a copy"
    np.testing.assert_array_equal(got.stamps_ns, expected.stamps_ns)
    np.testing.assert_array_equal(got.position, expected.position)
    np.testing.assert_array_equal(got.effort, expected.effort)
    assert _digests(packed) == before, 'the recording is read only'
    assert list(private_tmp.iterdir()) == [], 'no decompressed copy outlives the bag'


def test_a_file_compressed_storage_file_opens_on_its_own_and_in_a_directory_without_metadata(
        tmp_path, private_tmp):
    packed = _compressed_copy(_plain_bag(tmp_path / 'plain'), tmp_path / 'packed', 'file',
                              'mcap')
    got, _, _ = _joint_states(packed / 'packed.mcap.zstd')
    assert len(got) == 3000
    (packed / 'metadata.yaml').unlink()
    got, warnings, _ = _joint_states(packed)
    assert len(got) == 3000
    assert 'no metadata.yaml' in str(warnings[0])
    assert list(private_tmp.iterdir()) == []


def test_message_compressed_payloads_are_recognised_without_metadata(tmp_path):
    packed = _compressed_copy(_plain_bag(tmp_path / 'plain'), tmp_path / 'packed', 'message',
                              'mcap')
    (packed / 'metadata.yaml').unlink()
    got, _, _ = _joint_states(packed)
    assert len(got) == 3000
    assert np.isfinite(got.position).all()


def test_a_compressed_file_cut_short_is_read_up_to_the_cut_with_a_warning(tmp_path, private_tmp):
    packed = _compressed_copy(_plain_bag(tmp_path / 'plain', n=20_000), tmp_path / 'packed',
                              'file', 'mcap')
    file = packed / 'packed.mcap.zstd'
    whole = file.read_bytes()
    file.write_bytes(whole[:len(whole) * 3 // 4])
    got, warnings, _ = _joint_states(packed)
    assert 0 < len(got) < 20_000
    np.testing.assert_array_equal(np.diff(got.stamps_ns), 1_000_000)
    said = [str(w) for w in warnings]
    assert any(w.startswith('packed.mcap.zstd: ends inside a zstd frame') for w in said), said
    assert list(private_tmp.iterdir()) == []
    # Cut inside its first block, nothing decompresses: one error naming the file.
    file.write_bytes(whole[:20])
    with pytest.raises(BagError, match='packed.mcap.zstd ends inside a zstd frame before any'):
        open_bag(packed)
    assert list(private_tmp.iterdir()) == []


def test_a_compression_left_unfinished_beside_its_input_reads_the_input_once(tmp_path):
    # rosbag2 compresses a closed file, then deletes it: interrupted between the two, both
    # are there, the compressed one maybe cut short (and no metadata.yaml yet).
    plain = _plain_bag(tmp_path / 'plain')
    packed = _compressed_copy(plain, tmp_path / 'packed', 'file', 'mcap')
    (packed / 'metadata.yaml').unlink()
    (packed / 'packed.mcap').write_bytes(next(plain.glob('*.mcap')).read_bytes())
    got, warnings, files = _joint_states(packed)
    assert len(got) == 3000 and files == [packed / 'packed.mcap']
    assert any('packed.mcap is there too' in str(w) for w in warnings)


def test_a_compression_rosbag2_does_not_ship_is_refused_with_the_one_it_does(tmp_path):
    packed = _compressed_copy(_plain_bag(tmp_path / 'plain'), tmp_path / 'packed', 'file',
                              'mcap')
    meta = packed / 'metadata.yaml'
    meta.write_text(meta.read_text().replace('compression_format: zstd',
                                             'compression_format: lz4'))
    with pytest.raises(BagError, match="compression 'lz4' cannot be read; expected "
                                       'compression_format zstd'):
        open_bag(packed)


def _raw(payloads):
    lengths = np.array([len(p) for p in payloads], np.int64)
    offsets = np.concatenate([[0], np.cumsum(lengths)[:-1]]).astype(np.int64)
    n = len(payloads)
    return RawBatch(np.zeros(n, np.uint16), np.arange(n, dtype=np.uint32),
                    np.arange(n, dtype=np.int64), np.arange(n, dtype=np.int64),
                    np.frombuffer(b''.join(payloads), np.uint8), offsets, lengths)


def test_inflating_keeps_plain_payloads_and_leaves_out_frames_that_do_not_decompress():
    cdr = [b'\x00\x01\x00\x00' + bytes([i]) * (5 + i) for i in range(4)]
    broken = ZSTD_MAGIC + b'\x00' * 12
    batch, failed = inflate_batch(_raw([cdr[0], _zstd.compress(cdr[1]), broken,
                                        _zstd.compress(cdr[2]), cdr[3], b'']))
    assert failed == 1
    assert [batch.payload(i) for i in range(len(batch))] == cdr + [b'']
    assert batch.sequence.tolist() == [0, 1, 3, 4, 5], 'the frame that failed is left out'
    plain = _raw(cdr)
    assert inflate_batch(plain) == (plain, 0), 'a batch without frames is passed through'


def _streamed(payload):
    """Compress as a streaming compressor does: no content size in the frame's header."""
    compressor = _zstd.ZstdCompressor()
    return compressor.compress(payload) + compressor.flush()


def test_frames_with_and_without_their_size_inflate_and_a_cut_one_is_left_out():
    payloads = [b'\x00\x01\x00\x00' + bytes([i % 7]) * (40 + 13 * i) for i in range(6)]
    frames = [_zstd.compress(p) for p in payloads[:3]] + [_streamed(p) for p in payloads[3:]]
    batch, failed = inflate_batch(_raw(frames + [frames[4][:-3]]))
    assert failed == 1
    assert [batch.payload(i) for i in range(len(batch))] == payloads


def test_a_frame_that_does_not_decompress_is_counted_in_one_warning(tmp_path):
    packed = _compressed_copy(_plain_bag(tmp_path / 'plain', n=50), tmp_path / 'packed',
                              'message', 'sqlite3')
    import sqlite3
    db = sqlite3.connect(packed / 'packed.db3')
    db.execute('UPDATE messages SET data = ? WHERE id IN (3, 7)', (ZSTD_MAGIC + bytes(20),))
    db.commit()
    db.close()
    got, warnings, _ = _joint_states(packed)
    assert len(got) == 48
    assert [str(w) for w in warnings] == [
        'packed.db3: 2 message payload(s) are zstd frames that do not decompress (rosbag2 '
        'message compression); skipping them']


def test_the_decompressed_copy_is_not_made_beside_the_recording(tmp_path, private_tmp):
    packed = _compressed_copy(_plain_bag(tmp_path / 'plain'), tmp_path / 'packed', 'file',
                              'mcap')
    with open_bag(packed) as bag:
        copies = list(private_tmp.iterdir())
        assert len(copies) == 1 and Path(copies[0]).name.startswith('reducer-twin-bag-')
        assert sorted(p.name for p in packed.iterdir()) == ['metadata.yaml',
                                                            'packed.mcap.zstd']
        assert bag.topics['/joint_states'].count == 3000
    assert list(private_tmp.iterdir()) == []


def test_a_file_of_several_frames_decompresses_whole_and_a_cut_keeps_what_came_before(
        tmp_path, private_tmp):
    first, second = bytes(range(256)) * 3000, b'second frame ' * 50_000
    whole = _zstd.compress(first) + _zstd.compress(second)
    (tmp_path / 'a.mcap.zstd').write_bytes(whole)
    (tmp_path / 'b.mcap.zstd').write_bytes(whole[:-10])
    copies = DecompressedFiles()
    assert copies.decompress(tmp_path / 'a.mcap.zstd').read_bytes() == first + second
    kept = copies.decompress(tmp_path / 'b.mcap.zstd').read_bytes()
    assert kept.startswith(first) and len(kept) < len(first) + len(second)
    assert [w.path for w in copies.warnings] == [str(tmp_path / 'b.mcap.zstd')]
    copies.close()
    assert list(private_tmp.iterdir()) == []
