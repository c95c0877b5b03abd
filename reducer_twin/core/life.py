"""
Remaining useful life: the predictor of the twin (progpy vocabulary).

The event is the catalogue accuracy limit: lost motion at ±3 % of rated
torque reaching ``limit`` (default 3 arcmin). Two predictions are mixed, with
the estimator's probability that the observed growth law holds
(:attr:`.estimator.WearEstimator.trend_probability`):

* the wear model: the estimator's joint Gaussian on ``x = [w, ln s, b]``
  (wear, rate scale, as-built offset). The unit reaches the limit at the
  wear ``w_lim = h⁻¹(limit) - b`` of its own curve, so a unit built loose
  starts closer to it. With the run-in-free Archard rate of the recent duty
  ``ȧ`` [m per operating second] the wear follows ``S(w(t)) = S(w) + s·ȧ·t``
  (run-in map of :mod:`.wear`), so the time of event is closed form::

      t = (S(w_lim) - S(w)) / (s·ȧ)

* the observed trend (:mod:`.growth`): ``z = β + k·(A/A_now)^g`` in the
  Archard exposure ``A``, so the limit is met at
  ``A_lim = A_now·((limit - β)/k)^(1/g)`` and ``t = (A_lim - A_now)/ȧ``.

Both are evaluated for ``n_samples`` draws at once (a few milliseconds for
2000 samples); the draws carry everything the estimate is unsure of, so the
interval is wide while the observed trend has not yet told the model's curve
from another law. Two uncertainties of the future are added: the future mean
duty rate (log-normal, relative sd ``duty_rate_rel_std``: the estimator's
standard error of the recent rate, plus any configured allowance) and, for
the wear model, the slow drift of ``ln s`` that the estimator's process model
allows (``rate_drift`` per operating second: the mean of a random walk over
``t`` has variance ``q·t/3``). Times beyond ``horizon_s`` are censored: a
percentile beyond the horizon is reported as the horizon with its
``*_censored`` flag set, never as NaN or infinity.

:func:`catalogue_life` gives the vendor's rated-life formula for the same
duty, to be shown beside the estimate.
"""

from dataclasses import dataclass, field
import math
from typing import NamedTuple

import numpy as np

from .errors import InvalidInput, InvalidParameter, out_of_range
from .estimator import N_STATE
from .growth import EXPONENTS
from .state_space import lost_motion_curve, run_in_free_wear, unit_lost_motion
from .state_space import wear_at_lost_motion
from .transmission_error import model_tables
from .units import ARCMIN, HOUR

LOST_MOTION_LIMIT = 3.0 * ARCMIN
"""Default accuracy limit on lost motion [rad] (3 arcmin)."""

DEFAULT_HORIZON_S = 100000.0 * HOUR
"""Default prediction horizon [s of operation] (100 000 h, about 17 rated lives)."""


@dataclass(frozen=True)
class LifePrediction:
    """
    Remaining useful life with its uncertainty, in seconds of operation.

    Attributes
    ----------
    p10, p50, p90 : float
        Percentiles of the time of event [s]; the horizon when censored.
    p10_censored, p50_censored, p90_censored : bool
        The percentile lies beyond ``horizon_s``.
    mean : float
        Restricted mean ``E[min(t, horizon)]`` [s] (a censored sample has no
        mean of its own).
    fraction_censored : float
        Share of samples that do not reach the limit within the horizon.
    limit_reached : bool
        The estimated wear is already at or past the limit, and so is the observed
        growth law where it has a weight (all times 0).
    event_state : float
        1 for a new reducer, 0 at the limit (progpy ``event_state``), of the lost motion
        ``threshold_met`` compares.
    threshold_met : bool
        The estimated lost motion is at or above the limit: the wear model's at the mean
        mixed with the growth law's by the law's weight in the remaining life (the
        estimator's lost motion mixes them by the law's probability, which the weight
        moves towards its prior where the law is extrapolated beyond its scored span).
    horizon_s : float
        Horizon used [s].
    wear_limit : float
        Wear at which the limit is reached [m].
    n_samples : int
        Number of samples drawn.
    samples : ndarray or None
        The sampled times, capped at the horizon [s], when asked for.

    """

    p10: float
    p50: float
    p90: float
    p10_censored: bool
    p50_censored: bool
    p90_censored: bool
    mean: float
    fraction_censored: float
    limit_reached: bool
    event_state: float
    threshold_met: bool
    horizon_s: float
    wear_limit: float
    n_samples: int
    samples: np.ndarray = field(default=None, repr=False, compare=False)


