"""
Array operations over the windows of one stream, and least squares that keep to the data.

Shared by the window analysis (:mod:`.window_analysis`) and the friction fit
(:mod:`.friction_fit`): centred means cut at the windows' ends, shifted
copies, per-window medians, and stacked normal equations solved for the
parameters the data identify.
"""

import numpy as np

MIN_IDENTIFIABILITY = 3e-3
"""
Smallest fraction of a regressor's energy left after the other regressors.

Below it, a harmonic or the time offset cannot be told apart from the torque
dependence (e.g. the 1x order when gravity makes ``T`` proportional to
``cos(theta)`` at constant speed) and is reported as NaN. 0.3 %: at 0.1 % a
weakly identified 2x order absorbed the hysteresis of an unloaded joint whose
load sign follows its position (-48 % at 5 % effort noise); at 1 % the 1x order
was left in the torque lines of a gravity-loaded joint at 100 Hz (+4 %).
"""


def window_mean(values, half, win, starts, ends):
    """
    Centred mean of ``values[i - half .. i + half]`` cut at the ends of each window.

    ``half`` is one half-width [samples] for every window, or an array of one per
    window; a window's means depend on its own samples and half-width only.

    Returns
    -------
    tuple of ndarray
        The means and the number of samples each one averages (``2·half + 1`` inside a
        window, fewer within ``half`` of its ends); ``values`` itself when ``half`` is 0.

    """
    if np.ndim(half):
        return _window_mean_each(values, np.asarray(half), win, starts, ends)
    n = values.size
    width = 2 * half + 1
    count = np.full(n, width, dtype=np.int64)
    if half <= 0:
        return values, count
    # Whole inside, computed again (with its length) near the ends of each window.
    edge = window_edges(starts, ends, half)
    lo = np.maximum(edge - half, starts[win[edge]])
    hi = np.minimum(edge + half + 1, ends[win[edge]])
    acc = np.concatenate([[0.0], np.cumsum(values)])
    mean = np.empty(n)
    if n > 2 * half:
        mean[half:n - half] = (acc[width:] - acc[:n + 1 - width]) / width
    mean[edge] = (acc[hi] - acc[lo]) / (hi - lo)
    count[edge] = hi - lo
    return mean, count


def _window_mean_each(values, halves, win, starts, ends):
    """:func:`window_mean` with a half-width per window (the same sums, sample by sample)."""
    if halves.size == 0 or np.all(halves == halves[0]):
        return window_mean(values, int(halves[0]) if halves.size else 0, win, starts, ends)
    h = halves[win]
    index = np.arange(values.size)
    lo = np.maximum(index - h, starts[win])
    hi = np.minimum(index + h + 1, ends[win])
    acc = np.concatenate([[0.0], np.cumsum(values)])
    count = hi - lo
    mean = np.where(h > 0, (acc[hi] - acc[lo]) / count, values)
    return mean, np.where(h > 0, count, 2 * h + 1)


def shifted(values, shift):
    """Return ``values[clip(i + shift, 0, n - 1)]`` for every index ``i`` (slices, no gather)."""
    n = values.size
    out = np.empty_like(values)
    if n == 0:
        return out
    k = min(abs(shift), n)
    if shift >= 0:
        out[:n - k] = values[k:]
        out[n - k:] = values[-1]
    else:
        out[k:] = values[:n - k]
        out[:k] = values[0]
    return out


def window_edges(starts, ends, half):
    """Return the indices within ``half`` samples of either end of their window."""
    if half <= 0:
        return np.zeros(0, dtype=np.int64)
    offsets = np.arange(half)
    head = np.minimum(starts[:, None] + offsets, ends[:, None] - 1)
    tail = np.maximum(ends[:, None] - half + offsets, starts[:, None])
    return np.unique(np.concatenate([head.ravel(), tail.ravel()]))


def window_medians(values, starts, ends):
    """
    Median of ``values[starts[k]:ends[k]]`` per window, 0 for a window with none.

    Windows of equal length take one call of :func:`numpy.median` along rows (the
    same partition and mean as one window at a time).
    """
    out = np.zeros(starts.size)
    lengths = ends - starts
    for m in np.unique(lengths[lengths > 0]).tolist():
        rows = np.flatnonzero(lengths == m)
        out[rows] = np.median(values[starts[rows, None] + np.arange(m)], axis=1)
    return out


def solve_identifiable_many(normal, rhs, energy):
    """
    Solve a stack of normal equations, leaving out parameters the data cannot identify.

    Shapes (W, P, P), (W, P), (W, P). A parameter is identifiable when the share of
    its regressor's energy that no other regressor explains, ``1/(A^-1)_jj`` of the
    energy-scaled matrix ``A``, is at least :data:`MIN_IDENTIFIABILITY`; the least
    identifiable parameter of a system is removed until all that remain pass. Each
    round inverts the systems that keep the same parameters as one stack (the same
    LAPACK call per matrix as one at a time).

    Returns
    -------
    tuple of ndarray
        Coefficients (0 where not identifiable) and the identifiable masks.

    """
    n_sys, n_par = rhs.shape
    ident = energy > 0.0
    scale = np.where(ident, 1.0 / np.sqrt(np.where(ident, energy, 1.0)), 0.0)
    a = normal * (scale[:, :, None] * scale[:, None, :])
    b = rhs * scale
    beta = np.zeros((n_sys, n_par))
    bits = 1 << np.arange(n_par)
    active = ident.any(axis=1)
    while active.any():
        rows = np.flatnonzero(active)
        keys = ident[rows] @ bits
        for key in np.unique(keys).tolist():
            group = rows[keys == key]
            idx = np.flatnonzero(ident[group[0]])
            inv, share = _identifiability(a[group[:, None, None], idx[:, None], idx])
            worst = np.argmin(share, axis=1)
            for j, k in enumerate(group.tolist()):
                if share[j, worst[j]] >= MIN_IDENTIFIABILITY:
                    beta[k, idx] = inv[j] @ b[k, idx] * scale[k, idx]
                    active[k] = False
                else:
                    ident[k, idx[worst[j]]] = False
                    active[k] = ident[k].any()
    return beta, ident


