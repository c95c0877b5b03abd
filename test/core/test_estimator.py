"""
Tests of the wear state estimator (UKF on [w, ln s]).

Synthetic truth is made with the core itself: wear grows by
``wear.integrate_wear`` with a hidden rate scale, observations are
``model_tables(params).lost_motion(true_w)`` plus 0.05 arcmin of white noise.
"""

from dataclasses import dataclass, replace
import gc
import json
import math

from hypothesis import given, settings
from hypothesis import strategies as st
import numpy as np
import pytest

from reducer_twin.core import wear
from reducer_twin.core.errors import InvalidInput, InvalidParameter, StateFileError
from reducer_twin.core.estimator import (backup_path, encode_state, EstimatorConfig,
                                         load_with_fallback, params_fingerprint,
                                         run_in_free_wear, wear_from_run_in_free, WearEstimator)
from reducer_twin.core.params import ReducerParams
from reducer_twin.core.transmission_error import model_tables
from reducer_twin.core.units import ARCMIN, HOUR, UM

NOISE = 0.05 * ARCMIN
WINDOW = 10.0 * HOUR


@dataclass(frozen=True)
class DutySummary:
    """Duty of one window, as the TE extraction delivers it (SI units)."""

    duration_s: float
    exposure_s: float
    archard_increment: float
    mean_abs_torque: float = 0.0
    mean_abs_speed: float = 0.0
    cubic_mean_torque: float = 0.0
    mean_speed: float = 0.0
    max_abs_torque: float = 0.0


@dataclass(frozen=True)
class WindowFeatures:
    """Features of one window of encoder data (SI units)."""

    t_end: float
    lost_motion: float
    lost_motion_std: float
    duty: DutySummary
    wear_fit: float = math.nan
    wear_fit_std: float = math.nan
    loaded_mean_te: float = math.nan


@pytest.fixture(scope='module')
def params():
    return ReducerParams()


@pytest.fixture(scope='module')
def tables(params):
    return model_tables(params)


def synthetic_run(params, scale, seed, n=3000, window=WINDOW):
    """
    Return windows of a reducer wearing with a hidden rate ``scale``.

    Torque is uniform in 60-120 % of rated per window at the paper's speed;
    the run stops at the 3 arcmin limit.

    Returns
    -------
    tuple
        ``(features, true_wear [m], eol_index)``.

    """
    rng = np.random.default_rng(seed)
    tables = model_tables(params)
    exposure = np.full(n, window)
    torque = params.rating.rated_torque * rng.uniform(0.6, 1.2, n)
    speed = np.full(n, wear.reference_speed(params))
    increment = wear.wear_rate(torque, speed, 0.0, params) * exposure
    true_w = wear.integrate_wear(exposure, torque, speed, params, rate_scale=scale)
    z = tables.lost_motion(true_w) + rng.normal(0.0, NOISE, n)
    eol = int(np.argmax(tables.lost_motion(true_w) >= 3.0 * ARCMIN))
    features = [WindowFeatures(t_end=(k + 1) * 10.0, lost_motion=float(z[k]),
                               lost_motion_std=NOISE,
                               duty=DutySummary(10.0, float(exposure[k]), float(increment[k])))
                for k in range(eol + 1)]
    return features, true_w[:eol + 1], eol


def features_at(lost_motion, increment=1e-8, exposure=WINDOW, std=NOISE, t_end=0.0):
    return WindowFeatures(t_end=t_end, lost_motion=lost_motion, lost_motion_std=std,
                          duty=DutySummary(10.0, exposure, increment))


# --------------------------------------------------------------------------- convergence


@pytest.mark.parametrize('scale', [0.5, 1.0, 2.0])
def test_wear_and_rate_scale_are_learnt_within_a_quarter_of_life(params, scale):
    features, true_w, eol = synthetic_run(params, scale, seed=7)
    est = WearEstimator(params)
    quarter = eol // 4
    for f in features[:quarter + 1]:
        est.step(f)
    # Stated tolerances: wear within 10 %, scale within 15 % and 3 sd.
    assert abs(est.wear - true_w[quarter]) < 0.10 * true_w[quarter]
    assert abs(est.rate_scale - scale) < 0.15 * scale
    assert abs(est.rate_scale - scale) < 3.0 * est.rate_scale_std
    assert est.rejected == 0
    assert est.updates == quarter + 1


