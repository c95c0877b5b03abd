"""
reducer-twin analyze on recordings of the third generator (bench/third_generator.py).

The generator's physics is unlike the twin's (its figures are printed by
``bench/bench_accuracy.py --generators third``); here, what the twin says about a
controller form that hides the torque: a motor torque on the ``<joint>_motor`` entries
beside motor angles divided by the ratio.
"""

import json

from bench_scripts import load
from cli_runs import analyze_process
import numpy as np
import pytest
from reducer_twin.analysis.pipeline import analyze_bag

gen = load('third_generator')


@pytest.mark.slow
def test_a_motor_torque_beside_output_angles_is_read_as_one_and_joint_units_are_named(
        tmp_path):
    # With the motor angles divided by the ratio, 'auto' took the motor entries' effort
    # for output torque; a motor torque is then 1/ratio of it and never reaches the
    # lowest torque bin: each joint was "not observed" (exit 3). Now its size says it is
    # a motor torque, read as the setting motor_effort_units: motor reads it, and said;
    # told joint units, the joints are not observed with a reason naming the setting.
    spec = gen.Spec(seed=5, kinds=('shoulder', 'forearm'), hours=60.0 / 3600.0,
                    rate_hz=250.0, start_fraction=0.5, layout='combined',
                    motor_angles='output', effort_on='motor')
    gen.generate_bag(spec, tmp_path / 'bag')

    def analyze(out, units=None):
        extra = ()
        if units is not None:
            config = tmp_path / f'{units}.yaml'
            config.write_text(f'twin:\n  motor_effort_units: {units}\n')
            extra = ('--config', str(config))
        done = analyze_process(tmp_path / 'bag', tmp_path / out, *extra)
        return done, json.loads(done.stdout)

    done, auto = analyze('auto')
    assert done.returncode == 0, done.stderr[-500:]
    assert done.stderr.count("it is read as the motor's torque, times the ratio 81") == 2
    told, motor = analyze('motor', 'motor')
    assert told.returncode == 0 and "the motor's torque" not in told.stderr
    auto.pop('messages_per_s'), motor.pop('messages_per_s')
    assert auto == motor and all(j['observed'] for j in auto['joints'].values())
    done, joint_units = analyze('joint', 'joint')
    assert done.returncode == 3, done.stderr[-500:]
    for name, joint in joint_units['joints'].items():
        assert not joint['observed'], name
        assert 'stays within' in joint['reason'], joint['reason']
        assert 'motor_effort_units' in joint['reason']


@pytest.mark.slow
def test_a_base_loaded_by_its_accelerations_alone_is_not_refused_for_its_effort(tmp_path):
    # The base swings between two points: its loads beyond twice the test torque come
    # from its accelerations and fill two or three neighbouring bins, whose widths' slope
    # the noise decides. Judged by that slope (a median of 0.025 over 5 windows), the
    # joint was refused as an effort 40 times the torque.
    spec = gen.Spec(seed=8, kinds=('base', 'shoulder', 'forearm', 'wrist'), hours=400.0,
                    aging_factor=3600.0, start_fraction=0.1)
    gen.generate_bag(spec, tmp_path / 'bag')
    done = analyze_process(tmp_path / 'bag', tmp_path / 'd')
    assert done.returncode == 0, done.stderr[-500:]
    for name, joint in json.loads(done.stdout)['joints'].items():
        assert joint['observed'] and joint['reason'] is None, (name, joint['reason'])


@pytest.mark.slow
def test_a_forearm_whose_angle_error_follows_its_gravity_torque_is_not_refused_for_its_effort(
        tmp_path):
    # The forearm's link encoder has a 1x error of 35 arcsec and gravity gives it 178 N*m,
    # which follows cos(theta): the error is odd in the torque, the window fit cannot
    # identify it, and it took three quarters off the width's slope (a median ratio of
    # 0.24). The joint was refused as an effort 4.2 times the torque; an error of the angle
    # of up to 1 arcmin may lift it to 1.3, so no verdict on the effort's units is given.
    seed = 1007
    spec = gen.Spec(seed=seed, kinds=('base', 'shoulder', 'forearm'), hours=150.0 / 3600.0,
                    aging_factor=1.0, layout='split',
                    start_fraction=float(np.random.default_rng([seed, 7]).uniform(0.05, 0.8)))
    gen.generate_bag(spec, tmp_path / 'bag')
    forearm = gen.draw_robot(seed, spec.kinds)[0][2]
    assert forearm.gravity_nm > 150.0 and abs(forearm.eccentricity_rad) > 0.5 / 3437.75
    done = analyze_process(tmp_path / 'bag', tmp_path / 'd')
    assert done.returncode == 0, done.stderr[-500:]
    joint = json.loads(done.stdout)['joints']['joint_3']
    assert joint['observed'] and joint['reason'] is None, joint['reason']
    assert joint['lost_motion_arcmin'] > 0.0


