"""Tests of the remaining-life predictor, the catalogue life and the prognostic metrics."""

import math

from hypothesis import given, settings
from hypothesis import strategies as st
import numpy as np
import pytest

from reducer_twin.core import wear
from reducer_twin.core.errors import InvalidInput, InvalidParameter
from reducer_twin.core.estimator import EstimatorConfig, WearEstimator
from reducer_twin.core.life import (catalogue_life, event_state, GrowthTrendState, LifeDraws,
                                    LifeQuery, limit_wear, LOST_MOTION_LIMIT, remaining_life,
                                    remaining_lives, threshold_met)
from reducer_twin.core.metrics import (alpha_lambda, cumulative_relative_accuracy,
                                       interval_coverage, prognostic_horizon, relative_accuracy)
from reducer_twin.core.params import ReducerParams
from reducer_twin.core.state_space import run_in_free_wear
from reducer_twin.core.transmission_error import model_tables
from reducer_twin.core.units import ARCMIN, HOUR, UM
from wear_windows import WINDOW, window_duty, WindowFeatures


@pytest.fixture(scope='module')
def params():
    return ReducerParams()


@pytest.fixture(scope='module')
def rated_rate(params):
    """Run-in-free Archard rate at rated torque and the paper's speed [m/s]."""
    return float(wear.wear_rate(params.rating.rated_torque, wear.reference_speed(params), 0.0,
                                params))


def state(wear_m, scale=1.0, wear_sd=0.2e-6, log_scale_sd=0.05, rho=0.0):
    x = np.array([wear_m, math.log(scale)])
    c = rho * wear_sd * log_scale_sd
    return x, np.array([[wear_sd ** 2, c], [c, log_scale_sd ** 2]])


def rated_duty(params, torque=None, speed=None):
    t = params.rating.rated_torque if torque is None else torque
    n = params.rating.rated_output_speed if speed is None else speed
    return window_duty(10.0, WINDOW, 0.0, t, n)


# --------------------------------------------------------------------------- RUL


def test_percentiles_are_ordered_and_bracket_the_mean(params, rated_rate):
    life = remaining_life(state(5e-6, wear_sd=1e-6, log_scale_sd=0.3), rated_rate, params,
                          rng=np.random.default_rng(1))
    assert 0.0 < life.p10 < life.p50 < life.p90
    assert life.p10 < life.mean < life.p90
    assert not (life.p10_censored or life.p50_censored or life.p90_censored)
    assert life.fraction_censored == 0.0 and not life.limit_reached


def test_a_sharp_state_gives_the_closed_form_time_to_the_limit(params, rated_rate):
    w, s = 6e-6, 1.4
    life = remaining_life(state(w, s, wear_sd=1e-15, log_scale_sd=1e-12), rated_rate, params)
    w_lim = float(model_tables(params).wear_for_lost_motion(LOST_MOTION_LIMIT))
    expected = (run_in_free_wear(w_lim, params.wear) - run_in_free_wear(w, params.wear)) / (
        s * rated_rate)
    for value in (life.p10, life.p50, life.p90, life.mean):
        assert value == pytest.approx(float(expected), rel=1e-6)
    assert life.wear_limit == pytest.approx(w_lim, rel=1e-12)


def test_the_closed_form_agrees_with_integrate_wear_at_rated_duty(params, rated_rate):
    # Scale 1 from new: integrate_wear reaches w_lim after the predicted time (1 % tolerance).
    life = remaining_life(state(0.0, wear_sd=1e-15, log_scale_sd=1e-12), rated_rate, params)
    dt = np.full(2000, life.p50 / 2000)
    w = wear.integrate_wear(dt, params.rating.rated_torque, wear.reference_speed(params), params)
    assert w[-1] == pytest.approx(life.wear_limit, rel=1e-2)


def test_events_beyond_the_horizon_are_censored_not_nan(params, rated_rate):
    # Median life ~ 5000 h at rated duty with a wide scale: p90 beyond a 6000 h horizon.
    horizon = 6000.0 * HOUR
    life = remaining_life(state(1e-6, log_scale_sd=0.6), rated_rate, params, horizon_s=horizon,
                          rng=np.random.default_rng(2))
    assert not life.p10_censored and life.p90_censored
    assert life.p90 == horizon
    assert 0.1 < life.fraction_censored < 0.9
    assert life.mean <= horizon
    assert all(math.isfinite(v) for v in (life.p10, life.p50, life.p90, life.mean))


