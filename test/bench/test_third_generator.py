"""
bench/third_generator.py: recordings whose physics neither the twin nor the second generator has.

The truth is checked against what the module docstring states: the catalogue
lost motion (width of the torsional curve at +-3 % rated torque, at the middle of
the hysteresis loop, without the elastic windup) measured back from the recorded
encoders, the growth law's end at 3 arcmin, the direction-dependent efficiency
measured back from the recorded efforts, a duty that does not repeat, dropped
messages; every bag is read back with rosbags and with the mcap library. What both
generators promise (no import of the twin, every controller form, the command line) is
specified once in test_generators.py; ``split_bag`` and ``split_read`` come from conftest.py.
"""

from bench_scripts import load
import numpy as np
import pytest
import yaml

gen = load('third_generator')

ARCMIN = gen.ARCMIN
# 60 s of stream at 250 Hz from half of each life (aging factor 1: the lost motion is
# constant over the recording).
SHORT = {'seed': 11, 'kinds': ('base', 'shoulder', 'forearm'), 'hours': 60.0 / 3600.0,
         'rate_hz': 250.0, 'start_fraction': 0.5}


def test_the_catalogue_lost_motion_is_the_curve_width_at_3_percent_without_windup():
    # A quasi-static sweep to +-rated torque and back: at +-3 % rated the loading and
    # unloading branches differ by the hysteresis loss; their middle, less the elastic
    # windup 2*T/k2, is the lost motion the truth reports.
    for seed in range(8):
        (j,), _ = gen.draw_robot(seed, ('forearm',))
        rated, test = gen.RATED_TORQUE_NM, gen.TEST_TORQUE_FRACTION * gen.RATED_TORQUE_NM
        up = np.linspace(-rated, rated, 40_001)
        sweep = np.concatenate([up, up[::-1], up])
        lm = np.full(sweep.size, j.lost_motion(0.4))
        twist = j.twist(sweep, lm, gen.dahl_state(j, sweep))
        n = up.size
        loading, unloading = twist[2 * n:], twist[n:2 * n][::-1]
        at = [int(np.argmin(np.abs(up - t))) for t in (-test, test)]
        middle = 0.5 * (loading[at] + unloading[at])
        width = middle[1] - middle[0] - 2.0 * test / j.stiffness_nm_per_rad
        np.testing.assert_allclose(width, j.lost_motion(0.4), rtol=1e-3)
        zero = int(np.argmin(np.abs(up)))
        np.testing.assert_allclose(unloading[zero] - loading[zero], j.hysteresis_rad, rtol=1e-3)
        # The soft zone's stiffness k1 below the knee torque, k2 above it.
        w = j.lost_motion(0.4) / j.test_share
        k1 = 1.0 / (0.5 * w / j.knee_torque_nm + 1.0 / j.stiffness_nm_per_rad)
        inside = (np.abs(up) < 0.5 * j.knee_torque_nm)
        slope = np.polyfit(up[inside], middle_curve(j, up[inside]), 1)[0]
        np.testing.assert_allclose(1.0 / slope, k1, rtol=1e-6)


def middle_curve(joint, torque):
    """Torsional curve at the middle of the hysteresis loop, lost motion at 40 % of life."""
    lm = np.full(torque.size, joint.lost_motion(0.4))
    return joint.twist(torque, lm, np.zeros(torque.size))


def test_the_recorded_encoders_show_the_true_lost_motion_stiffness_and_hysteresis(
        split_bag, split_read):
    # The catalogue measurement on the recording: TE (encoder zeros and the known encoder
    # and mesh errors removed) against the torque at the link's latch time, fitted with
    # the soft zone, the straight line and the Dahl loop.
    _, stream, truth = split_bag
    link = np.array([m.position for _, m in split_read['/joint_states'][1]])
    motor = np.array([m.position for _, m in split_read['/motor_states'][1]])
    at_link = np.flatnonzero(stream.link_kept)
    at_motor = np.flatnonzero(stream.motor_kept)
    both = np.intersect1d(at_link, at_motor)
    link = link[np.searchsorted(at_link, both)]
    motor = motor[np.searchsorted(at_motor, both)]
    for i, j in enumerate(stream.joints):
        q, qd, qdd, u = stream.duty.motion(i, stream.t - j.link_latency_s)
        torque = gen.true_torque(j, q, qd, qdd, u)
        loop = gen.dahl_state(j, torque)[both]
        torque, q = torque[both], q[both]
        shaft = motor[:, i] - j.motor_offset_rad
        shaft -= j.motor_error_rad * np.sin(shaft + j.motor_error_phase)
        te = link[:, i] - j.link_offset_rad - j.eccentricity_rad * np.sin(
            q + j.eccentricity_phase) - j.mesh_error_rad * np.sin(
            gen.PIN_COUNT * q + j.mesh_phase) - (shaft / gen.RATIO + (q - stream.q[both, i]))
        zone = np.clip(torque / j.knee_torque_nm, -1.0, 1.0) / j.test_share
        a = np.column_stack([-0.5 * zone, -torque, 0.5 * loop, np.ones_like(torque)])
        (lm, compliance, hysteresis, _), *_ = np.linalg.lstsq(a, te, rcond=None)
        np.testing.assert_allclose(lm / ARCMIN, truth['joints'][j.name]['lost_motion_end_arcmin'],
                                   rtol=0.02)
        np.testing.assert_allclose(1.0 / compliance, j.stiffness_nm_per_rad, rtol=0.02)
        np.testing.assert_allclose(hysteresis, j.hysteresis_rad, rtol=0.05)