def test_prediction_alone_follows_integrate_wear_when_the_prior_is_sharp(params):
    config = EstimatorConfig(initial_wear_std=1e-12, initial_log_rate_scale_std=1e-9,
                             initial_rate_scale=1.7, wear_noise_density=0.0,
                             log_rate_scale_noise_density=0.0)
    rng = np.random.default_rng(3)
    torque = params.rating.rated_torque * rng.uniform(0.2, 1.5, 400)
    speed = rng.uniform(0.2, 1.6, 400)
    exposure = np.full(400, WINDOW)
    increment = wear.wear_rate(torque, speed, 0.0, params) * exposure
    truth = wear.integrate_wear(exposure, torque, speed, params, rate_scale=1.7)
    est = WearEstimator(params, config)
    for e, a in zip(exposure, increment):
        est.predict(DutySummary(10.0, e, a))
    np.testing.assert_allclose(est.wear, truth[-1], rtol=1e-6)
    assert est.exposure_s == pytest.approx(400 * WINDOW, rel=1e-12)


def test_run_in_maps_are_inverse_and_extend_with_slope_one_below_zero(params):
    w = np.array([-2e-6, 0.0, 1e-6, 20e-6, 400e-6, 1e-3])
    free = run_in_free_wear(w, params.wear)
    np.testing.assert_allclose(wear_from_run_in_free(free, params.wear), w, rtol=1e-12, atol=1e-18)
    assert free[0] == -2e-6
    assert np.all(np.diff(free) > 0.0)


def test_duty_rate_is_the_archard_rate_of_a_steady_duty(params):
    est = WearEstimator(params)
    for _ in range(50):
        est.predict(DutySummary(10.0, WINDOW, 3e-8))
    assert est.duty_rate == pytest.approx(3e-8 / WINDOW, rel=1e-12)


# --------------------------------------------------------------------------- cross-check


class NumpyUKF:
    """
    Plain-numpy UKF of the same equations, written from the textbook.

    Sigma points ``x ± sqrt((n+λ)·P)`` columns, ``λ = α²(n+κ) - n``; unscented
    transform; ``K = Pxz/S``; NIS gate; w projected onto >= 0. Process and
    observation models come straight from wear._run_in_map and the bilinear
    lost-motion table, not from the estimator module.
    """

    def __init__(self, params, config):
        self.params, self.config = params, config
        n, alpha, beta, kappa = 2, 1.0, 2.0, 1.0
        self.lam = alpha ** 2 * (n + kappa) - n
        self.wm = np.full(5, 0.5 / (n + self.lam))
        self.wc = self.wm.copy()
        self.wm[0] = self.lam / (n + self.lam)
        self.wc[0] = self.wm[0] + 1.0 - alpha ** 2 + beta
        self.x = np.array([config.initial_wear, math.log(config.initial_rate_scale)])
        self.P = np.diag([config.initial_wear_std ** 2, config.initial_log_rate_scale_std ** 2])
        self.grid_w, self.grid_s = wear._run_in_map(params.wear)
        self.tables = model_tables(params)
        # Below w = 0 the model continues with the slope of the table's first segment.
        w1 = float(self.tables.wear[1])
        self.slope0 = float(self.tables.lost_motion(w1) - self.tables.lost_motion(0.0)) / w1
        self.rejected = 0
        self.consecutive = 0

    def sigmas(self):
        L = np.linalg.cholesky((2 + self.lam) * self.P)
        return np.vstack([self.x, self.x + L.T, self.x - L.T])

    def f(self, x, da):
        free = (x[0] if x[0] < 0 else np.interp(x[0], self.grid_w, self.grid_s))
        free += math.exp(x[1]) * da
        w = free if free < 0 else np.interp(free, self.grid_s, self.grid_w)
        return np.array([w, x[1]])

    def h(self, x):
        w = x[0]
        return float(self.tables.lost_motion(max(w, 0.0))) + self.slope0 * min(w, 0.0)

    def predict(self, exposure, da):
        if exposure == 0.0 and da == 0.0:
            return
        chi = np.array([self.f(s, da) for s in self.sigmas()])
        self.x = self.wm @ chi
        d = chi - self.x
        Q = np.diag([self.config.wear_noise_density, self.config.log_rate_scale_noise_density])
        self.P = (d.T * self.wc) @ d + Q * exposure
        self.finish()

    def update(self, z, std):
        if not (math.isfinite(z) and math.isfinite(std)):
            return
        R = max(std, self.config.min_lost_motion_std) ** 2
        chi = self.sigmas()
        zs = np.array([self.h(s) for s in chi])
        zp = self.wm @ zs
        S = self.wc @ (zs - zp) ** 2 + R
        Pxz = (self.wc * (zs - zp)) @ (chi - self.x)
        y = z - zp
        if y * y / S > self.config.gate_nis:
            self.rejected += 1
            return
        K = Pxz / S
        self.x = self.x + K * y
        self.P = self.P - S * np.outer(K, K)
        self.finish()

    def finish(self):
        self.P = 0.5 * (self.P + self.P.T)
        self.x[0] = max(self.x[0], 0.0)