def _state_arrays(state):
    """
    Return ``(x, P)`` of an estimator or of an ``(x, P)`` pair, validated, as four states.

    A two-state ``[w, ln s]`` (the estimator before per-unit states) is a
    nominal unit: ``b = 0``, exactly.
    """
    if hasattr(state, 'x') and hasattr(state, 'P'):
        x, P = state.x, state.P
    else:
        try:
            x, P = state
        except (TypeError, ValueError) as err:
            raise InvalidInput(
                f'state must be an estimator or an (x, P) pair, got {type(state).__name__}'
            ) from err
    x = np.asarray(x, dtype=float)
    P = np.asarray(P, dtype=float)
    n = x.shape[0] if x.ndim == 1 else 0
    if n not in (2, N_STATE) or P.shape != (n, n):
        raise InvalidInput(f'state x must have shape (2,) or ({N_STATE},) and P the matching '
                           f'square, got {x.shape}, {P.shape}')
    if not (np.all(np.isfinite(x)) and np.all(np.isfinite(P))):
        raise InvalidInput('state x and P must be finite')
    if n == 2:
        x = np.concatenate([x, np.zeros(N_STATE - 2)])
        P = np.pad(P, ((0, N_STATE - 2), (0, N_STATE - 2)))
    return x, P


def _covariance_root(P):
    """Return ``L`` with ``L·Lᵀ = P`` (Cholesky; eigen-decomposition if only semidefinite)."""
    P = 0.5 * (P + P.T)
    try:
        return np.linalg.cholesky(P)
    except np.linalg.LinAlgError:
        vals, vecs = np.linalg.eigh(P)
        if vals.min() < -1e-9 * max(vals.max(), 0.0) - 1e-300:
            raise InvalidInput(f'state P must be positive semidefinite, eigenvalues {vals}')
        return vecs * np.sqrt(np.maximum(vals, 0.0))


def _covariance_roots(covs):
    """
    Return :func:`_covariance_root` of each of a stack of covariances, shape (Q, m, m).

    One batched Cholesky factorisation (the same LAPACK call per matrix); where one of
    them is only semidefinite, each goes through :func:`_covariance_root`.
    """
    covs = np.asarray(covs, dtype=float)
    sym = 0.5 * (covs + np.swapaxes(covs, -1, -2))
    try:
        return np.linalg.cholesky(sym)
    except np.linalg.LinAlgError:
        return np.array([_covariance_root(P) for P in covs])


def limit_wear(params, limit=LOST_MOTION_LIMIT):
    """
    Wear at which the lost motion reaches ``limit`` [m].

    Parameters
    ----------
    params : ReducerParams
        Reducer parameters.
    limit : float
        Lost-motion limit [rad]; must lie inside the tabulated range.

    Returns
    -------
    float
        ``w_lim = LM⁻¹(limit)`` [m] (``tables.wear_for_lost_motion``).

    Raises
    ------
    InvalidParameter
        If the limit is not above the new reducer's lost motion or beyond
        the table.

    """
    _check_limit(lost_motion_curve(params), limit)
    return float(model_tables(params).wear_for_lost_motion(limit))


def _check_limit(curve, limit):
    """Refuse a limit [rad] outside the tabulated lost motion of ``curve``."""
    lo, hi = float(curve.lost_motion[0]), float(curve.lost_motion[-1])
    if not (math.isfinite(limit) and lo < limit <= hi):
        raise InvalidParameter(out_of_range('limit', limit, 'rad', f'in ({lo:.6g}, {hi:.6g}]'))


def event_state(wear, params, limit=LOST_MOTION_LIMIT, baseline=0.0):
    """
    Health of the reducer, 1 when new, 0 at the accuracy limit (progpy).

    ``es = 1 - (LM(w) - LM(0))/(limit - LM(0))``, clipped to [0, 1], with
    ``LM(w) = h(w + b)`` the unit's lost-motion curve.

    Parameters
    ----------
    wear : array_like
        Combined wear [m].
    params : ReducerParams
        Reducer parameters.
    limit : float
        Lost-motion limit [rad].
    baseline : float
        The unit's as-built offset ``b`` [m] (0: nominal).

    Returns
    -------
    float or ndarray
        Event state.

    """
    curve = lost_motion_curve(params)
    return _event_state(curve, unit_lost_motion(wear, baseline, curve), limit, baseline)


