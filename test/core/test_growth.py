"""Tests of the observed-trend model: a power law of lost motion in Archard exposure."""

import json
import math

import numpy as np
import pytest

from reducer_twin.core.growth import EXPONENTS, GrowthTrend
from reducer_twin.core.units import ARCMIN

NOISE = 0.03 * ARCMIN


def history(g, beta=0.6 * ARCMIN, k=1.8 * ARCMIN, n=60, seed=0, step=3e-9):
    """Return a trend fed with ``z = beta + k·(A/A_n)^g`` plus noise, and the exposures."""
    rng = np.random.default_rng(seed)
    exposure = step * (np.arange(n) + 0.5)
    z = beta + k * (exposure / exposure[-1]) ** g + rng.normal(0.0, NOISE, n)
    trend = GrowthTrend()
    for a, zk in zip(exposure, z):
        trend.add(a, zk, NOISE ** 2)
    trend.advance(exposure[-1])
    return trend, exposure, z


@pytest.mark.parametrize('g', [0.4, 0.7, 1.0, 1.3])
def test_the_exponent_new_lost_motion_and_growth_are_recovered(g):
    trend, _, _ = history(g)
    mean, cov = trend.summary()
    sd = np.sqrt(np.diag(cov))
    assert abs(mean[2] - g) < max(3.0 * sd[2], 0.05)
    assert mean[0] == pytest.approx(0.6 * ARCMIN, abs=max(3.0 * sd[0], 0.05 * ARCMIN))
    assert mean[1] == pytest.approx(1.8 * ARCMIN, abs=max(3.0 * sd[1], 0.05 * ARCMIN))


def test_without_data_the_posterior_is_the_physics_prior():
    mean, cov = GrowthTrend().summary()
    # N(0.7, 0.3²) cut to the grid 0.2 .. 1.6: the mean moves up a little.
    assert mean[2] == pytest.approx(0.7, abs=0.05)
    assert math.sqrt(cov[2, 2]) == pytest.approx(0.3, abs=0.03)
    assert mean[0] == pytest.approx(0.65 * ARCMIN, rel=1e-6)


def test_the_predictive_density_of_the_next_window_brackets_it():
    trend, exposure, z = history(1.0, n=80)
    lw, m, v = trend.predictive(exposure[-1] * 1.05, NOISE ** 2)
    w = np.exp(lw)
    mean = w @ m
    sd = math.sqrt(w @ (v + (m - mean) ** 2))
    truth = 0.6 * ARCMIN + 1.8 * ARCMIN * 1.05
    assert abs(mean - truth) < 3.0 * sd
    assert sd < 0.1 * ARCMIN


def test_the_sums_survive_a_json_round_trip_and_give_the_same_posterior():
    trend, _, _ = history(0.8)
    restored = GrowthTrend.from_state(json.loads(json.dumps(trend.state())))
    for a, b in zip(trend.summary(), restored.summary()):
        np.testing.assert_array_equal(a, b)


def test_the_latest_noise_scale_weighs_every_window_alike():
    # The estimator learns the noise scale rho over its first windows. Windows taken
    # while rho was still 1 must not outweigh later ones: the law is the one it would be
    # had every window come with the latest rho.
    rng = np.random.default_rng(5)
    exposure = 3e-9 * (np.arange(40) + 0.5)
    z = 0.6 * ARCMIN + 1.8 * ARCMIN * (exposure / exposure[-1]) + rng.normal(0.0, NOISE, 40)
    learnt, hindsight = GrowthTrend(), GrowthTrend()
    for k, (a, zk) in enumerate(zip(exposure, z)):
        learnt.set_noise_scale(1.0 + 3.0 * k / 39)
        learnt.add(a, zk, NOISE ** 2)
        hindsight.add(a, zk, 4.0 * NOISE ** 2)
    for trend in (learnt, hindsight):
        trend.advance(exposure[-1])
    for a, b in zip(learnt.summary(), hindsight.summary()):
        np.testing.assert_allclose(a, b, rtol=1e-9, atol=1e-12 * ARCMIN)
    lw, m, v = learnt.predictive(exposure[-1], 4.0 * NOISE ** 2)
    lw2, m2, v2 = hindsight.predictive(exposure[-1], 4.0 * NOISE ** 2)
    np.testing.assert_allclose(lw, lw2, atol=1e-9)
    np.testing.assert_allclose(v, v2, rtol=1e-9)


