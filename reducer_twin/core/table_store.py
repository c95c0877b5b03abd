"""
Where the core's slow tables may be kept between processes (a hook, no I/O here).

Two tables take long enough to matter at every start of a node or a command: the
period-mean rotation tables of :mod:`.transmission_error` (seconds) and the depth
per mesh pass of :mod:`.wear` (about 0.1 s). The core computes them and keeps them in
memory; a store installed by the edges (:mod:`reducer_twin.io.table_cache`, a disk
cache) lets every process of the same parameters reuse them. The core itself never
opens a file.
"""

import hashlib

_STORE = None


def use_table_store(store):
    """
    Keep the core's tables in ``store`` between processes.

    Parameters
    ----------
    store : object or None
        ``load(key, shape)`` returns a finite array of ``shape`` or None,
        ``save(key, array)`` keeps one (and must not raise); None computes
        the tables in every process.

    """
    global _STORE
    _STORE = store


def table_store():
    """Return the installed store, or None."""
    return _STORE


def digest(*parts):
    """
    Return the key of a table: 24 hexadecimal digits of everything it depends on.

    Parameters
    ----------
    *parts
        Values whose ``repr`` (arrays: their bytes) fixes the table.

    Returns
    -------
    str
        The key.

    """
    return hashlib.sha256(repr(parts).encode()).hexdigest()[:24]


def stored_table(key, shape, build):
    """
    Return the table of ``key`` from the store, or build it and store it.

    Parameters
    ----------
    key : str
        :func:`digest` of what the table depends on.
    shape : tuple of int
        Its shape.
    build : callable
        Computes the table (no arguments) when the store has none.

    Returns
    -------
    ndarray
        The table.

    """
    store = _STORE
    if store is not None:
        table = store.load(key, shape)
        if table is not None:
            return table
    table = build()
    if store is not None:
        store.save(key, table)
    return table