def _event_state(curve, lost_motion, limit, baseline):
    """Event state of a unit of offset ``baseline`` [m] at ``lost_motion`` [rad] (arrays too)."""
    lm_new = curve(baseline)
    es = np.clip(1.0 - (lost_motion - lm_new) / np.maximum(limit - lm_new, 1e-12), 0.0, 1.0)
    return float(es) if np.ndim(es) == 0 else es


def threshold_met(wear, params, limit=LOST_MOTION_LIMIT, baseline=0.0):
    """
    Tell whether the lost motion at ``wear`` reached the limit.

    Parameters
    ----------
    wear : array_like
        Combined wear [m].
    params : ReducerParams
        Reducer parameters.
    limit : float
        Lost-motion limit [rad].
    baseline : float
        The unit's as-built offset ``b`` [m] (0: nominal).

    Returns
    -------
    bool or ndarray
        ``LM(w) >= limit``.

    """
    met = unit_lost_motion(wear, baseline, lost_motion_curve(params)) >= limit
    return bool(met) if np.ndim(met) == 0 else met


@dataclass(frozen=True)
class GrowthTrendState:
    """
    The observed growth law, as the estimator reports it (:mod:`.growth`).

    Attributes
    ----------
    probability : float
        Probability that it, not the model's curve, holds.
    mean : ndarray, shape (3,)
        ``[β [rad], k [rad], g]`` of ``z = β + k·(A/A_now)^g``.
    cov : ndarray, shape (3, 3)
        Their covariance.
    exposure : float
        ``A_now``, the Archard exposure since new [m].

    """

    probability: float
    mean: np.ndarray
    cov: np.ndarray
    exposure: float


@dataclass(frozen=True)
class LifeDraws:
    """
    The random numbers of one remaining-life prediction, drawn once and reused.

    Reusing the same draws for successive predictions gives common random numbers
    (successive predictions differ by the state only) without drawing them again.

    Attributes
    ----------
    state : ndarray, shape (n, 3)
        Standard normals of the state ``[w, ln s, b]``.
    duty, drift : ndarray, shape (n,)
        Standard normals of the future duty rate and of the drift of ``ln s``.
    trend : ndarray, shape (n, 3)
        Standard normals of the observed growth law ``[β, k, g]``.
    pick : ndarray, shape (n,)
        Uniforms in [0, 1) choosing the growth law over the wear model.

    """

    state: np.ndarray
    duty: np.ndarray
    drift: np.ndarray
    trend: np.ndarray
    pick: np.ndarray

    @classmethod
    def draw(cls, n_samples, rng=None):
        """
        Draw the numbers of ``n_samples`` samples.

        Parameters
        ----------
        n_samples : int
            Number of samples (>= 1).
        rng : numpy.random.Generator or int, optional
            Random source or seed; default the fixed seed of :func:`remaining_life`.

        Returns
        -------
        LifeDraws
            The draws, as :func:`remaining_life` takes them from ``rng``.

        """
        if not isinstance(rng, np.random.Generator):
            rng = np.random.default_rng(0 if rng is None else rng)
        normal = rng.standard_normal((n_samples, N_STATE + 5))
        pick = rng.random(n_samples)
        columns = (normal[:, :N_STATE], normal[:, N_STATE], normal[:, N_STATE + 1],
                   normal[:, N_STATE + 2:], pick)
        return cls(*(np.ascontiguousarray(c) for c in columns))

    @property
    def n_samples(self):
        """Return the number of samples."""
        return self.pick.shape[0]


