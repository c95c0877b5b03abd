"""
The bringup configuration means what it says (``reducer_twin/config.py``, ``--config``).

A value of the wrong kind is refused rather than guessed (a string is not a boolean),
numbers written as YAML 1.1 reads them as strings (``3.6e4``) are numbers, a motor side
that cannot be told from the link side is refused, a YAML syntax error is one line with
the file, line and column, and through ``reducer-twin analyze --config`` every problem is
one ``ERROR:`` line that names the flag; a configured topic that the bag does not have is
an error naming the topics it has.
"""

from pathlib import Path

import pytest
from reducer_twin.analysis.settings import AnalysisSettings
from reducer_twin.analysis.simulate import simulate_bag, SimulationSpec
from reducer_twin.analysis.stages import JointFront
from reducer_twin.cli import main
from reducer_twin.config import default_config, joint_reducers, load_config, twin_config
from reducer_twin.core.errors import InvalidParameter
from reducer_twin.core.joint_twin import TwinConfig
from reducer_twin.core.params import ReducerParams


def _file(tmp_path, text):
    path = tmp_path / 'twin.yaml'
    path.write_text(text)
    return path


BAD = [
    ('a string for a boolean', 'twin:\n  simulate: "yes"\n',
     "twin.simulate must be true or false, got 'yes' (a string)"),
    ('a number for a boolean', 'twin:\n  intra_process: 1\n', 'twin.intra_process must be '
     'true or false'),
    ('an empty motor suffix', "twin:\n  motor_suffix: ''\n", 'twin.motor_suffix must not be '
     'empty'),
    ('the link topic as motor topic', 'twin:\n  link_topic: /js\n  motor_topic: /js\n',
     'twin.motor_topic must differ from twin.link_topic'),
    ('a word for a number', 'twin:\n  window_s: two\n',
     "twin.window_s must be a finite number, got 'two'"),
    ('not a finite number', 'twin:\n  aging_factor: .nan\n', 'twin.aging_factor must be a '
     'finite number'),
    ('a fraction of samples', 'life:\n  n_samples: 2000.5\n', 'life.n_samples must be a whole '
     'number'),
    ('a topic that is not a string', 'twin:\n  link_topic: 5\n', 'twin.link_topic must be a '
     'string'),
    ('a YAML syntax error', 'twin:\n  joints: [joint_1\n  window_s: 2.0\n',
     'YAML syntax error at line 3, column 11'),
]


@pytest.mark.parametrize('text, message', [row[1:] for row in BAD],
                         ids=[row[0] for row in BAD])
def test_a_value_of_the_wrong_kind_is_refused_naming_the_file_and_the_key(
        tmp_path, text, message):
    path = _file(tmp_path, text)
    with pytest.raises(InvalidParameter) as err:
        load_config(path)
    assert str(err.value).startswith(str(path)) and message in str(err.value), err.value
    assert '\n' not in str(err.value)


def test_numbers_that_yaml_1_1_reads_as_strings_are_numbers(tmp_path):
    config = load_config(_file(tmp_path, 'twin:\n  aging_factor: 3.6e4\n  window_s: 2e0\n'
                                         'life:\n  warn_s: 3.6e6\n  n_samples: 2e3\n'
                                         'simulator:\n  wear_rate_scales: [1e0, 1.5]\n'))
    assert config['twin']['aging_factor'] == 36_000.0
    assert config['twin']['window_s'] == 2.0
    assert config['life'] == {'warn_s': 3.6e6, 'n_samples': 2000}
    assert config['simulator']['wear_rate_scales'] == [1.0, 1.5]
    settings = AnalysisSettings.from_config(_file(tmp_path, 'twin:\n  aging_factor: 3.6e4\n'))
    assert settings.aging_factor == 36_000.0


def test_a_missing_file_is_one_line_naming_it(tmp_path):
    with pytest.raises(InvalidParameter, match='none.yaml does not exist'):
        load_config(tmp_path / 'none.yaml')


def test_the_packaged_configuration_is_valid_as_it_is():
    config = load_config(default_config())
    assert config['twin']['simulate'] is False and config['twin']['motor_suffix'] == '_motor'


@pytest.fixture(scope='module')
def bag(tmp_path_factory):
    """Simulate a small bag on /joint_states."""
    out = tmp_path_factory.mktemp('cfg') / 'rec'
    simulate_bag(out, SimulationSpec(hours=500.0, aging_factor=360_000.0, rate_hz=250.0))
    return out


