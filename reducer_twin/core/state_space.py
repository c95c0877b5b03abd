"""
The wear estimator's state-space model: how wear grows and how it is seen.

Process: the run-in-free wear ``S(w) = ∫0^w dw'/g(w')`` grows by the Archard
increment times the rate scale (``w' = W(S(w) + e^θ·Δa)``, :func:`run_in_free_wear`
and its inverse :func:`wear_from_run_in_free`; ``g`` the run-in factor of
:mod:`.wear`, eq 7). Observation: the unit's lost motion at the catalogue test
torque, ``h(w + b)`` (:class:`LostMotionCurve` over the model tables of
:mod:`.transmission_error`; ``b`` the as-built offset). Pure functions of the
reducer parameters, cached per parameter set; :mod:`.wear_mixture` filters on
them, :mod:`.life` and the pipeline's stages read them.
"""

from functools import lru_cache

import numpy as np

from .transmission_error import model_tables
from .wear import _run_in_map, run_in_factor

INTERP_SEARCH_BELOW = 1000
"""
Values below which the run-in map is read by np.interp's binary search, not by division.

The division takes a few more passes over the values and wins only where the 15 steps
of a search over the map's 20 001 points cost more than those (measured: 150 values
6.6 against 8.6 µs, 2000 values 28 against 17 µs).
"""


def run_in_free_wear(wear, wear_params):
    """
    Map wear to run-in-free wear, ``S(w) = ∫0^w dw'/g(w')`` [m].

    ``g = (Rrms(w)/Rrms0)^1.589`` (:mod:`.wear`, eq 7); tabulated by
    :func:`.wear._run_in_map`, extended with slope 1 below zero and with the
    last slope beyond the table.

    Parameters
    ----------
    wear : array_like
        Combined wear w [m].
    wear_params : Wear
        Wear parameters.

    Returns
    -------
    ndarray
        S(w) [m], strictly increasing.

    """
    grid_w, grid_s, g_end = _run_in_free_map(wear_params)
    w = np.asarray(wear, dtype=float)
    if w.size < INTERP_SEARCH_BELOW:
        s = np.interp(w, grid_w, grid_s)
    else:
        # np.interp on the table's uniform grid, the interval found by division instead of
        # a binary search over its 20 001 points (NaN stays NaN).
        intervals = grid_w.size - 1
        u = w * (intervals / grid_w[-1])
        i = np.fmin(np.fmax(u, 0.0), float(intervals - 1)).astype(np.intp)
        s = grid_s[i] + (u - i) * _run_in_free_steps(wear_params)[i]
    s = np.where(w < 0.0, w, s)
    return np.where(w > grid_w[-1], grid_s[-1] + (w - grid_w[-1]) / g_end, s)


def wear_from_run_in_free(free_wear, wear_params):
    """
    Invert :func:`run_in_free_wear`: ``W(S) = w`` [m].

    Parameters
    ----------
    free_wear : array_like
        Run-in-free wear S [m].
    wear_params : Wear
        Wear parameters.

    Returns
    -------
    ndarray
        Combined wear w [m].

    """
    grid_w, grid_s, g_end = _run_in_free_map(wear_params)
    s = np.asarray(free_wear, dtype=float)
    w = np.interp(s, grid_s, grid_w)
    w = np.where(s < 0.0, s, w)
    return np.where(s > grid_s[-1], grid_w[-1] + (s - grid_s[-1]) * g_end, w)


@lru_cache(maxsize=16)
def _run_in_free_steps(wear_params):
    """Return the run-in-free wear's step per interval of the map's uniform wear grid [m]."""
    return np.diff(_run_in_free_map(wear_params)[1])


@lru_cache(maxsize=16)
def _run_in_free_map(wear_params):
    """
    Return the run-in map's grids ``(w, S)`` [m] and the settled rate factor beyond them.

    ``g_end = g(w_max)``, the rate factor where the table ends (the slope of ``W(S)``
    beyond it), with the grids of :func:`.wear._run_in_map`.
    """
    grid_w, grid_s = _run_in_map(wear_params)
    g_end = float(run_in_factor(grid_w[-1], wear_params)) ** wear_params.roughness_exponent
    return grid_w, grid_s, g_end


class LostMotionCurve:
    """
    Lost motion at the catalogue test torque as a function of wear, ``h(w)``.

    The nodes of ``model_tables(params)`` (bilinear in the table, hence
    piecewise linear in ``w`` at fixed torque), evaluated with ``np.interp``
    and extended linearly beyond both ends so that sigma points outside the
    table still see a monotone model.

    Parameters
    ----------
    params : ReducerParams
        Reducer parameters.

    """

    def __init__(self, params):
        tables = model_tables(params)
        self.wear = np.array(tables.wear, dtype=float)
        self.lost_motion = np.asarray(tables.lost_motion(self.wear), dtype=float)
        dw_new = self.wear[1] - self.wear[0]
        dw_end = self.wear[-1] - self.wear[-2]
        self.slope_new = (self.lost_motion[1] - self.lost_motion[0]) / dw_new
        self.slope_end = (self.lost_motion[-1] - self.lost_motion[-2]) / dw_end

    def __call__(self, wear):
        """
        Evaluate the lost motion [rad].

        Parameters
        ----------
        wear : array_like
            Combined wear [m].

        Returns
        -------
        ndarray
            Lost motion [rad].

        """
        w = np.asarray(wear, dtype=float)
        lm = np.interp(w, self.wear, self.lost_motion)
        return (lm + self.slope_new * np.minimum(w - self.wear[0], 0.0)
                + self.slope_end * np.maximum(w - self.wear[-1], 0.0))

    def inverse(self, lost_motion):
        """
        Return the wear whose lost motion is given, ``h⁻¹`` [m] (extended like ``h``).

        Parameters
        ----------
        lost_motion : array_like
            Lost motion [rad].

        Returns
        -------
        ndarray
            Wear [m].

        """
        lm = np.asarray(lost_motion, dtype=float)
        w = np.interp(lm, self.lost_motion, self.wear)
        w = w + np.minimum(lm - self.lost_motion[0], 0.0) / self.slope_new
        return w + np.maximum(lm - self.lost_motion[-1], 0.0) / self.slope_end


@lru_cache(maxsize=16)
def lost_motion_curve(params):
    """
    Return the cached :class:`LostMotionCurve` of a parameter set.

    Parameters
    ----------
    params : ReducerParams
        Reducer parameters.

    Returns
    -------
    LostMotionCurve
        Observation model ``h(w)``.

    """
    return LostMotionCurve(params)


def unit_lost_motion(wear, baseline, curve):
    """
    Lost motion of a unit at wear ``w`` [rad]: ``h(w + b)``.

    Parameters
    ----------
    wear, baseline : array_like
        ``w`` [m] and the as-built offset ``b`` [m] (broadcast together).
    curve : LostMotionCurve
        ``h``.

    Returns
    -------
    ndarray
        Lost motion [rad].

    """
    return curve(np.asarray(wear) + baseline)


def wear_at_lost_motion(lost_motion, baseline, curve):
    """
    Wear at which a unit's lost motion reaches ``lost_motion`` [m]: ``h⁻¹(z) - b``.

    Parameters
    ----------
    lost_motion : array_like
        Lost motion [rad].
    baseline : array_like
        The as-built offset ``b`` [m].
    curve : LostMotionCurve
        ``h``.

    Returns
    -------
    ndarray
        Wear ``w`` [m].

    """
    return curve.inverse(lost_motion) - baseline
