"""The effort smoothed within windows: its length per window, its noise band, the load model."""

import numpy as np
import pytest
from reducer_twin.core.torque_smoothing import nominal_step, SMOOTHING_MAX_S, TorqueSmoothing
from scipy.signal import butter, sosfiltfilt

RATED = 784.0
TAKEUP = 0.03 * RATED
SMOOTHING = TorqueSmoothing(0.03, 3.0, TAKEUP, RATED)


def _windows(lengths):
    ends = np.cumsum(lengths)
    starts = ends - np.asarray(lengths)
    return np.repeat(np.arange(len(lengths)), lengths), starts, ends


def test_the_nominal_step_of_a_jittered_clock_is_the_same_for_any_stretch_of_it():
    t = np.arange(20000) * 0.005 + np.random.default_rng(1).normal(0.0, 2e-6, 20000)
    steps = {nominal_step(t[a:a + n]) for a in (0, 3000, 11000) for n in (1500, 4000, 8000)}
    assert steps == {0.005}
    assert SMOOTHING.half_width(0.005) == 3 and SMOOTHING.half_width(0.001) == 15


def test_each_window_is_quieted_by_its_own_noise_and_load_passage():
    # Three windows at 1 kHz: a quiet effort, a noisy one, and a noisy one whose load never
    # passes the test torque. A slow ramp through the test torque: the passage allows the
    # longest average.
    n = 2000
    win, starts, ends = _windows([n, n, n])
    t = np.arange(3 * n) * 1e-3
    ramp = np.tile(np.linspace(-2.0 * TAKEUP, 2.0 * TAKEUP, n), 3)
    model = ramp.copy()
    model[2 * n:] = 5.0 * TAKEUP
    sigma = np.array([0.005 * RATED, 0.03 * RATED, 0.03 * RATED])
    halves = SMOOTHING.quiet_half(sigma, 15, t, 1e-3, model, win, starts, ends)
    assert halves[0] == 15                      # quiet enough with the base average
    assert 15 < halves[1] <= 0.5 * SMOOTHING_MAX_S / 1e-3
    assert halves[2] == 15                      # no passage of the test torque to time
    # Without a load model the base average stays everywhere.
    assert list(SMOOTHING.quiet_half(sigma, 15, t, 1e-3, None, win, starts, ends)) == [15] * 3


@pytest.mark.parametrize('hold', [1, 10])
def test_the_noise_band_follows_the_efforts_noise_and_the_averages_length(hold):
    n = 4000
    win, starts, ends = _windows([n])
    rng = np.random.default_rng(2)
    fresh = rng.normal(0.0, 10.0, n // hold)
    effort = 300.0 + np.repeat(fresh, hold)       # held over `hold` samples per update
    t = np.arange(n) * 1e-3
    smooth, band = SMOOTHING.smooth(effort, 15, t, 1e-3, None, win, starts, ends, hold)
    inside = slice(100, n - 100)
    assert np.std(smooth[inside] - 300.0) < 10.0
    # The band is sign_sigmas times the average's noise: 10 N*m over its independent updates.
    expected = 3.0 * 10.0 / np.sqrt(max(31 / hold, 1.0))
    assert np.median(band[inside]) == pytest.approx(expected, rel=0.2)


def _band_noise(n, rms, lo_hz, hi_hz, seed, fs=1000.0):
    sos = butter(4, [lo_hz, hi_hz], btype='band', fs=fs, output='sos')
    noise = sosfiltfilt(sos, np.random.default_rng(seed).normal(size=n))
    return noise * rms / np.sqrt(np.mean(noise ** 2))


def test_an_efforts_noise_correlated_over_samples_is_read_from_its_averages():
    # 2 % of rated torque in 5-50 Hz at 1 kHz: neighbouring samples barely differ, but a
    # 31-sample average keeps most of the noise; its band must say so, and the average be
    # lengthened, and it is said.
    n = 4000
    win, starts, ends = _windows([n, n])
    t = np.arange(2 * n) * 1e-3
    smoothing = TorqueSmoothing(0.03, 3.0, TAKEUP, RATED)
    effort = 300.0 + _band_noise(2 * n, 0.02 * RATED, 5.0, 50.0, 3)
    mean = np.convolve(effort - 300.0, np.ones(31) / 31, mode='same')[100:-100]
    _, band = smoothing.smooth(effort, 15, t, 1e-3, None, win, starts, ends)
    inside = slice(200, n - 200)
    # The band is sign_sigmas times the 31-sample average's own noise, within its scatter.
    assert np.median(band[inside]) == pytest.approx(3.0 * np.std(mean), rel=0.35)
    assert smoothing.correlated_windows == 2 and smoothing.correlated_ratio > 5.0


def test_white_noise_and_quiet_correlated_noise_keep_the_neighbours_figure():
    # White noise: its averages are as noisy as its scatter says. Correlated noise whose
    # averages are already below a tenth of the test torque is left as it is.
    n = 4000
    win, starts, ends = _windows([n, n])
    rng = np.random.default_rng(4)
    white = rng.normal(0.0, 0.02 * RATED, 2 * n)
    quiet = _band_noise(2 * n, 0.002 * RATED, 5.0, 50.0, 5)
    for noise in (white, quiet):
        smoothing = TorqueSmoothing(0.03, 3.0, TAKEUP, RATED)
        sigma = np.full(2, 1.4826 * np.median(np.abs(np.diff(noise, 2))) / np.sqrt(6.0))
        out = smoothing.mean_noise(300.0 + noise, sigma, 15, win, starts, ends)
        assert np.array_equal(out, sigma) and smoothing.correlated_windows == 0


def test_the_torque_goes_to_the_load_model_where_it_explains_the_effort():
    n = 2000
    win, starts, ends = _windows([n, n])
    rng = np.random.default_rng(3)
    model = np.tile(np.linspace(-100.0, 100.0, n), 2)
    torque = model + rng.normal(0.0, 5.0, 2 * n)
    torque[n:] += 80.0 * np.sin(np.linspace(0.0, 20.0, n))    # the model misses this window
    band = np.full(2 * n, 3.0 * 5.0)
    out, narrowed = SMOOTHING.toward_model(torque, band, model, win, starts)
    assert np.std(out[:n] - model[:n]) < 1.0 and np.all(narrowed[:n] < band[:n])
    assert np.std(out[n:] - torque[n:]) < 1.0 and np.allclose(narrowed[n:], band[n:], rtol=0.01)
