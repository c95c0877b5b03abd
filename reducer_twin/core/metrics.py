"""
Offline metrics of prognostic performance (Saxena et al.).

Pure functions over arrays of prediction times ``t`` [s], predicted RUL
``rul_pred`` [s] and true RUL ``rul_true`` [s], one entry per prediction,
in time order. Times are measured from the start of life, so the end of
life is ``EOL = t + rul_true`` (taken from the first entry).

Definitions follow

* A. Saxena, J. Celaya, E. Balaban, K. Goebel, B. Saha, S. Saha,
  M. Schwabacher, "Metrics for evaluating performance of prognostic
  techniques", Int. Conf. on Prognostics and Health Management (PHM 2008);
* A. Saxena, J. Celaya, B. Saha, S. Saha, K. Goebel, "Metrics for offline
  evaluation of prognostic performance", Int. J. of Prognostics and Health
  Management 1(1), 2010 (prognostic horizon, alpha-lambda accuracy,
  relative accuracy, cumulative relative accuracy).

Point predictions are used (e.g. the median, ``LifePrediction.p50``), i.e.
the beta criterion of the 2010 paper with the whole mass at the point.
"""

import numpy as np

from .errors import InvalidInput


def _arrays(t, rul_pred, rul_true):
    t = np.asarray(t, dtype=float)
    rul_pred = np.asarray(rul_pred, dtype=float)
    rul_true = np.asarray(rul_true, dtype=float)
    if t.ndim != 1 or t.size == 0 or rul_pred.shape != t.shape or rul_true.shape != t.shape:
        raise InvalidInput(
            't, rul_pred and rul_true must be 1-d arrays of one non-zero length, got shapes '
            f'{t.shape}, {rul_pred.shape}, {rul_true.shape}')
    if not (np.all(np.isfinite(t)) and np.all(np.isfinite(rul_true))):
        raise InvalidInput('t and rul_true must be finite')
    if np.any(np.diff(t) < 0.0):
        raise InvalidInput('t must be in increasing order')
    return t, rul_pred, rul_true


def end_of_life(t, rul_true):
    """
    Return the true end of life ``EOL = t[0] + rul_true[0]`` [s].

    Parameters
    ----------
    t : array_like
        Prediction times [s].
    rul_true : array_like
        True RUL at those times [s].

    Returns
    -------
    float
        EOL [s].

    """
    return float(np.asarray(t, dtype=float)[0] + np.asarray(rul_true, dtype=float)[0])


def alpha_lambda(t, rul_pred, rul_true, lam, alpha=0.2):
    """
    Alpha-lambda accuracy (Saxena et al. 2010).

    At ``t_λ = t_P + λ·(EOL - t_P)``, with ``t_P = t[0]`` the first
    prediction, the test holds when
    ``(1 - α)·r*(t_λ) <= r(t_λ) <= (1 + α)·r*(t_λ)``. With discrete
    predictions the first one at or after ``t_λ`` is used (as progpy does).

    Parameters
    ----------
    t : array_like
        Prediction times [s].
    rul_pred : array_like
        Predicted RUL [s].
    rul_true : array_like
        True RUL [s].
    lam : float
        Fraction λ of the time from first prediction to EOL, in [0, 1].
    alpha : float
        Accuracy cone half-width α, relative to the true RUL.

    Returns
    -------
    bool
        Whether the prediction at ``t_λ`` lies in the cone; False when no
        prediction is made at or after ``t_λ``.

    """
    t, rul_pred, rul_true = _arrays(t, rul_pred, rul_true)
    if not 0.0 <= lam <= 1.0:
        raise InvalidInput(f'lam must be in [0, 1], got {lam!r}')
    eol = end_of_life(t, rul_true)
    t_lam = t[0] + lam * (eol - t[0])
    after = np.nonzero(t >= t_lam)[0]
    if after.size == 0:
        return False
    i = after[0]
    r_true, r = rul_true[i], rul_pred[i]
    return bool((1.0 - alpha) * r_true <= r <= (1.0 + alpha) * r_true)


