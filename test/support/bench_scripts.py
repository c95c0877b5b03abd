"""Import the scripts of ``bench/`` (a folder of scripts, not a package) in tests."""

import importlib.util
from pathlib import Path
import sys

BENCH = Path(__file__).resolve().parents[2] / 'bench'


def load(name):
    """
    Import ``bench/<name>.py`` once and return the module.

    Parameters
    ----------
    name : str
        Script name without ``.py``, e.g. ``'independent_generator'``.

    Returns
    -------
    module
        The script as a module (registered in ``sys.modules`` under ``name``).

    """
    if name in sys.modules:
        return sys.modules[name]
    spec = importlib.util.spec_from_file_location(name, BENCH / f'{name}.py')
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return module
