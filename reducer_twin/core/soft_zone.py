"""
Whether a reducer's play is still being taken up at the lost-motion test torque.

A catalogue gives the lost motion as the width of the torsional curve at +-3 % of rated
torque. The window analysis reads it from the flanks of the TE's hysteresis, most of
whose torque bins lie well above the test torque, and extrapolates them down to it along
the model's curve (or a straight one): the play as taken up under load. A reducer whose
soft zone reaches beyond the test torque (a catalogue-style curve with its knee at 4-6 %
of rated) is narrower there than that: on the third generator
(``bench/third_generator.py``) such units read their full soft zone, 0.5-1.6 arcmin more
than their lost motion at the test torque, the bins at the test torque showing it.

:class:`SoftZoneCheck` compares, in each window that has both, the hysteresis width in
the bin at the test torque with the straight line through the bins of loads beyond
:data:`FAR_LOADS` times it, and pools the shortfall over the stream. The estimate is not
changed by it; it is said (:attr:`SoftZoneCheck.reason`). Measured per joint (one-off
survey, 300 h recordings at 1 kHz): third-generator units with knees at 4.0-6.0 % of
rated fell 0.5-1.6 arcmin (33-83 %) short at the test torque; knees at 2.2-3.4 % 0-0.23
arcmin (at most 14 %, the generator's friction loop still opening there); the independent
generator's units within 0.02 arcmin; the model's simulator within 0.01 arcmin on used
units and 0.06 arcmin (14 %) on new ones, whose contact curve bends most.
"""

import math

import numpy as np

from .units import ARCMIN

NEAR_SHARE = 0.15
"""Bins whose mean load lies within this share of the test torque are read as at it."""

FAR_LOADS = 2.5
"""Bins of loads from this multiple of the test torque on give the straight flanks."""

FAR_BINS = 3
"""Bins beyond :data:`FAR_LOADS` a window needs for its straight line."""

SHORTFALL_RAD = 0.2 * ARCMIN
"""Pooled shortfall (0.2 arcmin) from which the soft zone is said ..."""

SHORTFALL_SHARE = 0.2
"""... when it is also this share of the play read at the test torque ..."""

SHORTFALL_SIGMAS = 5.0
"""... and this many standard errors above zero ..."""

MIN_WINDOWS = 2
"""... from at least this many windows."""


class SoftZoneCheck:
    """
    Pool how much narrower the hysteresis is at the test torque than the loads above give.

    Parameters
    ----------
    takeup_torque : float
        The catalogue's lost-motion test torque [N·m].
    series_stiffness : float
        The model's series stiffness [N·m/rad]: the windup ``2·T/k`` taken off the
        straight line's width at the test torque gives the play read there.

    Attributes
    ----------
    windows : int
        Windows that had a bin at the test torque and the bins beyond.

    """

    def __init__(self, takeup_torque, series_stiffness):
        self.takeup_torque = float(takeup_torque)
        self.series_stiffness = float(series_stiffness)
        self.windows = 0
        self._weight = 0.0      # sum of 1/sd^2 of the windows' shortfalls
        self._shortfall = 0.0   # their weighted sum [rad]
        self._play = 0.0        # the weighted sum of the play read at the test torque [rad]

    def observe(self, torque_b, width_b, std_b, usable):
        """
        Add the windows of one batch.

        Parameters
        ----------
        torque_b, width_b, std_b : ndarray, shape (W, B)
            Mean load [N·m], hysteresis width [rad] and its standard error [rad] per bin.
        usable : ndarray of bool, shape (W, B)
            Bins that take part in the lost motion.

        """
        tt = self.takeup_torque
        near = usable & (np.abs(torque_b - tt) <= NEAR_SHARE * tt)
        far = usable & (torque_b >= FAR_LOADS * tt)
        rows = near.any(axis=1) & (far.sum(axis=1) >= FAR_BINS)
        if not rows.any():
            return
        near, far = near[rows], far[rows]
        # Unused bins may hold NaN: zero weight must not meet them.
        kept = near | far
        torque_b, width_b = (np.where(kept, v[rows], 0.0) for v in (torque_b, width_b))
        std_b = np.where(kept, std_b[rows], 1.0)
        # The straight line width = a + b·T through the far bins, weighted, per window.
        w = np.where(far, 1.0 / std_b ** 2, 0.0)
        s0, s1 = w.sum(axis=1), (w * torque_b).sum(axis=1)
        s2 = (w * torque_b ** 2).sum(axis=1)
        sy, sty = (w * width_b).sum(axis=1), (w * torque_b * width_b).sum(axis=1)
        det = s0 * s2 - s1 ** 2
        good = det > 0.0
        if not good.any():
            return
        det = np.where(good, det, 1.0)
        a, b = (s2 * sy - s1 * sty) / det, (s0 * sty - s1 * sy) / det
        # The near bins, averaged per window by their weights.
        wn = np.where(near, 1.0 / std_b ** 2, 0.0)
        wn_sum = np.maximum(wn.sum(axis=1), 1e-300)
        t_near = (wn * torque_b).sum(axis=1) / wn_sum
        h_near = (wn * width_b).sum(axis=1) / wn_sum
        line = a + b * t_near
        # Variance of the line at t_near, plus the near bins'.
        var = (s2 - 2.0 * t_near * s1 + t_near ** 2 * s0) / det + 1.0 / wn_sum
        weight = np.where(good & (var > 0.0), 1.0 / np.where(var > 0.0, var, 1.0), 0.0)
        self.windows += int(np.count_nonzero(weight))
        self._weight += float(weight.sum())
        self._shortfall += float((weight * (line - h_near)).sum())
        play = line - 2.0 * t_near / self.series_stiffness
        self._play += float((weight * play).sum())

    @property
    def shortfall(self):
        """Return the pooled shortfall, its standard error and the play read [rad], or None."""
        if self._weight <= 0.0:
            return None
        return (self._shortfall / self._weight, 1.0 / math.sqrt(self._weight),
                self._play / self._weight)

    @property
    def reason(self):
        """Say when the play is still being taken up at the test torque, else None."""
        found = self.shortfall
        if found is None or self.windows < MIN_WINDOWS:
            return None
        short, sd, play = found
        if not (short >= SHORTFALL_RAD and short >= SHORTFALL_SHARE * play
                and short >= SHORTFALL_SIGMAS * sd):
            return None
        return (f"the transmission error's hysteresis at the lost-motion test torque "
                f'({self.takeup_torque:.1f} N·m) is {short / ARCMIN:.2f} arcmin narrower than '
                f'the flanks of higher loads give ({self.windows} windows): the play is still '
                'being taken up there (a soft zone whose knee lies above the test torque). '
                f'Those flanks give {play / ARCMIN:.2f} arcmin of play, the width at the test '
                f"torque (the catalogue's lost motion) is about {(play - short) / ARCMIN:.2f}; "
                'the lost motion read lies between the two, nearer the play in windows without '
                'loads at the test torque, so the wear and remaining life are pessimistic '
                'against a limit stated at the test torque (not corrected)')