def _trend_times(trends, limit, duty_rate, normal, follow):
    """
    Time to the limit by the observed trends, for the samples that follow them.

    Parameters
    ----------
    trends : sequence of GrowthTrendState
        One growth law per estimate (Q).
    limit : float
        Lost-motion limit [rad].
    duty_rate : ndarray, shape (Q, n)
        Each sample's future duty rate [m per operating second].
    normal : ndarray, shape (n, 3)
        Standard-normal draws of ``[β, k, g]``.
    follow : ndarray of bool, shape (Q, n)
        The samples that follow the growth law.

    Returns
    -------
    ndarray
        The times of the samples in ``follow`` [s], in its order; each is the one of
        the whole set of draws of its estimate.

    """
    mean = np.array([np.asarray(tr.mean, dtype=float) for tr in trends])
    roots = np.swapaxes(_covariance_roots([tr.cov for tr in trends]), 1, 2)
    # Only the draws that follow the law: (estimate, draw) of each, in the order of follow.
    rows, cols = np.nonzero(follow)
    beta, k, g = _sampled_states(mean[rows], roots[rows], normal[cols], paired=True)
    exposure = np.array([float(tr.exposure) for tr in trends])[rows]
    g = np.clip(g, EXPONENTS[0], EXPONENTS[-1])
    with np.errstate(divide='ignore', invalid='ignore', over='ignore'):
        ratio = (limit - beta) / k
        a_lim = exposure * np.power(np.maximum(ratio, 0.0), 1.0 / g)
        t = np.where(k <= 0.0, np.inf, (a_lim - exposure) / duty_rate[follow])
    return np.where(np.isnan(t), np.inf, np.maximum(t, 0.0))


class LifeQuery(NamedTuple):
    """
    One estimate whose remaining life :func:`remaining_lives` samples.

    Attributes
    ----------
    state : WearEstimator or tuple
        The estimator, or its ``(x, P)`` (see :func:`remaining_life`).
    duty_rate : float
        Run-in-free Archard rate of the recent duty [m per operating second].
    duty_rate_rel_std : float
        Uncertainty of the future mean duty rate, sd of ``ln ȧ``.
    rate_drift : float
        Random-walk intensity of ``ln s`` per operating second [1/s].
    trend : GrowthTrendState or None
        The observed growth law and its probability.

    """

    state: object
    duty_rate: float
    duty_rate_rel_std: float = 0.0
    rate_drift: float = 0.0
    trend: object = None


def remaining_life(state, duty_rate, params, limit=LOST_MOTION_LIMIT, horizon_s=DEFAULT_HORIZON_S,
                   n_samples=2000, rng=None, duty_rate_rel_std=0.0, keep_samples=False,
                   rate_drift=0.0, trend=None, draws=None):
    """
    Sample the remaining useful life under the recent duty.

    Draws ``x = [w, ln s, b] ~ N(x, P)``, clips ``w`` at 0 (a wear below
    zero is the new reducer), finds each draw's ``w_lim`` on its own curve
    and evaluates ``t = (S(w_lim) - S(w))/(s·ȧ)``; with probability
    ``trend.probability`` a draw is taken from the observed growth law
    instead. The future duty is the recent one, with a log-normal
    uncertainty of relative sd ``duty_rate_rel_std`` on its mean rate;
    ``ln s`` may drift as a random walk of ``rate_drift`` per operating second.

    Parameters
    ----------
    state : WearEstimator or tuple
        The estimator, or its ``(x, P)`` with ``x = [w [m], ln s, b [m]]``
        (or ``[w, ln s]`` for a nominal unit).
    duty_rate : float
        Run-in-free Archard rate of the recent duty ȧ [m per operating
        second] (``Δa/Δe`` over a recent horizon, e.g.
        ``WearEstimator.duty_rate``); 0 means the reducer does not wear.
    params : ReducerParams
        Reducer parameters.
    limit : float
        Lost-motion limit [rad] (default 3 arcmin).
    horizon_s : float
        Prediction horizon [s of operation]; later events are censored.
    n_samples : int
        Number of samples.
    rng : numpy.random.Generator or int, optional
        Random source or seed. Default: a fixed seed, so that successive
        predictions differ by the state only (common random numbers).
    duty_rate_rel_std : float
        Uncertainty of the future mean duty rate, sd of ``ln ȧ`` (0: the
        recent duty continues exactly).
    keep_samples : bool
        Return the capped samples in ``LifePrediction.samples``.
    rate_drift : float
        Random-walk intensity of ``ln s`` per operating second [1/s]
        (``EstimatorConfig.log_rate_scale_noise_density``; 0: none).
    trend : GrowthTrendState, optional
        The observed growth law and its probability (None: the wear model alone).
    draws : LifeDraws, optional
        The random numbers, drawn before (``rng`` is then not used); the same
        prediction as drawing them from the same source here.

    Returns
    -------
    LifePrediction
        Percentiles, restricted mean and censoring [s of operation].

    Raises
    ------
    InvalidInput
        If the state or trend is malformed or ``duty_rate`` negative or not finite.
    InvalidParameter
        If ``limit``, ``horizon_s``, ``n_samples``, ``duty_rate_rel_std`` or
        ``rate_drift`` is out of range, or ``draws`` hold another number of samples.

    """
    query = LifeQuery(state, duty_rate, duty_rate_rel_std, rate_drift, trend)
    return remaining_lives([query], params, limit=limit, horizon_s=horizon_s,
                           n_samples=n_samples, rng=rng, keep_samples=keep_samples,
                           draws=draws)[0]


