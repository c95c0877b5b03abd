"""The joint simulator: determinism, sampling model, wear truth and time to the limit."""

import math

from hypothesis import given, settings
from hypothesis import strategies as st
import numpy as np
import pytest
from reducer_twin.core.errors import InvalidParameter
from reducer_twin.core.kinematics import total_ratio
from reducer_twin.core.params import ReducerParams
from reducer_twin.core.simulator import JointSimulator, JointTrajectory, load_torque, SimConfig
from reducer_twin.core.transmission_error import lost_motion, transmission_error
from reducer_twin.core.units import ARCMIN, ARCSEC, DEG
from reducer_twin.core.wear import integrate_wear

PARAMS = ReducerParams()
RATIO = total_ratio(PARAMS.geometry)   # 81, paper Table 4
QUIET = {'motor_noise_rad': 0.0, 'link_noise_rad': 0.0, 'velocity_noise_rad_s': 0.0,
         'effort_noise_nm': 0.0}


def fast(**kw):
    """Return a tabulated-mesh configuration (fast enough for many examples)."""
    return SimConfig(exact_mesh=False, **kw)


@settings(max_examples=15)
@given(sizes=st.lists(st.integers(0, 3000), min_size=1, max_size=6),
       profile=st.sampled_from(['robot', 'paper']))
def test_same_seed_gives_bit_identical_samples_whatever_the_step_sizes(sizes, profile):
    cfg = fast(profile=profile, aging_factor=3.6e5, seed=11)
    total = sum(sizes)
    whole = JointSimulator(PARAMS, cfg).step(total)
    sim = JointSimulator(PARAMS, cfg)
    parts = [sim.step(n) for n in sizes]
    for name in whole.__dataclass_fields__:
        joined = np.concatenate([getattr(p, name) for p in parts])
        assert np.array_equal(joined, getattr(whole, name)), name


def test_exact_mesh_samples_are_also_independent_of_the_step_sizes():
    cfg = SimConfig(aging_factor=3.6e5, seed=4)
    whole = JointSimulator(PARAMS, cfg).step(5000)
    sim = JointSimulator(PARAMS, cfg)
    parts = [sim.step(n) for n in (1, 2046, 2, 1, 2950)]
    for name in ('link_angle', 'true_te', 'true_wear', 'effort'):
        assert np.array_equal(np.concatenate([getattr(p, name) for p in parts]),
                              getattr(whole, name))


def test_different_seeds_give_different_noise_and_the_same_truth():
    a = JointSimulator(PARAMS, fast(seed=1)).step(500)
    b = JointSimulator(PARAMS, fast(seed=2)).step(500)
    assert not np.array_equal(a.effort, b.effort)
    np.testing.assert_array_equal(a.true_te, b.true_te)


@settings(max_examples=20)
@given(profile=st.sampled_from(['robot', 'paper']), load=st.sampled_from(['gravity', 'constant']),
       scale=st.floats(0.0, 50.0), aging=st.floats(0.0, 1e7), w0=st.floats(0.0, 60e-6))
def test_true_wear_is_monotone_non_decreasing_in_time(profile, load, scale, aging, w0):
    cfg = fast(profile=profile, load=load, wear_rate_scale=scale, aging_factor=aging,
               initial_wear_m=w0)
    sim = JointSimulator(PARAMS, cfg)
    wear = np.concatenate([sim.step(2500).true_wear, sim.step(2500).true_wear])
    assert wear[0] == w0
    assert np.all(np.diff(wear) >= 0.0)


def test_stamps_start_at_zero_spaced_by_one_over_the_rate():
    sim = JointSimulator(PARAMS, fast(rate_hz=500.0))
    sim.step(3)
    b = sim.step(4)
    np.testing.assert_array_equal(b.t, np.arange(3, 7) / 500.0)
    np.testing.assert_array_equal(b.exposure_s, b.t)   # aging 1 by default
    assert sim.time_s == 7 / 500.0


def test_motor_angle_is_multi_turn_and_whole_encoder_counts():
    cfg = fast(profile='paper')
    b = JointSimulator(PARAMS, cfg).step(2000)
    count = 2.0 * math.pi / cfg.motor_counts_per_rev
    counts = b.motor_angle / count
    np.testing.assert_allclose(counts, np.round(counts), atol=1e-6)
    # 2 s at 90 deg/s output is 40.5 motor turns: never wrapped.
    assert b.motor_angle[-1] > 40.0 * 2.0 * math.pi
    assert np.all(np.diff(b.motor_angle) > 0.0)


def test_link_angle_is_the_true_output_angle_sampled_after_the_time_offset():
    cfg = SimConfig(link_zero_offset_rad=0.25, initial_wear_m=7e-6, aging_factor=0.0,
                    time_offset_s=3e-4, **QUIET)
    b = JointSimulator(PARAMS, cfg).step(3000)
    half_count = math.pi / cfg.link_counts_per_rev
    assert np.abs(b.link_angle - (b.true_output_angle + 0.25)).max() <= half_count * 1.0001
    q, _, accel = JointTrajectory(cfg)(b.t + cfg.time_offset_s)
    te = transmission_error(RATIO * q, load_torque(q, accel, cfg), 7e-6, PARAMS)
    # Same model evaluated in one piece instead of blocks: equal to rounding.
    np.testing.assert_allclose(b.true_te, te, rtol=0, atol=1e-13)
    np.testing.assert_allclose(b.true_output_angle - q, b.true_te, rtol=0, atol=1e-12)


