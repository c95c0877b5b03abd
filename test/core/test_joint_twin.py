"""
One joint's pipeline in the core (``reducer_twin.core.joint_twin``).

Paired samples go in, frozen results come out: window features, the wear estimate, the
remaining life and the health summary the nodes' ``/diagnostics`` and the bag analysis
both show. The pieces the nodes drive one per node (:class:`TwinFront`,
:class:`TwinBack`) give what the whole :class:`JointTwin` gives, and the defaults of a
joint's processing are one validated spec.
"""

from dataclasses import FrozenInstanceError
import json
import re

from hypothesis import given
from hypothesis import strategies as st
import numpy as np
import pytest
from reducer_twin.core.errors import InvalidParameter, StateFileError
from reducer_twin.core.joint_twin import check_topic_tokens, node_token, topic_token, TwinBack
from reducer_twin.core.joint_twin import estimate_numbers, HealthSummary, joint_topic, JointTwin
from reducer_twin.core.joint_twin import maintenance_event
from reducer_twin.core.joint_twin import TwinConfig, TwinFront
from reducer_twin.core.params import ReducerParams
from reducer_twin.core.simulator import JointSimulator, SimConfig
from reducer_twin.core.transmission_error import lost_motion
from reducer_twin.core.units import ARCMIN
from te_streams import soft_zone_swing, within_zone_swing

PARAMS = ReducerParams()
AGING = 180_000.0
"""Seconds of wear exposure per stream second (50 h of wear per second)."""

DIAGNOSTIC_KEYS = ['wear_um', 'wear_std_um', 'rate_scale', 'lost_motion_arcmin',
                   'lost_motion_std_arcmin', 'lost_motion_obs_arcmin', 'rul_p10_h',
                   'rul_p50_h', 'rul_p90_h', 'rul_p90_censored', 'catalogue_life_h',
                   'exposure_h', 'updates', 'rejected_updates', 'te_pp_arcmin',
                   'rejected_messages', 'lost_motion_limit_arcmin']
"""The key/values of a reducer's ``/diagnostics`` status, in order (README, nodes)."""


@pytest.fixture(scope='module')
def stream():
    """Twenty seconds of one simulated joint at 250 Hz, in five pieces as a node takes it."""
    sim = JointSimulator(PARAMS, SimConfig(rate_hz=250.0, aging_factor=AGING, seed=7,
                                           exact_mesh=False, load_torque_nm=940.8))
    b = sim.step(5000)
    return [(b.t[k:k + 1000], b.motor_angle[k:k + 1000], b.link_angle[k:k + 1000],
             b.effort[k:k + 1000], b.link_velocity[k:k + 1000]) for k in range(0, 5000, 1000)]


@pytest.fixture(scope='module')
def updates(stream):
    twin = JointTwin('joint_1', PARAMS, TwinConfig(aging_factor=AGING))
    out = [u for piece in stream for u in twin.update(*piece)]
    return out + twin.flush()


def test_a_joint_twin_gives_a_frozen_update_per_window(updates):
    assert len(updates) >= 4
    u = updates[-1]
    assert u.wear.status in ('accepted', 'rejected', 'recovered', 'skipped')
    assert u.wear.record['stamp_s'] == u.features.t_end == u.record['window_end_s']
    assert u.life.level in ('OK', 'WARN', 'ERROR', 'STALE')
    for frozen, field in ((u, 'wear'), (u.wear, 'status'), (u.life, 'level'),
                          (u.summary, 'wear_um'), (u.features, 'te_pp')):
        with pytest.raises(FrozenInstanceError):
            setattr(frozen, field, None)
    with pytest.raises(TypeError):
        u.wear.record['wear_m'] = 0.0          # the records are read-only views too


def test_the_pieces_one_per_node_give_what_the_whole_twin_gives(stream, updates):
    # te_monitor holds a TwinFront; wear_estimator and life_publisher the two halves of a
    # TwinBack; the bag analysis a TwinFront per joint and a TwinBack in a worker.
    front = TwinFront(PARAMS, TwinConfig(aging_factor=AGING))
    back = TwinBack(PARAMS)
    records = [front.record(f) for piece in stream for f in front.update(*piece)]
    records += [front.record(f) for f in front.flush()]
    assert [r['window_end_s'] for r in records] == [u.record['window_end_s'] for u in updates]
    for record, u in zip(records, updates):
        wear, life = back.step(record)
        assert list(wear.record) == list(u.wear.record)
        np.testing.assert_array_equal(list(wear.record.values()), list(u.wear.record.values()))
        np.testing.assert_array_equal(list(life.record.values()), list(u.life.record.values()))
        assert back.summary(wear, life).as_dict().keys() == u.summary.as_dict().keys()


