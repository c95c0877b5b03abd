"""
Synthetic ``te_features`` windows of a reducer whose wear is known, for estimator tests.

Each window: torque 60-120 % of rated at the paper's speed, one exposure each, the
Archard wear of a reducer wearing at ``rate_scale`` x the model rate
(``wear.integrate_wear``), and the model's lost motion of that wear plus 0.05 arcmin
of noise. Every other feature is NaN, as a window without those figures.
"""

import math

import numpy as np
from reducer_twin.core import wear
from reducer_twin.core.duty_summary import DutySummary
from reducer_twin.core.pipeline import duty_to_record
from reducer_twin.core.transmission_error import model_tables
from reducer_twin.core.units import ARCMIN
from reducer_twin.msg_adapters.layouts import TE_FEATURES


def feature_records(params, n, seed, start_s, window_s, exposure_s, rate_scale=0.8):
    """
    Return ``n`` consecutive ``te_features`` records (dicts keyed by the layout fields).

    Parameters
    ----------
    params : ReducerParams
        The reducer.
    n : int
        Number of windows.
    seed : int
        Seed of the torques and the lost-motion noise.
    start_s : float
        Stamp of the first window's start [s].
    window_s : float
        Window length in stream time [s].
    exposure_s : float
        Operating time each window stands for [s].
    rate_scale : float
        The reducer's wear rate relative to the model's.

    Returns
    -------
    list of dict
        The records, oldest first.

    """
    rng = np.random.default_rng(seed)
    torque = params.rating.rated_torque * rng.uniform(0.6, 1.2, n)
    speed = np.full(n, wear.reference_speed(params))
    exposure = np.full(n, exposure_s)
    increment = wear.wear_rate(torque, speed, 0.0, params) * exposure
    true_w = wear.integrate_wear(exposure, torque, speed, params, rate_scale=rate_scale)
    z = model_tables(params).lost_motion(true_w) + rng.normal(0.0, 0.05 * ARCMIN, n)
    out = []
    for k in range(n):
        rec = dict.fromkeys(TE_FEATURES.fields, math.nan)
        rec.update({'window_start_s': start_s + k * window_s,
                    'window_end_s': start_s + (k + 1) * window_s, 'samples': 2000.0,
                    'lost_motion_rad': float(z[k]), 'lost_motion_std_rad': 0.05 * ARCMIN})
        rec.update(duty_to_record(DutySummary(
            window_s, exposure_s, float(increment[k]), float(torque[k]), float(speed[k]),
            float(torque[k]), float(1.1 * torque[k]))))
        out.append(rec)
    return out
