"""
The Gaussian sum's numerics (``reducer_twin.core.gaussian_sum``), without a reducer.

The sigma points are filterpy's; on a linear observation the unscented moments and the
update are exact (the Kalman filter's); a consider state keeps its prior moments; a
negligible component is dropped, coincident ones become one with the sum's moments,
distant ones stay.
"""

from filterpy.kalman import MerweScaledSigmaPoints
import numpy as np
import pytest
from reducer_twin.core.gaussian_sum import (
    chol, hold_states, MERGE_DISTANCE, mixture_moments, PRUNE_LOG_WEIGHT, tidy,
    UnscentedTransform)

RNG = np.random.default_rng(7)


def _covariances(count, n):
    a = RNG.standard_normal((count, n, n))
    return a @ np.swapaxes(a, 1, 2) + 0.1 * np.eye(n)


@pytest.mark.parametrize('alpha, beta, kappa', [(1.0, 2.0, 0.0), (0.5, 2.0, 1.0)])
def test_the_points_are_filterpys_and_keep_each_components_moments(alpha, beta, kappa):
    ut = UnscentedTransform(3, alpha, beta, kappa)
    m, P = RNG.standard_normal((2, 3)), _covariances(2, 3)
    X = ut.points(m, P)
    assert X.shape == (2, 7, 3)
    reference = MerweScaledSigmaPoints(3, alpha=alpha, beta=beta, kappa=kappa)
    for c in range(2):
        np.testing.assert_allclose(X[c], reference.sigma_points(m[c], P[c]), atol=1e-12)
    mean, cov = ut.moments(X)
    np.testing.assert_allclose(mean, m, atol=1e-12)
    np.testing.assert_allclose(cov, P, atol=1e-12)


def test_a_linear_observations_moments_are_exact():
    ut = UnscentedTransform(3, 1.0, 2.0, 0.0)
    m, P = RNG.standard_normal((2, 3)), _covariances(2, 3)
    H = np.array([0.5, -2.0, 1.0])
    X = ut.points(m, P)
    _, _, z, szz, cxz = ut.moments(X, X @ H)
    np.testing.assert_allclose(z, m @ H, atol=1e-12)
    np.testing.assert_allclose(szz, np.einsum('i,cij,j->c', H, P, H), atol=1e-12)
    np.testing.assert_allclose(cxz, P @ H, atol=1e-12)
    z_only, szz_only = ut.observed(X @ H)
    np.testing.assert_allclose([z_only, szz_only], [z, szz], atol=0.0)


@pytest.mark.parametrize('wide', [False, True], ids=['one pass', 'relinearised'])
def test_the_update_by_a_linear_observation_is_the_kalman_filters(wide):
    ut = UnscentedTransform(3, 1.0, 2.0, 0.0)
    m0, P0 = RNG.standard_normal((2, 3)), _covariances(2, 3)
    H, z, R = np.array([1.0, 0.3, -0.7]), 0.8, np.array([0.2, 0.5])
    X = ut.points(m0, P0)
    zc, szz, cxz = ut.observed(X @ H, X - ut.mean(X)[:, None, :])
    none = np.zeros(2, dtype=bool)
    m, P = ut.posterior(m0, P0, z, R, zc, szz, cxz, lambda pts: pts @ H,
                        np.full(2, wide), (none, 0))
    for c in range(2):
        S = H @ P0[c] @ H + R[c]
        K = P0[c] @ H / S
        np.testing.assert_allclose(m[c], m0[c] + K * (z - H @ m0[c]), atol=1e-9)
        np.testing.assert_allclose(P[c], P0[c] - np.outer(K, K) * S, atol=1e-9)


def test_a_consider_state_keeps_its_prior_mean_and_variance_not_its_covariances():
    ut = UnscentedTransform(2, 1.0, 2.0, 0.0)
    m0, P0 = np.array([[0.0, 0.0]]), np.array([[[1.0, 0.5], [0.5, 1.0]]])
    X = ut.points(m0, P0)
    H = np.array([1.0, 1.0])
    zc, szz, cxz = ut.observed(X @ H, X - ut.mean(X)[:, None, :])
    m, P = ut.posterior(m0, P0, 2.0, np.array([0.1]), zc, szz, cxz, lambda pts: pts @ H,
                        np.array([False]), (np.array([True]), 1))
    assert m[0, 1] == 0.0 and P[0, 1, 1] == 1.0
    assert m[0, 0] > 0.5 and P[0, 0, 1] < 0.5 and P[0, 0, 0] < 1.0
    held_m, held_P = m0.copy() + 1.0, P0.copy() * 2.0
    hold_states(held_m, held_P, m0, P0, np.array([False]), 1)
    assert held_m[0, 1] == 1.0      # not a component it applies to


def test_the_sums_moments_are_the_laws_of_total_mean_and_variance():
    lw = np.log([0.25, 0.75])
    means = np.array([[0.0], [4.0]])
    covs = np.array([[[1.0]], [[2.0]]])
    m, P = mixture_moments(lw + 3.0, means, covs)      # unnormalised weights alike
    assert m[0] == pytest.approx(3.0)
    assert P[0, 0] == pytest.approx(0.25 * 1 + 0.75 * 2 + 0.25 * 9 + 0.75 * 1)


def test_tidy_drops_negligible_components_and_normalises():
    lw = np.array([0.0, PRUNE_LOG_WEIGHT - 1.0, -1.0])
    m = np.array([[0.0, 0.0], [5.0, 5.0], [0.0, 10.0]])
    P = np.tile(np.eye(2), (3, 1, 1))
    lw2, m2, P2 = tidy(lw, m, P, order_by=1)
    assert lw2.size == 2 and np.exp(lw2).sum() == pytest.approx(1.0)
    np.testing.assert_array_equal(m2, m[[0, 2]])


def test_tidy_merges_coincident_neighbours_into_the_sums_moments_and_keeps_distant_ones():
    P = np.tile(np.eye(2), (3, 1, 1))
    near = 0.5 * MERGE_DISTANCE * np.sqrt(2.0)       # Mahalanobis under the summed cov
    m = np.array([[0.0, 20.0], [0.0, 0.0], [0.0, near]])
    lw = np.log([0.2, 0.5, 0.3])
    lw2, m2, P2 = tidy(lw, m, P, order_by=1)
    assert lw2.size == 2
    merged_m, merged_P = mixture_moments(lw[1:], m[1:], P[1:])
    np.testing.assert_allclose(m2[0], merged_m)      # ordered along state 1
    np.testing.assert_allclose(P2[0], merged_P)
    np.testing.assert_allclose(np.exp(lw2), [0.8, 0.2])
    np.testing.assert_array_equal(m2[1], m[0])


def test_a_covariance_that_lost_definiteness_still_gets_a_factor():
    P = np.array([[[1.0, 1.0], [1.0, 1.0 - 1e-15]]])       # rounding made it indefinite
    L = chol(P)
    assert np.all(np.isfinite(L))
    np.testing.assert_allclose(L[0] @ L[0].T, P[0], atol=1e-9)