def _analyze(argv, capsys):
    code = main([str(a) for a in argv])
    captured = capsys.readouterr()
    errors = [x for x in captured.err.splitlines() if x.startswith('ERROR:')]
    assert 'Traceback' not in captured.err
    return code, errors


@pytest.mark.parametrize('text, message', [
    ('twin:\n  link_topic: /arm/joint_states\n', 'twin.link_topic /arm/joint_states set in '
     '--config is not in the bag; found: /joint_states (sensor_msgs/msg/JointState)'),
    ('twin:\n  motor_topic: /motor_states\n', 'twin.motor_topic /motor_states set in --config '
     'is not in the bag; found:'),
    ('twin:\n  simulate: "yes"\n', '--config '),
    ('twin:\n  joints: [joint_1\n', 'YAML syntax error at line 3, column 1'),
], ids=['link topic not in the bag', 'motor topic not in the bag', 'string boolean',
        'syntax error'])
def test_analyze_config_problems_are_one_error_line_naming_the_flag_or_the_topics_found(
        bag, tmp_path, capsys, text, message):
    code, errors = _analyze(['analyze', bag, '--out', tmp_path / 'd', '--config',
                             _file(tmp_path, text)], capsys)
    assert code == 1 and len(errors) == 1 and message in errors[0], errors
    assert 'overwrite=' not in errors[0]
    assert not (tmp_path / 'd').exists()


def test_analyze_applies_an_aging_factor_written_as_3_6e4(bag, tmp_path, capsys):
    code, errors = _analyze(['analyze', bag, '--out', tmp_path / 'd', '--json', '--config',
                             _file(tmp_path, 'twin:\n  aging_factor: 3.6e4\n')], capsys)
    assert code == 0 and errors == []
    from reducer_twin.io.bag import open_bag
    with open_bag(tmp_path / 'd') as derived:
        assert float(derived.metadata['reducer_twin.aging_factor']) == 36_000.0
    assert Path(tmp_path / 'd').is_dir()


# --------------------------------------------------------------------------- reducers per joint


def test_each_joint_takes_its_own_reducer_from_a_file_or_overrides_and_the_rest_the_common(
        tmp_path):
    # A robot's base and wrist carry different reducers: one joint's from a file beside the
    # configuration (as config/rv80e.yaml is written), another's as overrides of `reducer`.
    (tmp_path / 'base.yaml').write_text('reducer:\n  rating:\n    rated_torque: 1568.0\n')
    path = _file(tmp_path, 'twin:\n  joints: [joint_1, joint_2, joint_3]\n'
                           'reducer:\n  rating:\n    rated_life: 3.6e7\n'
                           'reducers:\n  joint_1: base.yaml\n'
                           '  joint_3: {rating: {rated_torque: 392.0}}\n')
    common, own = joint_reducers(load_config(path))
    assert sorted(own) == ['joint_1', 'joint_3']
    assert common.rating.rated_life == 3.6e7 and common.rating.rated_torque == 784.0
    # A file is a whole reducer (from the packaged defaults); overrides start from `reducer`.
    assert own['joint_1'].rating.rated_torque == 1568.0
    assert own['joint_1'].rating.rated_life == ReducerParams().rating.rated_life
    assert own['joint_3'].rating.rated_torque == 392.0 and own['joint_3'].rating.rated_life \
        == 3.6e7


def test_a_motor_direction_other_than_1_or_minus_1_is_refused(tmp_path):
    assert load_config(_file(tmp_path, 'twin:\n  motor_direction: -1\n'))['twin'][
        'motor_direction'] == -1
    path = _file(tmp_path, 'twin:\n  motor_direction: 2\n')
    with pytest.raises(InvalidParameter, match=r'twin.motor_direction must be 1 .* got 2'):
        load_config(path)


def test_an_effort_scale_of_0_or_not_a_number_is_refused(tmp_path):
    assert load_config(_file(tmp_path, 'twin:\n  effort_scale: -1\n'))['twin'][
        'effort_scale'] == -1
    for bad in ('0', 'amps', '.nan'):
        path = _file(tmp_path, f'twin:\n  effort_scale: {bad}\n')
        with pytest.raises(InvalidParameter, match=r'twin.effort_scale must be a number of '
                                                   r'magnitude 1e-6 to 1e6 .* got '):
            load_config(path)