def test_a_reducer_that_does_not_wear_is_censored_everywhere(params):
    life = remaining_life(state(5e-6), 0.0, params, horizon_s=1e8)
    assert life.p10_censored and life.p50_censored and life.p90_censored
    assert life.p10 == life.p50 == life.p90 == life.mean == 1e8
    assert life.fraction_censored == 1.0


def test_a_reducer_past_the_limit_has_zero_life_and_meets_the_threshold(params, rated_rate):
    life = remaining_life(state(30e-6), rated_rate, params)
    assert life.limit_reached and life.threshold_met
    assert life.p10 == life.p50 == life.p90 == life.mean == 0.0
    assert life.event_state == 0.0


def test_a_wear_model_past_the_limit_beside_a_law_below_it_is_not_worn_out(params, rated_rate):
    # The lost motion is given as the two models mixed (2.3 arcmin by the law, 3.08 by the
    # wear model's 22 um, past the limit): the law's share of samples keeps its own times.
    below = trend_state(0.5, 1.0, growth_arcmin=1.8, new_arcmin=0.5)
    life = remaining_life(state(22e-6), rated_rate, params, trend=below, keep_samples=True)
    assert not life.limit_reached and not life.threshold_met
    assert life.p10 == 0.0 and life.p90 > 0.0
    assert np.mean(life.samples == 0.0) == pytest.approx(0.5, abs=0.05)
    assert 0.0 < life.event_state < 1.0


def test_a_wear_model_and_a_law_both_past_the_limit_are_worn_out(params, rated_rate):
    past = trend_state(0.5, 1.0, growth_arcmin=3.0, new_arcmin=0.5)
    life = remaining_life(state(22e-6), rated_rate, params, trend=past)
    assert life.limit_reached and life.threshold_met
    assert life.p10 == life.p50 == life.p90 == 0.0


def test_a_law_past_the_limit_meets_the_threshold_by_its_weight(params, rated_rate):
    # 3.5 arcmin by the law, 1.40 by the wear model at 5 um: mixed 2.45, or 3.29.
    past = trend_state(0.5, 1.0, growth_arcmin=3.0, new_arcmin=0.5)
    assert not remaining_life(state(5e-6), rated_rate, params, trend=past).threshold_met
    heavy = trend_state(0.9, 1.0, growth_arcmin=3.0, new_arcmin=0.5)
    assert remaining_life(state(5e-6), rated_rate, params, trend=heavy).threshold_met


def test_one_thousand_samples_are_drawn_and_kept_when_asked(params, rated_rate):
    # How long it takes is measured by bench/bench_life.py, never asserted here.
    x, P = state(5e-6, wear_sd=1e-6, log_scale_sd=0.3)
    life = remaining_life((x, P), rated_rate, params, n_samples=1000, keep_samples=True)
    assert life.samples.shape == (1000,) and life.n_samples == 1000


def test_the_default_rng_gives_the_same_answer_twice(params, rated_rate):
    a = remaining_life(state(5e-6, log_scale_sd=0.3), rated_rate, params)
    b = remaining_life(state(5e-6, log_scale_sd=0.3), rated_rate, params)
    assert a == b


@pytest.mark.parametrize('seed', [None, 7])
def test_draws_made_before_give_the_prediction_of_drawing_from_the_same_source(
        params, rated_rate, seed):
    # Every random number the prediction uses: duty, drift and the growth law included.
    x, P = state(5e-6, wear_sd=1e-6, log_scale_sd=0.3)
    args = {'duty_rate_rel_std': 0.2, 'rate_drift': 1e-9, 'trend': trend_state(0.4, 1.0),
            'keep_samples': True}
    drawn_here = remaining_life((x, P), rated_rate, params, rng=seed, **args)
    draws = LifeDraws.draw(2000, seed)
    for _ in range(2):   # reused: the draws are only read
        drawn_before = remaining_life((x, P), rated_rate, params, draws=draws, **args)
        assert drawn_before == drawn_here
        np.testing.assert_array_equal(drawn_before.samples, drawn_here.samples)


def assert_together_as_alone(queries, params, draws):
    """Assess ``queries`` at once; each answer must be exactly that of its own call."""
    together = remaining_lives(queries, params, draws=draws, keep_samples=True)
    for query, life in zip(queries, together):
        alone = remaining_life(query.state, query.duty_rate, params,
                               duty_rate_rel_std=query.duty_rate_rel_std,
                               rate_drift=query.rate_drift, trend=query.trend, draws=draws,
                               keep_samples=True)
        assert life == alone
        np.testing.assert_array_equal(life.samples, alone.samples)
    return together