def prognostic_horizon(t, rul_pred, rul_true, alpha=0.2, stay=True):
    """
    Prognostic horizon ``PH = EOL - t_i`` (Saxena et al. 2010).

    The bounds are ``r*(t) ± α·EOL`` (constant width). Saxena et al. take
    ``t_i`` as the first prediction inside the bounds; with ``stay=True``
    (default) ``t_i`` is the first prediction from which *all* later ones
    stay inside, which does not credit a prediction that enters the bounds
    by chance.

    Parameters
    ----------
    t : array_like
        Prediction times from the start of life [s].
    rul_pred : array_like
        Predicted RUL [s].
    rul_true : array_like
        True RUL [s].
    alpha : float
        Bound half-width as a fraction of EOL.
    stay : bool
        Require all later predictions to stay inside the bounds.

    Returns
    -------
    float
        PH [s]; 0 when no prediction qualifies.

    """
    t, rul_pred, rul_true = _arrays(t, rul_pred, rul_true)
    eol = end_of_life(t, rul_true)
    inside = np.abs(rul_pred - rul_true) <= alpha * eol
    if stay:
        # inside from i on: reverse cumulative AND
        inside = np.logical_and.accumulate(inside[::-1])[::-1]
    hits = np.nonzero(inside)[0]
    return float(eol - t[hits[0]]) if hits.size else 0.0


def relative_accuracy(rul_pred, rul_true):
    """
    Relative accuracy ``RA = 1 - |r* - r|/r*`` (Saxena et al. 2010).

    Parameters
    ----------
    rul_pred : array_like
        Predicted RUL [s].
    rul_true : array_like
        True RUL [s], > 0.

    Returns
    -------
    ndarray
        RA per prediction (1 is perfect; may be negative).

    """
    rul_pred = np.asarray(rul_pred, dtype=float)
    rul_true = np.asarray(rul_true, dtype=float)
    if np.any(rul_true <= 0.0):
        raise InvalidInput('rul_true must be > 0 for relative accuracy')
    return 1.0 - np.abs(rul_true - rul_pred) / rul_true


def cumulative_relative_accuracy(t, rul_pred, rul_true, weights=None):
    """
    Cumulative relative accuracy (Saxena et al. 2010).

    ``CRA = Σ w_i·RA_i / Σ w_i`` over the predictions made before EOL
    (``rul_true > 0``); uniform weights by default.

    Parameters
    ----------
    t : array_like
        Prediction times [s].
    rul_pred : array_like
        Predicted RUL [s].
    rul_true : array_like
        True RUL [s].
    weights : array_like, optional
        Weight of each prediction (e.g. more weight near EOL).

    Returns
    -------
    float
        CRA (1 is perfect); NaN if no prediction precedes EOL.

    """
    t, rul_pred, rul_true = _arrays(t, rul_pred, rul_true)
    w = np.ones_like(t) if weights is None else np.asarray(weights, dtype=float)
    if w.shape != t.shape or np.any(w < 0.0):
        raise InvalidInput(f'weights must be >= 0 with shape {t.shape}, got shape {w.shape}')
    before = rul_true > 0.0
    if not np.any(before) or w[before].sum() == 0.0:
        return float('nan')
    ra = relative_accuracy(rul_pred[before], rul_true[before])
    return float(np.sum(w[before] * ra) / np.sum(w[before]))


def interval_coverage(rul_true, lower, upper):
    """
    Share of predictions whose interval holds the true RUL (e.g. P10-P90).

    Parameters
    ----------
    rul_true : array_like
        True RUL [s].
    lower, upper : array_like
        Interval bounds, e.g. P10 and P90 [s].

    Returns
    -------
    float
        Coverage in [0, 1]; 0.8 is calibrated for P10-P90.

    """
    rul_true = np.asarray(rul_true, dtype=float)
    lower = np.asarray(lower, dtype=float)
    upper = np.asarray(upper, dtype=float)
    if rul_true.size == 0 or lower.shape != rul_true.shape or upper.shape != rul_true.shape:
        raise InvalidInput('rul_true, lower and upper must be non-empty arrays of one shape')
    return float(np.mean((lower <= rul_true) & (rul_true <= upper)))
