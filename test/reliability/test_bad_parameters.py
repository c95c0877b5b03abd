"""
Invalid parameters given to the installed node programs, at start and while they run.

In-process, every node's parameters are checked by ``test/nodes/test_params.py`` (and
the simulator's program by its start); here each installed program (``venv/bin/<exe>
--ros-args -p ...``) gets a value it must refuse: it exits 1 with one ``ERROR:`` line
naming the parameter, without a traceback. A running ``life_publisher`` gets a bad
value over the parameter service: it is rejected with the reason and the old value
stays.
"""

import signal
import subprocess

import pytest
from rclpy.parameter import Parameter
from rclpy.parameter_client import AsyncParameterClient

pytestmark = [pytest.mark.timeout(120, method='thread'), pytest.mark.slow]


BAD_START_VALUES = [
    ('encoder_ingest', 'motor_angles:=sideways', 'motor_angles'),
    ('encoder_ingest', 'ingest.max_gap_s:=-0.05', 'ingest.max_gap_s'),
    ('te_monitor', 'window_s:=-2.0', 'window_s'),
    ('te_monitor', 'window_s:=2', 'window_s'),          # a whole number for a double
    ('wear_estimator', 'estimator.gate_nis:=0.5', 'estimator.gate_nis'),
    ('life_publisher', 'life.warn_s:=-1.0', 'life.warn_s'),
    ('twin_bringup', 'config:=/nonexistent/twin.yaml', '/nonexistent/twin.yaml'),
    ('encoder_ingest', "motor_suffix:=''", 'motor_suffix'),   # joint and motor alike
    ('encoder_ingest', 'motor_topic:=/joint_states', 'motor_topic'),   # the link topic
]


@pytest.mark.parametrize('program, argument, named', [
    pytest.param(*row, id=f'{row[0]} -p {row[1]}') for row in BAD_START_VALUES])
def test_an_invalid_parameter_at_start_stops_the_program_naming_it(
        node_program, tmp_path, program, argument, named):
    extra = ['-p', f'state_dir:={tmp_path}'] if program == 'wear_estimator' else []
    result = subprocess.run([str(node_program(program)), '--ros-args', '-p', argument, *extra],
                            capture_output=True, text=True, timeout=60)
    assert result.returncode == 1
    assert 'Traceback' not in result.stderr
    errors = [x for x in result.stderr.splitlines() if x.startswith('ERROR: ')]
    assert len(errors) == 1 and named in errors[0], result.stderr


@pytest.mark.parametrize('text, named', [
    (None, 'does not exist'),
    ('wear_estimator:\n  ros__parameters:\n    joint: [a\n',
     'YAML syntax error at line 4, column 1'),
    ('- just\n- a list\n', 'expected a mapping of node names'),
], ids=['missing', 'syntax error', 'not a mapping'])
def test_a_bad_params_file_stops_the_program_with_one_line_naming_the_file(
        node_program, tmp_path, text, named):
    path = tmp_path / 'params.yaml'
    if text is not None:
        path.write_text(text)
    result = subprocess.run([str(node_program('wear_estimator')), '--ros-args', '--params-file',
                             str(path), '-p', f'state_dir:={tmp_path}'],
                            capture_output=True, text=True, timeout=60)
    assert result.returncode == 1 and 'Traceback' not in result.stderr
    errors = [x for x in result.stderr.splitlines() if x.startswith('ERROR: ')]
    assert len(errors) == 1 and f'--params-file {path}' in errors[0], result.stderr
    assert named in errors[0], errors[0]


def test_a_bad_value_set_on_a_running_program_is_rejected_and_the_old_value_stays(
        ros, node_program):
    name = f'life_publisher_{id(ros)}'
    proc = subprocess.Popen([str(node_program('life_publisher')), '--ros-args',
                             '-r', f'__node:={name}'],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        client = AsyncParameterClient(ros.probe(), name)
        ros.spin_until(lambda: client.services_are_ready(), timeout=30.0,
                       what=f'the parameter services of {name}')

        def get():
            return ros.ask(lambda: client.get_parameters(['life.warn_s', 'life.error_s']),
                           'a get_parameters response').values

        before = get()
        # error_s above warn_s: each value is in range, the pair is not.
        result = ros.ask(lambda: client.set_parameters([Parameter('life.error_s', value=1e9)]),
                         'a set_parameters response').results
        assert not result[0].successful
        assert 'must not exceed life.warn_s' in result[0].reason
        after = get()
        assert [v.double_value for v in after] == [v.double_value for v in before]
        assert proc.poll() is None, 'the program keeps running'
    finally:
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=20)
    assert proc.returncode == 0 and 'Traceback' not in err