def test_estimates_sampled_together_get_the_answers_each_gets_alone(params, rated_rate):
    # One reducer's windows, assessed at once: worn out, certain, drifting, following a
    # growth law, with the duty uncertain; each answer is exactly the one of its own call.
    draws = LifeDraws.draw(2000)
    queries = [LifeQuery(state(5e-6, wear_sd=1e-6, log_scale_sd=0.3), rated_rate, 0.2, 1e-9,
                         trend_state(0.4, 1.0)),
               LifeQuery(state(30e-6), rated_rate),
               LifeQuery(state(1e-6, log_scale_sd=0.6), rated_rate, 0.0, 1e-9),
               LifeQuery(state(5e-6), 0.0),
               LifeQuery(state(2e-6), rated_rate, 0.1, 0.0, trend_state(1.0, 0.7))]
    together = assert_together_as_alone(queries, params, draws)
    assert together[1].limit_reached and not together[0].limit_reached


def test_estimates_of_a_unit_with_its_own_offset_sampled_together_get_their_own_answers(
        params, rated_rate):
    # The estimator's states: [w, ln s, b] with a positive definite covariance (factorised
    # as one stack), one of them following a growth law.
    def unit(wear_m, baseline_m, rho):
        x = np.array([wear_m, 0.1, baseline_m])
        sd = np.array([0.5e-6, 0.2, 0.3e-6])
        corr = np.array([[1.0, rho, 0.2], [rho, 1.0, 0.0], [0.2, 0.0, 1.0]])
        return x, corr * np.outer(sd, sd)
    draws = LifeDraws.draw(2000)
    queries = [LifeQuery(unit(4e-6, 1e-6, 0.3), rated_rate, 0.1, 1e-9),
               LifeQuery(unit(8e-6, -1e-6, -0.5), rated_rate, 0.2, 0.0, trend_state(0.3, 1.2)),
               LifeQuery(unit(2e-6, 0.0, 0.0), 0.5 * rated_rate)]
    assert_together_as_alone(queries, params, draws)


def test_draws_of_another_sample_count_are_refused(params, rated_rate):
    with pytest.raises(InvalidParameter, match='draws hold 1000 samples'):
        remaining_life(state(5e-6), rated_rate, params, draws=LifeDraws.draw(1000))


def test_duty_uncertainty_widens_the_interval(params, rated_rate):
    x, P = state(5e-6)
    narrow = remaining_life((x, P), rated_rate, params)
    wide = remaining_life((x, P), rated_rate, params, duty_rate_rel_std=0.3)
    assert wide.p90 - wide.p10 > 2.0 * (narrow.p90 - narrow.p10)


@settings(max_examples=40)
@given(w_um=st.floats(0.0, 25.0), scale=st.floats(0.05, 20.0), wear_sd_um=st.floats(1e-3, 5.0),
       log_sd=st.floats(1e-3, 1.5), rho=st.floats(-0.95, 0.95))
def test_percentiles_are_ordered_finite_and_within_the_horizon(
        params, rated_rate, w_um, scale, wear_sd_um, log_sd, rho):
    horizon = 20000.0 * HOUR
    life = remaining_life(state(w_um * UM, scale, wear_sd_um * UM, log_sd, rho), rated_rate,
                          params, horizon_s=horizon, n_samples=200)
    values = (life.p10, life.p50, life.p90, life.mean)
    assert all(math.isfinite(v) and 0.0 <= v <= horizon for v in values)
    assert life.p10 <= life.p50 <= life.p90
    assert life.p90_censored == (life.p90 == horizon)


@settings(max_examples=30)
@given(w1=st.floats(0.0, 25.0), w2=st.floats(0.0, 25.0))
def test_more_wear_never_gives_more_life_with_common_random_numbers(params, rated_rate, w1, w2):
    lo, hi = sorted((w1, w2))
    a = remaining_life(state(lo * UM, wear_sd=0.5e-6, log_scale_sd=0.2), rated_rate, params,
                       n_samples=300)
    b = remaining_life(state(hi * UM, wear_sd=0.5e-6, log_scale_sd=0.2), rated_rate, params,
                       n_samples=300)
    assert b.p10 <= a.p10 and b.p50 <= a.p50 and b.p90 <= a.p90