def test_the_filterpy_estimator_equals_a_plain_numpy_ukf_to_1e_9(params):
    features, _, eol = synthetic_run(params, 1.3, seed=11)
    features = features[:150]
    # Mix in a window without reversals and an outlier the gate must reject.
    features[20] = replace(features[20], lost_motion=math.nan)
    features[40] = replace(features[40], lost_motion=features[40].lost_motion + 1.0 * ARCMIN)
    config = EstimatorConfig()
    est, ref = WearEstimator(params, config), NumpyUKF(params, config)
    for f in features:
        est.step(f)
        ref.predict(f.duty.exposure_s, f.duty.archard_increment)
        ref.update(f.lost_motion, f.lost_motion_std)
        # Relative 1e-9 on every element of x and P (P in correlation form).
        np.testing.assert_allclose(est.x, ref.x, rtol=1e-9, atol=0.0)
        sd_est, sd_ref = np.sqrt(np.diag(est.P)), np.sqrt(np.diag(ref.P))
        np.testing.assert_allclose(sd_est, sd_ref, rtol=1e-9)
        np.testing.assert_allclose(est.P / np.outer(sd_est, sd_est),
                                   ref.P / np.outer(sd_ref, sd_ref), rtol=0.0, atol=1e-9)
    assert est.rejected == ref.rejected == 1
    assert est.counters['skipped'] == 1


# --------------------------------------------------------------------------- gating, NaN


def test_nan_observations_are_skipped_and_leave_the_state_alone(params):
    est = WearEstimator(params)
    est.step(features_at(0.5 * ARCMIN))
    x, P = est.x, est.P
    for z, std in [(math.nan, NOISE), (0.5 * ARCMIN, math.nan), (math.inf, NOISE)]:
        result = est.update(features_at(z, std=std))
        assert result.status == 'skipped'
    assert np.array_equal(est.x, x) and np.array_equal(est.P, P)
    assert est.counters['skipped'] == 3


def test_an_outlier_is_rejected_counted_and_leaves_the_state_alone(params, tables):
    features, _, _ = synthetic_run(params, 1.0, seed=5)
    est = WearEstimator(params)
    for f in features[:100]:
        est.step(f)
    x, P = est.x, est.P
    result = est.update(replace(features[100], lost_motion=features[100].lost_motion
                                + 1.5 * ARCMIN))
    assert result.status == 'rejected'
    assert result.nis > est.config.gate_nis
    assert est.rejected == 1
    assert np.array_equal(est.x, x) and np.array_equal(est.P, P)


def test_a_run_of_rejections_inflates_the_covariance_and_recovers(params, tables):
    features, _, _ = synthetic_run(params, 1.0, seed=5)
    est = WearEstimator(params)
    for f in features[:150]:
        est.step(f)
    # The lost motion jumps by 10 um of wear (e.g. a pin fracture): the data are right.
    jumped = float(tables.lost_motion(est.wear + 10e-6))
    statuses = [est.step(features_at(jumped, increment=0.0)).status for _ in range(12)]
    n_max = est.config.max_consecutive_rejections
    assert statuses[:n_max - 1] == ['rejected'] * (n_max - 1)
    assert statuses[n_max - 1] == 'recovered'
    assert est.counters['recoveries'] == 1
    assert abs(float(tables.lost_motion(est.wear)) - jumped) < 0.3 * ARCMIN


@pytest.mark.parametrize('duty, message', [
    (DutySummary(1.0, math.nan, 0.0), 'exposure_s'),
    (DutySummary(1.0, -1.0, 0.0), 'exposure_s'),
    (DutySummary(1.0, 1.0, -1e-9), 'archard_increment'),
    (DutySummary(1.0, 1.0, math.inf), 'archard_increment'),
    (object(), 'exposure_s'),
])
def test_a_bad_duty_raises_invalid_input_naming_the_field(params, duty, message):
    with pytest.raises(InvalidInput, match=message):
        WearEstimator(params).predict(duty)


def test_a_negative_lost_motion_std_raises_invalid_input(params):
    with pytest.raises(InvalidInput, match='lost_motion_std'):
        WearEstimator(params).update(features_at(0.5 * ARCMIN, std=-1e-6))


