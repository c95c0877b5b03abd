"""The disk cache of the core's transmission-error tables."""

import numpy as np
import pytest
from reducer_twin.core import transmission_error
from reducer_twin.core.params import ReducerParams
from reducer_twin.io.table_cache import TableCache

PARAMS = ReducerParams()
TORQUE = np.array([0.0, 400.0, 800.0])
WEAR = np.array([0.0, 5e-6])


@pytest.fixture
def cache(tmp_path):
    """Install a table cache in a fresh directory for one test."""
    previous = transmission_error._TABLE_STORE
    store = TableCache(tmp_path / 'cache')
    transmission_error.use_table_store(store)
    yield store
    transmission_error.use_table_store(previous)


def test_a_computed_table_is_stored_and_read_back_equal_by_numpy(cache):
    beta = transmission_error._cached_table(PARAMS, TORQUE, WEAR)
    files = list(cache.root.iterdir())
    assert [f.name for f in files] == [
        f'mesh-table-{transmission_error.table_key(PARAMS, TORQUE, WEAR)}.npy']
    np.testing.assert_array_equal(np.load(files[0], allow_pickle=False), beta)
    np.testing.assert_array_equal(transmission_error._cached_table(PARAMS, TORQUE, WEAR), beta)


def test_the_core_alone_computes_the_same_table_without_any_file(tmp_path, cache):
    stored = transmission_error._cached_table(PARAMS, TORQUE, WEAR)
    transmission_error.use_table_store(None)
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
