"""
reducer-twin analyze on recordings of the independent generator (bench/independent_generator.py).

Issue 11's floor, on reducers unlike the twin's model: with an effort noise of 2 % of the
rated torque (a motor-current torque estimate) and the friction the motor current carries,
the lost motion of every joint, including the base rotation without gravity, is read
within 10 % of the truth. The recordings: three joints, link and motor on two topics, the
rate drawn among 100-1000 Hz, 150 s of stream of units at a drawn point of their lives
(aging factor 1: the lost motion is fixed over the recording). The full distribution over
random truths is printed by ``bench/bench_lost_motion.py``: these
three seeds are fixed regression cases, not evidence for the issue's 95 % floor.
"""

import dataclasses
import json
import re

from bench_scripts import load
from cli_runs import analyze_process
import numpy as np
import pytest
from reducer_twin.analysis.pipeline import analyze_bag
from reducer_twin.analysis.settings import AnalysisSettings
from reducer_twin.analysis.simulate import AGING_KEY
from reducer_twin.core.params import ReducerParams
from reducer_twin.core.te_extraction import compute_te, TIME_OFFSET_LINEAR_S
from reducer_twin.core.units import ARCSEC
from reducer_twin.core.window_analysis import WindowAnalyzer
from reducer_twin.io.bag import open_bag, write_bag_dir
from reducer_twin.msg_adapters.jointstate_cdr import JointStateBatch

gen = load('independent_generator')

SEEDS = (21, 22, 23)


@pytest.mark.slow
@pytest.mark.parametrize('seed', SEEDS)
def test_lost_motion_is_within_10_percent_of_truth_at_2_percent_effort_noise(tmp_path, seed):
    spec = gen.Spec(seed=seed, kinds=('base', 'shoulder', 'forearm'), hours=150.0 / 3600.0,
                    start_fraction=0.3, effort_noise_pct=2.0)
    truth = gen.generate_bag(spec, tmp_path / 'bag')
    done = analyze_process(tmp_path / 'bag', tmp_path / 'out')
    assert done.returncode == 0 and 'Traceback' not in done.stderr, done.stderr[-500:]
    reported = json.loads(done.stdout)['joints']
    errors = {}
    for name, t in truth['joints'].items():
        lm = reported[name].get('lost_motion_arcmin')
        true_lm = t['lost_motion_end_arcmin']
        errors[name] = (t['kind'], true_lm, lm)
    off = {name: e for name, e in errors.items()
           if e[2] is None or abs(e[2] - e[1]) > 0.10 * e[1]}
    assert not off, (f"{truth['rate_hz']:g} Hz; joint: (kind, true, reported arcmin) beyond "
                     f'10 %: {off}')


@pytest.mark.parametrize('seed', (1005, 1016))
def test_link_drag_the_reducer_carries_does_not_bias_an_unloaded_joints_lost_motion(seed):
    # The base rotation's torque is inertia plus drag of the link (cables, seals), which
    # the reducer carries. Given that exact torque as effort (no noise, no motor friction),
    # the friction identification still finds a viscous term (the drag) and takes it out:
    # where that flips the torque's sign the flank is unknown, and the harmonics are fitted
    # beyond half the lost-motion test torque, so the lost motion stays within 3 % (seed
    # 1016 read 6 % low when the subtracted drag decided flanks and bent the 1x harmonic,
    # 9 % low with the harmonics fitted from every sample whose flank is sure).
    stream = gen.generate(gen.Spec(seed=seed, kinds=('base',), hours=150.0 / 3600.0,
                                   start_fraction=0.3, effort_noise_pct=2.0))
    te = compute_te(stream.motor_stamp_ns * 1e-9, stream.motor[:, 0],
                    stream.link_stamp_ns * 1e-9, stream.link[:, 0], gen.RATIO)
    analyzer = WindowAnalyzer(ReducerParams())
    windows = analyzer.update(te, stream.torque[:, 0], stream.velocity[:, 0]) + analyzer.flush()
    assert stream.joints[0].drag_nm_s > 0.0 and analyzer.viscous_friction > 0.0
    observed = np.nanmedian([w.lost_motion for w in windows])
    assert observed == pytest.approx(stream.lost_motion[-1, 0], rel=0.03)


