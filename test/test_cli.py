"""The reducer-twin command: JSON output, and errors that read ERROR: without a traceback."""

import json
import os
from pathlib import Path
import signal
import subprocess
import sys

from cli_runs import run_cli as _run, STOP_IDS, stopped_once, STOPS
import pytest
from reducer_twin.commands.demo import is_demo_plot

T0 = 784.0   # rated torque [N*m], paper Table 3


def _console_script():
    return Path(sys.executable).parent / 'reducer-twin'


def _run_script(*args):
    """Run the installed console script (costs about a second: used for a few rows only)."""
    return subprocess.run([str(_console_script()), *args], capture_output=True, text=True,
                          timeout=120)


def _model_json(capsys, *extra):
    code, out, err = _run(['model', '--json', *extra], capsys)
    assert code == 0, err
    return json.loads(out)


def _error_lines(stderr):
    return [line for line in stderr.splitlines() if line.startswith('ERROR:')]


def test_paper_json_from_the_installed_script_has_the_three_tables():
    result = _run_script('paper', '--json')
    assert result.returncode == 0, result.stderr
    data = json.loads(result.stdout)
    assert {'table2', 'table4', 'table5'} <= set(data)
    assert len(data['table2']) == 6
    for row in data['table2']:
        assert {'hours', 'paper_mm', 'model_mm', 'rel_error'} <= set(row)
        assert abs(row['rel_error']) < 0.01
    assert data['table2'][0]['paper_mm'] == pytest.approx(0.004732318, rel=1e-12)  # Table 2
    assert 'fit, not a validation' in data['table2_fit']['note']
    t4 = data['table4']
    assert t4['ratio'] == 81.0                                      # paper Table 4
    assert t4['output_speed_deg_s'] == pytest.approx(90.0, rel=1e-12)
    assert t4['planet_speed_deg_s'] == pytest.approx(3645.0, rel=1e-12)
    assert [row['hours'] for row in data['table5']] == [1000.0 * k for k in range(1, 7)]
    assert 'Traceback' not in result.stderr


def test_model_json_from_the_installed_script_has_sane_values():
    result = _run_script('model', '--wear-um', '20', '--torque-nm', str(T0), '--json')
    assert result.returncode == 0, result.stderr
    data = json.loads(result.stdout)
    # Physics notes 4: between 2.75 (18.06 um) and 3.08 arcmin (21.99 um).
    assert 2.75 < data['lost_motion_arcmin'] < 3.08
    assert data['mean_te_arcmin'] < 0.0                  # the loaded output lags
    assert 0.0 < data['te_ripple_arcsec'] < 0.3          # physics notes 4
    assert 2 <= data['loaded_pins'] <= 2 * 21            # both discs, loaded flanks only
    # Above the no-clearance classical 4*(T/2)/(Zp*r_eff) = 440 N, below the +/+ new 1240 N.
    assert 440.0 < data['max_pin_force_n'] < 1240.0
    assert 0.3e9 < data['max_contact_pressure_pa'] < 1.2e9   # below 1.06 GPa of a new mesh
    assert data['wear_um'] == 20.0 and data['torque_nm'] == T0


def test_lost_motion_grows_0_7_to_0_95_arcmin_from_20_to_30_um(capsys):
    lm20 = _model_json(capsys, '--wear-um', '20', '--torque-nm', '784')['lost_motion_arcmin']
    lm30 = _model_json(capsys, '--wear-um', '30', '--torque-nm', '784')['lost_motion_arcmin']
    # Slope between 0.077 arcmin/um (2/r_eff, large wear) and a little more (physics notes 4).
    assert 0.70 <= lm30 - lm20 <= 0.95


def test_model_reads_a_params_file_and_set_overrides(capsys, repo_root):
    config = str(repo_root / 'config' / 'rv80e.yaml')
    base = _model_json(capsys, '--wear-um', '5', '--torque-nm', '100')
    from_file = _model_json(capsys, '--wear-um', '5', '--torque-nm', '100', '--params', config)
    assert from_file == base
    soft = _model_json(capsys, '--wear-um', '5', '--torque-nm', '100', '--params', config,
                       '--set', 'rating.contact_stiffness=2e8')
    assert soft['max_pin_force_n'] != base['max_pin_force_n']