@pytest.mark.parametrize('name, value', [
    ('initial_wear_std', 0.0), ('initial_rate_scale', -1.0),
    ('initial_log_rate_scale_std', math.nan), ('wear_noise_density', -1e-20),
    ('gate_nis', 0.5), ('max_consecutive_rejections', 2.5), ('duty_horizon_s', 0.0),
])
def test_bad_estimator_config_values_are_rejected(name, value):
    with pytest.raises(InvalidParameter, match=f'estimator.{name}'):
        EstimatorConfig(**{name: value})


# --------------------------------------------------------------------------- persistence


def stepped_estimator(params, n=60, seed=2):
    features, _, _ = synthetic_run(params, 0.8, seed=seed)
    est = WearEstimator(params)
    for f in features[:n]:
        est.step(f)
    return est, features


def test_a_state_dict_survives_a_json_round_trip_bit_for_bit(params):
    est, features = stepped_estimator(params)
    est.update(replace(features[60], lost_motion=features[60].lost_motion + 2.0 * ARCMIN))
    est.reset('drill: state round trip')
    for f in features[60:70]:
        est.step(f)
    restored = WearEstimator.from_state(params, json.loads(json.dumps(est.state_dict())))
    assert restored.state_dict() == est.state_dict()
    for f in features[70:90]:
        est.step(f)
        restored.step(f)
        assert np.array_equal(restored.x, est.x) and np.array_equal(restored.P, est.P)


def test_save_and_load_restore_exactly_and_keep_the_previous_copy(params, tmp_path):
    est, features = stepped_estimator(params)
    path = tmp_path / 'wear_state.json'
    est.save(path)
    first = est.state_dict()
    est.step(features[60])
    est.save(path)
    assert WearEstimator.load(path, params).state_dict() == est.state_dict()
    assert WearEstimator.load(backup_path(path), params).state_dict() == first
    assert [p.name for p in tmp_path.iterdir() if p.name.endswith('.tmp')] == []


def test_a_state_file_is_written_without_leaving_reference_cycles(params):
    # An estimator writes its file after every window for months: the encoding must leave
    # nothing for the cycle collector (the indenting json encoder leaves ~30 objects a call).
    est, _ = stepped_estimator(params, n=5)
    gc.collect()
    gc.disable()
    try:
        data = [encode_state(est.state_dict()) for _ in range(20)]
        assert gc.collect() == 0
    finally:
        gc.enable()
    lines = data[0].decode().splitlines()
    assert [line.split(':')[0] for line in lines[1:4]] == [' "format"', ' "sha256"', ' "state"']
    assert json.loads(data[0])['state'] == est.state_dict()


def corrupt_flip_digit(data):
    """Change the first digit of the wear in x: valid JSON, wrong checksum."""
    text = data.decode()
    i = text.index('"x":[')
    i += next(k for k, c in enumerate(text[i:]) if c in '123456789')
    return (text[:i] + ('1' if text[i] != '1' else '2') + text[i + 1:]).encode()


def reencode_with(data, **changes):
    state = json.loads(data)['state']
    state.update(changes)
    return encode_state(state)


