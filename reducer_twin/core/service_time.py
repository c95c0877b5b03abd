"""
A used reducer's service time (a robot's hour meter): what it says of the unit's rate.

A reducer met used whose operating time ``H`` before the twin's first window is known
(``service_time_s``) ran, at the duty the twin has since seen (rate ``r``: run-in-free
Archard wear per operating second at rate scale 1), to the run-in-free wear
``S(w) = e^θ·(r·H + a)``, ``a`` the Archard exposure since. Its past duty is not known
beyond a ratio ``e^ε``, ``ε ~ N(0, σ²)`` (``service_rate_log_std`` with the recent
rate's own standard error). The wear estimator (:mod:`.estimator`) takes it once, as
soon as the duty's rate is known, as the pseudo-observation
``S(w) - e^θ·(r·H + a) = 0`` of every component (:func:`service_update`): the lost
motion tells ``w``; with it the service time tells ``θ``, which a short recording of a
used unit cannot (without it that remaining life is the model's rate at the duty,
which may be many times off; measured: ``bench/bench_service_time.py``). A service
time that implies a rate beyond :data:`SERVICE_RATE_LIMIT` times the model's is not
taken, and :func:`service_note` says why.
"""

import numpy as np

from .gaussian_sum import logsumexp
from .units import HOUR

SERVICE_RATE_LIMIT = 1000.0
"""
Rate scale beyond which a service time is not taken (:func:`service_update`).

A service time that makes a unit's wear over it more than this many times the model's
rate at its duty is far likelier a time in hours read as seconds (3 600 times) than a
reducer that wore so fast all its life: the independent generator's units, whose lives
ignore the model, wear up to about 80 times its rate. Such a unit's own windows show
its rate soon anyway.
"""


def implied_rate_scale(free_wear, exposure):
    """
    Return the rate scale a service time implies: the unit's mean over its life so far.

    Parameters
    ----------
    free_wear : float
        Run-in-free wear ``S(w)`` of the wear the windows read so far [m].
    exposure : float
        Archard exposure over the service time and since, ``r·H + a`` [m].

    Returns
    -------
    float
        ``S(w)/(r·H + a)``, relative to the model's rate.

    """
    return float(free_wear) / exposure


def service_update(ut, lw, m, P, free_wear, past, exposure, log_std):
    """
    Update every component by the service time's pseudo-observation (unscented).

    Parameters
    ----------
    ut : UnscentedTransform
        The components' sigma points (:mod:`.gaussian_sum`).
    lw, m, P : ndarray, shapes (C,), (C, n), (C, n, n)
        The Gaussian sum over ``[w, ln s, ...]``.
    free_wear : callable
        ``S(w)`` of an array of wears [m].
    past : float
        Archard exposure over the service time, ``r·H`` [m].
    exposure : float
        Archard exposure over the service time and since, ``r·H + a`` [m].
    log_std : float
        Sd ``σ`` of the past duty's log ratio to today's.

    Returns
    -------
    tuple of ndarray
        ``(lw, m, P)``: each component updated with ``S(w) - e^θ·(r·H + a) = 0`` under
        the noise ``σ·e^θ·r·H`` at its mean, its weight by its likelihood (normalised).

    """
    X = ut.points(m, P)
    Z = free_wear(X[..., 0]) - np.exp(X[..., 1]) * exposure
    zc, szz, cxz = ut.observed(Z, X - ut.mean(X)[:, None, :])
    R = (log_std * np.exp(m[:, 1]) * past) ** 2
    S = szz + R
    gain = cxz / S[:, None]
    m_new = m - gain * zc[:, None]
    P_new = P - np.einsum('ci,cj->cij', gain, gain) * S[:, None, None]
    lw_new = lw - 0.5 * (np.log(S) + zc ** 2 / S)
    lw_new -= logsumexp(lw_new)
    return lw_new, m_new, 0.5 * (P_new + np.swapaxes(P_new, 1, 2))


def service_note(verdict, service_time_s):
    """
    Say how a reducer's service time was taken (:attr:`.estimator.WearEstimator.service_verdict`).

    Parameters
    ----------
    verdict : tuple
        ``(taken, rate_scale)``.
    service_time_s : float
        The service time [s].

    Returns
    -------
    str
        One line; one that is not taken names the likely mistake (hours given as seconds).

    """
    taken, scale = verdict
    hours = service_time_s / HOUR
    if taken:
        return (f'service time {hours:,.0f} h taken: its wear over it is {scale:.3g} times the '
                "model's rate at this duty")
    return (f'service time {service_time_s:g} s ({hours:,.1f} h) not taken: it would make the '
            f"unit's wear {scale:,.0f} times the model's rate at this duty (more than "
            f'{SERVICE_RATE_LIMIT:,.0f}); service_time_s is in seconds ({service_time_s:g} h '
            f'would be {service_time_s * HOUR:.4g} s)')