def remaining_lives(queries, params, limit=LOST_MOTION_LIMIT, horizon_s=DEFAULT_HORIZON_S,
                    n_samples=2000, rng=None, keep_samples=False, draws=None):
    """
    Sample the remaining life of several estimates at once (one reducer, common draws).

    Each answer is the one :func:`remaining_life` gives for its query alone with the
    same draws; the samples of all queries are evaluated as one array.

    Parameters
    ----------
    queries : sequence of LifeQuery
        The estimates, with their duty and growth law.
    params : ReducerParams
        Reducer parameters.
    limit, horizon_s, n_samples, rng, keep_samples, draws
        As for :func:`remaining_life`.

    Returns
    -------
    list of LifePrediction
        One per query, in order.

    Raises
    ------
    InvalidInput
        If a state or trend is malformed or a duty rate negative or not finite.
    InvalidParameter
        As for :func:`remaining_life`.

    """
    checked = [_check_query(q) for q in queries]
    if not (math.isfinite(horizon_s) and horizon_s > 0.0):
        raise InvalidParameter(out_of_range('horizon_s', horizon_s, 's', '> 0'))
    if isinstance(n_samples, bool) or int(n_samples) != n_samples or n_samples < 1:
        raise InvalidParameter(out_of_range('n_samples', n_samples, '', 'a whole number >= 1'))
    n_samples = int(n_samples)
    if draws is not None and draws.n_samples != n_samples:
        raise InvalidParameter(f'draws hold {draws.n_samples} samples, expected n_samples = '
                               f'{n_samples}')
    p_trends = [_check_future(q) for q in queries]
    curve = lost_motion_curve(params)
    _check_limit(curve, limit)  # the limit must lie inside the model's table
    out = [None] * len(queries)
    live = []
    if not queries:
        return out
    # Where each estimate stands (wear limit, lost motion, event state), all at once.
    means = np.array([x for x, _ in checked])
    wear_means, baselines = np.maximum(means[:, 0], 0.0), means[:, 2]
    w_lims = wear_at_lost_motion(limit, baselines, curve).tolist()
    lms, past = _standing(queries, p_trends, unit_lost_motion(wear_means, baselines, curve),
                          wear_means >= np.array(w_lims), limit)
    states = _event_state(curve, lms, limit, baselines).tolist()
    standing = zip(w_lims, lms.tolist(), states, past.tolist())
    for i, (w_lim, lm, es, both_past) in enumerate(standing):
        met = bool(lm >= limit)
        if both_past:
            zeros = np.zeros(n_samples) if keep_samples else None
            out[i] = LifePrediction(0.0, 0.0, 0.0, False, False, False, 0.0, 0.0, True, es, met,
                                    float(horizon_s), w_lim, n_samples, zeros)
        else:
            live.append((i, es, met, w_lim))
    if not live:
        return out
    if draws is None:
        draws = LifeDraws.draw(n_samples, rng)
    rows = [i for i, _, _, _ in live]
    t, censored = _sampled_times([queries[i] for i in rows], [checked[i] for i in rows],
                                 [p_trends[i] for i in rows], params, limit, horizon_s, draws,
                                 curve)
    capped = np.minimum(t, horizon_s)
    quantiles = np.quantile(capped, [0.1, 0.5, 0.9], axis=1).T.tolist()
    means = capped.mean(axis=1).tolist()
    for k, (i, es, met, w_lim) in enumerate(live):
        p10, p50, p90 = quantiles[k]
        out[i] = LifePrediction(
            p10=p10, p50=p50, p90=p90,
            p10_censored=p10 >= horizon_s, p50_censored=p50 >= horizon_s,
            p90_censored=p90 >= horizon_s,
            mean=means[k],
            fraction_censored=float(censored[k] / n_samples),
            limit_reached=False, event_state=es, threshold_met=met,
            horizon_s=float(horizon_s), wear_limit=w_lim, n_samples=n_samples,
            samples=capped[k] if keep_samples else None)
    return out


