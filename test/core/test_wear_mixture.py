"""
Specification of the wear estimator's Gaussian sum (``reducer_twin.core.wear_mixture``).

The mixture is exercised end to end through :class:`WearEstimator` (test_estimator.py);
these tests state what the mixture itself promises the estimator.
"""

import math

import numpy as np
import pytest
from reducer_twin.core.estimator import EstimatorConfig
from reducer_twin.core.params import ReducerParams
from reducer_twin.core.state_space import lost_motion_curve, run_in_free_wear
from reducer_twin.core.state_space import wear_from_run_in_free
from reducer_twin.core.units import ARCMIN, UM
from reducer_twin.core.wear_mixture import N_FILTER, prior_components, PRIOR_REACH
from reducer_twin.core.wear_mixture import RATE_GRID, WearMixture

PARAMS = ReducerParams()
NEW = EstimatorConfig(new_unit_probability=1.0)
"""A reducer known to be new: one hypothesis, the rate grid's components."""


def test_the_prior_spans_the_rate_grid_with_weights_of_the_rate_prior():
    lw, m, P = prior_components(NEW)
    lo, hi, step, sd = RATE_GRID
    thetas = math.log(NEW.initial_rate_scale) + np.arange(lo, hi + 0.5 * step, step)
    assert m.shape == (thetas.size, N_FILTER) and P.shape == (thetas.size, N_FILTER, N_FILTER)
    np.testing.assert_allclose(m[:, 1], thetas)
    np.testing.assert_allclose(np.exp(lw).sum(), 1.0, rtol=1e-12)
    # Weighted by the rate's prior N(ln s0, sd0²); the grid holds ln s0 itself.
    want = -0.5 * ((thetas - math.log(NEW.initial_rate_scale))
                   / NEW.initial_log_rate_scale_std) ** 2
    np.testing.assert_allclose(lw - lw.max(), want, atol=1e-12)
    assert np.allclose(P[:, 1, 1], sd ** 2)
    assert np.allclose(P[:, 2, 2], NEW.as_built_std ** 2)
    assert np.allclose(P[:, 3, 3], NEW.fit_bias_std ** 2)


def test_a_used_hypothesis_doubles_the_components_and_carries_its_weight():
    lw, m, _ = prior_components(EstimatorConfig(new_unit_probability=0.25))
    used = m[:, 0] == EstimatorConfig().used_wear
    assert used.sum() == (~used).sum()
    assert np.exp(lw[used]).sum() == pytest.approx(0.75, rel=1e-12)


def test_nothing_operated_predicts_nothing():
    mix = WearMixture(PARAMS, NEW, 1.0)
    m, P = mix.m.copy(), mix.P.copy()
    mix.predict(0.0, 0.0)
    np.testing.assert_array_equal(mix.m, m)
    np.testing.assert_array_equal(mix.P, P)


def test_a_prediction_grows_each_components_wear_by_its_rate_and_adds_the_process_noise():
    config = EstimatorConfig(new_unit_probability=1.0, initial_log_rate_scale_std=1e-9,
                             initial_wear_std=1e-12)
    mix = WearMixture(PARAMS, config, 1.0)
    assert mix.size == 1
    var_theta = mix.P[0, 1, 1]
    mix.predict(3600.0, 0.2 * UM)
    # w' = W(S(w) + e^θ·Δa), the run-in-free maps of the state space (a sharp prior:
    # the sigma points' mean is the map of the mean).
    wp = PARAMS.wear
    want = wear_from_run_in_free(run_in_free_wear(0.0, wp)
                                 + config.initial_rate_scale * 0.2 * UM, wp)
    assert mix.m[0, 0] == pytest.approx(float(want), rel=1e-6)
    assert mix.P[0, 1, 1] == pytest.approx(
        var_theta + config.log_rate_scale_noise_density * 3600.0, rel=1e-9)
    np.testing.assert_allclose(mix.P, np.swapaxes(mix.P, 1, 2), rtol=0.0, atol=0.0)


