"""
The numerics of a Gaussian sum of unscented filters, without the reducer in them.

The wear estimator (:mod:`.estimator`) carries its belief as a weighted sum of
Gaussian components ``(log w_c, m_c, P_c)``, each an unscented filter
(Alspach & Sorenson 1972; Julier & Uhlmann 1997). This module holds what that
takes and nothing of the reducer: the scaled sigma points of every component
at once and their moments (:class:`UnscentedTransform`), the update of every
component by one scalar observation, iterated by posterior linearisation where
a component is wide (García-Fernández et al. 2015), with consider states held at
their prior moments (Schmidt 1966), the moment matching of the sum
(:func:`mixture_moments`), and the pruning and merging that keep it small
(:func:`tidy`). The estimator gives the process and observation functions and
says which components are wide and which states are considered.
"""

import math

import numpy as np

from .sigma_points import merwe_weights

MERGE_DISTANCE = 1.0 / 3.0
"""Mahalanobis distance of two components' means below which they are merged."""

PRUNE_LOG_WEIGHT = -23.0
"""Components whose log weight falls this far below the best are dropped."""

POSTERIOR_ITERATIONS = 8
"""Most relinearisations of a wide component's update."""


def logsumexp(a):
    """Return ``log Σ exp(a)``, computed from the largest term."""
    top = float(np.max(a))
    return top + math.log(float(np.sum(np.exp(a - top))))


def chol(P):
    """Batched Cholesky factor of covariances, made positive definite where they are not."""
    try:
        return np.linalg.cholesky(P)
    except np.linalg.LinAlgError:
        vals, vecs = np.linalg.eigh(0.5 * (P + np.swapaxes(P, -1, -2)))
        floor = 1e-12 * np.maximum(vals.max(axis=-1, keepdims=True), 1e-300)
        fixed = (vecs * np.maximum(vals, floor)[..., None, :]) @ np.swapaxes(vecs, -1, -2)
        return np.linalg.cholesky(fixed)


def mixture_moments(log_weights, means, covs):
    """
    Moment-match a Gaussian sum: its mean and covariance.

    Parameters
    ----------
    log_weights : ndarray, shape (C,)
        Log weights (need not be normalised).
    means : ndarray, shape (C, n)
        Component means.
    covs : ndarray, shape (C, n, n)
        Component covariances.

    Returns
    -------
    tuple of ndarray
        Mean (n,) and covariance (n, n).

    """
    w = np.exp(log_weights - np.max(log_weights))
    w = w / w.sum()
    m = w @ means
    d = means - m
    P = np.einsum('c,cij->ij', w, covs) + np.einsum('c,ci,cj->ij', w, d, d)
    return m, 0.5 * (P + P.T)


def hold_states(m, P, m0, P0, which, index):
    """
    Keep consider states at their prior moments (Schmidt 1966).

    A consider state keeps its mean and variance through an update; its covariances
    with the other states are updated, so the reported uncertainty still carries
    what the data cannot remove.

    Parameters
    ----------
    m, P : ndarray, shapes (C, n), (C, n, n)
        Updated moments, changed in place.
    m0, P0 : ndarray
        Prior moments.
    which : ndarray of bool, shape (C,)
        The components to which it applies.
    index : int
        The state held.

    """
    m[which, index] = m0[which, index]
    P[which, index, index] = P0[which, index, index]


