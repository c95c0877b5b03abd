"""
The bringup configuration (``config/twin.yaml``), shared by the nodes and the bag analysis.

ROS-free: ``twin_bringup`` builds nodes from it, ``reducer-twin analyze --config`` reads
the same file to find joints and topics, the aging factor, the window length, the
life thresholds and the reducer overrides.
"""

import math
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
    data = {}
    if path:
        data = read_yaml(path, 'the bringup configuration') or {}
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
    _check_values(path, out)
    return out, given


def read_yaml(path, what):
    """
    Read a YAML file with ``safe_load``; every failure is one line naming the file.

    Parameters
    ----------
    path : str or Path
        The file.
    what : str
        What the file is, for messages.

    Returns
    -------
    object
        The document.

    Raises
    ------
    InvalidParameter
        If the file is missing or unreadable, or on a YAML syntax error (with its line
        and column).

    """
    import yaml
    path = Path(path)
    try:
        text = path.read_text(encoding='utf-8')
    except FileNotFoundError:
        raise InvalidParameter(f'{path} does not exist; expected {what} (YAML)') from None
    except (OSError, UnicodeDecodeError) as err:
        reason = getattr(err, 'strerror', None) or str(err)
        raise InvalidParameter(f'cannot read {what} {path}: {reason}') from None
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError as err:
        raise InvalidParameter(yaml_error_line(path, err)) from None


def yaml_error_line(path, err):
    """
    Say where a YAML document is broken, in one line: file, line, column and problem.

    Parameters
    ----------
    path : str or Path
        The file.
    err : yaml.YAMLError
        What PyYAML raised.

    Returns
    -------
    str
        ``'<path>: YAML syntax error at line L, column C: <problem>'``.

    """
    mark = getattr(err, 'problem_mark', None) or getattr(err, 'context_mark', None)
    where = f' at line {mark.line + 1}, column {mark.column + 1}' if mark is not None else ''
    problem = ' '.join(str(x) for x in (getattr(err, 'context', None),
                                        getattr(err, 'problem', None)) if x) or str(err)
    return f'{path}: YAML syntax error{where}: {" ".join(problem.split())}'


_BOOLEANS = ('simulate', 'intra_process')
_STRINGS = ('link_topic', 'motor_topic', 'motor_suffix', 'motor_angles', 'state_dir')
_NUMBERS = ('aging_factor', 'window_s')


def as_number(name, value, integer=False):
    """
    Take a YAML value as a finite number; numeric strings count (YAML 1.1 reads 3.6e4 as one).

    Parameters
    ----------
    name : str
        Dotted key, for messages.
    value : object
        The value read.
    integer : bool
        A whole number is required.

    Returns
    -------
    float or int
        The number.

    Raises
    ------
    InvalidParameter
        On a boolean, a non-numeric string, a non-finite or (for ``integer``) a
        fractional value.

    """
    number = None
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        number = float(value)
    elif isinstance(value, str):
        try:
            number = float(value.strip())
        except ValueError:
            number = None
    kind = 'a whole number' if integer else 'a finite number'
    if number is None or not math.isfinite(number) or (integer and number != int(number)):
        raise InvalidParameter(f'{name} must be {kind}, got {value!r}')
    return int(number) if integer else number


def _check_values(path, config):
    """Check and convert the types of the values, in place."""
    twin = config['twin']
    for key in _BOOLEANS:
        if not isinstance(twin[key], bool):
            kind = 'a string' if isinstance(twin[key], str) else type(twin[key]).__name__
            raise InvalidParameter(f'{path}: twin.{key} must be true or false, got '
                                   f'{twin[key]!r} ({kind})')
    for key in _STRINGS:
        if not isinstance(twin[key], str):
            raise InvalidParameter(f'{path}: twin.{key} must be a string, got {twin[key]!r}')
    try:
        for key in _NUMBERS:
            twin[key] = as_number(f'twin.{key}', twin[key])
        life = config['life']
        for key in life:
            life[key] = as_number(f'life.{key}', life[key], integer=key == 'n_samples')
        scales = config['simulator'].get('wear_rate_scales') or []
        if not isinstance(scales, list):
            raise InvalidParameter(f'simulator.wear_rate_scales must be a list of numbers, '
                                   f'got {scales!r}')
        config['simulator']['wear_rate_scales'] = [
            as_number('simulator.wear_rate_scales[]', x) for x in scales]
    except InvalidParameter as err:
        raise InvalidParameter(f'{path}: {err}') from None
    if twin['motor_topic'] and twin['motor_topic'] == twin['link_topic']:
        link = twin['link_topic']
        raise InvalidParameter(f'{path}: twin.motor_topic must differ from twin.link_topic '
                               f"({link!r}); leave it '' when the motor entries are in the "
                               'link topic')
    if not twin['motor_topic'] and not twin['motor_suffix']:
        link = twin['link_topic']
        raise InvalidParameter(f'{path}: twin.motor_suffix must not be empty when the motor '
                               f'entries are in twin.link_topic ({link!r}): <joint> and '
                               '<joint><motor_suffix> would be the same entry; e.g. '
                               "'_motor'")


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