def test_lost_motion_runs_in_then_grows_linearly_and_reaches_3_arcmin_at_the_drawn_life():
    joints = [j for seed in range(40) for j in gen.draw_robot(seed, ('shoulder',))[0]]
    contaminated = [j for j in joints if j.contamination_factor > 1.0]
    assert 0 < len(contaminated) < len(joints)
    for j in joints:
        x = np.linspace(0.0, 1.0, 2001)
        lm = j.lost_motion(x)
        assert lm[0] == j.lost_motion_new_rad and np.all(np.diff(lm) > 0)
        np.testing.assert_allclose(j.lost_motion(1.0), 3.0 * ARCMIN, rtol=1e-12)
        # Past the run-in (10 e-foldings) the growth is linear, steeper by m after x_c.
        late = x > 10.0 * j.run_in_fraction
        slope = np.diff(lm)[late[1:]]
        xs = x[1:][late[1:]]
        before = slope[xs < j.contamination_fraction - 1e-3]
        after = slope[xs > j.contamination_fraction + 1e-3]
        if before.size > 1:
            np.testing.assert_allclose(before, before[-1], rtol=1e-3)
        if after.size and before.size:
            np.testing.assert_allclose(after[0] / before[-1], j.contamination_factor, rtol=1e-3)


def test_the_limit_comes_near_the_drawn_life_under_the_recordings_own_random_duty():
    # The drawn life is at the duty's mean exposure rate; a recording's own duty differs.
    for seed, kind in ((1, 'base'), (2, 'shoulder'), (3, 'forearm')):
        (j,), _ = gen.draw_robot(seed, (kind,))
        aging = j.life_h * 3600.0 / 1000.0
        stream = gen.generate(gen.Spec(seed=seed, kinds=(kind,), hours=1.3 * j.life_h,
                                       aging_factor=aging, rate_hz=100.0, truth_topics=False))
        eol = stream.end_of_life_h()[0]
        assert abs(eol / j.life_h - 1.0) < 0.1
        k = int(np.searchsorted(stream.hours_at(np.arange(len(stream.t))), eol))
        np.testing.assert_allclose(stream.lost_motion[k, 0], 3.0 * ARCMIN, rtol=1e-3)


def test_the_duty_never_repeats_and_the_payload_changes_between_cycles(split_bag):
    _, stream, _ = split_bag
    d = stream.duty
    assert len(np.unique(np.round(d.origin_rad, 9), axis=0)) == len(d.origin_rad)
    assert np.ptp(d.move_s) > 0.3 and np.ptp(np.diff(d.start_s) - d.move_s[:-1]) > 0.5
    changes = np.flatnonzero(np.diff(d.payload) != 0.0)
    assert changes.size >= 2
    # Some moves leave a joint still; the others reverse it or not, as the waypoints fall.
    holds = d.step_rad == 0.0
    assert holds.any() and not holds.all()
    same = []
    for steps in d.step_rad.T:
        signs = np.sign(steps[steps != 0.0])
        same.extend(signs[1:] == signs[:-1])
    assert any(same) and not all(same)


def test_the_effort_shows_the_efficiency_by_power_direction(split_bag, split_read):
    # Regressed on the recorded efforts where the joint moves: T*Kt/eta while the motor
    # drives the load, T*Kt*eta while the load drives the motor, plus the no-load torque.
    _, stream, _ = split_bag
    kept = np.flatnonzero(stream.link_kept)
    effort = np.array([m.effort for _, m in split_read['/joint_states'][1]])
    for i, j in enumerate(stream.joints):
        qd, torque = stream.qd[kept, i], stream.torque[kept, i]
        sel = np.abs(qd) > 0.1
        drive = torque * qd > 0
        a = np.column_stack([torque * drive, torque * ~drive, np.sign(qd)])[sel]
        (k_drive, k_back, no_load), *_ = np.linalg.lstsq(a, effort[sel, i], rcond=None)
        kt = j.torque_constant_scale
        np.testing.assert_allclose(k_drive, kt / j.efficiency, rtol=0.02)
        np.testing.assert_allclose(k_back, kt * j.efficiency, rtol=0.02)
        np.testing.assert_allclose(no_load, kt * j.no_load_nm, rtol=0.25)


