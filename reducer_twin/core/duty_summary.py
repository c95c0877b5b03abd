"""
What a reducer went through in each window: its duty, the wear exposure the estimator takes.

:func:`duty_summaries` sums, per window of a stream, the operating time, the
run-in-free Archard wear at rate scale 1 (:func:`.wear.wear_rate`; the estimator
applies the rate scale and the run-in itself) and the catalogue's load figures
(mean speed, equivalent torque ``Tm``, peak torque).
"""

from dataclasses import dataclass
import math

import numpy as np

from .wear import wear_rate


@dataclass(frozen=True)
class DutySummary:
    """
    What the reducer went through in one window (run-in-free wear exposure).

    Attributes
    ----------
    duration_s : float
        Stream time covered by the window's samples [s] (gaps excluded).
    exposure_s : float
        Operating seconds of wear exposure, ``duration_s·aging_factor`` [s].
    archard_increment : float
        ``aging·∫ wear_rate(T, omega, 0) dt`` [m]: Archard wear at rate
        scale 1 without run-in (the estimator applies both itself).
    mean_abs_torque : float
        Time mean of ``|T|`` [N·m].
    mean_abs_speed : float
        Time mean of ``|omega|`` [rad/s]: the mean speed ``Nm`` of the
        catalogue life formula.
    cubic_mean_torque : float
        ``Tm = (∫|omega|·|T|^(10/3) dt / ∫|omega| dt)^(3/10)`` [N·m], the
        catalogue's equivalent torque (exponent ``rating.life_exponent``);
        NaN when the joint did not move.
    max_abs_torque : float
        Largest ``|T|`` [N·m].

    """

    duration_s: float
    exposure_s: float
    archard_increment: float
    mean_abs_torque: float
    mean_abs_speed: float
    cubic_mean_torque: float
    max_abs_torque: float

    @property
    def mean_speed(self):
        """Mean speed ``Nm`` of the catalogue life formula, ``mean_abs_speed`` [rad/s]."""
        return self.mean_abs_speed


def duty_summaries(torque, speed, dt, starts, params, aging_factor):
    """
    Return the duty of each window of a stream's samples.

    Parameters
    ----------
    torque, speed, dt : ndarray, shape (N,)
        Output torque [N·m], output speed [rad/s] and each sample's share of the
        stream time [s] (0 after a gap).
    starts : ndarray of int, shape (W,)
        Each window's first sample (the next one's start ends it; the last ends at N).
    params : ReducerParams
        Reducer parameters (wear law, the catalogue's life exponent).
    aging_factor : float
        Seconds of wear exposure per second of stream.

    Returns
    -------
    list of DutySummary
        One per window.

    """
    size, rate = np.abs(torque), np.abs(speed)
    exponent = params.rating.life_exponent
    archard = wear_rate(size, rate, 0.0, params)
    rows = (dt, size * dt, rate * dt, rate * size ** exponent * dt, archard * dt)
    sums = np.stack([np.add.reduceat(row, starts) for row in rows], axis=1)
    peak = np.maximum.reduceat(size, starts)
    out = []
    for (dur, s_t, s_w, s_cube, s_wear), top in zip(sums.tolist(), peak.tolist()):
        out.append(DutySummary(
            duration_s=dur, exposure_s=dur * aging_factor,
            archard_increment=s_wear * aging_factor,
            mean_abs_torque=s_t / dur if dur > 0 else math.nan,
            mean_abs_speed=s_w / dur if dur > 0 else math.nan,
            cubic_mean_torque=(s_cube / s_w) ** (1.0 / exponent) if s_w > 0 else math.nan,
            max_abs_torque=top))
    return out
