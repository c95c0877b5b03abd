"""
The wear estimator's state as plain JSON-able data, and back: continuing exactly.

:func:`estimator_state` writes everything a :class:`.estimator.WearEstimator` needs to
continue exactly (its Gaussian components, noise history, growth sums, lagged
predictions, duty sums, counters, events, the service time's verdict);
:func:`restore_estimator` checks a state (kind, version, the reducer parameters it was
made with, finite values) and rebuilds the estimator from it, converting a version-1
state of the two-state filter. The files themselves are :mod:`reducer_twin.io.state_file`'s.
"""

from dataclasses import asdict, fields
import math

import numpy as np

from .errors import StateFileError
from .estimator import (
    EstimatorConfig, params_fingerprint, STATE_KIND, STATE_VERSION, WearEstimator)
from .growth import GrowthTrend, window_terms
from .noise_scale import NoiseScale
from .recovery import Disagreement
from .trend_score import SCORE_AFTER, SCORE_LAG
from .wear_mixture import N_FILTER


def _components_state(lw, m, P):
    return [[float(a), [float(v) for v in b], [float(v) for v in c.ravel()]]
            for a, b, c in zip(lw, m, P)]


def _components_from_state(rows):
    lw = np.array([c[0] for c in rows], dtype=float)
    m = np.array([c[1] for c in rows], dtype=float)
    P = np.array([c[2] for c in rows], dtype=float).reshape(-1, N_FILTER, N_FILTER)
    return _checked_components(lw, m, P)


def _checked_components(lw, m, P):
    if lw.ndim != 1 or lw.size == 0 or m.shape != (lw.size, N_FILTER):
        raise ValueError(f'components must be [log weight, {N_FILTER} means, '
                         f'{N_FILTER}x{N_FILTER} covariance], got {m.shape}')
    if not (np.all(np.isfinite(lw)) and np.all(np.isfinite(m)) and np.all(np.isfinite(P))):
        raise ValueError('component weights, means and covariances must be finite')
    return lw, m, P


def _snapshot_state(snap):
    return {'archard': float(snap['archard']), 'exposure_s': float(snap['exposure_s']),
            'components': _components_state(snap['lw'], snap['m'], snap['P']),
            'windows': int(snap['windows']), 'growth_exposure': float(snap['growth_exposure'])}


def _snapshot_from_state(d):
    lw, m, P = _components_from_state(d['components'])
    return {'archard': float(d['archard']), 'exposure_s': float(d['exposure_s']),
            'lw': lw, 'm': m, 'P': P, 'windows': int(d['windows']),
            'growth_exposure': float(d['growth_exposure'])}


def estimator_state(est):
    """
    Return everything needed to continue exactly, as plain JSON-able data.

    Returns
    -------
    dict
        ``kind``, ``version``, ``params_sha256``, ``config``, ``x`` and
        ``P`` (the mixture's moments, for people and tools),
        ``components`` (``[log weight, mean, covariance]`` each),
        ``noise`` (recent innovations ``[y, V, σ²]``), ``trend``, the lagged predictions'
        squared errors (``forecast_errors``), exposures, duty sums,
        ``t_end``, ``counters``, ``events``.

    """
    return {
        'kind': STATE_KIND,
        'version': STATE_VERSION,
        'params_sha256': params_fingerprint(est.params),
        'config': asdict(est.config),
        'x': [float(v) for v in est.x],
        'P': [[float(v) for v in row] for row in est.P],
        'components': _components_state(est._mix.lw, est._mix.m, est._mix.P),
        'noise': est._noise.state(),
        'growth': est._scoring.law.state(),
        'lagged': [_snapshot_state(snap) for snap in est._scoring.lagged],
        'recent': [[float(v) for v in row] for row in est._scoring.recent],
        'archard_exposure': float(est._archard),
        'trend_score': [float(est._scoring.score), int(est._scoring.scored)],
        'score_settle': int(est._scoring.settle),
        'forecast_errors': [float(v) for v in est._scoring.forecast],
        'service_pending': bool(est._service_pending),
        'service_verdict': None if est._service_verdict is None else [
            bool(est._service_verdict[0]), float(est._service_verdict[1])],
        'trend': [float(est._disagreement.trend), int(est._disagreement.count)],
        'exposure_s': est._exposure_s,
        'exposure_since_reset_s': est._exposure_since_reset_s,
        **est._duty.state(),
        't_end': est._t_end,
        'counters': dict(est._counters),
        'events': [dict(e) for e in est._events],
    }


