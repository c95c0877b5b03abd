"""
The bringup configuration (``config/twin.yaml``), shared by the nodes and the bag analysis.

ROS-free: ``twin_bringup`` builds nodes from it, ``reducer-twin analyze --config`` reads
the same file to find joints and topics, the aging factor, the window length, the
life thresholds and the reducer overrides.
"""

from pathlib import Path
import sys

from reducer_twin.core.errors import InvalidParameter

DEFAULTS = {
    'twin': {'joints': ['joint_1'], 'link_topic': '/joint_states', 'motor_topic': '',
             'motor_suffix': '_motor', 'motor_angles': 'raw', 'effort_source': 'auto',
             'motor_effort_units': 'auto', 'aging_factor': 1.0,
             'window_s': 2.0, 'state_dir': '', 'simulate': False,
             'intra_process': True, 'robot': '', 'store': '', 'store_period_s': 60.0,
             'interfaces': {}},
    'life': {}, 'simulator': {'profile': 'robot', 'wear_rate_scales': []}, 'reducer': {},
}


def default_config():
    """Return the packaged ``config/twin.yaml`` (source tree or installed share)."""
    here = Path(__file__).resolve()
    for candidate in (here.parents[1] / 'config' / 'twin.yaml',
                      Path(sys.prefix) / 'share' / 'reducer_twin' / 'config' / 'twin.yaml'):
        if candidate.is_file():
            return candidate
    return None


def load_config_sources(path):
    """
    Load and check a bringup YAML; also say which keys the file set.

    Parameters
    ----------
    path : str or Path or None
        YAML file; None uses the defaults only.

    Returns
    -------
    config : dict
        Sections ``twin``, ``life``, ``simulator``, ``reducer`` with defaults
        filled in.
    given : set of str
        ``'section.key'`` of every value the file set (the rest are defaults).

    Raises
    ------
    InvalidParameter
        If the file cannot be read or holds unknown keys.

    """
    import yaml
    data = {}
    if path:
        try:
            data = yaml.safe_load(Path(path).read_text(encoding='utf-8')) or {}
        except (OSError, yaml.YAMLError) as err:
            raise InvalidParameter(f'cannot read bringup config {path}: {err}') from err
        if not isinstance(data, dict):
            raise InvalidParameter(f'{path}: expected a mapping, got {type(data).__name__}')
    out = {}
    given = set()
    for section, defaults in DEFAULTS.items():
        values = data.get(section) or {}
        if not isinstance(values, dict):
            raise InvalidParameter(f'{path}: section {section!r} must be a mapping')
        if section == 'twin':
            unknown = set(values) - set(defaults)
            if unknown:
                raise InvalidParameter(f'{path}: unknown twin keys {sorted(unknown)}; allowed: '
                                       f'{sorted(defaults)}')
        given.update(f'{section}.{key}' for key in values)
        out[section] = {**defaults, **values}
    unknown = set(data) - set(DEFAULTS)
    if unknown:
        raise InvalidParameter(f'{path}: unknown sections {sorted(unknown)}')
    joints = out['twin']['joints']
    named = isinstance(joints, list) and all(isinstance(j, str) and j for j in joints)
    if not joints or not named or len(set(joints)) != len(joints):
        raise InvalidParameter(f'{path}: twin.joints must be distinct names, got {joints!r}')
    return out, given


def load_config(path):
    """
    Load and check a bringup YAML.

    Parameters
    ----------
    path : str or Path or None
        YAML file; None uses the defaults only.

    Returns
    -------
    dict
        Sections ``twin``, ``life``, ``simulator``, ``reducer`` with defaults
        filled in.

    Raises
    ------
    InvalidParameter
        If the file cannot be read or holds unknown keys.

    """
    return load_config_sources(path)[0]
