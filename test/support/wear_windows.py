"""
Windows of a reducer wearing by the twin's own model, for the estimator's tests.

The truth is made with the core itself: wear grows by ``wear.integrate_wear`` with a
hidden rate scale, observations are ``model_tables(params).lost_motion(true_w + b)``
(a unit built ``b`` looser) plus white noise of :data:`NOISE`, reported as such.
"""

from dataclasses import dataclass
import math

import numpy as np
from reducer_twin.core import wear
from reducer_twin.core.duty_summary import DutySummary
from reducer_twin.core.transmission_error import model_tables
from reducer_twin.core.units import ARCMIN, HOUR

NOISE = 0.05 * ARCMIN
"""Sd of the windows' lost motion, as reported."""

WINDOW = 10.0 * HOUR
"""Exposure of one window (a time-compressed recording)."""


def window_duty(duration_s, exposure_s, archard_increment, torque=0.0, speed=0.0):
    """Return a window's duty (the window analysis's DutySummary) at one load and speed."""
    return DutySummary(duration_s, exposure_s, archard_increment, torque, speed, torque, torque)


@dataclass(frozen=True)
class WindowFeatures:
    """Features of one window of encoder data (SI units)."""

    t_end: float
    lost_motion: float
    lost_motion_std: float
    duty: DutySummary
    wear_fit: float = math.nan
    wear_fit_std: float = math.nan
    loaded_mean_te: float = math.nan


def synthetic_run(params, scale, seed, n=3000, window=WINDOW, as_built=0.0, wear0=0.0, bias=0.0):
    """
    Return windows of a reducer wearing with a hidden rate ``scale``.

    Torque is uniform in 60-120 % of rated per window at the paper's speed;
    the lost motion is the model's at ``w + as_built`` observed at the
    window's middle, plus ``bias``; where ``w + as_built`` is below the
    table (a tight unit), the fit sits on the table's lower bound as the
    window analysis reports it (``wear_fit = 0``). The run stops at the 3
    arcmin limit.

    Returns
    -------
    tuple
        ``(features, true_wear [m] at each window's end, eol_index)``.

    """
    rng = np.random.default_rng(seed)
    tables = model_tables(params)
    exposure = np.full(n, window)
    torque = params.rating.rated_torque * rng.uniform(0.6, 1.2, n)
    speed = np.full(n, wear.reference_speed(params))
    increment = wear.wear_rate(torque, speed, 0.0, params) * exposure
    half = np.repeat(0.5 * exposure, 2)
    true_half = wear.integrate_wear(half, np.repeat(torque, 2), np.repeat(speed, 2), params,
                                    wear0=wear0, rate_scale=scale)
    true_w, mid_w = true_half[1::2], true_half[0::2]
    z = tables.lost_motion(mid_w + as_built) + bias + rng.normal(0.0, NOISE, n)
    fit = np.where(mid_w + as_built > 0.0, mid_w + as_built, 0.0)
    eol = int(np.argmax(tables.lost_motion(true_w + as_built) >= 3.0 * ARCMIN))
    features = [WindowFeatures(t_end=(k + 1) * 10.0, lost_motion=float(z[k]),
                               lost_motion_std=NOISE, wear_fit=float(fit[k]),
                               duty=window_duty(10.0, float(exposure[k]), float(increment[k])))
                for k in range(eol + 1)]
    return features, true_w[:eol + 1], eol


def features_at(lost_motion, increment=1e-8, exposure=WINDOW, std=NOISE, t_end=0.0):
    return WindowFeatures(t_end=t_end, lost_motion=lost_motion, lost_motion_std=std,
                          duty=window_duty(10.0, exposure, increment), wear_fit=1e-6)