BAD_REDUCERS = [
    ('a joint the robot does not have', 'twin:\n  joints: [joint_1]\n'
     'reducers:\n  joint_9: {rating: {rated_torque: 392.0}}\n',
     "reducers names joints that twin.joints does not have: ['joint_9']"),
    ('a missing reducer file', 'reducers:\n  joint_1: none.yaml\n',
     'reducers.joint_1: '),
    ('a value out of range', 'reducers:\n  joint_1: {rating: {rated_torque: -1.0}}\n',
     'reducers.joint_1: rating.rated_torque must be in (0'),
    ('not a file or a mapping', 'reducers:\n  joint_1: 5\n',
     'reducers.joint_1: expected a reducer file or a mapping of overrides, got 5'),
]


BAD_SERVICE = [
    ('a joint the robot does not have', 'twin:\n  joints: [joint_1]\n'
     'service_time_s:\n  joint_9: 3600.0\n',
     "service_time_s names joints that twin.joints does not have: ['joint_9']"),
    ('negative', 'service_time_s:\n  joint_1: -3600.0\n',
     'service_time_s.joint_1 must be in [0, 1e10] s (operating time before the twin starts), '
     'got -3600.0'),
    ('not a number', 'service_time_s:\n  joint_1: 12000h\n',
     "service_time_s.joint_1 must be a finite number, got '12000h'"),
    ('not a mapping', 'service_time_s: [3600.0]\n', "section 'service_time_s' must be a "
     'mapping'),
]


@pytest.mark.parametrize('text, message', [row[1:] for row in BAD_REDUCERS + BAD_SERVICE],
                         ids=[row[0] for row in BAD_REDUCERS]
                         + [f'service time {row[0]}' for row in BAD_SERVICE])
def test_a_bad_joint_reducer_or_service_time_is_refused_naming_the_joint(tmp_path, text,
                                                                         message):
    path = _file(tmp_path, text)
    with pytest.raises(InvalidParameter) as err:
        load_config(path)
    assert str(err.value).startswith(str(path)) and message in str(err.value), err.value


# ------------------------------------------------------------------- service time per joint


def test_a_joints_service_time_reaches_its_estimator_and_the_others_stay_unknown(tmp_path):
    path = _file(tmp_path, 'twin:\n  joints: [joint_1, joint_2]\n'
                           'service_time_s:\n  joint_1: 4.32e7\n')
    assert load_config(path)['service_time_s'] == {'joint_1': 4.32e7}
    settings = AnalysisSettings.from_config(path)
    assert settings.estimator_of('joint_1').service_time_s == 4.32e7
    assert settings.estimator_of('joint_2') is None


def test_friction_in_effort_is_0_or_1_and_reaches_the_window_analysis(tmp_path):
    config = load_config(_file(tmp_path, 'twin:\n  friction_in_effort: 0\n'))
    assert twin_config(config).friction_in_effort == 0
    assert AnalysisSettings.from_config(_file(tmp_path, 'twin:\n  friction_in_effort: 0\n')
                                        ).friction_in_effort == 0
    for bad, said in (('2', 'must be in [0, 1], got 2'), ('0.5', 'must be a whole number'),
                      ('torque_sensor', 'must be a whole number')):
        path = _file(tmp_path, f'twin:\n  friction_in_effort: {bad}\n')
        with pytest.raises(InvalidParameter) as err:
            load_config(path)
        assert str(err.value).startswith(f'{path}: twin.friction_in_effort {said}'), err.value


def test_the_effort_lag_reaches_the_window_analysis_and_is_checked(tmp_path):
    # A drive's torque filter time constant, in seconds: 0-1 s.
    path = _file(tmp_path, 'twin:\n  effort_lag_s: 0.05\n')
    assert twin_config(load_config(path)).effort_lag_s == 0.05
    settings = AnalysisSettings.from_config(path)
    assert settings.effort_lag_s == 0.05
    assert JointFront('joint_1', settings, 1.0, 1.0, 1).analyzer.effort_lag_s == 0.05
    path = _file(tmp_path, 'twin:\n  effort_lag_s: 50\n')
    with pytest.raises(InvalidParameter) as err:
        twin_config(load_config(path))
    assert 'effort_lag_s' in str(err.value) and '50' in str(err.value), err.value


def test_the_twin_defaults_are_the_core_spec_of_a_joints_processing():
    config = load_config(None)
    spec = TwinConfig()
    assert (config['twin']['window_s'], config['twin']['max_gap_s'],
            config['twin']['aging_factor'], config['twin']['friction_in_effort'],
            config['twin']['effort_lag_s']) == (
        spec.window_s, spec.max_gap_s, spec.aging_factor, spec.friction_in_effort,
        spec.effort_lag_s)
    settings = AnalysisSettings()
    assert (settings.window_s, settings.max_gap_s, settings.friction_in_effort) == (
        spec.window_s, spec.max_gap_s, spec.friction_in_effort)
