"""The flanks of a window's hysteresis and the harmonics pooled with them, by the simulator."""

import math

import numpy as np
import pytest
from reducer_twin.core import flanks
from reducer_twin.core.transmission_error import lost_motion, model_tables
from reducer_twin.core.units import ARCSEC
from te_streams import analyse, PARAMS, simulated


def test_a_window_whose_reversal_fell_into_its_neighbour_reads_the_pooled_flanks():
    # Windows of 2 s cut a slow cycle so that some meet their loads under one sign only:
    # 4 of 15 windows had no lost motion. The pool's flank lines (recent windows, this one
    # included) complete their bins, both flanks from the same samples.
    # The first window is read before the friction can be told from the load: none.
    _, b = simulated(wear=10e-6, samples=30000)
    lm = np.array([f.lost_motion for f in analyse(b)])
    assert np.isfinite(lm[1:]).all() and lm.size == 15
    np.testing.assert_allclose(lm[1:], lost_motion(10e-6, PARAMS), rtol=0.03)


def test_hysteresis_widths_follow_the_model_at_the_true_wear():
    _, b = simulated(wear=15e-6, samples=20000)
    tables = model_tables(PARAMS)
    for f in analyse(b):
        if f.hysteresis.size:
            model = tables.hysteresis(f.hysteresis_torque, 15e-6)
            # Unidentified 1x harmonic (8.4 arcsec) leaks in proportion to |T|: 3 % of H.
            np.testing.assert_allclose(f.hysteresis, model, rtol=0.03, atol=1.0 * ARCSEC)
            assert (f.hysteresis_std > 0.0).all()


def test_constant_speed_and_load_give_orders_but_no_lost_motion_or_time_offset():
    _, b = simulated(profile='paper', load='constant', samples=24000)
    feats = analyse(b)
    assert {f.end_reason for f in feats[:-1]} == {'revolution'}
    m = PARAMS.manufacturing
    for f in feats[:-1]:
        assert math.isnan(f.lost_motion) and math.isnan(f.lost_motion_std)
        assert math.isnan(f.time_offset_s)        # omega is constant: an offset like any other
        # Fitted against the output angle over one revolution: within 0.3 arcsec of the
        # manufacturing harmonics (mesh ripple 0.3 arcsec p-p, noise 0.2 arcsec).
        assert f.orders[1] == pytest.approx(m.order1_amplitude, abs=0.3 * ARCSEC)
        assert f.orders[2] == pytest.approx(m.order2_amplitude, abs=0.3 * ARCSEC)
        assert f.orders[40] == pytest.approx(m.crank_amplitude, abs=0.3 * ARCSEC)
        assert f.orders[39] < 0.3 * ARCSEC
        assert f.te_max >= f.te_mean >= f.te_min and f.te_pp == f.te_max - f.te_min


RATED = 784.0


def _pool_counts(friction_taken, windows=3, samples=2000, te_mean=None, offset=0.0,
                 speed_mean=None, windup_mean=None, steps=None):
    """Flank samples in the pool after each window, by what the friction fit took out."""
    te_mean = np.zeros(windows) if te_mean is None else np.asarray(te_mean)
    pool = flanks.FlankPool((1, 2), np.geomspace(20.0, 800.0, 13), RATED, 2, 1.0)
    pool._offset = offset       # as identified by earlier windows
    rng = np.random.default_rng(1)
    n = windows * samples
    theta = np.linspace(0.0, 12.0, n)
    torque = 300.0 * np.sin(np.linspace(0.0, 40.0 * np.pi, n))
    y = 1e-4 * np.sign(torque) + 1e-6 * rng.standard_normal(n)
    starts = np.arange(windows) * samples
    ends = starts + samples
    win = np.repeat(np.arange(windows), samples)
    z = pool.regressors(pool.harmonics(theta), np.full(n, 0.5), y)
    stats = pool.group_stats(z, torque, pool.bins(z, torque), win, starts, ends)
    own = stats['count'].reshape(windows, -1).sum(axis=1)
    *_, groups = pool.fit_harmonics(stats, windows, te_mean, np.zeros(windows),
                                    friction_taken, speed_mean, windup_mean)
    if steps is not None:
        steps += pool.steps
    return groups['count'].sum(axis=1), own