def restore_estimator(params, d, config=None):
    """
    Restore an estimator exactly from :func:`estimator_state` output.

    A version-1 state (``[w, ln s]``, one filter) is converted: its wear,
    rate and their covariance carry over, the as-built offset and the
    fit's bias start from their priors, the growth law from no history.

    Parameters
    ----------
    params : ReducerParams
        Parameters of the reducer; must be those the state was made with.
    d : mapping
        A state dict.
    config : EstimatorConfig, optional
        Tuning; by default the one stored in the state.

    Returns
    -------
    WearEstimator
        The restored estimator.

    Raises
    ------
    StateFileError
        If the state is of another kind or version, belongs to other
        reducer parameters or is malformed.

    """
    if not isinstance(d, dict) or d.get('kind') != STATE_KIND:
        kind = d.get('kind') if isinstance(d, dict) else type(d).__name__
        raise StateFileError(f'state kind must be {STATE_KIND!r}, got {kind!r}')
    version = d.get('version')
    if version not in (1, STATE_VERSION):
        raise StateFileError(
            f'state version must be 1 or {STATE_VERSION}, got {version!r}')
    expected = params_fingerprint(params)
    if d.get('params_sha256') != expected:
        raise StateFileError(
            'state belongs to other reducer parameters: params_sha256 must be '
            f'{expected}, got {d.get("params_sha256")!r}')
    try:
        if config is None:
            names = {f.name for f in fields(EstimatorConfig)}
            stored = {k: v for k, v in d['config'].items() if k in names}
            if version == 1:
                stored = {k: v for k, v in stored.items() if k not in (
                    'initial_wear_std', 'initial_log_rate_scale_std', 'min_lost_motion_std',
                    'max_consecutive_rejections')}
            config = EstimatorConfig(**stored)
        est = WearEstimator(params, config)
        if version == 1:
            lw, m, P, noise, trend = _from_version_1(d, config)
            growth, archard, score, lagged, recent = GrowthTrend(), 0.0, (0.0, 0), [], []
        else:
            lw, m, P = _components_from_state(d['components'])
            noise = [[float(v) for v in row] for row in d['noise']]
            if any(len(row) != 3 for row in noise):
                raise ValueError('noise rows must hold 3 values')
            trend = (float(d['trend'][0]), int(d['trend'][1]))
            est._noise = NoiseScale(noise)
            growth = GrowthTrend.from_state(d['growth'], legacy_scale=est.noise_scale)
            lagged = [_snapshot_from_state(snap) for snap in d.get('lagged', [])]
            recent = [[float(v) for v in row] for row in d.get('recent', [])]
            if len(lagged) > SCORE_LAG or len(recent) > SCORE_LAG or any(
                    len(row) != 3 for row in recent):
                raise ValueError(f'lagged and recent must hold at most {SCORE_LAG} '
                                 'snapshots and windows [A, z, R]')
            if lagged and growth.windows - lagged[0]['windows'] > len(recent):
                raise ValueError('recent must hold the windows since the oldest snapshot')
            archard = float(d['archard_exposure'])
            score = (float(d['trend_score'][0]), int(d['trend_score'][1]))
        settle = int(d.get('score_settle', 0))     # (not in earlier states: 0)
        # (nor these: the lagged errors' mean starts afresh, from its prior)
        forecast = [float(v) for v in d.get('forecast_errors', [0.0, 0.0])]
        if len(forecast) != 2 or not all(math.isfinite(v) and v >= 0.0 for v in forecast):
            raise ValueError(f'forecast_errors must be two finite sums >= 0, got {forecast}')
        verdict = d.get('service_verdict')         # (nor this: None)
        if verdict is not None:
            verdict = (bool(verdict[0]), float(verdict[1]))
        if not 0 <= settle <= SCORE_AFTER + 1:
            raise ValueError(f'score_settle must be 0 .. {SCORE_AFTER + 1}, got {settle}')
        lw, m, P = _checked_components(lw, m, P)
        added = ('censored',) if version == 1 else ()
        counters = {k: int(d['counters'][k]) if k not in added else 0
                    for k in est._counters}
        events = [{'exposure_s': float(e['exposure_s']), 'reason': str(e['reason'])}
                  for e in d['events']]
        names = ('exposure_s', 'exposure_since_reset_s', 'duty_increment', 'duty_exposure')
        scalars = {k: float(d[k]) for k in names}
        if version == 1:
            batch, sums = [0.0, 0.0, 0], [0.0, 0.0, 0.0, 0.0]
        else:
            batch = [float(d['duty_batch'][0]), float(d['duty_batch'][1]),
                     int(d['duty_batch'][2])]
            sums = [float(v) for v in d['duty_batch_sums']]
            if len(sums) != 4:
                raise ValueError('duty_batch_sums must hold 4 values')
        t_end = None if d['t_end'] is None else float(d['t_end'])
    except (KeyError, TypeError, ValueError, AttributeError, IndexError) as err:
        raise StateFileError(f'state is malformed: {type(err).__name__}: {err}') from err
    est._mix.assign(lw, m, P)
    scoring = est._scoring
    scoring.law, est._archard = growth, archard
    scoring.lagged, scoring.recent = lagged, recent
    scoring.recent_terms = [window_terms(*row) for row in recent]
    scoring.score, scoring.scored = score
    scoring.settle = settle
    scoring.forecast = forecast
    # (not in earlier states: the service time, if any, was taken)
    est._service_pending = bool(d.get('service_pending', False))
    est._service_verdict = verdict
    est._noise = NoiseScale(noise)
    est._disagreement = Disagreement(*trend)
    est._exposure_s = scalars['exposure_s']
    est._exposure_since_reset_s = scalars['exposure_since_reset_s']
    est._duty.restore(scalars['duty_increment'], scalars['duty_exposure'], batch, sums)
    est._t_end = t_end
    est._counters = counters
    est._events = events
    return est


def _from_version_1(d, config):
    """Convert a version-1 state (``[w, ln s]``, one filter) to components."""
    x = np.array(d['x'], dtype=float)
    P = np.array(d['P'], dtype=float)
    if x.shape != (2,) or P.shape != (2, 2):
        raise ValueError(f'x must have shape (2,) and P (2, 2), got {x.shape}, {P.shape}')
    m = np.array([[x[0], x[1], 0.0, 0.0]])
    cov = np.zeros((1, N_FILTER, N_FILTER))
    cov[0, :2, :2] = P
    cov[0, 2, 2] = config.as_built_std ** 2
    cov[0, 3, 3] = config.fit_bias_std ** 2
    return np.zeros(1), m, cov, [], (0.0, 0)