def test_windows_stepped_together_give_what_each_step_gives(stream, updates):
    # The bag analysis hands a chunk's windows over at once: the estimator steps each in
    # turn and the life predictions of all are sampled together, with the same results.
    front = TwinFront(PARAMS, TwinConfig(aging_factor=AGING))
    records = [front.record(f) for piece in stream for f in front.update(*piece)]
    records += [front.record(f) for f in front.flush()]
    back = TwinBack(PARAMS)
    steps = back.step_many(records[:2]) + back.step_many(records[2:])
    assert len(steps) == len(updates)
    for (wear, life, summary), u in zip(steps, updates):
        assert wear.status == u.wear.status
        np.testing.assert_array_equal(list(wear.record.values()), list(u.wear.record.values()))
        np.testing.assert_array_equal(list(life.record.values()), list(u.life.record.values()))
        assert (life.level, life.message) == (u.life.level, u.life.message)
        assert summary == u.summary


def test_the_next_bags_back_keeps_the_soft_zone_said_before(stream):
    # A reducer's next bag starts where the last ended (BagResult.states, the fleet):
    # its windows say no soft zone until their own check has seen enough, and the lost
    # motion stays at the test torque meanwhile.
    front = TwinFront(PARAMS, TwinConfig(aging_factor=AGING))
    records = [front.record(f) for piece in stream for f in front.update(*piece)]
    back = TwinBack(PARAMS)
    for record in records[:3]:
        back.step({**record, 'soft_zone_shortfall_rad': 0.4 * ARCMIN})
    state = json.loads(json.dumps(back.state()))
    assert state['soft_zone_shortfall_rad'] == 0.4 * ARCMIN
    after = TwinBack(PARAMS)
    after.restore(state)
    wear, life = after.step(records[3])
    assert wear.record['soft_zone_shortfall_rad'] == 0.4 * ARCMIN
    # The stream that said it and then did not (the first back) follows its windows.
    ended, ended_life = back.step(records[3])
    assert ended.record['soft_zone_shortfall_rad'] == 0.0
    assert wear.record['lost_motion_rad'] == pytest.approx(
        ended.record['lost_motion_rad'] - 0.4 * ARCMIN)
    # The health summary (/diagnostics, the demo) says so beside the lost motion.
    carried = after.summary(wear, life).as_dict()
    assert carried['soft_zone_shortfall_arcmin'] == pytest.approx(0.4)
    assert 'soft_zone_shortfall_arcmin' not in back.summary(ended, ended_life).as_dict()


def test_the_health_summary_is_the_diagnostic_status_in_its_documented_order(updates):
    summary = updates[-1].summary
    level, message, values = summary.diagnostic()
    assert list(values) == DIAGNOSTIC_KEYS
    assert (level, message) == (summary.level, summary.message)
    assert values['te_pp_arcmin'] == pytest.approx(updates[-1].record['te_pp_rad']
                                                   * 10800.0 / np.pi, rel=1e-12)
    assert 'te_pp_arcmin' not in HealthSummary.of(updates[0].wear.record, updates[0].life
                                                  ).as_dict()


def test_rejected_messages_turn_an_ok_with_a_finite_life_into_a_warning(updates):
    ok = [u.summary for u in updates if u.summary.level == 'OK' and
          np.isfinite(u.summary.rul_p10_h)]
    assert ok, 'the simulated reducer is healthy'
    assert ok[-1].diagnostic(rejected_messages=3)[0] == 'WARN'
    assert ok[-1].diagnostic(rejected_messages=0)[0] == 'OK'


def test_a_twin_that_saw_no_window_says_stale_never_ok():
    wear, life = TwinBack(PARAMS).start(0.0)
    assert wear.status == 'start' and life.level == 'STALE'
    assert life.message.startswith('not observed')


def test_the_topics_of_a_joint_are_named_in_one_place():
    assert joint_topic('wrist', 'te_features') == '/reducer_twin/wrist/te_features'


@pytest.mark.parametrize('name, value, message', [
    ('window_s', 0.0, r'twin\.window_s must be in \(0, 3600\] s'),
    ('max_gap_s', -0.05, r'twin\.max_gap_s must be in \(0, 3600\] s'),
    ('aging_factor', -1.0, r'twin\.aging_factor must be in \[0, 1e\+09\]'),
    ('analysis_period_s', float('nan'), r'twin\.analysis_period_s must be'),
])
def test_a_bad_joint_setting_is_refused_naming_it(name, value, message):
    with pytest.raises(InvalidParameter, match=message):
        TwinConfig(**{name: value})