def test_model_and_paper_print_tables_without_json(capsys):
    code, out, err = _run(['model', '--wear-um', '3', '--torque-nm', '50'], capsys)
    assert code == 0, err
    assert 'lost_motion_arcmin' in out
    code, out, err = _run(['paper'], capsys)
    assert code == 0, err
    assert 'Table 2' in out and 'Table 4' in out and 'Table 5' in out
    flat = ' '.join(out.split())
    assert 'Fitted to Table 2: rate multiplier' in flat and 'fit, not a validation' in flat


# Usage errors: argparse rejects the command line, exit 2.
USAGE_ERRORS = [
    ('missing --torque-nm', ['model', '--wear-um', '20'], '--torque-nm'),
    ('non-numeric value', ['model', '--wear-um', 'abc', '--torque-nm', '1'], 'abc'),
    ('unknown subcommand', ['frobnicate'], 'frobnicate'),
    ('unknown flag', ['model', '--wear-um', '1', '--torque-nm', '1', '--bogus'], '--bogus'),
    ('no subcommand', [], 'required'),
]

# Invalid values: the command line parses, the value is out of range, exit 1.
VALUE_ERRORS = [
    ('negative wear', ['model', '--wear-um', '-5', '--torque-nm', '100'],
     ['--wear-um', '-5', 'um', '[0, 500]']),
    ('NaN torque', ['model', '--wear-um', '5', '--torque-nm', 'nan'], ['--torque-nm', 'nan']),
    ('torque beyond 5x rated', ['model', '--wear-um', '5', '--torque-nm', '4000'],
     ['--torque-nm', '4000', 'N*m', '3920']),
    ('negative speed', ['model', '--wear-um', '5', '--torque-nm', '1', '--speed-rpm', '-3'],
     ['--speed-rpm', '-3', 'rpm']),
    ('--set out of range', ['model', '--wear-um', '5', '--torque-nm', '1',
                            '--set', 'geometry.pin_radius=-0.001'],
     ['geometry.pin_radius', '-0.001', ' m']),
    ('--set without =', ['model', '--wear-um', '5', '--torque-nm', '1',
                         '--set', 'geometry.pin_radius'], ['SECTION.NAME=VALUE']),
    ('--set not a number', ['paper', '--set', 'geometry.pin_radius=big'],
     ['geometry.pin_radius', 'big']),
    ('--set unknown name', ['paper', '--set', 'geometry.pin_diameter=0.01'],
     ['geometry.pin_diameter']),
    ('--params missing file', ['model', '--wear-um', '5', '--torque-nm', '1',
                               '--params', '/nonexistent/rv.yaml'], ['/nonexistent/rv.yaml']),
]


@pytest.mark.parametrize('argv, fragment', [row[1:] for row in USAGE_ERRORS],
                         ids=[row[0] for row in USAGE_ERRORS])
def test_usage_errors_exit_2_with_one_error_line(capsys, argv, fragment):
    code, out, err = _run(argv, capsys)
    assert code == 2
    lines = _error_lines(err)
    assert len(lines) == 1 and fragment in lines[0], err
    assert 'Traceback' not in err + out


@pytest.mark.parametrize('argv, fragments', [row[1:] for row in VALUE_ERRORS],
                         ids=[row[0] for row in VALUE_ERRORS])
def test_invalid_values_exit_1_naming_the_quantity(capsys, argv, fragments):
    code, out, err = _run(argv, capsys)
    assert code == 1
    lines = _error_lines(err)
    assert len(lines) == 1, err
    for fragment in fragments:
        assert fragment in lines[0], f'{fragment!r} missing from {lines[0]!r}'
    assert 'Traceback' not in err + out
    assert out == ''


def test_the_installed_script_returns_exit_1_on_an_invalid_value_without_a_traceback():
    # In-process rows above cover the messages; this one checks that main()'s return value
    # reaches the shell through the console script.
    result = _run_script('model', '--wear-um', '5', '--torque-nm', '4000')
    assert result.returncode == 1
    assert _error_lines(result.stderr), result.stderr
    assert 'Traceback' not in result.stderr + result.stdout


def test_a_params_file_with_a_non_mapping_reducer_key_is_an_invalid_value(capsys, tmp_path):
    path = tmp_path / 'bad.yaml'
    path.write_text('reducer: [1, 2]\n', encoding='utf-8')
    code, _, err = _run(['model', '--wear-um', '5', '--torque-nm', '1',
                         '--params', str(path)], capsys)
    assert code == 1 and _error_lines(err)


