"""The friction and efficiency an effort carries, found and taken out of the torque."""


import numpy as np
import pytest
from reducer_twin.core.flanks import FlankPool
from reducer_twin.core.friction_fit import FrictionFit
from reducer_twin.core.simulator import JointSimulator, SimConfig
from reducer_twin.core.te_extraction import compute_te
from reducer_twin.core.transmission_error import lost_motion
from reducer_twin.core.window_analysis import WindowAnalyzer
from te_streams import analyzed, PARAMS, RATIO, simulated


def test_no_lost_motion_is_read_before_the_friction_can_be_told_from_the_load():
    # A motor current carries the motor's friction, which gives the torque near a reversal
    # the sign of the motion; until the joint has moved both ways (a fifth of the samples
    # each) the fit cannot take it out. Read then, the independent generator's first
    # windows were 0.28 arcmin off at the 90th percentile (0.10 once the friction was known).
    first = simulated(samples=2200)[1]
    analyzer = analyzed(first)
    assert analyzer.fit.windows_friction_unknown == 1 and analyzer.windows_observed == 0
    assert analyzer.not_observed_reason().startswith(
        'the friction in the effort could not yet be told from the load')
    # Once the joint has moved both ways, its windows are read.
    analyzer = analyzed(simulated(samples=4400)[1])
    assert analyzer.windows_observed >= 1 and analyzer.not_observed_reason() is None
    # An effort declared free of friction (friction=False: a torque sensor) is read at once.
    analyzer = analyzed(first, friction=False)
    assert analyzer.fit.windows_friction_unknown == 0 and analyzer.windows_observed == 1


def test_friction_the_effort_carries_is_identified_and_taken_out_of_the_torque():
    # A motor current also pays the motor's and first stage's friction, which the cycloid
    # mesh does not transmit (on the independent generator's unloaded joints it made the
    # lost motion read 60-80 % low: test/analysis/test_independent_truth.py). Here: the
    # friction is found from the effort alone and the lost motion stays right.
    cfg = SimConfig(load='gravity', load_torque_nm=470.0, effort_noise_nm=15.7,
                    rate_hz=500.0, initial_wear_m=10e-6, aging_factor=0.0, exact_mesh=False,
                    seed=3)
    b = JointSimulator(PARAMS, cfg).step(60000)
    coulomb, viscous = 20.0, 15.0
    effort = b.effort + coulomb * np.tanh(b.link_velocity / 0.02) + viscous * b.link_velocity
    stream = compute_te(b.t, b.motor_angle, b.t, b.link_angle, RATIO, max_gap_s=0.05)
    analyzer = WindowAnalyzer(PARAMS)
    feats = analyzer.update(stream, effort, b.link_velocity) + analyzer.flush()
    assert analyzer.coulomb_friction == pytest.approx(coulomb, rel=0.2)
    assert analyzer.viscous_friction == pytest.approx(viscous, rel=0.2)
    lm = np.array([f.lost_motion for f in feats])
    assert np.median(lm[np.isfinite(lm)]) == pytest.approx(lost_motion(10e-6, PARAMS),
                                                           rel=0.05)


def _through_gearing(eta, samples):
    """Simulate a gravity-loaded joint; return it and its drive's effort at efficiency eta."""
    cfg = SimConfig(load='gravity', load_torque_nm=470.0, effort_noise_nm=7.8,
                    rate_hz=500.0, initial_wear_m=10e-6, aging_factor=0.0, exact_mesh=False,
                    seed=4)
    b = JointSimulator(PARAMS, cfg).step(samples)
    moving = np.tanh(b.link_velocity / 0.01)
    driving = np.maximum(np.sign(b.effort) * moving, 0.0)
    back = np.maximum(-np.sign(b.effort) * moving, 0.0)
    return b, b.effort * (1.0 + (1.0 / eta - 1.0) * driving - (1.0 - eta) * back)


@pytest.mark.parametrize('eta', [0.8, 0.7])
def test_a_drive_torque_through_a_gearing_of_efficiency_eta_reads_the_lost_motion_right(eta):
    # A drive reports T/eta while it drives the load and T*eta while the load drives it
    # back. Read as a constant Coulomb friction (fitted at 48-94 N*m on the third
    # generator's units), it is taken out at zero load too and bends the low torque
    # bins where the lost motion is read: 0.4-1.2 arcmin low there, and here 78 % low.
    # The fit now weighs efficiencies 1 to 0.65 as a factor of the rigid-body load and
    # divides it out.
    b, effort = _through_gearing(eta, 60000)
    stream = compute_te(b.t, b.motor_angle, b.t, b.link_angle, RATIO, max_gap_s=0.05)
    analyzer = WindowAnalyzer(PARAMS)
    feats = analyzer.update(stream, effort, b.link_velocity) + analyzer.flush()
    assert analyzer.efficiency == pytest.approx(eta, abs=0.05)
    lm = np.array([f.lost_motion for f in feats])
    assert np.median(lm[np.isfinite(lm)]) == pytest.approx(lost_motion(10e-6, PARAMS),
                                                           rel=0.03)


def test_no_friction_is_taken_out_of_an_effort_without_friction():
    _, b = simulated(samples=30000)
    analyzer = WindowAnalyzer(PARAMS)
    stream = compute_te(b.t, b.motor_angle, b.t, b.link_angle, RATIO)
    analyzer.update(stream, b.effort, b.link_velocity)
    assert analyzer.coulomb_friction < 0.005 * PARAMS.rating.rated_torque
    assert analyzer.efficiency == 1.0


def test_the_friction_taken_out_is_the_map_from_effort_to_torque_not_a_loss_at_each_load():
    # A drive of efficiency 0.75 under a load whose RMS differs from window to window (a
    # joint moving between waypoints; a base loaded by its accelerations swings more): what
    # is taken out is reported as the map, (Coulomb, viscous, RMS speed, efficiency, RMS
    # load), from which the flank pool decides whether the torque moved
    # (flanks._POOL_FRICTION_JUMP). Reported as a loss at each window's own load, it moved
    # with the load and restarted the pool at about every other window of a
    # third-generator base (8 of its 153 windows read a lost motion).
    eta = 0.75
    b, effort = _through_gearing(eta, 40000)
    starts = np.arange(0, b.t.size, 1000)
    ends = np.append(starts[1:], b.t.size)
    win = np.repeat(np.arange(starts.size), ends - starts)
    stream = compute_te(b.t, b.motor_angle, b.t, b.link_angle, RATIO, max_gap_s=0.05)
    pool = FlankPool((1, 2), np.geomspace(20.0, 800.0, 13), 784.0, 2, 1.0)
    fit = FrictionFit(PARAMS.rating.rated_torque, 20.0)
    _, _, _, taken, _ = fit.fit(effort, stream.t, pool.harmonics(stream.output_angle),
                                b.link_velocity, win, starts, ends, 5)
    later = taken[starts.size // 2:]
    assert later.shape[1] == 5
    np.testing.assert_allclose(later[:, 3], eta, atol=0.05)
    loads = later[:, 4]
    # The efficiency's loss at each window's load would differ by this much [N*m]:
    loss = 0.5 * (1.0 / eta - eta) * loads
    assert np.ptp(loss) > 0.02 * PARAMS.rating.rated_torque
    # The friction taken out does not follow the load.
    assert np.ptp(later[:, 0]) < 0.005 * PARAMS.rating.rated_torque