def test_windows_that_scatter_beyond_their_noise_scale_are_taken_at_their_scatter():
    # The noise scale is learnt from successive windows' differences: a slow error of
    # the readings escapes it. The law, fitted over the whole history, is then no surer
    # of its exponent than the windows' own scatter about it allows.
    rng = np.random.default_rng(11)
    exposure = 3e-9 * (np.arange(80) + 0.5)
    z = 0.6 * ARCMIN + 0.3 * ARCMIN * (exposure / exposure[-1]) ** 0.6 \
        + rng.normal(0.0, NOISE, 80)
    told_right, told_small = GrowthTrend(), GrowthTrend()
    for a, zk in zip(exposure, z):
        told_right.add(a, zk, NOISE ** 2)
        told_small.add(a, zk, (0.2 * NOISE) ** 2)
    for trend in (told_right, told_small):
        trend.advance(exposure[-1])
    # The same residuals in 25 times smaller variances (less the prior's share).
    assert told_small.residual_scale() == pytest.approx(25.0 * told_right.residual_scale(),
                                                        rel=0.05)
    assert told_right.residual_scale() < 1.0 < told_small.residual_scale()
    sd_right = math.sqrt(told_right.summary()[1][2, 2])
    sd_small = math.sqrt(told_small.summary()[1][2, 2])
    assert sd_small == pytest.approx(sd_right, rel=0.5)
    assert sd_small > 2.0 * 0.2 * sd_right


def test_a_state_without_a_noise_scale_is_restored_as_it_was():
    # Sums written before rho was kept out of them carry the rho of their time; restored
    # with the estimator's rho now, the law is the one it was.
    trend, _, _ = history(0.8)
    old = trend.state()
    del old['noise_scale']
    restored = GrowthTrend.from_state(old, legacy_scale=2.5)
    assert restored.noise_scale == 2.5
    for a, b in zip(trend.summary(), restored.summary()):
        np.testing.assert_allclose(a, b, rtol=1e-9, atol=1e-15)


@pytest.mark.parametrize('change', [
    {'sxx': [[0.0, 0.0, 0.0]]},
    {'sxz': [[math.nan, 0.0]] * EXPONENTS.size},
    {'noise_scale': 0.0},
    {'noise_scale': math.inf},
])
def test_malformed_sums_are_refused(change):
    state = GrowthTrend().state()
    state.update(change)
    with pytest.raises(ValueError):
        GrowthTrend.from_state(state)


def test_the_exposure_only_moves_forward():
    trend = GrowthTrend()
    trend.advance(2e-9)
    trend.advance(1e-9)
    assert trend.exposure == 2e-9


def test_windows_that_drift_down_give_no_negative_growth():
    # Lost motion never shrinks with wear: windows reading 10 % lower by the end of a
    # recording (a bias settling, not wear) give k >= 0, and the law reads their level.
    rng = np.random.default_rng(3)
    exposure = 1e-12 * (np.arange(40) + 0.5)
    z = (0.8 - 0.08 * np.arange(40) / 39) * ARCMIN + rng.normal(0.0, NOISE, 40)
    trend = GrowthTrend()
    for a, zk in zip(exposure, z):
        trend.add(a, zk, NOISE ** 2)
    trend.advance(exposure[-1])
    mean, cov = trend.summary()
    assert mean[1] >= 0.0
    assert mean[0] + mean[1] == pytest.approx(np.mean(z), abs=0.03 * ARCMIN)


def test_without_windows_no_growth_is_assumed():
    # k >= 0 is imposed only once the windows place k; the prior alone reads no growth
    # (a half-normal prior would put 2.4 arcmin of growth on a unit never seen).
    mean, _ = GrowthTrend().summary()
    assert mean[1] == 0.0


def mid_life(new_probability, n=30, seed=1):
    """Return a law fed with a unit met at 75 % of its life, ``z = 0.6 + 1.8·(A/A_end)^0.5``."""
    rng = np.random.default_rng(seed)
    before = 3e-7                                   # exposure before the twin started
    exposure = 3e-9 * (np.arange(n) + 0.5)          # counted from the twin's start
    end = before + 4 * 3e-9 * n                     # the limit's exposure
    z = 0.6 * ARCMIN + 1.8 * ARCMIN * ((before + exposure) / end) ** 0.5 \
        + rng.normal(0.0, NOISE, n)
    trend = GrowthTrend(new_probability)
    for a, zk in zip(exposure, z):
        trend.add(a, zk, NOISE ** 2)
    trend.advance(exposure[-1])
    return trend, z