def bench_recording(seed, joint):
    """
    One joint of a bench_lost_motion robot (2 % effort noise, 150 s) through the window analysis.

    Returns
    -------
    tuple
        ``(stream, analyzer, windows)``.

    """
    start = float(np.random.default_rng([seed, 7]).uniform(0.05, 0.8))
    stream = gen.generate(gen.Spec(seed=seed, kinds=('base', 'shoulder', 'forearm'),
                                   hours=150.0 / 3600.0, start_fraction=start,
                                   effort_noise_pct=2.0))
    te = compute_te(stream.motor_stamp_ns * 1e-9, stream.motor[:, joint],
                    stream.link_stamp_ns * 1e-9, stream.link[:, joint], gen.RATIO)
    analyzer = WindowAnalyzer(ReducerParams())
    windows = (analyzer.update(te, stream.effort[:, joint], stream.velocity[:, joint])
               + analyzer.flush())
    return stream, analyzer, windows


@pytest.mark.parametrize('seed', (1009, 2000))
def test_the_pooled_fit_restarts_once_the_friction_of_an_unloaded_joint_is_known(seed):
    # A base rotation whose motor friction (Coulomb 3-4 % of rated torque) is most of its
    # effort: until the joint has moved both ways the friction cannot be identified, and the
    # first windows' torque carries all of it, so samples sit in the wrong flank groups. The
    # pooled harmonic fit kept them: its 1x harmonic took half the lost motion (43 arcsec
    # where the unit has 2) and the windows read 28 % high (1009) and 19 % low (2000). The
    # pool now starts afresh when the friction taken out changes by 1 % of rated torque.
    stream, analyzer, windows = bench_recording(seed, 0)
    assert analyzer.coulomb_friction > 0.02 * gen.RATED_TORQUE_NM
    observed = np.nanmedian([w.lost_motion for w in windows])
    assert observed == pytest.approx(stream.lost_motion[-1, 0], rel=0.07)


def test_a_noisy_effort_on_a_slowly_loaded_joint_is_averaged_longer_not_read_low():
    # Seed 2000's base rotation: inertia and drag, its load passes the lost-motion test
    # torque in about 0.4 s. At an effort noise of 2 % of rated torque the 0.03 s average
    # left a noise of 0.3 times the test torque: samples near it fell into the wrong bins
    # and flanks, and the harmonics of the output angle (the base accelerates at one end
    # of a move and brakes at the other) took up part of the lost motion: 6.5 % low over
    # the recording, 12 % in its last ten windows (1 % with the noise-free torque). The
    # average is lengthened until its noise is a tenth of the test torque, within half
    # the load's passage (a fast reversal keeps the short one: test_te_extraction).
    stream, _, windows = bench_recording(2000, 0)
    lm = np.array([w.lost_motion for w in windows])
    truth = stream.lost_motion[-1, 0]
    assert np.nanmedian(lm) == pytest.approx(truth, rel=0.04)
    assert np.nanmedian(lm[-10:]) == pytest.approx(truth, rel=0.07)


def test_a_joint_whose_windows_rarely_hold_both_signs_of_a_load_is_read_in_most_windows():
    # Seed 2005's forearm at 400 Hz: its torque changes sign once per move, so most 2.5 s
    # windows meet a load under one sign only. 2 of 60 windows gave a lost motion and the
    # reported value leaned on the estimator's prior (+10 to +15 %); the pooled flanks of
    # the recent windows now complete the bins of such windows.
    stream, _, windows = bench_recording(2005, 2)
    lm = np.array([w.lost_motion for w in windows])
    assert np.isfinite(lm).sum() >= 0.8 * lm.size
    assert np.nanmedian(lm) == pytest.approx(stream.lost_motion[-1, 2], rel=0.04)


@pytest.mark.parametrize('seed', (31, 2023))
def test_a_forearm_at_100_hz_reads_its_lost_motion_near_the_test_torque(seed):
    # At 100 Hz a window lasts 10 s, yet the forearm's gravity torque crosses zero at full
    # speed, so each flank of the bins below 10 % of rated torque held 5-20 samples, under
    # the 20 a flank needed: the lost motion was extrapolated from 15 % of rated torque on
    # and read 4 % high (31) and 6 % low (2023; 9 % at 2 % noise). A flank below 200 Hz
    # needs the samples of the same stream time, 10 at 100 Hz. The median of 15 windows
    # scatters by about 1 % (windows +-3-6 %): seed 31 read +0.9 % over 150 s and +2.1 %
    # over 300 s with a 0.03 s torque average, +2.2 % and +1.4 % with the lengthened one
    # (+0.8 % over 600 s with either), so the bound is 3 %, not 2 %.
    start = float(np.random.default_rng([seed, 7]).uniform(0.05, 0.8))
    stream = gen.generate(gen.Spec(seed=seed, kinds=('base', 'shoulder', 'forearm'),
                                   hours=150.0 / 3600.0, start_fraction=start,
                                   effort_noise_pct=1.0, rate_hz=100.0))
    te = compute_te(stream.motor_stamp_ns * 1e-9, stream.motor[:, 2],
                    stream.link_stamp_ns * 1e-9, stream.link[:, 2], gen.RATIO, max_gap_s=0.05)
    analyzer = WindowAnalyzer(ReducerParams())
    windows = analyzer.update(te, stream.effort[:, 2], stream.velocity[:, 2]) + analyzer.flush()
    observed = [w for w in windows if np.isfinite(w.lost_motion)]
    near = [w.hysteresis_torque.min() < 0.1 * gen.RATED_TORQUE_NM for w in observed]
    assert len(observed) >= 12 and np.mean(near) >= 0.4
    assert np.median([w.lost_motion for w in observed]) == pytest.approx(
        stream.lost_motion[-1, 2], rel=0.03)