def test_the_pool_restarts_where_the_te_steps_not_where_the_speed_moves_it():
    # A motor turn count lost, a link encoder re-homed: the TE's constant steps and the
    # pool starts afresh. A time offset between the encoders moves the windows' means with
    # their mean speed (the regressors' speed is 0.5 rad/s here): once the pool has
    # identified the offset, that share is not a step (10 ms: 5 mrad a window).
    for step in (0.005, 0.02):
        said = []
        pooled, own = _pool_counts(None, te_mean=[0.0, step, step], steps=said)
        np.testing.assert_allclose(pooled, [own[0], own[1], own[1] + own[2]])
        assert said == [(1, pytest.approx(step))]      # window 1 of the batch, the step
    pooled, own = _pool_counts(None, te_mean=[0.0, 0.001, -0.001])    # windup, play: kept
    np.testing.assert_allclose(pooled, np.cumsum(own))
    pooled, own = _pool_counts(None, te_mean=[0.0, 0.02, 0.04], offset=0.04,
                               speed_mean=[0.0, 0.5, 1.0])
    np.testing.assert_allclose(pooled, np.cumsum(own))
    # Nor is the windup under a window's mean load (loads of opposite signs beyond rated).
    swing = [-0.002, 0.002, -0.002]
    pooled, own = _pool_counts(None, te_mean=swing, windup_mean=swing)
    np.testing.assert_allclose(pooled, np.cumsum(own))
    pooled, own = _pool_counts(None, te_mean=swing)
    np.testing.assert_allclose(pooled, own)


def test_the_pool_keeps_windows_whose_load_differs_under_the_same_friction_and_efficiency():
    # A base loaded by its accelerations, or a payload changed: the RMS load moves from
    # window to window while the map from effort to torque stays. Counting the efficiency's
    # loss at each window's own load restarted the pool at about every other window of a
    # third-generator base (8 of its 153 windows read a lost motion, counted once; now 20).
    taken = np.array([[20.0, 5.0, 0.5, 0.75, load] for load in (40.0, 250.0, 600.0)])
    pooled, own = _pool_counts(taken)
    np.testing.assert_allclose(pooled, np.cumsum(own))


@pytest.mark.parametrize('second', [
    [20.0 + 0.02 * RATED, 5.0, 0.5, 0.75, 250.0],    # the Coulomb friction moved
    [20.0, 5.0 + 0.04 * RATED, 0.5, 0.75, 250.0],    # the viscous friction at this speed
    [20.0, 5.0, 0.5, 0.70, 250.0],                   # the efficiency at this load
], ids=['Coulomb', 'viscous', 'efficiency'])
def test_the_pool_restarts_where_the_torque_map_changed(second):
    taken = np.array([[20.0, 5.0, 0.5, 0.75, 250.0], second])
    pooled, own = _pool_counts(taken, windows=2)
    assert pooled[0] == own[0] and pooled[1] == own[1], 'the second window starts afresh'


def test_a_coulomb_friction_traded_for_an_efficiency_at_the_window_s_load_keeps_the_pool():
    # The fit may explain the same torque at the window's load by a higher efficiency and
    # more Coulomb friction: the samples fall into the same flank groups.
    loss = 0.5 * ((1.0 / 0.75 - 0.75) - (1.0 / 0.8 - 0.8)) * 250.0
    taken = np.array([[20.0, 5.0, 0.5, 0.75, 250.0], [20.0 + loss, 5.0, 0.5, 0.8, 250.0]])
    pooled, own = _pool_counts(taken, windows=2)
    np.testing.assert_allclose(pooled, np.cumsum(own))


def test_a_window_without_friction_taken_keeps_the_pool():
    pooled, own = _pool_counts(None)
    np.testing.assert_allclose(pooled, np.cumsum(own))


def test_retiming_the_pool_equals_pooling_the_retimed_te():
    # Once the calibration adds the learnt offset to the link stamps, the pooled windows'
    # TE is referred to the new stamps, y - delta*omega, by a linear map of the sums:
    # the pool is as if its windows had been extracted with the offset applied.
    rng = np.random.default_rng(2)
    windows, samples, delta = 3, 2000, 50e-6
    n = windows * samples
    theta = np.linspace(0.0, 12.0, n)
    torque = 300.0 * np.sin(np.linspace(0.0, 40.0 * np.pi, n))
    speed = 0.5 + 0.4 * np.cos(np.linspace(0.0, 31.0, n))
    y = 1e-4 * np.sign(torque) + delta * speed + 1e-6 * rng.standard_normal(n)
    starts = np.arange(windows) * samples
    win = np.repeat(np.arange(windows), samples)

    def pooled(te):
        pool = flanks.FlankPool((1, 2), np.geomspace(20.0, 800.0, 13), RATED, 2, 0.9)
        z = pool.regressors(pool.harmonics(theta), speed, te)
        stats = pool.group_stats(z, torque, pool.bins(z, torque), win, starts,
                                 starts + samples)
        pool.fit_harmonics(stats, windows, np.zeros(windows), np.ones(windows), None)
        return pool

    retimed = pooled(y)
    retimed.retime(delta)
    direct = pooled(y - delta * speed)
    for key, value in direct._pool.items():
        np.testing.assert_allclose(retimed._pool[key], value, rtol=1e-9, atol=1e-18,
                                   err_msg=key)