def test_tabulated_mesh_agrees_with_the_exact_mesh_within_half_an_arcsecond():
    # Mesh ripple < 0.3 arcsec (physics notes 4) plus table interpolation < 0.1 arcsec.
    exact = JointSimulator(PARAMS, SimConfig(initial_wear_m=12e-6, aging_factor=0.0)).step(6000)
    table = JointSimulator(PARAMS, fast(initial_wear_m=12e-6, aging_factor=0.0)).step(6000)
    assert np.abs(exact.true_te - table.true_te).max() < 0.5 * ARCSEC


def test_true_wear_follows_integrate_wear_with_the_hidden_scale_and_aging():
    cfg = fast(wear_rate_scale=2.5, aging_factor=7.2e5, initial_wear_m=3e-6)
    sim = JointSimulator(PARAMS, cfg)
    b = sim.step(10000)
    q, speed, accel = JointTrajectory(cfg)(b.t)
    after = integrate_wear(np.full(b.t.size, 1e-3), load_torque(q, accel, cfg), speed, PARAMS,
                           wear0=3e-6, rate_scale=2.5, aging=7.2e5)
    # Block-wise vs one cumulative sum: equal up to rounding of the sums.
    np.testing.assert_allclose(b.true_wear[1:], after[:-1], rtol=1e-9)
    assert sim.truth().wear == pytest.approx(after[-1], rel=1e-9)


@pytest.mark.parametrize('profile, load', [('robot', 'gravity'), ('paper', 'gravity'),
                                           ('robot', 'constant')])
def test_limit_time_matches_the_simulated_lost_motion_crossing_within_half_a_percent(
        profile, load):
    base = {'profile': profile, 'load': load, 'wear_rate_scale': 3.0, 'initial_wear_m': 2e-6}
    limit = JointSimulator(PARAMS, fast(**base)).limit_time_s
    # Age so that the crossing comes after 300 s of stream: about 20 robot cycles, so the
    # cycle-average rate applies to within a fraction of one cycle (0.3 %).
    cfg = fast(aging_factor=limit / 300.0, **base)
    sim = JointSimulator(PARAMS, cfg)
    truth = sim.truth()
    b = sim.step(330_000)
    k = np.searchsorted(b.true_wear, truth.wear_limit)
    assert lost_motion(b.true_wear[k], PARAMS) == pytest.approx(3.0 * ARCMIN, rel=1e-3)
    assert b.exposure_s[k] == pytest.approx(truth.limit_time_s, rel=5e-3)


def test_truth_reports_the_state_at_the_next_sample():
    cfg = fast(aging_factor=3.6e6, initial_wear_m=4e-6)
    sim = JointSimulator(PARAMS, cfg)
    first = sim.truth()
    assert first.wear == 4e-6 and first.exposure_s == 0.0 and first.time_s == 0.0
    b = sim.step(1234)
    nxt = sim.step(1)
    truth = sim.truth()
    assert truth.time_s == pytest.approx(1235e-3)
    assert truth.exposure_s == pytest.approx(1235e-3 * 3.6e6)
    assert b.true_wear[-1] <= nxt.true_wear[0] <= truth.wear
    assert truth.lost_motion == pytest.approx(lost_motion(truth.wear, PARAMS), rel=1e-12)
    assert lost_motion(truth.wear_limit, PARAMS) == pytest.approx(3.0 * ARCMIN, rel=1e-6)


def test_true_rul_is_the_limit_time_less_the_exposure():
    sim = JointSimulator(PARAMS, fast(aging_factor=1000.0), lost_motion_limit=2.0 * ARCMIN)
    sim.step(500)
    assert sim.true_rul_s() == pytest.approx(sim.limit_time_s - 0.5 * 1000.0)
    assert sim.true_rul_s(10.0) == pytest.approx(sim.limit_time_s - 1e4)
    assert sim.truth().lost_motion_limit == 2.0 * ARCMIN


def test_a_joint_that_does_not_wear_never_reaches_the_limit():
    assert JointSimulator(PARAMS, fast(wear_rate_scale=0.0)).limit_time_s == math.inf


def test_a_joint_already_past_the_limit_has_a_negative_limit_time():
    sim = JointSimulator(PARAMS, fast(initial_wear_m=40e-6))
    assert sim.limit_time_s < 0.0 and sim.true_rul_s() < 0.0


def test_paper_profile_turns_at_constant_speed_under_constant_load():
    cfg = fast(profile='paper', load='constant', load_torque_nm=784.0, **QUIET)
    b = JointSimulator(PARAMS, cfg).step(1000)
    np.testing.assert_allclose(b.link_velocity, 90.0 * DEG, rtol=1e-12)
    np.testing.assert_allclose(b.effort, 784.0, rtol=1e-12)
    np.testing.assert_allclose(np.diff(b.motor_angle) * 1000.0, 7290.0 * DEG, rtol=1e-3)