def test_the_estimator_median_life_is_within_15_percent_at_half_life(params):
    rng = np.random.default_rng(4)
    n = 1200
    torque = params.rating.rated_torque * rng.uniform(0.6, 1.2, n)
    speed = np.full(n, wear.reference_speed(params))
    exposure = np.full(n, WINDOW)
    increment = wear.wear_rate(torque, speed, 0.0, params) * exposure
    true_w = wear.integrate_wear(exposure, torque, speed, params)
    tables = model_tables(params)
    z = tables.lost_motion(true_w) + rng.normal(0.0, 0.05 * ARCMIN, n)
    eol = int(np.argmax(true_w >= limit_wear(params)))
    est = WearEstimator(params)
    for k in range(eol // 2):
        duty = window_duty(10.0, WINDOW, float(increment[k]))
        est.step(WindowFeatures(k * 10.0, float(z[k]), 0.05 * ARCMIN, duty))
    life = remaining_life(est, est.duty_rate, params, rng=np.random.default_rng(5))
    true_rul = (eol - eol // 2 + 0.5) * WINDOW
    assert life.p50 == pytest.approx(true_rul, rel=0.15)
    assert life.p10 < life.p90


@pytest.mark.parametrize('kwargs, error, message', [
    ({'duty_rate': -1e-12}, InvalidInput, 'duty_rate'),
    ({'duty_rate': math.nan}, InvalidInput, 'duty_rate'),
    ({'limit': 0.2 * ARCMIN}, InvalidParameter, 'limit'),
    ({'limit': 60.0 * ARCMIN}, InvalidParameter, 'limit'),
    ({'horizon_s': 0.0}, InvalidParameter, 'horizon_s'),
    ({'n_samples': 0}, InvalidParameter, 'n_samples'),
    ({'n_samples': 2.5}, InvalidParameter, 'n_samples'),
    ({'duty_rate_rel_std': -0.1}, InvalidParameter, 'duty_rate_rel_std'),
    ({'state': ([1.0], [[1.0]])}, InvalidInput, 'shape'),
    ({'state': 3.0}, InvalidInput, 'state'),
    ({'state': ([0.0, math.nan], np.eye(2))}, InvalidInput, 'finite'),
])
def test_bad_inputs_to_remaining_life_are_rejected(params, rated_rate, kwargs, error, message):
    args = {'state': state(5e-6), 'duty_rate': rated_rate, 'params': params}
    args.update(kwargs)
    with pytest.raises(error, match=message):
        remaining_life(**args)


# --------------------------------------------------------------------------- health


def test_event_state_is_one_when_new_and_zero_at_the_limit(params):
    w_lim = limit_wear(params)
    assert event_state(0.0, params) == pytest.approx(1.0)
    assert event_state(w_lim, params) == pytest.approx(0.0, abs=1e-9)
    assert event_state(2 * w_lim, params) == 0.0
    lm_new = float(model_tables(params).lost_motion(0.0))
    w_mid = float(model_tables(params).wear_for_lost_motion(0.5 * (lm_new + LOST_MOTION_LIMIT)))
    assert event_state(w_mid, params) == pytest.approx(0.5, abs=1e-9)
    assert not threshold_met(0.99 * w_lim, params) and threshold_met(1.01 * w_lim, params)


# --------------------------------------------------------------------------- catalogue


def test_catalogue_life_is_the_rated_6000_hours_at_rated_torque_and_speed(params):
    assert catalogue_life(rated_duty(params), params) == pytest.approx(6000.0 * HOUR, rel=1e-12)


def test_catalogue_life_follows_the_speed_ratio_and_the_ten_thirds_power(params):
    t0, n0 = params.rating.rated_torque, params.rating.rated_output_speed
    half_torque = catalogue_life(rated_duty(params, torque=0.5 * t0), params)
    assert half_torque == pytest.approx(6000.0 * HOUR * 2.0 ** (10.0 / 3.0), rel=1e-12)
    double_speed = catalogue_life(rated_duty(params, speed=-2.0 * n0), params)
    assert double_speed == pytest.approx(3000.0 * HOUR, rel=1e-12)
    assert catalogue_life(rated_duty(params, speed=0.0), params) == math.inf


def test_catalogue_life_rejects_a_duty_without_numbers(params):
    with pytest.raises(InvalidInput, match='mean_speed'):
        catalogue_life(object(), params)


# --------------------------------------------------------------------------- metrics


@pytest.fixture
def hand_made():
    """Life of 100 h, predictions every 10 h from t = 10 h (times in hours)."""
    t = np.arange(10.0, 100.0, 10.0)
    rul_true = 100.0 - t
    #            10   20   30   40   50   60   70   80   90
    rul_pred = [60., 95., 52., 68., 45., 44., 28., 21., 10.5]
    return t, np.array(rul_pred), rul_true


def test_alpha_lambda_on_a_hand_made_example(hand_made):
    t, pred, true = hand_made
    # t_lambda = 10 + lam*90. lam=0: t=10, true 90, pred 60: outside [72, 108].
    assert not alpha_lambda(t, pred, true, 0.0)
    # lam=0.3 -> t=37, first prediction after is t=40: true 60, pred 68 inside [48, 72].
    assert alpha_lambda(t, pred, true, 0.3)
    # lam=0.5 -> t=55, first prediction after is t=60: true 40, pred 44 inside [32, 48].
    assert alpha_lambda(t, pred, true, 0.5)
    # lam=0.6 -> t=64 -> t=70: true 30, pred 28 inside [24, 36]; a tighter alpha fails.
    assert alpha_lambda(t, pred, true, 0.6) and not alpha_lambda(t, pred, true, 0.6, alpha=0.05)
    # lam=1 -> t=100: no prediction at or after EOL.
    assert not alpha_lambda(t, pred, true, 1.0)


def test_prognostic_horizon_on_a_hand_made_example(hand_made):
    t, pred, true = hand_made
    # Bounds +-0.2*EOL = +-20 h. Errors: -30, 15, -18, 8, -5, 4, -2, 1, 0.5.
    # First inside: t=20 (PH 80 h); inside from then on: t=20 too.
    assert prognostic_horizon(t, pred, true) == pytest.approx(80.0)
    # With alpha 0.1 (+-10 h): first inside t=40; staying inside from t=40 as well.
    assert prognostic_horizon(t, pred, true, alpha=0.1) == pytest.approx(60.0)
    # With alpha 0.16 (+-16 h) t=20 is inside, t=30 is not: first hit 80 h, stay 60 h.
    assert prognostic_horizon(t, pred, true, alpha=0.16, stay=False) == pytest.approx(80.0)
    assert prognostic_horizon(t, pred, true, alpha=0.16) == pytest.approx(60.0)
    assert prognostic_horizon(t, pred + 1000.0, true) == 0.0


def test_cumulative_relative_accuracy_is_the_mean_relative_accuracy(hand_made):
    t, pred, true = hand_made
    ra = 1.0 - np.abs(true - pred) / true
    np.testing.assert_allclose(relative_accuracy(pred, true), ra, rtol=1e-15)
    assert cumulative_relative_accuracy(t, pred, true) == pytest.approx(ra.mean(), rel=1e-15)
    assert cumulative_relative_accuracy(t, true, true) == 1.0
    weights = np.arange(1.0, 10.0)
    assert cumulative_relative_accuracy(t, pred, true, weights) == pytest.approx(
        np.sum(weights * ra) / weights.sum(), rel=1e-15)


def test_interval_coverage_counts_the_true_rul_inside_p10_p90():
    true = np.array([10.0, 20.0, 30.0, 40.0])
    assert interval_coverage(true, true - 1.0, true + 1.0) == 1.0
    assert interval_coverage(true, [0, 25, 0, 41], [15, 30, 29, 50]) == 0.25


@pytest.mark.parametrize('t, pred, true', [
    ([], [], []),
    ([0.0, 1.0], [1.0], [1.0, 0.0]),
    ([1.0, 0.0], [1.0, 1.0], [1.0, 2.0]),
    ([0.0, math.nan], [1.0, 1.0], [1.0, 0.0]),
])
def test_metrics_reject_malformed_arrays(t, pred, true):
    with pytest.raises(InvalidInput):
        prognostic_horizon(t, pred, true)


# --------------------------------------------------------------------------- per-unit states


def test_a_unit_built_looser_reaches_the_limit_at_less_wear(params, rated_rate):
    x, P = state(5e-6)
    nominal = remaining_life((x, P), rated_rate, params)
    x3 = np.array([5e-6, 0.0, 3e-6])
    P3 = np.diag([0.2e-6 ** 2, 0.05 ** 2, 1e-20])
    loose = remaining_life((x3, P3), rated_rate, params)
    assert loose.wear_limit == pytest.approx(nominal.wear_limit - 3e-6, rel=1e-9)
    # Closed form: the run-in-free wear left to the limit shrinks by the as-built offset.
    s = [float(run_in_free_wear(w, params.wear)) for w in (5e-6, nominal.wear_limit,
                                                           loose.wear_limit)]
    assert loose.p50 / nominal.p50 == pytest.approx((s[2] - s[0]) / (s[1] - s[0]), rel=0.02)


def trend_state(probability, g, growth_arcmin=1.5, new_arcmin=0.5, exposure=1e-6):
    mean = np.array([new_arcmin * ARCMIN, growth_arcmin * ARCMIN, g])
    cov = np.diag([(0.01 * ARCMIN) ** 2, (0.01 * ARCMIN) ** 2, 0.01 ** 2])
    return GrowthTrendState(probability, mean, cov, exposure)


def test_a_certain_linear_trend_gives_the_linear_time_to_the_limit(params, rated_rate):
    # 2 arcmin now after 1 um of exposure, growing linearly: 1 arcmin to go takes 2/3 um.
    life = remaining_life(state(5e-6), rated_rate, params, trend=trend_state(1.0, 1.0))
    expected = (1.0e-6 * (2.5 / 1.5) - 1.0e-6) / rated_rate
    assert life.p50 == pytest.approx(expected, rel=0.03)


def test_the_trend_and_the_wear_model_are_mixed_by_the_trend_probability(params, rated_rate):
    x, P = state(5e-6, wear_sd=0.05e-6, log_scale_sd=0.01)
    model = remaining_life((x, P), rated_rate, params).p50
    trend = remaining_life((x, P), rated_rate, params, trend=trend_state(1.0, 1.0)).p50
    mixed = remaining_life((x, P), rated_rate, params, trend=trend_state(0.5, 1.0),
                           keep_samples=True)
    assert min(model, trend) < mixed.p50 < max(model, trend)
    near_model = np.abs(mixed.samples - model) < np.abs(mixed.samples - trend)
    assert 0.4 < near_model.mean() < 0.6


def test_a_bad_trend_is_refused(params, rated_rate):
    with pytest.raises(InvalidInput, match='trend'):
        remaining_life(state(5e-6), rated_rate, params, trend=trend_state(1.5, 1.0))
    with pytest.raises(InvalidInput, match='trend'):
        remaining_life(state(5e-6), rated_rate, params, trend=object())


# --------------------------------------------------------------------------- calibration


def test_the_p10_p90_interval_covers_the_true_life_from_both_sides(params):
    """16 units drawn from the estimator's prior, 3 predictions each: both tails 2-22 %."""
    rng = np.random.default_rng(12)
    config = EstimatorConfig()
    tables = model_tables(params)
    below = above = total = 0
    for seed in range(16):
        scale = math.exp(rng.normal(0.0, 0.7))
        as_built = rng.normal(0.0, config.as_built_std)
        bias = rng.normal(0.0, config.fit_bias_std)
        n = 2000
        window = 30.0 * HOUR / scale
        torque = params.rating.rated_torque * rng.uniform(0.6, 1.2, n)
        speed = np.full(n, wear.reference_speed(params))
        exposure = np.full(n, window)
        increment = wear.wear_rate(torque, speed, 0.0, params) * exposure
        true_w = wear.integrate_wear(exposure, torque, speed, params, rate_scale=scale)
        lm = tables.lost_motion(true_w + as_built)
        eol = int(np.argmax(lm >= LOST_MOTION_LIMIT))
        z = lm + bias + rng.normal(0.0, 0.05 * ARCMIN, n)
        est = WearEstimator(params, config)
        marks = [int(f * eol) for f in (0.3, 0.5, 0.7)]
        for k in range(marks[-1] + 1):
            duty = window_duty(10.0, window, float(increment[k]))
            est.step(WindowFeatures(k * 10.0, float(z[k]), 0.05 * ARCMIN, duty))
            if k in marks:
                life = remaining_life(est, est.duty_rate, params,
                                      duty_rate_rel_std=est.duty_rate_rel_std,
                                      rate_drift=config.log_rate_scale_noise_density)
                true_rul = (eol - k - 0.5) * window
                below += true_rul < life.p10
                above += true_rul > life.p90
                total += 1
    assert 0.02 <= below / total <= 0.22
    assert 0.02 <= above / total <= 0.22
