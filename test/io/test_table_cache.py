"""The disk cache of the core's slow tables: rotation tables and the depth per mesh pass."""

import numpy as np
import pytest
from reducer_twin.core import table_store, transmission_error, wear
from reducer_twin.core.params import ReducerParams
from reducer_twin.io.table_cache import TableCache

PARAMS = ReducerParams()
TORQUE = np.array([0.0, 400.0, 800.0])
WEAR = np.array([0.0, 5e-6])


@pytest.fixture
def cache(tmp_path):
    """Install a table cache in a fresh directory for one test."""
    previous = table_store.table_store()
    store = TableCache(tmp_path / 'cache')
    table_store.use_table_store(store)
    yield store
    table_store.use_table_store(previous)


def test_a_computed_table_is_stored_and_read_back_equal_by_numpy(cache):
    beta = transmission_error._cached_table(PARAMS, TORQUE, WEAR)
    files = list(cache.root.iterdir())
    assert [f.name for f in files] == [
        f'mesh-table-{transmission_error.table_key(PARAMS, TORQUE, WEAR)}.npy']
    np.testing.assert_array_equal(np.load(files[0], allow_pickle=False), beta)
    np.testing.assert_array_equal(transmission_error._cached_table(PARAMS, TORQUE, WEAR), beta)


def test_the_core_alone_computes_the_same_table_without_any_file(tmp_path, cache):
    stored = transmission_error._cached_table(PARAMS, TORQUE, WEAR)
    table_store.use_table_store(None)
    np.testing.assert_array_equal(transmission_error._cached_table(PARAMS, TORQUE, WEAR),
                                  stored)


@pytest.mark.parametrize('damage', [b'', b'not a numpy file', None],
                         ids=['empty', 'garbage', 'wrong shape'])
def test_an_unusable_file_is_rebuilt(cache, damage):
    beta = transmission_error._cached_table(PARAMS, TORQUE, WEAR)
    path = cache.path(transmission_error.table_key(PARAMS, TORQUE, WEAR))
    if damage is None:
        np.save(path, np.zeros((2, 2)), allow_pickle=False)
    else:
        path.write_bytes(damage)
    assert cache.load(transmission_error.table_key(PARAMS, TORQUE, WEAR), beta.shape) is None
    np.testing.assert_array_equal(transmission_error._cached_table(PARAMS, TORQUE, WEAR), beta)
    np.testing.assert_array_equal(np.load(path, allow_pickle=False), beta)


def test_a_cache_that_cannot_be_written_is_skipped(tmp_path):
    blocker = tmp_path / 'file'
    blocker.write_text('not a directory')
    store = TableCache(blocker / 'cache')
    store.save('key', np.ones((2, 2)))
    assert store.load('key', (2, 2)) is None
    assert blocker.read_text() == 'not a directory'


def test_the_depth_table_is_stored_and_a_new_process_reads_it_back_bit_for_bit(cache):
    # The depth per mesh pass takes ~0.1 s at every start of a node or a command.
    wear._depth_table.cache_clear()
    built = wear._table_for.__wrapped__(PARAMS)
    assert len(list(cache.root.iterdir())) == 1
    wear._depth_table.cache_clear()      # as a new process would start
    read = wear._table_for.__wrapped__(PARAMS)
    np.testing.assert_array_equal(read.depth, built.depth)
    np.testing.assert_array_equal(read.step, built.step)
    table_store.use_table_store(None)
    wear._depth_table.cache_clear()
    np.testing.assert_array_equal(wear._table_for.__wrapped__(PARAMS).depth, built.depth)
    wear._depth_table.cache_clear()
