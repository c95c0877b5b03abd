"""
The bringup configuration (``config/twin.yaml``), shared by the nodes and the bag analysis.

ROS-free: ``twin_bringup`` builds nodes from it, ``reducer-twin analyze --config`` reads
the same file to find joints and topics, the aging factor, the window length, the
life thresholds and the reducer parameters: ``reducer`` (overrides for every joint) and
``reducers`` (per joint, a reducer file or overrides: a robot's base and wrist carry
different reducers), and ``service_time_s`` (per joint, the reducer's operating time
before the twin first sees it: a robot's hour meter). The defaults of a joint's processing
come from :class:`~reducer_twin.core.joint_twin.TwinConfig`, not from here.
"""

import math
from pathlib import Path
import sys

from reducer_twin.core.errors import InvalidParameter
from reducer_twin.core.joint_twin import TwinConfig
from reducer_twin.core.params import ReducerParams
from reducer_twin.core.robot_ingest import check_effort_scale, check_motor_direction
from reducer_twin.core.robot_ingest import check_streams, STREAMS
from reducer_twin.nodes.settings import StoreSettings

_TWIN = TwinConfig()

DEFAULTS = {
    'twin': {**{name: (list(default) if isinstance(default, list) else default)
                for name, (default, _) in STREAMS.items()},
             'aging_factor': _TWIN.aging_factor,
             'window_s': _TWIN.window_s, 'max_gap_s': _TWIN.max_gap_s,
             'friction_in_effort': _TWIN.friction_in_effort,
             'effort_lag_s': _TWIN.effort_lag_s, 'state_dir': '',
             'simulate': False, 'intra_process': True, 'reliable': True, 'robot': '',
             'store': '',
             'store_period_s': StoreSettings().store_period_s, 'interfaces': {}},
    'life': {}, 'simulator': {'profile': 'robot', 'wear_rate_scales': []}, 'reducer': {},
    'reducers': {}, 'service_time_s': {},
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
    if path and isinstance(out['reducers'], dict):
        # Reducer files named relative to this file are found beside it, wherever it runs.
        out['reducers'] = {joint: _beside(path, value) for joint, value in out['reducers'].items()}
    joints = out['twin']['joints']
    named = isinstance(joints, list) and all(isinstance(j, str) and j for j in joints)
    if not joints or not named or len(set(joints)) != len(joints):
        raise InvalidParameter(f'{path}: twin.joints must be distinct names, got {joints!r}')
    _check_values(path, out)
    for section in ('reducers', 'service_time_s'):
        unknown = sorted(set(out[section]) - set(joints)) if 'twin.joints' in given else []
        if unknown:
            raise InvalidParameter(f'{path}: {section} names joints that twin.joints does not '
                                   f'have: {unknown}; joints: {joints}')
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


_BOOLEANS = ('simulate', 'intra_process', 'reliable')
_STRINGS = ('link_topic', 'motor_topic', 'motor_suffix', 'motor_angles', 'state_dir')
_NUMBERS = ('aging_factor', 'window_s', 'max_gap_s')
_WHOLE_NUMBERS = ('friction_in_effort',)


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
        for key in _WHOLE_NUMBERS:
            twin[key] = as_number(f'twin.{key}', twin[key], integer=True)
        life = config['life']
        for key in life:
            life[key] = as_number(f'life.{key}', life[key], integer=key == 'n_samples')
        scales = config['simulator'].get('wear_rate_scales') or []
        if not isinstance(scales, list):
            raise InvalidParameter(f'simulator.wear_rate_scales must be a list of numbers, '
                                   f'got {scales!r}')
        config['simulator']['wear_rate_scales'] = [
            as_number('simulator.wear_rate_scales[]', x) for x in scales]
        twin_config(config)
        joint_reducers(config, path)
        config['service_time_s'] = service_times(config)
    except InvalidParameter as err:
        raise InvalidParameter(f'{path}: {err}') from None
    try:
        check_streams(twin['joints'], twin['link_topic'], twin['motor_topic'],
                      twin['motor_suffix'], 'twin.')
        check_motor_direction(twin['motor_direction'], 'twin.')
        check_effort_scale(twin['effort_scale'], 'twin.')
    except InvalidParameter as err:
        raise InvalidParameter(f'{path}: {err}') from None


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


def twin_config(config):
    """
    Return the :class:`~reducer_twin.core.joint_twin.TwinConfig` of a loaded configuration.

    Raises
    ------
    InvalidParameter
        If a value is out of its range.

    """
    twin = config['twin']
    return TwinConfig(aging_factor=twin['aging_factor'], window_s=twin['window_s'],
                      max_gap_s=twin['max_gap_s'], friction_in_effort=twin['friction_in_effort'],
                      effort_lag_s=twin['effort_lag_s'])


def joint_reducers(config, path=None):
    """
    Return the reducer parameters of every joint: the common set and each joint's own.

    ``reducer`` overrides the packaged defaults for every joint. ``reducers`` maps a
    joint to its own reducer: a YAML file (as ``config/rv80e.yaml``; relative to the
    configuration's folder), or a mapping of overrides of ``reducer``, which may name a
    ``file`` to start from instead.

    Parameters
    ----------
    config : dict
        Output of :func:`load_config`.
    path : str or Path, optional
        The configuration file (relative reducer files are found beside it).

    Returns
    -------
    common : ReducerParams
        The reducer of every joint without its own.
    own : dict of str to ReducerParams
        Per joint named in ``reducers``.

    Raises
    ------
    InvalidParameter
        On an unreadable file, an unknown name or a value out of range, naming the joint.

    """
    common = ReducerParams().with_overrides(config['reducer']) if config['reducer'] \
        else ReducerParams()
    given = config.get('reducers') or {}
    if not isinstance(given, dict):
        raise InvalidParameter(f'reducers must map joint names to a reducer file or '
                               f'overrides, got {given!r}')
    own = {}
    for joint, value in given.items():
        try:
            own[str(joint)] = _joint_reducer(common, value, path)
        except InvalidParameter as err:
            raise InvalidParameter(f'reducers.{joint}: {err}') from None
    return common, own


def service_times(config):
    """
    Return each joint's reducer service time [s] (``service_time_s`` of the configuration).

    The operating time of a joint's reducer before the twin first sees it (a robot's hour
    meter since the reducer was fitted; :attr:`.core.estimator.EstimatorConfig.service_time_s`).
    A joint left out: not known.

    Raises
    ------
    InvalidParameter
        On a value that is no number in [0, 1e10] s, naming the joint.

    """
    given = config.get('service_time_s') or {}
    if not isinstance(given, dict):
        raise InvalidParameter(f'service_time_s must map joint names to operating seconds, '
                               f'got {given!r}')
    out = {}
    for joint, value in given.items():
        seconds = as_number(f'service_time_s.{joint}', value)
        if not 0.0 <= seconds <= 1e10:
            raise InvalidParameter(f'service_time_s.{joint} must be in [0, 1e10] s (operating '
                                   f'time before the twin starts), got {value!r}')
        out[str(joint)] = seconds
    return out


def _beside(path, value):
    """Resolve the reducer file of a ``reducers`` entry against the configuration's folder."""
    entry = {'file': value} if isinstance(value, str) else value
    if not isinstance(entry, dict) or 'file' not in entry:
        return value
    file = Path(str(entry['file'])).expanduser()
    if not file.is_absolute():
        file = Path(path).resolve().parent / file
    return {**entry, 'file': str(file)}


def _joint_reducer(common, value, path):
    if isinstance(value, str):
        value = {'file': value}
    if not isinstance(value, dict):
        raise InvalidParameter(f'expected a reducer file or a mapping of overrides, got '
                               f'{value!r}')
    overrides = {k: v for k, v in value.items() if k != 'file'}
    start = common
    if 'file' in value:
        file = Path(str(value['file'])).expanduser()
        if not file.is_absolute() and path:
            file = Path(path).resolve().parent / file
        data = read_yaml(file, 'reducer parameters') or {}
        data = data.get('reducer', data) if isinstance(data, dict) else data
        if not isinstance(data, dict):
            raise InvalidParameter(f'{file}: expected a mapping of sections, got '
                                   f'{type(data).__name__}')
        start = ReducerParams().with_overrides(data)
    return start.with_overrides(overrides) if overrides else start