class UnscentedTransform:
    """
    Scaled sigma points of every component of a Gaussian sum, and their moments.

    Van der Merwe's scaled points (:func:`.sigma_points.merwe_weights`): ``2n + 1``
    per component, at the mean and at ``±sqrt(α²(n + κ))`` times the columns of the
    covariance's Cholesky factor.

    Parameters
    ----------
    n : int
        State dimension.
    alpha, beta, kappa : float
        The points' spread, prior knowledge of the distribution and secondary scaling.

    """

    def __init__(self, n, alpha, beta, kappa):
        self.wm, self.wc = merwe_weights(n, alpha, beta, kappa)
        self.spread = math.sqrt(alpha ** 2 * (n + kappa))

    def points(self, m, P):
        """Sigma points of every component, shape (C, 2n+1, n)."""
        L = chol(P) * self.spread
        cols = np.swapaxes(L, -1, -2)
        return np.concatenate([m[:, None, :], m[:, None, :] + cols, m[:, None, :] - cols], axis=1)

    def mean(self, X):
        """Weighted mean of every component's points, shape (C, n)."""
        return np.einsum('k,ckn->cn', self.wm, X)

    def moments(self, X, Z=None):
        """Weighted mean and covariance of sigma points (and of their observations)."""
        m = self.mean(X)
        d = X - m[:, None, :]
        P = np.einsum('k,cki,ckj->cij', self.wc, d, d)
        if Z is None:
            return m, P
        return (m, P) + self.observed(Z, d)

    def observed(self, Z, d=None):
        """
        Mean and variance of the points' observations, and their covariance with the state.

        ``d`` the points less their mean (:meth:`moments`' terms); without it, only the
        mean and variance. The state's own covariance, a sum over every point and pair
        of states, is not formed where it is not wanted.
        """
        z = Z @ self.wm
        dz = Z - z[:, None]
        szz = (dz ** 2) @ self.wc
        if d is None:
            return z, szz
        return z, szz, np.einsum('k,cki,ck->ci', self.wc, d, dz)

    def posterior(self, m0, P0, z, R, zc, szz, cxz, hx, wide, hold):
        """
        Update every component by a scalar observation; relinearise the wide ones.

        Parameters
        ----------
        m0, P0 : ndarray, shapes (C, n), (C, n, n)
            The components' prior moments.
        z : float
            The observation.
        R : ndarray, shape (C,)
            Its noise per component.
        zc, szz, cxz : ndarray
            The prior's observed moments (:meth:`observed`): the first iterate.
        hx : callable
            The observation of sigma points, ``(C, 2n+1, n) -> (C, 2n+1)``.
        wide : ndarray of bool, shape (C,)
            The components whose update is relinearised about its posterior (at most
            :data:`POSTERIOR_ITERATIONS` times, until the mean moves by less than
            1e-3 sd).
        hold : tuple
            ``(which, index)`` of :func:`hold_states`, applied to every iterate.

        Returns
        -------
        tuple of ndarray
            The posterior means and covariances.

        """
        S = szz + R
        K = cxz / S[:, None]
        m = m0 + K * (z - zc)[:, None]
        P = P0 - np.einsum('ci,cj->cij', K, K) * S[:, None, None]
        which, index = hold
        hold_states(m, P, m0, P0, which, index)
        if not wide.any():
            return m, P
        for _ in range(POSTERIOR_ITERATIONS):
            X = self.points(m[wide], P[wide])
            mi, Pi, zi, szi, cxi = self.moments(X, hx(X))
            H = np.linalg.solve(Pi, cxi[..., None])[..., 0]
            omega = np.maximum(szi - np.einsum('ci,cij,cj->c', H, Pi, H), 0.0)
            P0w, m0w = P0[wide], m0[wide]
            Sw = np.einsum('ci,cij,cj->c', H, P0w, H) + R[wide] + omega
            Kw = np.einsum('cij,cj->ci', P0w, H) / Sw[:, None]
            resid = z - (zi - np.einsum('ci,ci->c', H, mi)) - np.einsum('ci,ci->c', H, m0w)
            new_m = m0w + Kw * resid[:, None]
            new_P = P0w - np.einsum('ci,cj->cij', Kw, Kw) * Sw[:, None, None]
            hold_states(new_m, new_P, m0w, P0w, which[wide], index)
            moved = np.abs(new_m - m[wide]) / np.sqrt(np.einsum('cii->ci', P[wide]))
            m[wide] = new_m
            P[wide] = new_P
            if np.all(moved < 1e-3):
                break
        return m, P


def tidy(lw, m, P, order_by):
    """
    Drop negligible components, merge converged ones; return the sum, weights normalised.

    A component whose log weight is :data:`PRUNE_LOG_WEIGHT` below the best is dropped.
    The rest, in the order of state ``order_by``, are merged with their neighbour when
    their means lie within :data:`MERGE_DISTANCE` of each other (Mahalanobis distance
    under the summed covariance): one component does.

    Parameters
    ----------
    lw, m, P : ndarray, shapes (C,), (C, n), (C, n, n)
        Log weights, means and covariances.
    order_by : int
        The state along which neighbours are taken.

    Returns
    -------
    tuple of ndarray
        ``(lw, m, P)`` of the tidied sum.

    """
    keep = lw >= lw.max() + PRUNE_LOG_WEIGHT
    if not keep.all():
        lw, m, P = lw[keep], m[keep], P[keep]
    if lw.size > 1:
        order = np.argsort(m[:, order_by], kind='stable')
        lw, m, P = lw[order], m[order], P[order]
        # Each neighbour's pair, solved at once (the same LAPACK solve per pair); a
        # pair after a merge is solved on its own.
        gaps = m[1:] - m[:-1]
        try:
            solved = np.linalg.solve(P[:-1] + P[1:], gaps[..., None])[..., 0]
        except np.linalg.LinAlgError:
            solved = None
        if solved is not None and \
                np.all(np.einsum('ci,ci->c', gaps, solved) > MERGE_DISTANCE ** 2):
            # No neighbours close enough: the components stay as they are (in order).
            return lw - logsumexp(lw), m, P
        out = [[lw[0], m[0], P[0]]]
        merged = False
        for k in range(1, lw.size):
            a = out[-1]
            if merged or solved is None:
                d = m[k] - a[1]
                x = np.linalg.solve(a[2] + P[k], d)
            else:
                d, x = gaps[k - 1], solved[k - 1]
            merged = d @ x <= MERGE_DISTANCE ** 2
            if merged:
                both = np.array([a[0], lw[k]])
                mm, pp = mixture_moments(both, np.array([a[1], m[k]]), np.array([a[2], P[k]]))
                out[-1] = [logsumexp(both), mm, pp]
            else:
                out.append([lw[k], m[k], P[k]])
        lw = np.array([o[0] for o in out])
        m = np.array([o[1] for o in out])
        P = np.array([o[2] for o in out])
    return lw - logsumexp(lw), m, P