def test_rosbags_reads_the_declared_topics_with_the_drops_the_truth_counts(split_bag, split_read):
    path, stream, truth = split_bag
    names = [f'/truth/joint_{i}' for i in (1, 2, 3)]
    assert set(split_read) == {'/joint_states', '/motor_states', *names}
    n = len(stream.t)
    assert truth['messages']['/joint_states'] == n - truth['dropped_link']
    assert truth['messages']['/motor_states'] == n - truth['dropped_motor']
    assert 0 <= truth['dropped_link'] <= 0.02 * n and 0 <= truth['dropped_motor'] <= 0.02 * n
    for topic, (con, msgs) in split_read.items():
        assert con.msgcount == len(msgs) == truth['messages'][topic]
    con, msgs = split_read['/joint_states']
    stamps = np.array([m.header.stamp.sec * 10 ** 9 + m.header.stamp.nanosec for _, m in msgs])
    np.testing.assert_array_equal(stamps, stream.link_stamp_ns[stream.link_kept])
    np.testing.assert_array_equal([m.velocity for _, m in msgs],
                                  stream.velocity[stream.link_kept])
    logs = np.array([log for log, _ in msgs])
    assert np.all(logs > stamps) and np.all(np.diff(logs) >= 0)
    meta = yaml.safe_load((path / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    assert meta['version'] == 9 and meta['storage_identifier'] == 'mcap'
    assert float(meta['custom_data'][gen.AGING_KEY]) == 1.0
    rows = np.array([m.data for _, m in split_read['/truth/joint_2'][1]])
    lm = rows[:, gen.TRUTH_FIELDS.index('lost_motion_rad')]
    np.testing.assert_allclose(lm[-1] / ARCMIN,
                               truth['joints']['joint_2']['lost_motion_end_arcmin'], rtol=1e-12)


def test_the_mcap_library_reads_every_message(split_bag, mcap_reader):
    path, stream, truth = split_bag
    counts, _, motor = mcap_reader(path, '/motor_states')
    assert counts == truth['messages']
    np.testing.assert_array_equal(motor, stream.motor[stream.motor_kept])


def test_the_same_seed_draws_the_same_recording_and_options_never_change_the_units():
    spec = gen.Spec(seed=7, kinds=('base', 'wrist'), hours=3 / 3600, rate_hz=200.0)
    a, b = gen.generate(spec), gen.generate(spec)
    for name in ('link', 'motor', 'effort', 'velocity', 'lost_motion', 'link_stamp_ns',
                 'link_kept', 'motor_kept'):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    assert a.joints == gen.draw_robot(7, ('base', 'wrist'))[0]
    assert a.joints[0] != gen.draw_robot(8, ('base', 'wrist'))[0][0]
    faster = gen.generate(gen.Spec(seed=7, kinds=('base', 'wrist'), hours=3 / 3600,
                                   rate_hz=1000.0, layout='combined'))
    assert faster.joints == a.joints
    np.testing.assert_array_equal(faster.exposure_rate, a.exposure_rate)


def test_drawn_truths_span_the_stated_ranges():
    robots = [gen.draw_robot(seed, gen.KINDS) for seed in range(40)]
    joints = [j for js, _ in robots for j in js]

    def span(values, lo, hi, spread):
        v = np.array(values)
        assert v.min() >= lo and v.max() <= hi and np.ptp(v) > spread * (hi - lo)

    span([j.lost_motion_new_rad / ARCMIN for j in joints], 0.3, 1.0, 0.8)
    span([j.stiffness_nm_per_rad * ARCMIN for j in joints], 0.8 * 196.0, 1.2 * 196.0, 0.8)
    span([j.knee_torque_nm / gen.RATED_TORQUE_NM for j in joints], 0.02, 0.06, 0.8)
    span([j.hysteresis_rad / ARCMIN for j in joints], 0.1, 0.4, 0.8)
    span([j.life_h for j in joints], 3000.0, 30000.0, 0.7)
    span([j.efficiency for j in joints], 0.70, 0.90, 0.8)
    span([j.eccentricity_rad / gen.ARCSEC for j in joints], 10.0, 40.0, 0.8)
    span([j.link_latency_s for j in joints], 0.0, 1e-3, 0.8)
    span([j.effort_noise_nm / gen.RATED_TORQUE_NM for j in joints], 0.005, 0.03, 0.8)
    assert all(j.gravity_nm == 0.0 for j in joints if j.kind == 'base')
    assert all(j.gravity_nm >= 0.3 * gen.RATED_TORQUE_NM for j in joints if j.kind == 'shoulder')
    rates = np.concatenate([r for _, r in robots])
    assert np.all(rates > 0.0)


@pytest.mark.parametrize('option', [{'law': 'linear'}, {'effort_noise_pct': 2.0}])
def test_options_this_generator_draws_itself_are_refused(option):
    with pytest.raises(gen.GeneratorError, match='not an option'):
        gen.generate(gen.Spec(hours=1 / 3600, **option))