@pytest.mark.slow
def test_a_play_still_taken_up_beyond_the_test_torque_is_said_with_its_width_there(tmp_path):
    # The forearm's soft zone reaches to 6.0 % of rated, twice the 3 % test torque: its
    # lost motion (the catalogue's width at the test torque) is about half the play the
    # loaded flanks give, which is what the twin's windows read. It says so, with the width
    # at the test torque, and gives the lost motion there; the shoulder, whose knee is at
    # 2.6 %, is read right and says nothing.
    spec = gen.Spec(seed=7, kinds=('base', 'shoulder', 'forearm'), hours=300.0,
                    aging_factor=3600.0, rate_hz=1000.0, start_fraction=0.4)
    truth = gen.generate_bag(spec, tmp_path / 'bag')['joints']
    assert truth['joint_3']['knee_torque_pct'] > 5.5 > 3.0 > truth['joint_2']['knee_torque_pct']
    done = analyze_process(tmp_path / 'bag', tmp_path / 'd', '--report', tmp_path / 'report')
    assert done.returncode == 0, done.stderr[-500:]
    said = [line for line in done.stderr.splitlines() if 'narrower than the flanks' in line]
    assert len(said) == 1 and ': joint_3: ' in said[0], said
    width = float(said[0].split('is about ')[1].split(';')[0])
    assert width == pytest.approx(truth['joint_3']['lost_motion_end_arcmin'], rel=0.15)
    joints = json.loads(done.stdout)['joints']
    assert [line for line in joints['joint_3']['inputs'] if 'narrower' in line] \
        == [said[0].split(': joint_3: ', 1)[1]]
    assert not any('narrower' in line for line in joints['joint_2']['inputs'])
    figures = joints['joint_3']['soft_zone']      # the line's numbers, for programs
    assert figures['width_arcmin'] == pytest.approx(width, abs=0.006)
    assert figures['play_arcmin'] - figures['shortfall_arcmin'] == pytest.approx(
        figures['width_arcmin'])
    assert joints['joint_2']['soft_zone'] is None and joints['joint_1']['soft_zone'] is None
    reported = joints['joint_3']['lost_motion_arcmin']
    # The lost motion is given at the test torque: the play the estimate follows (3.26
    # arcmin; read as the lost motion before, +110 %) less the stream's shortfall, no
    # further than the width there; --json says how much was taken off.
    assert reported == pytest.approx(truth['joint_3']['lost_motion_end_arcmin'], rel=0.25)
    assert 0.0 < figures['taken_off_arcmin'] <= figures['shortfall_arcmin']
    assert figures['taken_off_arcmin'] == pytest.approx(figures['shortfall_arcmin']) or \
        reported == pytest.approx(figures['width_arcmin'], abs=1e-3)
    assert 'narrower than the flanks' in (tmp_path / 'report' / 'index.html').read_text()


@pytest.mark.slow
def test_a_soft_zone_found_in_one_bag_gives_the_next_bags_lost_motion_at_the_test_torque(
        tmp_path, monkeypatch):
    # The forearm above, then 20 s of it a day later: too short for its own check to say
    # the soft zone, so alone it reads its play (and is called worn out). Continued from
    # the first bag's state (as the fleet store chains them) its soft-zone check goes on
    # with the first bag's comparisons, as a restarted te_monitor's does: it says the soft
    # zone, where that evidence came from, and gives the lost motion at the test torque.
    # A state from before the check was kept (the estimator's alone) keeps the shortfall
    # found there and says so.
    runs = {}
    for k, (hours, start) in enumerate(((300.0, 0.4), (20.0, 0.41))):
        monkeypatch.setattr(gen.indep, 'START_S', gen.indep.START_S + 86400 * k)
        spec = gen.Spec(seed=7, kinds=('base', 'shoulder', 'forearm'), hours=hours,
                        aging_factor=3600.0, rate_hz=1000.0, start_fraction=start)
        truth = gen.generate_bag(spec, tmp_path / f'bag{k}')['joints']['joint_3']
        first = runs.get('first')
        older = None if first is None else {
            j: {k: v for k, v in state.items() if k != 'front'}
            for j, state in first.states.items()}
        for name, states in ((('first', None),) if k == 0 else
                             (('chained', first.states), ('older', older), ('alone', None))):
            runs[name] = analyze_bag(tmp_path / f'bag{k}', tmp_path / f'out_{name}',
                                     initial_states=states)
    true_lm = truth['lost_motion_end_arcmin']
    chained, older, alone = (runs[n].joints['joint_3'].summary()
                             for n in ('chained', 'older', 'alone'))
    assert alone['soft_zone'] is None and older['soft_zone'] is None   # not seen in 20 s
    assert alone['lost_motion_arcmin'] > 1.5 * true_lm
    for run in (chained, older):
        assert run['lost_motion_arcmin'] == pytest.approx(true_lm, rel=0.25)
    said = [line for line in chained['inputs'] if 'narrower than the flanks' in line]
    assert chained['soft_zone'] is not None and len(said) == 1
    carried = runs['first'].joints['joint_3'].summary()['soft_zone']['windows']
    assert f'; {carried} of them carried over from earlier streams of this reducer' in said[0]
    assert chained['soft_zone']['windows'] >= carried
    said = [line for line in older['inputs'] if 'an earlier recording of this' in line]
    assert len(said) == 1 and 'has not shown it yet' in said[0]
    assert not any('an earlier recording' in line or 'narrower' in line
                   for line in alone['inputs'])