@pytest.mark.parametrize('seed', (44, 46))
def test_a_unit_whose_spring_is_straight_above_its_takeup_is_read_without_the_models_bend(seed):
    # The generator's hysteresis is straight above the take-up torque; the model's contacts
    # stiffen with the load, so its curve bends most on units of little lost motion. Read
    # along the model's curve, units of 0.6-0.8 arcmin came out 5-6 % off (44: base +5 %,
    # shoulder -5 %; 46: base +6 %) with the true torque as effort and exact stamps, the
    # window fit alone. The fit now weighs a straight curve against the model's.
    stream = gen.generate(gen.Spec(seed=seed, kinds=('base', 'shoulder', 'forearm'),
                                   hours=60.0 / 3600.0, start_fraction=0.05,
                                   effort_noise_pct=1.0, stamp_jitter_us=0.0, rate_hz=500.0))
    errors = {}
    for joint in range(3):
        te = compute_te(stream.motor_stamp_ns * 1e-9, stream.motor[:, joint],
                        stream.link_stamp_ns * 1e-9, stream.link[:, joint], gen.RATIO)
        analyzer = WindowAnalyzer(ReducerParams())
        windows = (analyzer.update(te, stream.torque[:, joint], stream.velocity[:, joint])
                   + analyzer.flush())
        observed = np.nanmedian([w.lost_motion for w in windows])
        errors[stream.joints[joint].kind] = observed / stream.lost_motion[-1, joint] - 1.0
    assert all(abs(e) <= 0.03 for e in errors.values()), errors


def test_analyze_says_it_pairs_the_generators_jittered_stamps_by_controller_tick(tmp_path):
    # The generator samples both encoders on the tick and jitters each topic's stamps by
    # 10-50 µs: the analysis finds that from the data and says so per joint; pairing by
    # tick rejects nothing (a fact, not a fault).
    spec = gen.Spec(seed=2023, kinds=('base', 'forearm'), hours=20.0 / 3600.0,
                    start_fraction=0.3, effort_noise_pct=1.0)
    gen.generate_bag(spec, tmp_path / 'bag')
    done = analyze_process(tmp_path / 'bag', tmp_path / 'out')
    assert done.returncode == 0, done.stderr[-500:]
    for name, joint in json.loads(done.stdout)['joints'].items():
        assert joint['pairing'].startswith('tick: the stamps of one controller tick differ by '
                                           'jitter'), (name, joint['pairing'])
        assert joint['rejected'] == 0