def test_an_unobserved_reducer_has_no_number_in_the_summaries_and_an_observed_one_has(updates):
    # analyze --json and the fleet's live segments say the same numbers (estimate_numbers).
    u = updates[-1]
    seen = estimate_numbers(u.wear.record, u.life.record, observed=True)
    assert seen['wear_um'] == pytest.approx(u.summary.wear_um, rel=1e-12)
    assert seen['rul_p50_h'] == pytest.approx(u.summary.rul_p50_h, rel=1e-12)
    assert set(estimate_numbers(u.wear.record, u.life.record, observed=False).values()) == {None}
    assert set(estimate_numbers({}, {}, observed=True).values()) == {None}


@pytest.mark.parametrize('joint, token', [
    ('joint_1', 'joint_1'),
    ('robot_b/joint_1', 'robot_b/joint_1'),
    ('joint-1', 'joint_1'),
    ('Joint 2', 'Joint_2'),
    ('3rd_axis', '_3rd_axis'),
    ('arm/6', 'arm/_6'),
    ('/arm//a1', 'arm/a1'),
    ('Gelenk_ä', 'Gelenk__'),
], ids=['valid', 'namespaced', 'hyphen', 'space', 'leading digit', 'digit token',
        'empty tokens', 'not ASCII'])
def test_a_joints_topic_token_is_a_valid_ros_name_and_a_valid_name_stays(joint, token):
    assert topic_token(joint) == token
    assert joint_topic(joint, 'wear') == f'/reducer_twin/{token}/wear'
    assert node_token(joint) == token.replace('/', '_')


ROS_NAME = re.compile(r'[A-Za-z_][A-Za-z0-9_]*(/[A-Za-z_][A-Za-z0-9_]*)*')


@given(st.text(min_size=1, max_size=30))
def test_any_joint_name_gives_a_topic_token_by_the_ros_2_rules(joint):
    token = topic_token(joint)
    assert ROS_NAME.fullmatch(token), token
    if ROS_NAME.fullmatch(joint):
        assert token == joint


def test_joints_that_would_share_their_topics_are_refused():
    check_topic_tokens(['joint_1', 'joint_2', 'robot_b/joint_1'])
    with pytest.raises(InvalidParameter, match="'joint-1' and 'joint_1' would publish"):
        check_topic_tokens(['joint-1', 'joint_2', 'joint_1'])


def test_windows_after_the_time_offset_is_learnt_read_as_if_it_had_been_known():
    # The calibration adds the first windows' median offset to the link stamps; the TE
    # already buffered and pooled is referred to the new stamps with it. Before, the pool
    # mixed two offsets for 15-30 windows: the next windows' fits still found 43, 38, 31 µs
    # and read their lost motion up to 0.12 arcmin high (model's simulator, 1-4 kHz).
    sim = JointSimulator(PARAMS, SimConfig(initial_wear_m=8e-6, seed=3))
    b = sim.step(40000)
    front = TwinFront(PARAMS)
    windows, calibrated_at = [], None
    for k in range(0, b.t.size, 500):
        piece = slice(k, k + 500)
        windows += front.update(b.t[piece], b.motor_angle[piece], b.link_angle[piece],
                                b.effort[piece], b.link_velocity[piece])
        if calibrated_at is None and front.calibration.applied is not None:
            calibrated_at = len(windows)
    assert front.calibration.applied == pytest.approx(sim.config.time_offset_s, abs=3e-6)
    after = windows[calibrated_at:]
    offsets = np.array([f.time_offset_s for f in after])
    assert len(after) >= 10 and np.all(np.abs(offsets[np.isfinite(offsets)]) < 2e-6)
    lm = np.array([f.lost_motion for f in after])
    np.testing.assert_allclose(lm[np.isfinite(lm)], lost_motion(8e-6, PARAMS), rtol=0.02)


@pytest.fixture(scope='module')
def unloaded_noisy():
    """Simulate an unloaded joint (no gravity) at 1 kHz, 2 % effort noise, 60 s."""
    cfg = SimConfig(load='gravity', load_torque_nm=0.0, effort_noise_nm=0.02 * 784.0,
                    rate_hz=1000.0, initial_wear_m=2e-6, aging_factor=0.0, exact_mesh=False,
                    seed=11)
    return JointSimulator(PARAMS, cfg).step(60000)


