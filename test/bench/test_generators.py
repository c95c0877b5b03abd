"""
What both truth generators promise (bench/independent_generator.py, bench/third_generator.py).

Each test runs on both: neither imports the twin, both write every controller form
as asked (the third without its dropped messages), and both command lines write a
bag and print its truth, or give one ``ERROR:`` line and exit 1.
"""

import ast
import json
import subprocess
import sys

from bench_scripts import BENCH, load
import numpy as np
import pytest

GENERATORS = ('independent_generator', 'third_generator')


@pytest.mark.parametrize('name', GENERATORS)
def test_the_generator_imports_nothing_from_the_twin(name):
    tree = ast.parse((BENCH / f'{name}.py').read_text())
    modules = {a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names}
    modules |= {n.module for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)}
    assert not {m for m in modules if m.split('.')[0] in ('reducer_twin', 'msg_adapters')}
    code = (f'import sys, tempfile; sys.path.insert(0, sys.argv[1]); import {name} '
            'as g; g.generate_bag(g.Spec(hours=2 / 3600, rate_hz=100), tempfile.mkdtemp() + '
            "'/b'); print(sorted(m for m in sys.modules if m.split('.')[0] in "
            "('reducer_twin', 'msg_adapters')))")
    done = subprocess.run([sys.executable, '-c', code, str(BENCH)], capture_output=True,
                          text=True, check=True)
    assert done.stdout.strip() == '[]'


@pytest.mark.parametrize('name', GENERATORS)
@pytest.mark.parametrize('layout,motor_angles,effort_on,velocity', [
    ('combined', 'raw', 'link', True),
    ('combined', 'output', 'motor', False),
    ('split', 'output', 'motor', False),
])
def test_every_controller_form_is_written_as_asked(tmp_path, rosbags_reader, name, layout,
                                                   motor_angles, effort_on, velocity):
    gen = load(name)
    spec = gen.Spec(seed=2, hours=3.0 / 3600.0, rate_hz=100.0, layout=layout,
                    motor_angles=motor_angles, effort_on=effort_on, velocity=velocity)
    stream = gen.generate(spec)
    gen.write_bag(stream, tmp_path / 'b')
    read = rosbags_reader(tmp_path / 'b')
    scale = 1.0 if motor_angles == 'raw' else 1.0 / gen.RATIO
    link = [m for _, m in read['/joint_states'][1]]
    # Messages that arrived: every one from the independent generator.
    every = np.ones(len(stream.t), dtype=bool)
    kept = getattr(stream, 'link_kept', every)
    motor_kept = getattr(stream, 'motor_kept', every)
    if layout == 'combined':
        assert '/motor_states' not in read
        np.testing.assert_array_equal(kept, motor_kept)
        assert list(link[0].name) == ['joint_1', 'joint_2', 'joint_3', 'joint_1_motor',
                                      'joint_2_motor', 'joint_3_motor']
        pos = np.array([m.position for m in link])
        np.testing.assert_array_equal(pos, np.hstack([stream.link, stream.motor * scale])[kept])
        nan = np.full_like(stream.link, np.nan)
        want = np.hstack([stream.effort, nan] if effort_on == 'link'
                         else [nan, stream.effort / gen.RATIO])
        np.testing.assert_array_equal([m.effort for m in link], want[kept])
    else:
        motor = [m for _, m in read['/motor_states'][1]]
        np.testing.assert_array_equal([m.position for m in motor],
                                      stream.motor[motor_kept] * scale)
        np.testing.assert_array_equal([m.effort for m in motor],
                                      stream.effort[motor_kept] / gen.RATIO)
        assert all(len(m.effort) == 0 for m in link)
    assert all((len(m.velocity) > 0) == velocity for m in link)


@pytest.mark.parametrize('name,keys', [
    ('independent_generator', ('lost_motion_new_arcmin', 'stiffness_nm_per_arcmin', 'law',
                               'law_exponent', 'lost_motion_end_arcmin',
                               'remaining_life_end_h')),
    ('third_generator', ('lost_motion_new_arcmin', 'knee_torque_pct', 'hysteresis_arcmin',
                         'efficiency', 'lost_motion_end_arcmin', 'remaining_life_end_h')),
])
def test_the_cli_writes_the_bag_and_prints_its_truth(tmp_path, name, keys):
    out = tmp_path / 'bag'
    done = subprocess.run([sys.executable, str(BENCH / f'{name}.py'), '--out',
                           str(out), '--seed', '9', '--hours', str(5 / 3600), '--rate-hz', '125',
                           '--kinds', 'base,forearm', '--json'],
                          capture_output=True, text=True, check=True)
    truth = json.loads(done.stdout)
    assert set(truth['joints']) == {'joint_1', 'joint_2'}
    assert truth['joints']['joint_1']['kind'] == 'base'
    for key in keys:
        assert key in truth['joints']['joint_2']
    # 5 s at 125 Hz, less the third generator's dropped messages.
    assert truth['messages']['/joint_states'] == 626 - truth.get('dropped_link', 0)
    assert (out / 'metadata.yaml').exists()
    assert [p.name for p in tmp_path.iterdir()] == ['bag']


BAD_OPTIONS = [
    (['--hours', '-1'], '--hours'),
    (['--aging-factor', '0'], '--aging-factor'),
    (['--kinds', 'base,elbowx'], '--kinds'),
    (['--rate-hz', '0.5'], '--rate-hz'),
    (['--start-fraction', '-0.1'], '--start-fraction'),
    (['--hours', '100000'], '--hours'),
]


@pytest.mark.parametrize('name,args,named', [
    *[(name, args, named) for name in GENERATORS for args, named in BAD_OPTIONS],
    ('independent_generator', ['--effort-noise', '60'], '--effort-noise'),
])
def test_bad_options_give_one_error_line_and_exit_1(tmp_path, name, args, named):
    done = subprocess.run([sys.executable, str(BENCH / f'{name}.py'), '--out',
                           str(tmp_path / 'b'), *args], capture_output=True, text=True)
    assert done.returncode == 1 and done.stdout == ''
    (line,) = done.stderr.splitlines()
    assert line.startswith('ERROR: ') and named in line and 'got' in line
    assert not (tmp_path / 'b').exists()


@pytest.mark.parametrize('name', GENERATORS)
def test_an_existing_out_is_refused_and_left_untouched(tmp_path, name):
    out = tmp_path / 'b'
    out.mkdir()
    (out / 'keep').write_text('x')
    done = subprocess.run([sys.executable, str(BENCH / f'{name}.py'), '--out',
                           str(out), '--hours', str(1 / 3600)], capture_output=True, text=True)
    assert done.returncode == 1 and 'exists' in done.stderr
    assert [p.name for p in out.iterdir()] == ['keep']