def _standing(queries, p_trends, lms, wear_past, limit):
    """
    Return each estimate's lost motion now and whether it is past the limit by all it follows.

    The wear model's ``h(w + b)`` at the mean, mixed with the growth law's ``β + k`` by
    the law's weight in the remaining life (``p_trends``; the estimator's lost motion,
    :meth:`.estimator.WearEstimator.lost_motion`, mixes them by its probability); an
    estimate is past the limit when the wear model's mean wear is (``wear_past``; its
    ``h(w + b)`` is then at the limit too), and the law (where it has a weight) stands
    there too. A
    wear model past the limit beside a law that is not gives the law's share of samples
    their own times: "worn out" beside a lost motion given below the limit (a base whose
    first windows read its play at 3.0 arcmin, the law of its later ones 2.3) told a user
    two things at once.

    Returns
    -------
    tuple of ndarray
        The lost motion [rad] and the flags, one each per query.

    """
    lms = np.array(lms, dtype=float)
    past = np.array(wear_past, dtype=bool)
    for i, (query, p) in enumerate(zip(queries, p_trends)):
        if p > 0.0:
            law = float(query.trend.mean[0] + query.trend.mean[1])
            lms[i] = p * law + (1.0 - p) * lms[i]
            past[i] &= law >= limit
    return lms, past


def _check_query(query):
    """Validate a query's state and duty rate; return its ``(x, P)`` as four states."""
    x, P = _state_arrays(query.state)
    duty_rate = query.duty_rate
    if not (math.isfinite(duty_rate) and duty_rate >= 0.0):
        raise InvalidInput(out_of_range('duty_rate', duty_rate, 'm/s', 'finite and >= 0'))
    return x, P


def _check_future(query):
    """Validate a query's duty uncertainty, drift and growth law; return its probability."""
    rel_std, drift = query.duty_rate_rel_std, query.rate_drift
    if not (math.isfinite(rel_std) and rel_std >= 0.0):
        raise InvalidParameter(out_of_range('duty_rate_rel_std', rel_std, '', '>= 0'))
    if not (math.isfinite(drift) and drift >= 0.0):
        raise InvalidParameter(out_of_range('rate_drift', drift, '1/s', '>= 0'))
    return _trend_probability(query.trend)


def _sampled_times(queries, states, p_trends, params, limit, horizon_s, draws, curve):
    """
    Time of event of every draw of every query, shape (queries, samples) [s].

    Returns the times (infinite where the limit is never met) and, per query, the
    count of times beyond the horizon.
    """
    x = np.array([s[0] for s in states])
    roots = np.swapaxes(_covariance_roots([s[1] for s in states]), 1, 2)
    rate = np.array([float(q.duty_rate) for q in queries])[:, None]
    rel_std = np.array([float(q.duty_rate_rel_std) for q in queries])[:, None]
    drift = np.array([float(q.rate_drift) for q in queries])
    wear, log_scale, baseline = _sampled_states(x, roots, draws.state)
    wear = np.maximum(wear, 0.0)
    lim = wear_at_lost_motion(limit, baseline, curve)
    duty = np.exp(rel_std * draws.duty)
    wp = params.wear
    remaining = run_in_free_wear(lim, wp) - run_in_free_wear(wear, wp)
    speed = np.exp(log_scale) * duty * rate
    with np.errstate(divide='ignore', invalid='ignore', over='ignore'):
        t = np.where(remaining <= 0.0, 0.0, remaining / speed)
        t[np.isnan(t)] = np.inf
        drifting = np.flatnonzero(drift > 0.0)
        if drifting.size:
            # The mean of the drifting ln s over the time to the event.
            part = t[drifting]
            spread = np.sqrt(drift[drifting, None] * np.minimum(part, 10.0 * horizon_s) / 3.0)
            t[drifting] = part * np.exp(-spread * draws.drift)
        trending = [k for k, p_trend in enumerate(p_trends) if p_trend > 0.0]
        if trending:
            # The samples that follow the growth law (a share p_trend) get its times.
            follow = draws.pick < np.array([p_trends[k] for k in trending])[:, None]
            part = t[trending]
            part[follow] = _trend_times([queries[k].trend for k in trending], limit,
                                        duty[trending] * rate[trending], draws.trend, follow)
            t[trending] = part
    return t, np.count_nonzero(t > horizon_s, axis=1)


