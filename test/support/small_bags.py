"""The small simulated recording the reliability tests analyse (10 s of two joints)."""

from reducer_twin.analysis.simulate import simulate_bag, SimulationSpec

SMALL = {'hours': 1000.0, 'aging_factor': 360_000.0, 'joints': 2, 'rate_hz': 500.0, 'seed': 31}
"""10 s of stream, 5000 ticks of two joints: analysed in well under a second."""


def small_bag(tmp_path_factory, folder, name='rec', **changes):
    """
    Simulate the :data:`SMALL` spec (with ``changes``) into a new temporary folder.

    Parameters
    ----------
    tmp_path_factory : pytest.TempPathFactory
        The session's factory of temporary folders.
    folder, name : str
        The folder's stem and the bag directory's name in it.
    **changes
        Fields of :class:`SimulationSpec` that differ from :data:`SMALL`.

    Returns
    -------
    pathlib.Path
        The bag directory.

    """
    out = tmp_path_factory.mktemp(folder) / name
    simulate_bag(out, SimulationSpec(**{**SMALL, **changes}))
    return out