def _stamped_apart(b, offset_s):
    """Feed a front with the motor stamped ``offset_s`` late in 0.5 s pieces; its windows."""
    front, windows = TwinFront(PARAMS), []
    for k in range(0, b.t.size, 500):
        piece = slice(k, k + 500)
        stream = front.extractor.update(b.t[piece] + offset_s, b.motor_angle[piece],
                                        b.t[piece], b.link_angle[piece])
        windows += front.analyze(stream, b.effort[piece], b.link_velocity[piece])
    return front, windows


@pytest.mark.parametrize('offset_ms', [10.0, 20.0, -20.0])
def test_an_unloaded_joint_with_its_encoders_stamped_milliseconds_apart_reads_its_lost_motion(
        unloaded_noisy, offset_ms):
    # The TE's offset term is linear only in the encoders' common motion: through the play
    # the motor moves and the link does not. Windows read before the offset was removed
    # carried that into the pool and the effort check: the joint read +41 % at 10 ms and
    # was refused at 20 ms ("the effort is not the output torque"), with a TE "step" said.
    front, windows = _stamped_apart(unloaded_noisy, offset_ms * 1e-3)
    assert front.calibration.applied == pytest.approx(offset_ms * 1e-3, abs=0.2e-3)
    assert front.analyzer.effort_fault is None and front.analyzer.fit.te_step is None
    lm = np.array([f.lost_motion for f in windows])
    read = lm[np.isfinite(lm)]
    assert read.size >= 18
    assert np.median(read) == pytest.approx(lost_motion(2e-6, PARAMS), rel=0.03)
    # What was read with the offset in it gives no lost motion: none of the first five.
    assert not np.isfinite(lm[:5]).any() and front.analyzer.fit.windows_offset_unremoved > 0


def test_an_offset_within_a_linear_term_keeps_the_windows_read_before_it_was_learnt(
        unloaded_noisy):
    front, windows = _stamped_apart(unloaded_noisy, 0.0)       # the simulator's 50 µs
    assert front.calibration.settled and front.analyzer.fit.windows_offset_unremoved == 0
    assert np.isfinite([f.lost_motion for f in windows[1:5]]).all()


@pytest.mark.parametrize('offset_s', [8e-3, -8e-3], ids=['link read late', 'link read early'])
def test_a_link_read_milliseconds_off_its_stamp_reads_the_same_in_small_chunks_as_whole(
        offset_s):
    # The motor angle that far from a chunk's first or last samples lies in the chunk
    # before or after: carried over (read early) or waited for (read late), not
    # extrapolated along the end segment (alpha·delta²/2). Extrapolated, 0.1 s chunks of a
    # 20 ms offset read the lost motion 16-19 % high against the whole recording.
    sim = JointSimulator(PARAMS, SimConfig(initial_wear_m=8e-6, seed=3, time_offset_s=offset_s))
    b = sim.step(40000)

    def windows(size):
        front, found = TwinFront(PARAMS), []
        front.extractor.link_time_offset_s = offset_s     # as if learnt
        for k in range(0, b.t.size, size):
            piece = slice(k, k + size)
            found += front.update(b.t[piece], b.motor_angle[piece], b.link_angle[piece],
                                  b.effort[piece], b.link_velocity[piece])
        return found + front.flush()

    whole, pieces = windows(b.t.size), windows(100)
    assert [(f.t_start, f.samples) for f in pieces] == [(f.t_start, f.samples) for f in whole]
    lm = np.array([[f.lost_motion for f in pieces], [f.lost_motion for f in whole]])
    assert np.isfinite(lm[1]).sum() >= 10
    np.testing.assert_allclose(lm[0], lm[1], rtol=1e-3)   # the learnt µs: chunk-timed


@pytest.mark.parametrize('late_ms', [0, 20])
def test_a_link_reading_latched_late_in_its_message_is_said_by_its_velocity(late_ms):
    # The link angle older than its velocity and effort: the calibration removes the
    # encoders' offset, but the effort then stays that far from the TE (not corrected).
    sim = JointSimulator(PARAMS, SimConfig(initial_wear_m=8e-6, seed=3))
    b = sim.step(40000)
    shift = int(round(late_ms * 1e-3 / np.median(np.diff(b.t))))
    link = np.concatenate([np.full(shift, b.link_angle[0]), b.link_angle[:b.t.size - shift]])
    front = TwinFront(PARAMS)
    for k in range(0, b.t.size, 500):
        piece = slice(k, k + 500)
        front.update(b.t[piece], b.motor_angle[piece], link[piece], b.effort[piece],
                     b.link_velocity[piece])
    said = front.input_warnings().get('velocity_leads')
    if not late_ms:
        assert said is None
    else:
        (lead,) = re.findall(r'leads the link angle.s rate by ([0-9.]+) ms', said)
        assert float(lead) == pytest.approx(late_ms, abs=2.0)