def _sampled_states(mean, roots, normal, paired=False):
    """
    Draws ``mean + normal·root`` of several queries, one array per state component.

    Parameters
    ----------
    mean : ndarray, shape (Q, m)
        Each query's mean.
    roots : ndarray, shape (Q, m, m)
        Each query's transposed covariance root (``rootᵀ·root`` the covariance).
    normal : ndarray, shape (n, m)
        Standard-normal draws, common to the queries; with ``paired``, shape (Q, m):
        one draw per query (row ``q`` of ``normal`` belongs to query ``q``).
    paired : bool
        One draw per query instead of every draw for every query.

    Returns
    -------
    list of ndarray
        ``m`` arrays of shape (Q, n) (``paired``: (Q,)): component ``j`` of every
        query's draws.

    Notes
    -----
    Each component is the mean plus ``m`` products of a draw column with the roots'
    entries (whole-array passes over every query): the stacked ``(n, m)·(m, m)``
    products take five times as long for a few queries of thousands of draws, and no
    BLAS call means no BLAS threads spinning beside a worker process. A paired draw
    gets the same products, in the same order, as in the whole array.

    """
    columns = np.ascontiguousarray(normal.T)
    pick = (lambda a: a) if paired else (lambda a: a[:, None])
    out = []
    for j in range(mean.shape[1]):
        total = pick(mean[:, j]) + pick(roots[:, 0, j]) * columns[0]
        for i in range(1, columns.shape[0]):
            total += pick(roots[:, i, j]) * columns[i]
        out.append(total)
    return out


def _trend_probability(trend):
    """Validate a :class:`GrowthTrendState` (or None) and return its probability."""
    if trend is None:
        return 0.0
    try:
        p = float(trend.probability)
        mean = np.asarray(trend.mean, dtype=float)
        cov = np.asarray(trend.cov, dtype=float)
        exposure = float(trend.exposure)
    except (AttributeError, TypeError, ValueError) as err:
        raise InvalidInput(f'trend must be a GrowthTrendState, got {trend!r}') from err
    if not (0.0 <= p <= 1.0 and mean.shape == (3,) and cov.shape == (3, 3)
            and np.all(np.isfinite(mean)) and np.all(np.isfinite(cov))
            and math.isfinite(exposure) and exposure >= 0.0):
        raise InvalidInput('trend needs a probability in [0, 1], a finite mean of 3, a 3x3 '
                           f'covariance and an exposure >= 0 m, got {p!r}, {mean.tolist()}, '
                           f'{cov.tolist()}, {exposure!r}')
    return p


def catalogue_life(duty, params):
    """
    Rated-life formula of the catalogue for a duty [s of operation].

    ``L = K·(N0/Nm)·(T0/Tm)^(10/3)`` with ``K`` the rated life at rated
    torque ``T0`` and rated output speed ``N0``, ``Nm`` the mean output
    speed and ``Tm`` the cubic-mean torque of the duty (physics notes
    section 1; the exponent is ``rating.life_exponent``).

    Parameters
    ----------
    duty : object
        With ``mean_speed`` Nm [rad/s] (sign ignored) and
        ``cubic_mean_torque`` Tm [N·m].
    params : ReducerParams
        Reducer parameters (``rating``).

    Returns
    -------
    float
        Life L [s]; ``inf`` for a duty without speed or torque.

    Raises
    ------
    InvalidInput
        If a duty value is missing or not finite.

    """
    r = params.rating
    nm = getattr(duty, 'mean_speed', None)
    tm = getattr(duty, 'cubic_mean_torque', None)
    for name, value, unit in (('mean_speed', nm, 'rad/s'), ('cubic_mean_torque', tm, 'N*m')):
        try:
            ok = math.isfinite(float(value))
        except (TypeError, ValueError):
            ok = False
        if not ok:
            raise InvalidInput(f'duty.{name} must be a finite number {unit}, got {value!r}')
    nm, tm = abs(float(nm)), abs(float(tm))
    if nm == 0.0 or tm == 0.0:
        return math.inf
    return r.rated_life * (r.rated_output_speed / nm) * (r.rated_torque / tm) ** r.life_exponent