def test_means_are_projected_into_the_physical_ranges():
    mix = WearMixture(PARAMS, NEW, 1.0)
    mix.m[:, 0] = -1 * UM
    mix.m[:, 2] = 50 * UM
    mix.m[:, 3] = -ARCMIN
    mix.project()
    assert (mix.m[:, 0] == 0.0).all()
    assert (mix.m[:, 2] == PRIOR_REACH * NEW.as_built_std).all()
    assert (mix.m[:, 3] == -PRIOR_REACH * NEW.fit_bias_std).all()


def test_the_innovation_is_the_window_against_the_mixtures_prediction():
    mix = WearMixture(PARAMS, NEW, 1.0)
    z_new = float(lost_motion_curve(PARAMS)(0.0))
    predicted = mix.lost_motion()[0]           # the unit's own: the bias c has mean 0
    told = mix.update(z_new + 0.1 * ARCMIN, 1.0, (0.02 * ARCMIN) ** 2, 0.0)
    assert told.y == pytest.approx(z_new + 0.1 * ARCMIN - predicted, rel=1e-9)
    assert told.spread == 0.0
    assert told.nis == pytest.approx(told.y ** 2 / (told.variance + (0.02 * ARCMIN) ** 2))
    # The mixture moved towards the window and its weights stay normalised.
    assert mix.lost_motion()[0] > predicted
    assert np.exp(mix.lw).sum() == pytest.approx(1.0, rel=1e-12)


def test_a_window_without_growth_leaves_the_fit_bias_mean_and_variance_alone():
    # A window across which the lost motion does not grow cannot tell the fit's bias c
    # from the as-built offset b: c is a consider state (its mean and variance stay).
    mix = WearMixture(PARAMS, NEW, 1.0)
    c_mean, c_var = mix.m[:, 3].copy(), mix.P[:, 3, 3].copy()
    b_var = mix.P[:, 2, 2].copy()
    mix.update(0.6 * ARCMIN, 1.0, (0.02 * ARCMIN) ** 2, 0.0)
    np.testing.assert_array_equal(mix.m[:, 3], c_mean)
    np.testing.assert_array_equal(mix.P[:, 3, 3], c_var)
    assert (mix.P[:, 2, 2] < b_var).all(), 'the as-built offset is learnt from the window'


def test_a_window_across_which_the_lost_motion_grows_also_updates_the_fit_bias():
    mix = WearMixture(PARAMS, NEW, 1.0)
    c_var = mix.P[:, 3, 3].copy()
    # A time-compressed window: its Archard increment grows the lost motion within it.
    assert (mix.smear(5.0 * UM) > 0.0).all()
    mix.update(0.6 * ARCMIN, 1.0, (0.02 * ARCMIN) ** 2, 5.0 * UM)
    assert (mix.P[:, 3, 3] < c_var).any()


def test_the_estimate_is_the_mixtures_moments_and_follows_every_change():
    mix = WearMixture(PARAMS, NEW, 1.0)
    x0 = mix.estimate()[0].copy()
    w = np.exp(mix.lw)
    np.testing.assert_allclose(x0, w @ mix.m, rtol=1e-12)
    mix.predict(3600.0, 1.0 * UM)
    x1, P1 = (v.copy() for v in mix.estimate())
    assert x1[0] > x0[0]
    # Pruning and merging keep the moments (moment matching).
    mix.tidy()
    np.testing.assert_allclose(mix.estimate()[0], x1, rtol=1e-6, atol=1e-15)


def test_a_respread_returns_to_the_rate_grid_keeping_the_wear():
    mix = WearMixture(PARAMS, NEW, 1.0)
    for _ in range(20):
        mix.predict(3600.0, 0.2 * UM)
        mix.update(float(mix.lost_motion()[0]), 1.0, (0.02 * ARCMIN) ** 2, 0.0)
        mix.tidy()
    wear, var = mix.estimate()[0][0], mix.estimate()[1][0, 0]
    assert mix.size < prior_components(NEW)[0].size
    mix.respread(0.3 * ARCMIN, (0.02 * ARCMIN) ** 2)
    assert mix.size == prior_components(NEW)[0].size
    assert mix.m[:, 0] == pytest.approx(wear, rel=1e-12)
    assert (mix.P[:, 0, 0] > var).all(), 'the wear is widened to take the innovation as 1 sd'
