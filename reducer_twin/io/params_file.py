"""
Reducer parameter files: YAML in SI units, read into the core's frozen dataclasses.

The core takes mappings (:meth:`~reducer_twin.core.params.ReducerParams.from_mapping`);
this module reads the file, with PyYAML's safe loader, and names it in every message.
"""

from pathlib import Path
import sys

from reducer_twin.core.errors import InvalidParameter
from reducer_twin.core.params import ReducerParams
import yaml


def read_reducer_params(path, overrides=None):
    """
    Load reducer parameters from a YAML file (SI units), then apply overrides.

    Parameters
    ----------
    path : str or Path
        YAML file with top-level key ``reducer`` (or the sections directly).
    overrides : mapping, optional
        Extra overrides, as for :meth:`ReducerParams.with_overrides`.

    Returns
    -------
    ReducerParams
        Validated parameters.

    Raises
    ------
    InvalidParameter
        If the file cannot be read, is not a mapping or holds bad values.

    """
    try:
        text = Path(path).read_text(encoding='utf-8')
        data = yaml.safe_load(text) or {}
    except (OSError, yaml.YAMLError) as err:
        raise InvalidParameter(f'cannot read reducer parameters from {path}: {err}') from err
    return ReducerParams.from_mapping(data, overrides, source=str(path))


def default_config_path():
    """
    Return the path of the packaged ``config/rv80e.yaml`` if it can be found.

    Returns
    -------
    Path or None
        The source-tree copy, the installed ``share/reducer_twin/config``
        copy, or None.

    """
    here = Path(__file__).resolve()
    candidates = [here.parents[2] / 'config' / 'rv80e.yaml',
                  Path(sys.prefix) / 'share' / 'reducer_twin' / 'config' / 'rv80e.yaml']
    for candidate in candidates:
        if candidate.is_file():
            return candidate
    return None