def _identifiability(sub):
    """
    Inverses of a stack of scaled normal matrices and each parameter's unexplained share.

    A singular matrix gets a share of 0 for every parameter.
    """
    try:
        inv = np.linalg.inv(sub)
    except np.linalg.LinAlgError:
        inv = np.zeros_like(sub)
        share = np.zeros(sub.shape[:2])
        for j in range(sub.shape[0]):
            try:
                inv[j] = np.linalg.inv(sub[j])
            except np.linalg.LinAlgError:
                continue
            with np.errstate(divide='ignore'):
                share[j] = 1.0 / np.diag(inv[j])
        return inv, np.where(np.isfinite(share), share, 0.0)
    with np.errstate(divide='ignore'):
        share = 1.0 / np.diagonal(inv, axis1=1, axis2=2)
    return inv, np.where(np.isfinite(share), share, 0.0)


class FadedLeastSquares:
    """
    Weighted least squares over a stream's recent windows, older windows faded.

    The normal equations ``Σ w·u·uᵀ``, ``Σ w·u·y``, ``Σ w·y²`` and the count of rows are
    kept, each window's rows added at once and everything before them multiplied by
    ``fade``; the solution's covariance is scaled by the rows' scatter about it where it
    exceeds their standard errors (the Birge ratio). Used by the checks that compare the
    windows' readings with a line or plane pooled over the stream
    (:mod:`.within_zone`, :mod:`.load_reach`).

    Parameters
    ----------
    size : int
        The number of regressors ``k`` (a row ``u`` holds ``k`` values).
    fade : float
        The factor a window's rows are kept by at each next window (0-1).

    """

    MAX_CONDITION = 1e12
    """Condition number of the scaled normal matrix beyond which nothing is solved."""

    def __init__(self, size, fade):
        self.size, self.fade = int(size), float(fade)
        self.S = np.zeros((self.size, self.size))
        self.r = np.zeros(self.size)
        self.yy = 0.0
        self.n = 0.0

    def add(self, u, y, w):
        """
        Add one window's rows after fading the earlier ones.

        Parameters
        ----------
        u : ndarray, shape (m, k)
            Regressors.
        y, w : ndarray, shape (m,)
            Readings and their weights (inverse variances).

        """
        u, y, w = np.atleast_2d(u), np.asarray(y, dtype=float), np.asarray(w, dtype=float)
        self.S = self.fade * self.S + (u * w[:, None]).T @ u
        self.r = self.fade * self.r + u.T @ (w * y)
        self.yy = self.fade * self.yy + float(w @ (y * y))
        self.n = self.fade * self.n + float(y.size)

    def solve(self):
        """
        Return the coefficients and their covariance (Birge-scaled), or None.

        Returns
        -------
        tuple or None
            ``(beta, cov)``; None with no more rows than regressors, or a normal matrix
            singular or conditioned past :data:`MAX_CONDITION`.

        """
        scale = np.sqrt(np.diag(self.S))
        if not (self.n > self.size and np.all(scale > 0.0)):
            return None
        norm = self.S / np.outer(scale, scale)
        if not np.linalg.cond(norm) < self.MAX_CONDITION:
            return None
        inv = np.linalg.inv(norm) / np.outer(scale, scale)
        beta = inv @ self.r
        rss = max(self.yy - float(beta @ self.r), 0.0)
        return beta, inv * max(1.0, rss / (self.n - self.size))

    def state(self):
        """Return the sums as plain JSON-able data."""
        return {'S': self.S.ravel().tolist(), 'r': self.r.tolist(), 'yy': self.yy,
                'n': self.n}

    def continue_from(self, state):
        """
        Continue from :meth:`state`.

        Raises
        ------
        ValueError
            If a sum is of the wrong size or not finite; nothing is changed then.
        KeyError, TypeError
            If a key is missing or a value is of the wrong type.

        """
        S = np.array(state['S'], dtype=float)
        r = np.array(state['r'], dtype=float)
        yy, n = float(state['yy']), float(state['n'])
        if not (S.shape == (self.size ** 2,) and r.shape == (self.size,)
                and np.all(np.isfinite(S)) and np.all(np.isfinite(r))
                and np.isfinite(yy) and np.isfinite(n) and n >= 0.0):
            raise ValueError(f'S must be {self.size ** 2} finite sums, r {self.size}, yy and '
                             'n finite')
        self.S, self.r, self.yy, self.n = S.reshape(self.size, self.size), r, yy, n