def _held_link_windows(judge=True, motor_too=False, wear=8e-6):
    """Return the front and lost motions of a link (and motor) read every 4th sample at 1 kHz."""
    sim = JointSimulator(PARAMS, SimConfig(initial_wear_m=wear, seed=4))
    b = sim.step(60000)
    idx = np.arange(b.t.size)
    link = b.link_angle[idx - idx % 4]
    motor = b.motor_angle[idx - idx % 4] if motor_too else b.motor_angle
    front = TwinFront(PARAMS)
    if not judge:
        front.extractor.held = None
    windows = []
    for k in range(0, b.t.size, 500):
        piece = slice(k, k + 500)
        windows += front.update(b.t[piece], motor[piece], link[piece],
                                b.effort[piece], b.link_velocity[piece])
    lm = np.array([f.lost_motion for f in windows])
    return front, lm[np.isfinite(lm)]


def test_a_link_reading_held_between_slower_updates_is_read_at_its_updates_and_said():
    # Taken as fresh, a reading held for 4 samples is up to 3 ms old: its TE carries the
    # motion since, which the windows read as play.
    front, lm = _held_link_windows()
    truth = lost_motion(8e-6, PARAMS)
    assert lm.size >= 10
    np.testing.assert_allclose(np.median(lm), truth, rtol=0.02)
    assert 'link encoder repeats its reading' in front.extractor.held_reason
    assert 'about 250 Hz on a 1000 Hz stream' in front.extractor.held_reason
    _, as_fresh = _held_link_windows(judge=False)
    assert abs(np.median(as_fresh) / truth - 1.0) > 0.05


def test_both_readings_held_together_are_read_at_their_updates_and_said():
    # Their TE is right but as old as the update, beside a fresh effort (new units of the
    # model's simulator read 6-9 % high in an outside-in sweep of bags); read at the updates.
    front, lm = _held_link_windows(motor_too=True)
    np.testing.assert_allclose(np.median(lm), lost_motion(8e-6, PARAMS), rtol=0.02)
    assert 'link and motor encoders repeat their readings together' in \
        front.extractor.held_reason


def test_a_held_link_on_a_topic_apart_from_the_motor_is_read_at_its_updates_too():
    # Link and motor on topics of their own (stamps 20 µs apart): the link is judged against
    # the motor read at its stamps. Taken as fresh, a link held for 4 samples read 0.45 of
    # the true lost motion.
    sim = JointSimulator(PARAMS, SimConfig(initial_wear_m=8e-6, seed=4))
    b = sim.step(60000)
    idx = np.arange(b.t.size)
    link = b.link_angle[idx - idx % 4]
    t_motor = b.t + np.random.default_rng(1).normal(0.0, 20e-6, b.t.size)
    front = TwinFront(PARAMS)
    windows = []
    for k in range(0, b.t.size, 500):
        piece = slice(k, k + 500)
        stream = front.extractor.update(t_motor[piece], b.motor_angle[piece], b.t[piece],
                                        link[piece])
        windows += front.analyze(stream, b.effort[piece], b.link_velocity[piece])
    lm = np.array([f.lost_motion for f in windows])
    assert front.extractor.held.held['link']
    np.testing.assert_allclose(np.median(lm[np.isfinite(lm)]), lost_motion(8e-6, PARAMS),
                               rtol=0.02)


def _swing_stamped_apart(front, seed, offset_s, t0_s=0.0, seconds=60.0):
    """
    Return the windows of the soft-zone swing with the motor stamped ``offset_s`` late.

    :func:`te_streams.soft_zone_swing` (1.5 arcmin to a knee at 5 %) fed in 0.5-s pieces.
    """
    t, theta, omega, te, effort = soft_zone_swing(1.5, 0.05, seed=seed)
    keep = t < seconds
    t, theta, omega, te, effort = t[keep] + t0_s, theta[keep], omega[keep], te[keep], effort[keep]
    motor, windows = 81.0 * (theta - te), []
    for k in range(0, t.size, 500):
        piece = slice(k, k + 500)
        stream = front.extractor.update(t[piece] + offset_s, motor[piece], t[piece],
                                        theta[piece])
        windows += front.analyze(stream, effort[piece], omega[piece])
    return windows


