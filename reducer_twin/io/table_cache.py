"""
The disk cache of the core's slow tables (rotation tables, depth per mesh pass).

:func:`reducer_twin.core.table_store.use_table_store` takes any store;
this one keeps each table as ``mesh-table-<key>.npy`` in
``$XDG_CACHE_HOME/reducer_twin`` (``~/.cache/reducer_twin``), so every process
(nodes, the command, tests) of the same parameters and grid reuses it. A
missing, unreadable or mismatched file is simply rebuilt; a cache that cannot
be written is skipped.
"""

import os
from pathlib import Path

import numpy as np
from reducer_twin.core import table_store


def default_cache_dir():
    """
    Return the cache directory, ``$XDG_CACHE_HOME/reducer_twin``.

    Returns
    -------
    Path
        ``~/.cache/reducer_twin`` when ``XDG_CACHE_HOME`` is unset.

    """
    return Path(os.environ.get('XDG_CACHE_HOME') or Path.home() / '.cache') / 'reducer_twin'


class TableCache:
    """
    Rotation tables as ``.npy`` files in one directory.

    Parameters
    ----------
    root : str or Path, optional
        The directory; default :func:`default_cache_dir`.

    """

    def __init__(self, root=None):
        self.root = Path(root) if root is not None else default_cache_dir()

    def path(self, key):
        """Return the file of a table key."""
        return self.root / f'mesh-table-{key}.npy'

    def load(self, key, shape):
        """
        Return the stored table of ``key`` if it is readable, finite and of ``shape``.

        Parameters
        ----------
        key : str
            :func:`~reducer_twin.core.table_store.digest` of the table.
        shape : tuple of int
            The expected shape.

        Returns
        -------
        ndarray or None
            None when there is no usable file.

        """
        try:
            beta = np.load(self.path(key), allow_pickle=False)
        except (OSError, ValueError, EOFError):   # an empty file raises EOFError
            return None
        if beta.shape == tuple(shape) and np.all(np.isfinite(beta)):
            return beta
        return None

    def save(self, key, beta):
        """
        Store a table atomically (temporary file and rename); never raise.

        Parameters
        ----------
        key : str
            :func:`~reducer_twin.core.table_store.digest` of the table.
        beta : ndarray
            The table.

        """
        path = self.path(key)
        tmp = path.with_name(f'{path.name}.{os.getpid()}.tmp')
        try:
            self.root.mkdir(parents=True, exist_ok=True)
            with open(tmp, 'wb') as fh:
                np.save(fh, beta, allow_pickle=False)
            os.replace(tmp, path)
        except OSError:
            try:
                tmp.unlink()
            except OSError:
                pass


def install(root=None):
    """
    Let the core keep its rotation tables on disk (done by every entry point).

    Parameters
    ----------
    root : str or Path, optional
        Cache directory; default :func:`default_cache_dir`.

    Returns
    -------
    TableCache
        The installed cache.

    """
    cache = TableCache(root)
    table_store.use_table_store(cache)
    return cache
