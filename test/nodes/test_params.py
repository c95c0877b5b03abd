"""
Every node's parameters: descriptors with descriptions and ranges, and bad values refused.

In-process nodes check the descriptors and the errors a bad start value
raises; the installed ``joint_simulator`` and ``encoder_ingest`` programs
check what a user sees on the command line: one ``ERROR:`` line naming the
parameter and exit 1, never a traceback, and a clean exit on Ctrl-C.
"""

import subprocess

import pytest
from rclpy.parameter import Parameter
from reducer_twin.core.errors import InvalidParameter
from reducer_twin.nodes.encoder_ingest import EncoderIngest
from reducer_twin.nodes.joint_simulator import JointSimulatorNode
from reducer_twin.nodes.life_publisher import LifePublisher
from reducer_twin.nodes.te_monitor import TEMonitor
from reducer_twin.nodes.wear_estimator import WearEstimatorNode

pytestmark = pytest.mark.timeout(90, method='thread')

RCLPY_OWN = {'use_sim_time', 'start_type_description_service'}
"""Parameters rclpy declares on every node."""

NODES = {
    'joint_simulator': (JointSimulatorNode, []),
    'encoder_ingest': (EncoderIngest, []),
    'te_monitor': (TEMonitor, []),
    'wear_estimator': (WearEstimatorNode, [Parameter('state_file', value='none')]),
    'life_publisher': (LifePublisher, []),
}


def make(ros, kind, overrides=()):
    """Create a node of ``kind`` on the test's context (not spun)."""
    cls, base = NODES[kind]
    return ros.add(cls(context=ros.context, parameter_overrides=[*base, *overrides]))


def descriptors(node):
    """Return ``{name: ParameterDescriptor}`` of the node's own parameters."""
    names = [n for n in node.list_parameters([], 0).names if n not in RCLPY_OWN]
    return {d.name: d for d in node.describe_parameters(names)}


@pytest.mark.parametrize('kind', sorted(NODES))
def test_every_parameter_of_every_node_has_a_description(ros, kind):
    node = make(ros, kind)
    found = descriptors(node)
    assert len(found) >= 5
    undescribed = sorted(name for name, d in found.items() if not d.description.strip())
    assert undescribed == []


@pytest.mark.parametrize('kind, prefix', [
    ('joint_simulator', 'sim.'), ('encoder_ingest', 'ingest.'),
    ('wear_estimator', 'estimator.'), ('life_publisher', 'life.'),
])
def test_every_parameter_from_the_core_has_its_range_and_unit(ros, kind, prefix):
    found = {n: d for n, d in descriptors(make(ros, kind)).items() if n.startswith(prefix)}
    assert len(found) >= 3
    for name, d in found.items():
        assert d.additional_constraints, name
        assert d.floating_point_range or d.integer_range, f'{name} declares no range'
        assert d.description.endswith(']'), f'{name}: the unit closes the description'


def test_sim_rate_hz_has_a_floating_point_range_and_says_its_lower_bound_is_open(ros):
    d = descriptors(make(ros, 'joint_simulator'))['sim.rate_hz']
    assert d.type == Parameter.Type.DOUBLE.value
    (fp,) = d.floating_point_range
    assert (fp.from_value, fp.to_value, fp.step) == (0.0, 1e5, 0.0)
    assert d.additional_constraints == 'in (0, 100000] Hz'
    assert d.description == 'sample rate of the encoder stream [Hz]'


def test_whole_number_parameters_have_an_integer_range(ros):
    found = descriptors(make(ros, 'joint_simulator'))
    (ir,) = found['sim.seed'].integer_range
    assert (ir.from_value, ir.step) == (0, 1)
    assert found['sim.seed'].type == Parameter.Type.INTEGER.value
    (ir,) = descriptors(make(ros, 'life_publisher'))['life.n_samples'].integer_range
    assert (ir.from_value, ir.to_value) == (100, 1_000_000)


def test_life_thresholds_and_limit_are_described_in_si_units(ros):
    found = descriptors(make(ros, 'life_publisher'))
    assert found['life.warn_s'].additional_constraints == 'in [0, 1e+10] s'
    assert found['life.lost_motion_limit'].additional_constraints == 'in (0, 0.1] rad'
    assert not found['life.warn_s'].read_only, 'life.* are applied at run time'