@pytest.fixture(scope='module')
def learnt_front():
    """Return a front that learnt a 10-ms time offset and said a soft zone, and its state."""
    front = TwinFront(PARAMS, TwinConfig(friction_in_effort=0))
    _swing_stamped_apart(front, 0, 0.01)
    return front, json.dumps(front.state())


def test_a_front_continued_from_its_state_has_the_offset_and_the_soft_zone_from_its_first_window(
        learnt_front):
    # A te_monitor restarted without its state learns the offset again (its first windows
    # give no lost motion) and needs five standard errors over two windows to say the soft
    # zone again, while its windows carry none: the estimator gave the play meanwhile.
    learnt, state = learnt_front
    assert learnt.calibration.applied == pytest.approx(0.01, abs=1e-4)
    said = learnt.soft_zone
    assert said is not None
    front = TwinFront(PARAMS, TwinConfig(friction_in_effort=0))
    lines = front.continue_from(json.loads(state))
    assert lines[0].startswith(f'link encoder time offset {learnt.calibration.applied * 1e6:.1f}'
                               ' us carried over (checked by the next windows')
    assert 'soft-zone check continued' in lines[1] and 'said:' in lines[1]
    assert front.calibration.applied == learnt.calibration.applied and front.soft_zone == said
    windows = _swing_stamped_apart(front, 1, 0.01, t0_s=60.0, seconds=20.0)
    shortfall = np.array([w.soft_zone_shortfall for w in windows])
    np.testing.assert_allclose(shortfall, said['shortfall'], rtol=0.02)
    fresh = TwinFront(PARAMS, TwinConfig(friction_in_effort=0))
    again = _swing_stamped_apart(fresh, 1, 0.01, t0_s=60.0, seconds=20.0)
    assert not any(w.soft_zone_shortfall for w in again[:5])
    read = [np.isfinite(w.lost_motion) for w in windows]
    assert sum(read) >= sum(np.isfinite(w.lost_motion) for w in again) + 4
    assert all(read[1:])


def test_a_front_state_of_another_reducers_check_starts_the_check_afresh(learnt_front):
    state = json.loads(learnt_front[1])
    state['soft_zone']['takeup_torque_nm'] = 50.0
    front = TwinFront(PARAMS)
    lines = front.continue_from(state)
    assert 'starts afresh' in lines[-1] and 'made for another reducer (test torque 50.00' \
        in lines[-1]
    assert front.soft_zone is None and front.analyzer.fit.soft_zone.windows == 0
    assert front.calibration.carried     # the encoders are the joint's, not the reducer's


def _within_zone_windows(front, seconds, t0_s=0.0):
    """Feed ``seconds`` of a swing whose loads never leave its soft zone; return its windows."""
    t, theta, omega, te, effort = within_zone_swing(0.5, 3.0, 80.0)
    keep = t < seconds
    t, theta, omega, te, effort = t[keep] + t0_s, theta[keep], omega[keep], te[keep], effort[keep]
    windows = []
    for k in range(0, t.size, 500):
        piece = slice(k, k + 500)
        windows += front.update(t[piece], 81.0 * (theta[piece] - te[piece]), theta[piece],
                                effort[piece], omega[piece])
    return windows


def test_a_front_continued_from_its_state_gives_loads_within_a_soft_zone_their_width_at_once():
    # The within-zone check's pools are kept with the soft-zone check's: a restarted
    # te_monitor's windows carry the gap to the width at the test torque from the first,
    # where a fresh check needs two windows again (the lost motion given drops meanwhile).
    learnt = TwinFront(PARAMS, TwinConfig(friction_in_effort=0))
    _within_zone_windows(learnt, 30.0)
    said = learnt.analyzer.fit.within_zone.said
    assert said is not None and learnt.analyzer.within_zone is not None
    state = json.loads(json.dumps(learnt.state()))
    front = TwinFront(PARAMS, TwinConfig(friction_in_effort=0))
    front.continue_from(state)
    assert front.analyzer.fit.within_zone.said == said
    windows = _within_zone_windows(front, 10.0, t0_s=60.0)
    assert windows and all(w.soft_zone_shortfall < 0.0 for w in windows)
    fresh = _within_zone_windows(TwinFront(PARAMS, TwinConfig(friction_in_effort=0)), 10.0,
                                 t0_s=60.0)
    assert fresh[0].soft_zone_shortfall == 0.0
    # A state from before the check was kept continues without it.
    del state['within_zone']
    older = TwinFront(PARAMS, TwinConfig(friction_in_effort=0))
    older.continue_from(state)
    assert older.analyzer.fit.within_zone.windows == 0