def test_a_unit_used_before_the_twin_started_gets_a_law_from_its_lost_motion_then():
    # Placed as from new (beta at 0.65 arcmin), a unit met at 2 arcmin was bent into a
    # steep start that flattens: its remaining life came out long.
    trend, z = mid_life(0.9)
    lw, _, _, _ = trend._posterior()
    start_weight = np.exp(lw[EXPONENTS.size:]).sum()
    assert start_weight > 0.99
    mean, cov = trend.summary()
    assert mean[0] == pytest.approx(z[0], abs=0.05 * ARCMIN)     # the lost motion then
    assert abs(mean[2] - 1.0) < 0.3     # seen from mid-life, the growth is near linear
    # Out to the limit (4 times the exposure seen: 2.4 arcmin) the law follows the unit;
    # placed as from new only, it is bent towards its prior exponent (0.7) and falls short.

    def at_limit(m):
        return m[0] + m[1] * 4.0 ** m[2]

    assert at_limit(mean) == pytest.approx(2.4 * ARCMIN, abs=0.05 * ARCMIN)
    bent, _ = mid_life(1.0)
    assert at_limit(bent.summary()[0]) < 2.4 * ARCMIN - 0.1 * ARCMIN


def test_a_new_unit_keeps_the_law_placed_from_new():
    trend, _, _ = history(0.7)
    weighed = GrowthTrend(0.9)
    weighed.sxx, weighed.sxz, weighed.szz = trend.sxx, trend.sxz, trend.szz
    weighed.advance(trend.exposure)
    lw, _, _, _ = weighed._posterior()
    assert np.exp(lw[EXPONENTS.size:]).sum() < 0.05
    for a, b in zip(trend.summary(), weighed.summary()):
        np.testing.assert_allclose(a, b, rtol=0.05, atol=0.02 * ARCMIN)


def test_the_laws_origin_odds_survive_a_round_trip_and_old_states_are_from_new():
    trend, _ = mid_life(0.9)
    state = json.loads(json.dumps(trend.state()))
    restored = GrowthTrend.from_state(state)
    assert restored.new_probability == 0.9
    for a, b in zip(trend.summary(), restored.summary()):
        np.testing.assert_array_equal(a, b)
    del state['new_probability']
    assert GrowthTrend.from_state(state).new_probability == 1.0
    with pytest.raises(ValueError, match='new_probability'):
        GrowthTrend.from_state({**state, 'new_probability': 1.5})


def test_a_law_with_an_origin_is_the_law_of_the_exposure_counted_from_new():
    # A unit whose service before the twin is known: its windows' exposure counts from
    # new, so the law is that of the same windows fed with the service's exposure added.
    origin = 2e-7
    served, counted = GrowthTrend(origin=origin), GrowthTrend()
    rng = np.random.default_rng(3)
    for a in 3e-9 * (np.arange(40) + 0.5):
        z = 0.6 * ARCMIN + 1.8 * ARCMIN * ((origin + a) / 3.2e-7) + rng.normal(0.0, NOISE)
        served.add(a, z, NOISE ** 2)
        counted.add(origin + a, z, NOISE ** 2)
    served.advance(1.2e-7)
    counted.advance(origin + 1.2e-7)
    assert served.exposure == counted.exposure
    for a, b in zip(served.summary(), counted.summary()):
        np.testing.assert_allclose(a, b, rtol=1e-12)
    later = served.predictive(1.3e-7, NOISE ** 2)
    for a, b in zip(later, counted.predictive(origin + 1.3e-7, NOISE ** 2)):
        np.testing.assert_allclose(a, b, rtol=1e-12)
    restored = GrowthTrend.from_state(json.loads(json.dumps(served.state())))
    assert restored.origin == origin
    state = served.state()
    del state['origin']
    assert GrowthTrend.from_state(state).origin == 0.0
    with pytest.raises(ValueError, match='origin'):
        GrowthTrend.from_state({**state, 'origin': -1.0})