@pytest.mark.parametrize('mangle, message', [
    (lambda d: d[:len(d) // 2], 'not valid JSON'),
    (lambda d: b'', 'not valid JSON'),
    (lambda d: b'\xff\xfe garbage', 'not valid JSON'),
    (corrupt_flip_digit, 'checksum mismatch'),
    (lambda d: reencode_with(d, version=99), 'version'),
    (lambda d: reencode_with(d, params_sha256='0' * 64), 'other reducer parameters'),
    (lambda d: reencode_with(d, x=[1.0]), 'malformed'),
    (lambda d: reencode_with(d, counters={}), 'malformed'),
    (lambda d: json.dumps({'format': 'something else'}).encode(), 'format'),
    (lambda d: b'[1, 2, 3]', 'format'),
])
def test_a_bad_state_file_raises_state_file_error(params, tmp_path, mangle, message):
    est, _ = stepped_estimator(params, n=5)
    path = tmp_path / 'state.json'
    est.save(path)
    path.write_bytes(mangle(path.read_bytes()))
    with pytest.raises(StateFileError, match=message):
        WearEstimator.load(path, params)


def test_a_state_of_another_reducer_is_detected_as_foreign(params, tmp_path):
    other = params.with_overrides({'geometry.equidistant_modification': 0.04e-3})
    assert params_fingerprint(other) != params_fingerprint(params)
    est, _ = stepped_estimator(params, n=5)
    est.save(tmp_path / 'state.json')
    with pytest.raises(StateFileError, match='other reducer parameters'):
        WearEstimator.load(tmp_path / 'state.json', other)


def test_a_missing_file_raises_state_file_error(params, tmp_path):
    with pytest.raises(StateFileError, match='cannot read'):
        WearEstimator.load(tmp_path / 'absent.json', params)


def test_a_corrupt_primary_falls_back_to_the_backup_and_says_so(params, tmp_path):
    est, features = stepped_estimator(params)
    path = tmp_path / 'state.json'
    est.save(path)
    good = est.state_dict()
    est.step(features[60])
    est.save(path)
    path.write_bytes(path.read_bytes()[:100])
    loaded = load_with_fallback(path, params)
    assert loaded.used_backup and loaded.path == backup_path(path)
    assert 'not valid JSON' in loaded.primary_error
    assert loaded.estimator.state_dict() == good
    # Saving over the corrupt primary must not overwrite the good backup with it.
    loaded.estimator.save(path)
    assert WearEstimator.load(backup_path(path), params).state_dict() == good


def test_fallback_without_a_usable_file_raises_naming_both(params, tmp_path):
    path = tmp_path / 'state.json'
    path.write_bytes(b'{"truncated')
    with pytest.raises(StateFileError, match='no usable estimator state.*backup'):
        load_with_fallback(path, params)


def test_an_intact_primary_is_used_without_fallback(params, tmp_path):
    est, _ = stepped_estimator(params, n=5)
    est.save(tmp_path / 'state.json')
    loaded = load_with_fallback(tmp_path / 'state.json', params)
    assert not loaded.used_backup and loaded.primary_error is None


# --------------------------------------------------------------------------- reset


def test_reset_returns_to_the_prior_keeps_counters_and_logs_the_event(params):
    est, _ = stepped_estimator(params)
    counters, exposure = est.counters, est.exposure_s
    est.reset('reducer replaced')
    fresh = WearEstimator(params)
    assert np.array_equal(est.x, fresh.x) and np.array_equal(est.P, fresh.P)
    assert est.counters == counters
    assert est.exposure_s == exposure and est.exposure_since_reset_s == 0.0
    assert est.events == [{'exposure_s': exposure, 'reason': 'reducer replaced'}]
    assert est.state_dict()['events'] == est.events


@pytest.mark.parametrize('reason', ['', '   ', None, 3])
def test_reset_needs_a_reason(params, reason):
    with pytest.raises(InvalidInput, match='reason'):
        WearEstimator(params).reset(reason)


# --------------------------------------------------------------------------- invariants


window_strategy = st.tuples(
    st.floats(0.0, 200.0 * HOUR),                       # exposure [s]
    st.floats(0.0, 3.0),                                # Archard rate / rated rate
    st.one_of(st.just(math.nan), st.floats(-0.5, 5.0)),  # lost motion offset [arcmin]
    st.floats(0.0, 0.5),                                # reported sd [arcmin]
)


@settings(max_examples=40)
@given(windows=st.lists(window_strategy, min_size=1, max_size=25))
def test_covariance_stays_symmetric_positive_definite_and_wear_non_negative(params, windows):
    rated = float(wear.wear_rate(params.rating.rated_torque, wear.reference_speed(params), 0.0,
                                 params))
    est = WearEstimator(params)
    for exposure, rate, offset, sd in windows:
        z = float(model_tables(params).lost_motion(est.wear)) + offset * ARCMIN
        est.step(features_at(z, increment=rate * rated * exposure, exposure=exposure,
                             std=sd * ARCMIN))
        P = est.P
        assert np.array_equal(P, P.T)
        assert np.all(np.linalg.eigvalsh(P) > 0.0)
        assert est.wear >= 0.0 and np.all(np.isfinite(est.x))
        assert est.rate_scale > 0.0


@settings(max_examples=30)
@given(increments=st.lists(st.floats(0.0, 1e-6), min_size=1, max_size=20))
def test_predicted_wear_never_decreases_without_observations(params, increments):
    est = WearEstimator(params)
    previous = est.wear
    for a in increments:
        est.predict(DutySummary(1.0, WINDOW, a))
        assert est.wear >= previous - 1e-18
        previous = est.wear


def test_a_state_dict_of_other_parameters_is_refused(params):
    assert params_fingerprint(params) == params_fingerprint(ReducerParams())
    with pytest.raises(StateFileError, match='other reducer parameters'):
        WearEstimator.from_state(params.with_overrides({'rating.rated_torque': 800.0}),
                                 WearEstimator(params).state_dict())


def test_estimates_after_sixty_windows_are_micrometres_with_sub_micrometre_sd(params):
    est, _ = stepped_estimator(params)
    assert 0.0 < est.wear / UM < 30.0
    assert 0.0 < est.wear_std / UM < 1.0