@pytest.mark.parametrize('kind, names', [
    ('joint_simulator', ['joints', 'layout', 'sim.rate_hz', 'sim.aging_factor']),
    ('encoder_ingest', ['joints', 'motor_angles', 'ingest.max_gap_s']),
    ('te_monitor', ['joint', 'window_s', 'friction_in_effort', 'effort_lag_s']),
    ('wear_estimator', ['state_file', 'estimator.gate_nis']),
])
def test_parameters_a_node_reads_only_at_start_are_read_only(ros, kind, names):
    node = make(ros, kind)
    found = descriptors(node)
    assert all(found[n].read_only for n in names)
    old = node.get_parameter(names[-1]).value
    (result,) = node.set_parameters([Parameter(names[-1], value=old)])
    assert not result.successful and 'read-only' in result.reason


@pytest.mark.parametrize('kind, name, value, message', [
    ('joint_simulator', 'sim.rate_hz', -5.0, r'sim\.rate_hz must be in \(0, 100000\] Hz'),
    ('joint_simulator', 'sim.rate_hz', -5, r'sim\.rate_hz must be in \(0, 100000\] Hz'),
    ('joint_simulator', 'sim.rate_hz', 500, r'sim\.rate_hz must be a floating-point number'),
    ('joint_simulator', 'sim.seed', 2.5, r'sim\.seed must be a whole number'),
    ('joint_simulator', 'sim.load_torque_nm', -1.0, r'sim\.load_torque_nm must be in \[0'),
    ('joint_simulator', 'layout', 'sideways', 'layout must be'),
    ('encoder_ingest', 'ingest.max_gap_s', 0.0, r'ingest\.max_gap_s must be in \(0, 60\] s'),
    ('encoder_ingest', 'motor_angles', 'degrees', 'motor_angles must be'),
    ('encoder_ingest', 'batch_period_s', 2.0, 'batch_period_s must be'),
    ('te_monitor', 'window_s', 0.0, 'window_s must be'),
    ('te_monitor', 'friction_in_effort', 2, r'friction_in_effort must be in \[0, 1\]'),
    ('te_monitor', 'effort_lag_s', 50.0, r'effort_lag_s must be in \[0, 1\] s'),
    ('wear_estimator', 'estimator.gate_nis', 0.5, r'estimator\.gate_nis must be in \[1'),
    ('life_publisher', 'life.warn_s', -1.0, r'life\.warn_s must be in \[0'),
    ('life_publisher', 'life.error_s', 1e9, r'life\.error_s .* must not exceed life\.warn_s'),
])
def test_an_invalid_start_value_raises_invalid_parameter_naming_it(ros, kind, name, value,
                                                                   message):
    cls, base = NODES[kind]
    with pytest.raises(InvalidParameter, match=message):
        cls(context=ros.context, parameter_overrides=[*base, Parameter(name, value=value)])


def test_the_installed_simulator_refuses_a_negative_rate_with_one_error_line(node_program):
    result = subprocess.run(
        [node_program('joint_simulator'), '--ros-args', '-p', 'sim.rate_hz:=-5'],
        capture_output=True, text=True, timeout=60)
    assert result.returncode == 1
    assert 'Traceback' not in result.stderr
    assert result.stderr.startswith('ERROR: ') or '\nERROR: ' in result.stderr, result.stderr
    assert 'sim.rate_hz must be in (0, 100000] Hz, got -5' in result.stderr


def test_a_wrongly_typed_plain_parameter_is_an_error_line_too(node_program):
    result = subprocess.run(
        [node_program('encoder_ingest'), '--ros-args', '-p', 'batch_period_s:=1'],
        capture_output=True, text=True, timeout=60)
    assert result.returncode == 1
    assert 'Traceback' not in result.stderr
    assert 'ERROR: ' in result.stderr and 'batch_period_s' in result.stderr


def test_the_installed_simulator_runs_on_the_packaged_params_file_and_stops_on_ctrl_c(
        node_program, run_for, repo_root):
    alive, code, out, err = run_for(
        [node_program('joint_simulator'), '--ros-args', '--params-file',
         repo_root / 'config' / 'nodes.yaml'], seconds=3.0)
    assert alive, f'joint_simulator exited early ({code}):\n{err}'
    assert code == 0, err
    assert 'Traceback' not in err
    assert 'simulating 1 joint(s)' in out + err