@pytest.mark.slow
def test_a_short_recording_says_when_its_lost_motion_is_the_play_of_the_loaded_flanks(tmp_path):
    # 20 s at 200 Hz of a shoulder whose soft zone reaches to 6.0 % of rated: one window
    # compared its width at the test torque with the loaded flanks. The soft zone is said
    # from two, so the lost motion given is the play (4.85 arcmin for a true 2.53: "worn
    # out", with 4 250 h left); the answer now says the catalogue's lost motion may be as
    # little as the width that window gave. The forearm beside it is not observed, and
    # says nothing of the kind.
    spec = gen.Spec(seed=9030, kinds=('forearm', 'shoulder'), hours=20.0, aging_factor=3600.0,
                    start_fraction=0.8, rate_hz=200.0, layout='combined', motor_angles='raw',
                    effort_on='motor', velocity=False)
    truth = gen.generate_bag(spec, tmp_path / 'bag')['joints']['joint_2']
    done = analyze_process(tmp_path / 'bag', tmp_path / 'd')
    assert done.returncode == 3, done.stderr[-500:]        # the forearm is not observed
    joints = json.loads(done.stdout)['joints']
    shoulder = joints['joint_2']
    assert shoulder['observed'] and shoulder['soft_zone'] is None
    assert shoulder['test_torque_check'] == 'unconfirmed'
    said = [line for line in done.stderr.splitlines() if 'may be as little as' in line]
    assert len(said) == 1 and ': joint_2: ' in said[0], said
    assert said[0].split(': joint_2: ', 1)[1] in shoulder['inputs']
    width = float(said[0].split('may be as little as ')[1].split()[0])
    true = truth['lost_motion_end_arcmin']
    assert shoulder['lost_motion_arcmin'] > 1.5 * true        # the play
    assert abs(width - true) < 0.2 * true
    assert joints['joint_1']['test_torque_check'] is None
    assert not any('test torque' in line for line in joints['joint_1']['inputs'])


def test_a_wrist_whose_loads_never_leave_its_soft_zone_is_given_the_width_at_the_test_torque(
        tmp_path):
    # A wrist loaded to 61 N·m whose soft zone is taken up only at 38 N·m: every bin is in
    # the zone, the flanks' extrapolation to no load reads far below the catalogue's lost
    # motion, and its remaining life was given far too long without a word (300 h of it:
    # 0.81 arcmin for a true 2.30, P10 100 000 h for 1 880 h left). Now it is said, and the
    # lost motion given at its bins' width at the test torque less the windup.
    spec = gen.Spec(seed=17038, kinds=('wrist',), hours=60.0, aging_factor=3600.0,
                    start_fraction=0.69, rate_hz=1000.0, layout='combined',
                    motor_angles='output', effort_on='link', stamp_jitter_us=50.0)
    truth = gen.generate_bag(spec, tmp_path / 'bag')['joints']['joint_1']
    done = analyze_process(tmp_path / 'bag', tmp_path / 'd')
    assert done.returncode == 0, done.stderr[-500:]
    wrist = json.loads(done.stdout)['joints']['joint_1']
    true = truth['lost_motion_end_arcmin']
    said = [line for line in done.stderr.splitlines() if 'extrapolation to no load' in line]
    assert len(said) == 1 and said[0].startswith('WARNING: ') and ': joint_1: ' in said[0]
    assert said[0].split(': joint_1: ', 1)[1] in wrist['inputs']
    width = float(said[0].split('less the windup there (')[1].split()[0])
    read = float(said[0].split('the lost motion read from the flanks (')[1].split()[0])
    assert read < 0.75 * true                                 # the flanks' under-read
    # The lost motion is given no lower than that width, no higher either: nearer the
    # truth (given at the flanks' reading before, -37 %), and the life's interval holds it.
    given = wrist['lost_motion_arcmin']
    assert read < given <= width + 0.005
    assert abs(given - true) < abs(read - true)
    assert wrist['rul_p10_h'] <= truth['remaining_life_end_h'] <= wrist['rul_p90_h']
    # The line's figures, for a machine: --json's within_zone.
    figures = wrist['within_zone']
    assert figures['width_arcmin'] == pytest.approx(width, abs=0.005)
    assert figures['read_arcmin'] == pytest.approx(read, abs=0.005)
    assert figures['gap_arcmin'] == pytest.approx(width - read, abs=0.01)
    assert figures['slope'] > 1.0 and figures['windows'] >= 2
    assert 0.0 < figures['added_arcmin'] <= figures['gap_arcmin'] + 1e-9
    # Not compared with the flanks of higher loads, but not said to be their play either.
    assert wrist['test_torque_check'] == 'not compared'
    assert not any('no window held' in line for line in wrist['inputs'])