def test_an_effort_held_between_slower_updates_reads_like_the_fresh_one(tmp_path):
    # A drive's 100 Hz current loop on a 1 kHz stream: the effort repeats 9 samples in 10
    # and hid its noise from the window analysis; the base joint's wear read 32 % low and
    # the shoulder's effort was refused as "about 4 times the torque".
    spec = gen.Spec(seed=4, kinds=('base', 'shoulder'), hours=150.0, aging_factor=3600.0,
                    start_fraction=0.5, layout='combined', rate_hz=1000.0)
    gen.generate_bag(spec, tmp_path / 'bag')
    with open_bag(tmp_path / 'bag') as bag:
        js = bag.read_joint_states()['/joint_states']
    held = js.effort[(np.arange(len(js)) // 10) * 10]
    write_bag_dir(tmp_path / 'held', {'/joint_states': JointStateBatch(
        js.stamps_ns, js.names, js.position, js.velocity, held)},
        custom_data={AGING_KEY: repr(3600.0)})
    settings = AnalysisSettings(aging_factor=3600.0)
    fresh = analyze_bag(tmp_path / 'bag', tmp_path / 'd1', settings)
    got = analyze_bag(tmp_path / 'held', tmp_path / 'd2', settings)
    for joint, res in fresh.joints.items():
        want = res.summary()
        assert want['observed'], joint
        held_joint = got.joints[joint]
        assert held_joint.summary()['observed'], (joint, held_joint.reason)
        assert held_joint.summary()['wear_um'] == pytest.approx(want['wear_um'], rel=0.05)
        assert held_joint.summary()['lost_motion_arcmin'] == pytest.approx(
            want['lost_motion_arcmin'], rel=0.03)


@pytest.fixture(scope='module')
def split_1khz(tmp_path_factory):
    """Write a split recording of three joints at 1 kHz, 2 % effort noise; its truth, topics."""
    root = tmp_path_factory.mktemp('split')
    spec = gen.Spec(seed=1, hours=150.0 / 3600.0, start_fraction=0.4, effort_noise_pct=2.0,
                    layout='split', rate_hz=1000.0)
    truth = gen.generate_bag(spec, root / 'bag')
    with open_bag(root / 'bag') as bag:
        return truth, bag.read_joint_states()


def _assert_within_5_percent(truth, got):
    for name, t in truth['joints'].items():
        summary = got.joints[name].summary()
        assert summary['observed'], (name, got.joints[name].reason)
        assert summary['lost_motion_arcmin'] == pytest.approx(t['lost_motion_end_arcmin'],
                                                              rel=0.05), name


@pytest.mark.parametrize('step', [0.005, 0.02])
def test_a_link_encoder_re_homed_halfway_reads_like_one_that_was_not(tmp_path, split_1khz, step):
    # The link's offset steps by 17 or 69 arcmin halfway through (re-homed, or its offset
    # changed): the flank pool starts afresh at the step. Below 0.01 rad it did not, and
    # the forearm read 24 % high at 0.005 rad.
    truth, js = split_1khz
    link = js['/joint_states']
    position = link.position.copy()
    position[len(position) // 2:] += step
    write_bag_dir(tmp_path / 'rehomed', {
        '/joint_states': JointStateBatch(link.stamps_ns, link.names, position, link.velocity,
                                         link.effort),
        '/motor_states': js['/motor_states']})
    got = analyze_bag(tmp_path / 'rehomed', tmp_path / 'out')
    _assert_within_5_percent(truth, got)
    # The step is said: at the link of every joint, seen in the windows' means.
    said = [w.message for w in got.warnings if "transmission error's constant stepped" in
            w.message]
    assert len(said) == len(truth['joints']), said
    assert all('s into the stream' in line for line in said)


@pytest.mark.parametrize('offset_ms', [10, 50, -20])
def test_a_motor_topic_stamped_milliseconds_apart_is_learnt_and_said(tmp_path, split_1khz,
                                                                     offset_ms):
    # Link and motor on two topics, the motor's stamped a control cycle of a 100 Hz loop
    # late (or early): the TE then follows the speed (34 arcmin at 1 rad/s for 10 ms). The
    # window means moved by 50 arcmin from one window to the next; taken for a new TE
    # constant, they kept the offset from being learnt and the base was refused as "the
    # effort has the opposite sign". At 50 ms the first windows' median missed by more
    # than a linear term and the base was refused: refined by later windows. Said.
    truth, js = split_1khz
    motor = js['/motor_states']
    late = JointStateBatch(motor.stamps_ns + offset_ms * 1_000_000, motor.names,
                           motor.position, motor.velocity, motor.effort)
    write_bag_dir(tmp_path / 'late', {'/joint_states': js['/joint_states'],
                                      '/motor_states': late})
    got = analyze_bag(tmp_path / 'late', tmp_path / 'out')
    said = '\n'.join(w.message for w in got.warnings)
    _assert_within_5_percent(truth, got)
    assert 'constant stepped' not in said      # the means follow the speed: no step
    for name in truth['joints']:
        (apart,) = re.findall(rf'{name}: the link and motor encoders are stamped ([0-9.]+) ms '
                              'apart', said)
        # Learnt to within a linear term of the TE (the window fits take what is left).
        assert float(apart) == pytest.approx(abs(offset_ms), abs=1e3 * TIME_OFFSET_LINEAR_S)


def test_short_bags_of_encoders_stamped_apart_are_observed_from_the_reducers_second_bag(
        tmp_path, monkeypatch):
    # A fleet's snippets of 12 s, the motor topic stamped 5 ms late: each bag spent its
    # windows learning the offset again, and every bag of the reducer was "not observed".
    # The next bag starts from the offset the last one ended with (BagResult.states, as
    # the fleet chains them) and reads its windows; the first still says why it cannot.
    states, got = None, []
    for k in range(3):
        monkeypatch.setattr(gen, 'START_S', gen.START_S + 3600)    # bags an hour apart
        spec = gen.Spec(seed=21, kinds=('shoulder', 'forearm'), hours=12.0 / 3600.0,
                        start_hours=1000.0 + 100.0 * k, rate_hz=500.0,
                        motor_stamp_offset_s=0.005)
        truth = gen.generate_bag(spec, tmp_path / f'bag{k}')['joints']
        result = analyze_bag(tmp_path / f'bag{k}', tmp_path / f'out{k}', initial_states=states)
        states = result.states
        got.append((truth, {j: r.summary() for j, r in result.joints.items()}))
        assert all(s['time_offset_s'] == pytest.approx(0.005, abs=1e-4)
                   for s in states.values())
    first = got[0][1]
    assert all(not j['observed'] and 'stamped up to 5' in j['reason'] for j in first.values())
    for truth, joints in got[1:]:
        for name, j in joints.items():
            assert j['observed'] and j['windows'] >= 4, (name, j['reason'])
            assert j['lost_motion_arcmin'] == pytest.approx(
                truth[name]['lost_motion_end_arcmin'], rel=0.1)
            assert any('carried over from the reducer' in line for line in j['inputs'])


@pytest.mark.parametrize('ppm', [20, 100])
def test_a_motor_clock_drifting_from_the_links_is_followed_and_said(tmp_path, split_1khz, ppm):
    # Two clocks that are not synchronised drift apart by a crystal's tolerance: 3 and 15 ms
    # over this 150 s. With the offset learnt once, nothing was said at 20 ppm and the
    # base was refused at 100 ppm ("the effort has the opposite sign").
    truth, js = split_1khz
    motor = js['/motor_states']
    drifting = motor.stamps_ns + ((motor.stamps_ns - motor.stamps_ns[0]) * ppm // 1_000_000)
    write_bag_dir(tmp_path / 'drift', {'/joint_states': js['/joint_states'],
                                       '/motor_states': JointStateBatch(
                                           drifting, motor.names, motor.position,
                                           motor.velocity, motor.effort)})
    got = analyze_bag(tmp_path / 'drift', tmp_path / 'out')
    _assert_within_5_percent(truth, got)
    said = '\n'.join(w.message for w in got.warnings)
    for name in truth['joints']:
        (rate,) = re.findall(rf'{name}: the link and motor encoders are stamped [0-9.]+ ms '
                             r'apart and drift by [0-9.]+ ms a minute \(([0-9]+) ppm', said)
        assert int(rate) == pytest.approx(ppm, rel=0.3), name


@pytest.mark.slow
@pytest.mark.parametrize('arcsec', [5.0, 20.0])
def test_a_noisy_link_encoder_is_read_without_a_word_of_what_it_is_not(tmp_path, monkeypatch,
                                                                       arcsec):
    # Tens of arcsec rms on the link angle (a cheap output encoder): the lost motion
    # averages it out. Before, at 20 arcsec the velocity check counted a standing joint as
    # turning and replaced each true field as "other units" (0.33-0.47 times the rate), and
    # the travel ratio read 80.58 for 81 and was said. Each joint is read within 3 % and
    # nothing is said. (At 50 arcsec a TE step is still said where there is none: README.)
    def noisy(*args, **kwargs):
        return dataclasses.replace(draw(*args, **kwargs), link_noise_rad=arcsec * ARCSEC)

    draw = gen.draw_joint
    monkeypatch.setattr(gen, 'draw_joint', noisy)
    spec = gen.Spec(seed=1, kinds=('base', 'shoulder', 'forearm'), hours=150.0 / 3600.0,
                    rate_hz=1000.0, start_fraction=0.5, effort_noise_pct=2.0)
    truth = gen.generate_bag(spec, tmp_path / 'bag')
    done = analyze_process(tmp_path / 'bag', tmp_path / 'out')
    assert done.returncode == 0, done.stderr[-500:]
    for name, joint in json.loads(done.stdout)['joints'].items():
        true = truth['joints'][name]['lost_motion_end_arcmin']
        assert joint['lost_motion_arcmin'] == pytest.approx(true, rel=0.03), name
        assert joint['inputs'] == [], (name, joint['inputs'])
