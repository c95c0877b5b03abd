"""
bench/independent_generator.py: real rosbag2 bags with a truth the twin's model does not share.

Every bag is read back with rosbags and with the mcap library; the truth is checked
against the drawn ranges and against the recorded samples themselves (the lost motion is
measured back from the bag's encoders, the effort noise from its efforts). What both
generators promise (no import of the twin, every controller form, the command line) is
specified once in test_generators.py; ``split_bag`` and ``split_read`` come from conftest.py.
"""

import math

from bench_scripts import load
import numpy as np
import pytest
from rosbags.interfaces import QosDurability, QosReliability
import yaml

gen = load('independent_generator')

JOINT_STATE = 'sensor_msgs/msg/JointState'
MULTIARRAY = 'std_msgs/msg/Float64MultiArray'
# 40 s of stream at 250 Hz: 10 001 samples per topic, several duty cycles.
SHORT = {'seed': 5, 'hours': 40.0 / 3600.0, 'rate_hz': 250.0, 'start_fraction': 0.3}


def test_rosbags_reads_the_declared_topics_types_counts_and_qos(split_bag, split_read):
    path, stream, truth = split_bag
    n = len(stream.t)
    names = [f'/truth/joint_{i}' for i in (1, 2, 3)]
    assert set(split_read) == {'/joint_states', '/motor_states', *names}
    assert truth['messages']['/joint_states'] == truth['messages']['/motor_states'] == n
    for topic, (con, msgs) in split_read.items():
        assert con.msgtype == (JOINT_STATE if topic.endswith('states') else MULTIARRAY)
        assert con.msgcount == len(msgs) == truth['messages'][topic]
        (qos,) = con.ext.offered_qos_profiles
        assert qos.reliability == QosReliability.RELIABLE
        assert qos.durability == (QosDurability.VOLATILE if topic.endswith('states')
                                  else QosDurability.TRANSIENT_LOCAL)
    # A truth message every stream second and one at the end.
    assert truth['messages'][names[0]] == math.ceil(stream.t[-1]) + 1
    meta = yaml.safe_load((path / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    assert meta['version'] == 9 and meta['storage_identifier'] == 'mcap'
    assert float(meta['custom_data'][gen.AGING_KEY]) == 1.0


def test_the_mcap_library_reads_every_message_with_its_qos(split_bag, mcap_reader):
    path, stream, truth = split_bag
    counts, channels, link = mcap_reader(path, '/joint_states')
    assert counts == truth['messages']
    for channel, schema in channels:
        qos = yaml.safe_load(channel.metadata['offered_qos_profiles'])
        assert qos[0]['reliability'] == 'reliable'
        assert schema.encoding == 'ros2msg'
    np.testing.assert_array_equal(link, stream.link)


def test_messages_carry_the_generated_samples_in_receive_order(split_bag, split_read):
    _, stream, _ = split_bag
    con, msgs = split_read['/joint_states']
    assert list(msgs[0][1].name) == ['joint_1', 'joint_2', 'joint_3']
    np.testing.assert_array_equal([m.effort for _, m in msgs], stream.effort)
    np.testing.assert_array_equal([m.velocity for _, m in msgs], stream.velocity)
    stamps = np.array([m.header.stamp.sec * 10 ** 9 + m.header.stamp.nanosec for _, m in msgs])
    np.testing.assert_array_equal(stamps, stream.link_stamp_ns)
    logs = np.array([log for log, _ in msgs])
    assert np.all(logs > stamps) and np.all(np.diff(logs) >= 0)
    _, motor = split_read['/motor_states']
    np.testing.assert_array_equal([m.position for _, m in motor], stream.motor)
    assert all(len(m.velocity) == 0 and len(m.effort) == 0 for _, m in motor)


def test_stamps_are_jittered_by_the_drawn_amount_and_encoders_sample_on_the_clock(split_bag):
    _, stream, truth = split_bag
    assert 10.0 <= truth['stamp_jitter_us'] <= 50.0
    for stamp in (stream.link_stamp_ns, stream.motor_stamp_ns):
        offset = (stamp - gen.START_S * 10 ** 9) * 1e-9 - stream.t
        np.testing.assert_allclose(np.std(offset), stream.jitter_s, rtol=0.05)
    assert not np.array_equal(stream.link_stamp_ns, stream.motor_stamp_ns)


def test_the_same_seed_draws_the_same_units_and_options_never_change_them():
    a = gen.draw_robot(7, ('base', 'shoulder'))
    assert a == gen.draw_robot(7, ('base', 'shoulder'))
    assert a[0][0] != gen.draw_robot(8, ('base', 'shoulder'))[0][0]
    t1 = gen.generate(gen.Spec(seed=7, hours=2 / 3600, rate_hz=100.0, effort_noise_pct=2.0))
    t2 = gen.generate(gen.Spec(seed=7, hours=2 / 3600, rate_hz=1000.0, effort_noise_pct=1.0))
    for j1, j2 in zip(t1.joints, t2.joints):
        assert j1.lost_motion_new_rad == j2.lost_motion_new_rad
        assert j1.stiffness_nm_per_rad == j2.stiffness_nm_per_rad
        assert (j1.law, j1.life_h, j1.coulomb_nm) == (j2.law, j2.life_h, j2.coulomb_nm)
        assert (j1.effort_noise_fraction, j2.effort_noise_fraction) == (0.02, 0.01)


def test_drawn_truths_span_the_stated_ranges():
    joints = [j for seed in range(60) for j in gen.draw_robot(seed, gen.KINDS)[0]]
    lm = np.array([j.lost_motion_new_rad for j in joints]) / gen.ARCMIN
    k = np.array([j.stiffness_nm_per_rad for j in joints]) * gen.ARCMIN
    life = np.array([j.life_h for j in joints])
    noise = np.array([j.effort_noise_fraction for j in joints])
    p = np.array([j.torque_exponent for j in joints])
    assert lm.min() >= 0.3 and lm.max() <= 1.0 and np.ptp(lm) > 0.5
    assert k.min() >= 0.85 * 196.0 and k.max() <= 1.15 * 196.0 and np.ptp(k) > 40.0
    assert life.min() >= 3000.0 and life.max() <= 30000.0 and np.ptp(life) > 15000.0
    assert noise.min() >= 0.01 and noise.max() <= 0.05
    assert p.min() >= 1.0 and p.max() <= 2.5
    assert {j.law for j in joints} == set(gen.LAWS)
    concave = [j.law_exponent for j in joints if j.law == 'concave']
    assert all(0.35 <= g <= 0.75 for g in concave)
    assert all(j.law_exponent == 1.0 for j in joints if j.law == 'linear')
    assert all(j.gravity_nm == 0.0 for j in joints if j.kind == 'base')
    assert all(j.gravity_nm > 0.3 * gen.RATED_TORQUE_NM for j in joints if j.kind == 'shoulder')


def test_the_ratio_is_the_one_the_twins_catalogue_file_implies(repo_root):
    geometry = yaml.safe_load((repo_root / 'config' / 'rv80e.yaml').read_text())
    g = geometry['reducer']['geometry']
    assert gen.RATIO == 1 + g['z_planet'] / g['z_sun'] * g['z_pins']


@pytest.mark.parametrize('law', gen.LAWS)
def test_lost_motion_grows_monotonically_from_new_to_the_limit_at_the_drawn_life(law):
    joint, _ = gen.draw_robot(3, ('forearm',), law=law)
    (j,) = joint
    x = np.linspace(0.0, 1.5, 301)
    lm = j.lost_motion(x)
    assert np.all(np.diff(lm) > 0)
    assert lm[0] == j.lost_motion_new_rad
    np.testing.assert_allclose(j.lost_motion(1.0), 3.0 * gen.ARCMIN, rtol=1e-12)
    slope = np.diff(lm)
    if law == 'linear':
        np.testing.assert_allclose(slope, slope[0], rtol=1e-9)
    else:
        assert np.all(np.diff(slope) < 0)


def test_aged_recording_truth_follows_its_law_and_the_remaining_life_its_hours(tmp_path,
                                                                               rosbags_reader):
    # 1500 operating hours in 60 s of stream at 200 Hz, from 10 % of the life.
    spec = gen.Spec(seed=4, hours=1500.0, aging_factor=1500.0 * 3600.0 / 60.0, rate_hz=200.0,
                    start_fraction=0.1)
    stream = gen.generate(spec)
    gen.write_bag(stream, tmp_path / 'b')
    read = rosbags_reader(tmp_path / 'b')
    meta = yaml.safe_load((tmp_path / 'b' / 'metadata.yaml').read_text())
    aging = float(meta['rosbag2_bagfile_information']['custom_data'][gen.AGING_KEY])
    assert aging == pytest.approx(90_000.0)
    truth = stream.truth_json()
    for i, j in enumerate(stream.joints):
        rows = np.array([m.data for _, m in read[f'/truth/{j.name}'][1]])
        lm = rows[:, gen.TRUTH_FIELDS.index('lost_motion_rad')]
        hours = rows[:, gen.TRUTH_FIELDS.index('operating_hours')]
        assert np.all(np.diff(lm) >= 0) and lm[-1] > lm[0]
        np.testing.assert_allclose(hours[[0, -1]], [0.1 * j.life_h, 0.1 * j.life_h + 1500.0],
                                   rtol=1e-6)
        # The exposure of whole duty cycles is the cycle-mean rate times the time: the
        # hours the exposure is worth differ from the hours run by less than one cycle.
        exposure = rows[:, gen.TRUTH_FIELDS.index('exposure')]
        worth_h = exposure / stream.exposure_rate[i] / 3600.0
        cycle_h = stream.cycle.period_s * spec.aging_factor / 3600.0
        assert np.all(np.abs(worth_h - hours) <= cycle_h)
        np.testing.assert_allclose(lm, j.lost_motion(worth_h / j.life_h), rtol=1e-9)
        t = truth['joints'][j.name]
        assert t['remaining_life_end_h'] == pytest.approx(j.life_h - worth_h[-1], rel=1e-9)
        assert t['lost_motion_end_arcmin'] == pytest.approx(lm[-1] / gen.ARCMIN)


def test_effort_noise_has_the_drawn_standard_deviation(split_bag, split_read):
    _, stream, _ = split_bag
    effort = np.array([m.effort for _, m in split_read['/joint_states'][1]])
    for i, j in enumerate(stream.joints):
        residual = effort[:, i] - stream.torque[:, i] - gen.friction(j, stream.qd[:, i])
        np.testing.assert_allclose(np.std(residual), j.effort_noise_nm, rtol=0.03)
        assert abs(np.mean(residual)) < 4.0 * j.effort_noise_nm / math.sqrt(residual.size)


def test_band_limited_effort_noise_keeps_its_rms_and_its_band():
    # A current loop's ripple: the same RMS, nearly nothing between neighbouring samples, and
    # none of it outside the band.
    spec = gen.Spec(**{**SHORT, 'rate_hz': 1000.0, 'hours': 10.0 / 3600.0},
                    kinds=('shoulder',), effort_noise_pct=2.0, effort_noise_band_hz=(5.0, 50.0))
    stream = gen.generate(spec)
    j = stream.joints[0]
    residual = stream.effort[:, 0] - stream.torque[:, 0] - gen.friction(j, stream.qd[:, 0])
    np.testing.assert_allclose(np.std(residual), 0.02 * 784.0, rtol=0.03)
    assert np.std(np.diff(residual, 2)) < 0.2 * np.std(residual)
    spectrum = np.abs(np.fft.rfft(residual)) ** 2
    hz = np.fft.rfftfreq(residual.size, 1.0 / stream.rate_hz)
    assert spectrum[(hz > 2.0) & (hz < 70.0)].sum() > 0.99 * spectrum[hz > 0.0].sum()
    with pytest.raises(gen.GeneratorError, match='--effort-noise-band'):
        gen.Spec(**SHORT, effort_noise_band_hz=(5.0, 200.0)).check()


def test_a_filtered_velocity_field_lags_the_motion_by_its_time_constant():
    # A drive's filtered velocity: the same motion, late by about the filter's time constant.
    spec = gen.Spec(**{**SHORT, 'rate_hz': 1000.0, 'hours': 10.0 / 3600.0},
                    kinds=('shoulder',), velocity_filter_s=0.02)
    stream = gen.generate(spec)
    fresh = gen.generate(gen.Spec(**{**SHORT, 'rate_hz': 1000.0, 'hours': 10.0 / 3600.0},
                                  kinds=('shoulder',)))
    lags = np.arange(0, 60)
    misfit = [np.mean((stream.velocity[100 + k:, 0] - fresh.velocity[100:-k or None, 0]) ** 2)
              for k in lags]
    assert 15 <= lags[int(np.argmin(misfit))] <= 21
    with pytest.raises(gen.GeneratorError, match='--velocity-filter-ms'):
        gen.Spec(**SHORT, velocity_filter_s=2.0).check()


def test_a_filtered_effort_lags_the_load_by_its_time_constant():
    # A drive's filtered torque estimate: the same effort, late by the filter's constant.
    short = {**SHORT, 'rate_hz': 1000.0, 'hours': 10.0 / 3600.0, 'effort_noise_pct': 0.0}
    stream = gen.generate(gen.Spec(**short, kinds=('shoulder',), effort_filter_s=0.03))
    fresh = gen.generate(gen.Spec(**short, kinds=('shoulder',)))
    lags = np.arange(0, 80)
    misfit = [np.mean((stream.effort[200 + k:, 0] - fresh.effort[200:-k or None, 0]) ** 2)
              for k in lags]
    assert 25 <= lags[int(np.argmin(misfit))] <= 31
    with pytest.raises(gen.GeneratorError, match='--effort-filter-ms'):
        gen.Spec(**SHORT, effort_filter_s=2.0).check()


def test_a_motor_topic_on_another_clock_is_stamped_late_and_drifts():
    # Two clocks: the motor's stamps later by the offset plus the drift's share; nothing
    # else about the recording moves.
    short = {**SHORT, 'rate_hz': 1000.0, 'hours': 10.0 / 3600.0}
    other = gen.generate(gen.Spec(**short, motor_stamp_offset_s=0.02, motor_clock_ppm=100.0))
    fresh = gen.generate(gen.Spec(**short))
    late = (other.motor_stamp_ns - fresh.motor_stamp_ns) * 1e-9
    np.testing.assert_allclose(late, 0.02 + 1e-4 * fresh.t, atol=1e-9)
    np.testing.assert_array_equal(other.link_stamp_ns, fresh.link_stamp_ns)
    np.testing.assert_array_equal(other.motor, fresh.motor)
    with pytest.raises(gen.GeneratorError, match='--motor-clock-ppm'):
        gen.Spec(**{**SHORT, 'layout': 'combined'}, motor_clock_ppm=50.0).check()


def test_effort_carries_friction_the_reducer_does_not_transmit(split_bag):
    _, stream, _ = split_bag
    for i, j in enumerate(stream.joints):
        moving = np.abs(stream.qd[:, i]) > 0.2
        excess = stream.effort[moving, i] - stream.torque[moving, i]
        direction = np.sign(stream.qd[moving, i])
        assert np.mean(excess * direction) > j.coulomb_nm


def test_the_recorded_encoders_show_the_true_lost_motion_and_stiffness(split_bag, split_read):
    # The catalogue measurement on the recording: TE at +-|T| beyond the take-up torque,
    # without the known encoder zeros and harmonics; its width at |T| is LM + 2|T|/k.
    _, stream, truth = split_bag
    link = np.array([m.position for _, m in split_read['/joint_states'][1]])
    motor = np.array([m.position for _, m in split_read['/motor_states'][1]])
    for i, j in enumerate(stream.joints):
        q = stream.q[:, i]
        te = link[:, i] - j.link_offset_rad - (motor[:, i] - j.motor_offset_rad) / gen.RATIO
        te -= j.order1_rad * np.sin(q + j.order1_phase) + j.order2_rad * np.sin(
            2.0 * q + j.order2_phase)
        torque = stream.torque[:, i]
        taken = np.abs(torque) >= j.takeup_torque_nm
        a = np.column_stack([np.where(torque < 0, 0.5, -0.5), -torque, np.ones_like(torque)])
        (lm, compliance, _), *_ = np.linalg.lstsq(a[taken], te[taken], rcond=None)
        np.testing.assert_allclose(lm / gen.ARCMIN,
                                   truth['joints'][j.name]['lost_motion_end_arcmin'], rtol=0.01)
        np.testing.assert_allclose(1.0 / compliance, j.stiffness_nm_per_rad, rtol=0.02)


def test_a_lightly_loaded_joint_rests_at_zero_torque_on_the_side_of_its_last_move(split_bag):
    _, stream, _ = split_bag
    (i,) = [k for k, j in enumerate(stream.joints) if j.kind == 'base']
    j = stream.joints[i]
    still = (stream.qd[:, i] == 0.0) & (np.cumsum(np.abs(stream.qd[:, i])) > 0)
    assert still.mean() > 0.05 and np.all(stream.torque[still, i] == 0.0)
    side = gen.play_side(j, stream.torque[:, i])[still]
    # Braking ends every move: the output keeps r of the half play on the braking side.
    np.testing.assert_allclose(np.abs(side), j.play_memory, atol=1e-12)
    if j.play_memory > 0:
        assert side.min() < 0 < side.max()