def test_the_demo_piped_prints_its_final_table_once_within_80_columns(tmp_path):
    plot = tmp_path / 'demo.png'
    result = _run_script('demo', '--joints', '2', '--hours', '1000', '--duration-s', '6',
                         '--plot', str(plot))
    assert result.returncode == 0, result.stderr
    lines = result.stdout.splitlines()    # a line of text, the table, the plot's path
    assert max(len(line) for line in lines[1:-1]) <= 80, result.stdout
    assert [line.strip() for line in lines].count('reducer_twin demo: final state') == 1
    assert lines[-2].startswith('arcmin: TE p-p, LM (lost motion); um: wear; h: RUL; ')
    assert lines[-2].rstrip().endswith(' dropped')
    assert lines[-1] == f'wear history plot: {plot}'
    assert is_demo_plot(plot), 'the plot says a demo wrote it (a later demo may replace it)'


@pytest.mark.parametrize('where', ['own file', 'directory', 'missing directory'])
def test_the_demo_refuses_a_plot_path_it_may_not_write_before_it_runs(
        tmp_path, capsys, where):
    # The plot was written at the end, over whatever file was there (a user's own
    # image), and a path in a missing directory failed after the whole run.
    own = tmp_path / 'photo.png'
    own.write_bytes(b'\x89PNG\r\n\x1a\n a user image')
    plot = {'own file': own, 'directory': tmp_path,
            'missing directory': tmp_path / 'nowhere' / 'demo.png'}[where]
    code, out, err = _run(['demo', '--plot', str(plot)], capsys)
    lines = _error_lines(err)
    assert code == 1 and len(lines) == 1 and '--plot' in lines[0], err
    assert out == '' and own.read_bytes() == b'\x89PNG\r\n\x1a\n a user image'
    assert sorted(p.name for p in tmp_path.iterdir()) == ['photo.png']


@pytest.mark.parametrize('sig, code, group', STOPS, ids=STOP_IDS)
def test_the_demo_stopped_says_so_in_one_line_and_leaves_no_state_behind(
        tmp_path, sig, code, group):
    # rclpy's own handlers shut the context down under the running callbacks: SIGTERM
    # ended in ExternalShutdownException tracebacks and exit 1, Ctrl-C printed the
    # simulator timer's traceback; each run left its state directory in TMPDIR.
    env = {**os.environ, 'TMPDIR': str(tmp_path)}
    seen = []

    def running():
        seen[:] = list(tmp_path.glob('reducer-twin-demo-*/*'))
        return bool(seen)   # the estimators have written their first states
    returncode, err = stopped_once(
        [str(_console_script()), 'demo', '--joints', '2', '--hours', '1000',
         '--duration-s', '60', '--json'], sig, running, 'a state file', env=env, group=group)
    said = 'ERROR: terminated (SIGTERM)' if sig == signal.SIGTERM else 'ERROR: interrupted'
    lines = err.splitlines()
    assert returncode == code and len(lines) == 1 and lines[0].startswith(said), err
    assert list(tmp_path.iterdir()) == [], 'the state directory is removed'


def test_the_demo_stops_its_simulator_at_the_hours_asked_and_reads_the_wear_of_those(tmp_path):
    # Real DDS in the command's own process (the README's main job, a third as long). The
    # simulator stops when its stream is complete, so the final truth is that of the hours
    # asked: left running through the drain, it stood about 700 h further at this speed and
    # the final table compared the estimate with that. The wear is read within the
    # acceptance check's 20 % from the nine windows of 20 s.
    result = _run_script('demo', '--joints', '1', '--hours', '6000', '--duration-s', '20',
                         '--json', '--plot', str(tmp_path / 'demo.png'))
    assert result.returncode == 0, result.stderr
    joint = json.loads(result.stdout)['joints']['joint_1']
    assert joint['exposure_h'] == pytest.approx(6000.0, rel=0.01)
    assert joint['dropped'] == 0 and joint['windows'] >= 8
    assert joint['wear_um'] == pytest.approx(joint['true_wear_um'], rel=0.2)
    assert is_demo_plot(tmp_path / 'demo.png')