@pytest.mark.parametrize('change, message', [
    (lambda s: s.update(kind='reducer_twin.estimator'), "must be 'reducer_twin.front_state'"),
    (lambda s: s['within_zone']['line'].update(S=[0.0] * 3),
     "within_zone is not its check's state: S must be 4 finite sums"),
    (lambda s: s['within_zone'].update(windows=-1), 'windows a count'),
    (lambda s: s['within_zone'].pop('read'), "within_zone is not its check's"),
    (lambda s: s['load_reach'].update(windows=True),
     "load_reach is not its check's state: last and t0 must be finite"),
    (lambda s: s.update(version=2), 'version 1'),
    (lambda s: s.update(time_offset_s='10 ms'), 'time_offset_s must be null or a finite'),
    (lambda s: s.update(time_offset_s=float('inf')), 'time_offset_s must be null or a finite'),
    (lambda s: s['soft_zone'].update(line=[0.0] * 4), "soft_zone is not a soft-zone check's"),
    (lambda s: s['soft_zone'].update(full=[float('nan')] * 6), 'finite'),
    (lambda s: s['soft_zone'].pop('standing'), "soft_zone is not a soft-zone check's"),
    (lambda s: s.update(maintenance=3), 'maintenance must be null or an event text, got 3'),
])
def test_a_broken_front_state_is_refused_naming_the_value_and_changes_nothing(
        learnt_front, change, message):
    state = json.loads(learnt_front[1])
    change(state)
    front = TwinFront(PARAMS)
    with pytest.raises(StateFileError, match=re.escape(message)):
        front.continue_from(state)
    assert front.calibration.applied is None and front.analyzer.fit.soft_zone.windows == 0
    assert front.analyzer.fit.within_zone.windows == 0
    assert front.analyzer.fit.load_reach.windows == 0


def test_a_replaced_reducer_starts_the_window_analysis_afresh_and_keeps_the_time_offset(
        learnt_front):
    # What the windows learnt of the old reducer (its soft zone above all, which the
    # estimator takes off the lost motion) must not be given to the new one; the encoders'
    # time offset is not the reducer's.
    front = TwinFront(PARAMS, TwinConfig(friction_in_effort=0))
    front.continue_from(json.loads(learnt_front[1]))
    assert front.soft_zone is not None
    event = maintenance_event([{'exposure_s': 7200.0, 'reason': 'maintenance: reducer replaced'}])
    assert event == 'maintenance event 1 after 2.000 h of operation: maintenance: reducer replaced'
    front.new_reducer(event)
    assert front.soft_zone is None and front.analyzer.fit.soft_zone.windows == 0
    assert front.calibration.applied == learnt_front[0].calibration.applied
    state = front.state()
    assert state['maintenance'] == event
    again = TwinFront(PARAMS)
    again.continue_from(json.loads(json.dumps(state)))
    assert again.maintenance == event and maintenance_event([]) is None


def test_until_the_offset_is_learnt_a_chunk_of_any_length_reads_as_short_pieces():
    # A te_monitor's backlog (a stalled executor, a burst) came as one piece: its windows
    # read after the offset was learnt within it still carried the offset into the flank
    # pool and the soft-zone check, and this 0.6-arcmin soft zone went unsaid
    # (0.52 +- 0.10 arcmin pooled).
    t, theta, omega, te, effort = soft_zone_swing(1.5, 0.05)
    rows = (t, 81.0 * (theta - te), np.interp(t - 0.004, t, theta), effort,
            np.interp(t - 0.004, t, omega))
    said = []
    for cuts in ([500, t.size], [t.size]):
        front, start = TwinFront(PARAMS, TwinConfig(friction_in_effort=0)), 0
        for end in cuts:
            front.update(*(r[start:end] for r in rows))
            start = end
        assert front.calibration.applied == pytest.approx(-0.004, abs=1e-5)
        said.append(front.soft_zone)
    assert said[0] is not None and said[1] is not None
    assert said[1]['shortfall'] == pytest.approx(said[0]['shortfall'], rel=0.01)
    assert said[1]['shortfall_sd'] == pytest.approx(said[0]['shortfall_sd'], rel=0.1)