def test_robot_cycle_reverses_direction_dwells_and_reverses_the_gravity_torque():
    cfg = fast(**QUIET)
    trajectory = JointTrajectory(cfg)
    b = JointSimulator(PARAMS, cfg).step(int(trajectory.period * 1000))
    speed = b.link_velocity
    assert (speed > 0.1).any() and (speed < -0.1).any()
    assert np.count_nonzero(speed == 0.0) > 1000        # dwells: 2 s per cycle
    assert np.abs(speed).max() == pytest.approx(90.0 * DEG)
    assert b.effort.max() > 300.0 and b.effort.min() < -300.0
    q, v, a = trajectory(np.array([0.0, trajectory.period]))
    np.testing.assert_allclose(q, 0.0, atol=1e-12)     # the cycle closes


def test_reported_noise_has_the_configured_standard_deviations():
    cfg = fast(profile='paper', load='constant', effort_noise_nm=3.0, velocity_noise_rad_s=0.01)
    b = JointSimulator(PARAMS, cfg).step(20000)
    # 20000 samples: the sample std is within 3 % of the true one (5 sigma).
    assert np.std(b.effort - b.true_torque) == pytest.approx(3.0, rel=0.03)
    assert np.std(b.link_velocity - 90.0 * DEG) == pytest.approx(0.01, rel=0.03)


BAD_CONFIG = [
    ('rate_hz', 0.0, 'Hz', '(0, 100000]'),
    ('rate_hz', float('nan'), 'Hz', ''),
    ('load_torque_nm', -1.0, 'N*m', '0, 100000'),
    ('peak_speed_rad_s', 0.0, 'rad/s', '0, 20'),
    ('motor_counts_per_rev', 1000.5, '', 'whole number'),
    ('link_counts_per_rev', 0, '', '1, 1.09951e+12'),
    ('link_noise_rad', -1e-6, 'rad', '0, 0.01'),
    ('time_offset_s', 0.5, 's', '-0.01, 0.01'),
    ('wear_rate_scale', -0.1, '', '0, 10000'),
    ('aging_factor', -1.0, '', '0, 1e+09'),
    ('initial_wear_m', 2e-4, 'm', '0, 0.0001'),
    ('seed', -3, '', '0, 9.22337e+18'),
    ('seed', True, '', ''),
    ('profile', 'wave', '', "'paper', 'robot'"),
    ('load', 'spring', '', "'constant', 'gravity'"),
    ('name', '', '', 'non-empty'),
    ('exact_mesh', 'yes', '', 'True or False'),
]


@pytest.mark.parametrize('name, value, unit, allowed', BAD_CONFIG)
def test_invalid_sim_config_names_quantity_value_unit_and_range(name, value, unit, allowed):
    with pytest.raises(InvalidParameter) as err:
        SimConfig(**{name: value})
    message = str(err.value)
    assert f'sim.{name}' in message and repr(value) in message
    assert unit in message and allowed in message


@pytest.mark.parametrize('limit', [0.0, -ARCMIN, float('nan'), 'big', True])
def test_invalid_lost_motion_limit_is_rejected(limit):
    with pytest.raises(InvalidParameter, match='lost_motion_limit'):
        JointSimulator(PARAMS, fast(), lost_motion_limit=limit)


@pytest.mark.parametrize('n', [-1, 2.5, True, '10'])
def test_step_counts_must_be_whole_and_non_negative(n):
    with pytest.raises(InvalidParameter, match='samples'):
        JointSimulator(PARAMS, fast()).step(n)


def test_a_zero_step_returns_an_empty_batch_and_does_not_advance():
    sim = JointSimulator(PARAMS, fast())
    assert len(sim.step(0)) == 0 and sim.time_s == 0.0


@pytest.mark.parametrize('before, skipped, after', [
    (0, 5000, 3000), (100, 300_000, 700), (7, 2048 * 70 - 2, 9000), (2048 * 3, 4096, 1)],
    ids=['from the start', 'many passes', 'block edge', 'whole blocks'])
def test_advancing_gives_the_samples_and_truth_of_one_continuous_run(before, skipped, after):
    cfg = SimConfig(exact_mesh=False, rate_hz=1000.0, aging_factor=3600.0, seed=3)
    whole = JointSimulator(PARAMS, cfg)
    full = whole.step(before + skipped + after)
    later = JointSimulator(PARAMS, cfg)
    later.step(before)
    later.advance(skipped)
    part = later.step(after)
    for name in ('t', 'motor_angle', 'link_angle', 'link_velocity', 'effort', 'true_wear'):
        np.testing.assert_array_equal(getattr(full, name)[before + skipped:],
                                      getattr(part, name), err_msg=name)
    assert later.truth() == whole.truth()
    with pytest.raises(InvalidParameter, match='whole number'):
        later.advance(-1)
