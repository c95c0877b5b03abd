"""Array operations over the windows of one stream, against plain loops."""

from hypothesis import given, settings
from hypothesis import strategies as st
import numpy as np
import pytest
from reducer_twin.core.window_ops import FadedLeastSquares
from reducer_twin.core.window_ops import MIN_IDENTIFIABILITY, shifted, solve_identifiable_many
from reducer_twin.core.window_ops import window_mean, window_medians


def _windows(lengths):
    ends = np.cumsum(lengths)
    starts = ends - np.asarray(lengths)
    win = np.repeat(np.arange(len(lengths)), lengths)
    return win, starts, ends


@settings(max_examples=60)
@given(lengths=st.lists(st.integers(1, 30), min_size=1, max_size=6), half=st.integers(0, 5),
       seed=st.integers(0, 100))
def test_the_centred_mean_is_cut_at_the_ends_of_each_window(lengths, half, seed):
    values = np.random.default_rng(seed).normal(size=sum(lengths))
    win, starts, ends = _windows(lengths)
    mean, count = window_mean(values, half, win, starts, ends)
    for i in range(values.size):
        lo = max(i - half, starts[win[i]])
        hi = min(i + half + 1, ends[win[i]])
        assert count[i] == (hi - lo if half else 2 * half + 1)
        assert np.isclose(mean[i], values[lo:hi].mean() if half else values[i])


@settings(max_examples=60)
@given(shape=st.lists(st.tuples(st.integers(1, 30), st.integers(0, 5)), min_size=1,
                      max_size=6), seed=st.integers(0, 100))
def test_a_window_averaged_with_its_own_half_width_is_as_if_averaged_alone(shape, seed):
    lengths, halves = zip(*shape)
    values = np.random.default_rng(seed).normal(size=sum(lengths))
    win, starts, ends = _windows(lengths)
    mean, count = window_mean(values, np.array(halves), win, starts, ends)
    for k, half in enumerate(halves):
        one = slice(starts[k], ends[k])
        alone = window_mean(values[one], half, *_windows([lengths[k]]))
        np.testing.assert_array_equal(count[one], alone[1])
        np.testing.assert_allclose(mean[one], alone[0], rtol=1e-12, atol=1e-12)


def test_a_shifted_copy_repeats_the_end_samples():
    values = np.arange(5.0)
    np.testing.assert_array_equal(shifted(values, 2), [2, 3, 4, 4, 4])
    np.testing.assert_array_equal(shifted(values, -2), [0, 0, 0, 1, 2])
    np.testing.assert_array_equal(shifted(values, 9), [4, 4, 4, 4, 4])
    assert shifted(np.zeros(0), 1).size == 0


def test_per_window_medians_are_each_windows_median_and_0_for_an_empty_one():
    values = np.random.default_rng(3).normal(size=40)
    starts, ends = np.array([0, 10, 10, 25]), np.array([10, 10, 25, 40])
    got = window_medians(values, starts, ends)
    want = [np.median(values[a:b]) if b > a else 0.0 for a, b in zip(starts, ends)]
    np.testing.assert_array_equal(got, want)


def test_a_regressor_another_explains_is_left_out_and_the_rest_solved_exactly():
    # Three regressors, the third a copy of the first plus a trace of noise below the
    # identifiability floor: it is dropped; the first two keep the coefficients that made y.
    rng = np.random.default_rng(0)
    x = rng.normal(size=(2, 500))
    third = x[0] + np.sqrt(0.1 * MIN_IDENTIFIABILITY) * rng.normal(size=500)
    a = np.vstack([x, third])
    y = 2.0 * x[0] - 3.0 * x[1]
    normal, rhs, energy = a @ a.T, a @ y, np.einsum('ij,ij->i', a, a)
    beta, ident = solve_identifiable_many(normal[None], rhs[None], energy[None])
    assert ident[0].tolist() in ([True, True, False], [False, True, True])
    fitted = beta[0] @ a
    np.testing.assert_allclose(fitted, y, atol=0.05 * np.abs(y).max())
    # The same system with an independent third regressor keeps all three.
    a[2] = rng.normal(size=500)
    normal, rhs, energy = a @ a.T, a @ y, np.einsum('ij,ij->i', a, a)
    beta, ident = solve_identifiable_many(normal[None], rhs[None], energy[None])
    assert ident[0].all()
    np.testing.assert_allclose(beta[0], [2.0, -3.0, 0.0], atol=1e-9)


def test_a_faded_line_recovers_its_coefficients_and_scales_its_covariance_by_the_scatter():
    rng = np.random.default_rng(0)
    fit = FadedLeastSquares(2, 0.9)
    assert fit.solve() is None                      # no rows
    fit.add([[1.0, 1.0]], [3.0], [1.0])
    fit.add([[1.0, 2.0]], [5.0], [1.0])
    assert fit.solve() is None                      # no more rows than coefficients
    for _ in range(40):
        x = rng.uniform(0.0, 10.0, 5)
        fit.add(np.column_stack([np.ones(5), x]), 1.0 + 2.0 * x + rng.normal(0.0, 0.5, 5),
                np.full(5, 1.0 / 0.01 ** 2))
    beta, cov = fit.solve()
    np.testing.assert_allclose(beta, [1.0, 2.0], atol=0.3)
    # Standard errors of 0.01 claimed, 0.5 scattered: the covariance is widened to it.
    assert 0.02 < np.sqrt(cov[1, 1]) < 0.1
    again = FadedLeastSquares(2, 0.9)
    again.continue_from(fit.state())
    np.testing.assert_array_equal(again.solve()[0], beta)


def test_old_windows_fade_away():
    fit = FadedLeastSquares(1, 0.5)
    for _ in range(60):
        fit.add([[1.0]], [1.0], [1.0])
    for _ in range(60):
        fit.add([[1.0]], [3.0], [1.0])
    assert fit.solve()[0][0] == pytest.approx(3.0, abs=1e-9)
    assert fit.n == pytest.approx(2.0)