def _refused_in_units(scale, velocity=True, motor=None):
    """
    Return the refusal of a joint whose angles are published ``scale`` times radians.

    ``motor``: the motor angles' own scale, where it differs (the velocity field is the
    link's, in the link's units).
    """
    sim = JointSimulator(PARAMS, SimConfig(profile='robot', exact_mesh=False, aging_factor=3.6e3,
                                           initial_wear_m=8e-6, seed=4))
    b = sim.step(60000)
    field = scale * b.link_velocity if velocity else np.full(b.t.size, np.nan)
    if velocity and motor is None:
        field = b.link_velocity     # a velocity in rad/s beside angles in other units
    motor = scale if motor is None else motor
    front = TwinFront(PARAMS, TwinConfig(aging_factor=3.6e3))
    for k in range(0, b.t.size, 500):
        piece = slice(k, k + 500)
        front.update(b.t[piece], motor * b.motor_angle[piece], scale * b.link_angle[piece],
                     b.effort[piece], field[piece])
    return front.refusal(front.analyzer.not_observed_reason('/joint_states'))


@pytest.mark.parametrize('unit, scale, ratio, shows', [
    ('degrees', 180.0 / np.pi, '0.01746 times', 'the motor and link encoders do not measure'),
    ('revolutions', 0.5 / np.pi, '6.283 times', 'the effort is not the output torque'),
])
def test_angles_published_in_other_units_are_refused_naming_the_units_first(
        unit, scale, ratio, shows):
    # A driver that publishes positions in degrees (or revolutions) beside a velocity in
    # rad/s: the TE is in those units. The joint was refused for what that TE shows, with
    # its causes (a frozen encoder, swapped entries; an effort in other units, with the
    # advice to set effort_scale), none of which was the case.
    reason = _refused_in_units(scale)
    assert reason.startswith(f'the angles look published in {unit}: the velocity field reads '
                             f'{ratio} the rate of the link angle')
    assert f'publish them in radians. What the transmission error in {unit} shows: {shows}' \
        in reason


@pytest.mark.parametrize('motor, link, named', [
    (1.0, 180.0 / np.pi, 'a link angle in degrees beside a motor angle in radians'),
    (0.5 / np.pi, 1.0, 'a motor angle in revolutions beside a link angle in radians'),
    (1.0, 0.5 / np.pi, 'a link angle in revolutions beside a motor angle in radians'),
])
def test_encoders_in_mixed_units_are_refused_naming_them_and_no_clock_offset(
        motor, link, named):
    # One encoder in degrees or revolutions, the other in radians: the TE grows with the
    # angle by degrees. The refusal named no ratio (the moves fell outside the travel
    # ratio's gate), and the windows' fits of that TE were learnt as the encoders being
    # stamped 40-1090 ms apart, said as a fact.
    reason = _refused_in_units(link, motor=motor)
    assert reason.startswith('the motor and link encoders do not measure the same motion')
    assert f'That is {motor / link:.4g} times the configured ratio, which {named} gives: ' \
        'publish both angles in radians (REP 103)' in reason
    assert 'stamped' not in reason


def test_a_motor_in_degrees_whose_moves_fold_into_turns_is_refused_without_a_ratio():
    # At 1 kHz such a motor moves more than half a "turn" a sample: no ratio is measured
    # (rather than a wrong one), and the causes named include angles in degrees.
    reason = _refused_in_units(1.0, motor=180.0 / np.pi)
    assert reason.endswith('a wrong reduction ratio or motor_angles, or angles in degrees or '
                           'revolutions')


def test_without_a_velocity_field_angles_in_revolutions_are_named_beside_an_effort_scale():
    # Positions in revolutions without a velocity field: the TE grows 2 pi times slower with
    # the torque, read as an effort 6.2 times the torque, and the only advice was to set
    # effort_scale; nothing in the stream tells the two apart, so both are named.
    reason = _refused_in_units(0.5 / np.pi, velocity=False)
    assert reason.startswith('the effort is not the output torque in N*m')
    assert 'so the effort reads about 6.23 times the torque' in reason
    assert reason.endswith('; or, if the effort is in N*m, the angles are published in '
                           'revolutions (a transmission error in revolutions grows 2*pi = '
                           '6.28 times slower with the torque than in radians, and reads '
                           'so): positions are read in radians (REP 103), publish them in '
                           'radians')


def test_without_a_velocity_field_a_te_of_degrees_with_the_configured_ratio_says_degrees():
    # The same positions in degrees without a velocity field: the motor still turns the
    # configured ratio times the link, so the encoders do measure one motion, in degrees.
    reason = _refused_in_units(180.0 / np.pi, velocity=False)
    assert reason.startswith('the motor and link encoders do not measure the same motion')
    assert reason.endswith('the configured ratio (81), so they do: read in degrees, a span of '
                           "5.41 is 5.67 arcmin, a reducer's. The angles look published in "
                           'degrees: publish them in radians (REP 103)')
