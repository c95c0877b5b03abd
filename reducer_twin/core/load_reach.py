"""
Whether a joint's lost motion read depends on how far its windows' loads reach.

Each window reads the lost motion from the flanks of its TE's hysteresis, over the bins of
load it holds (:mod:`.wear_fit`). Where the reducer's curve is what the fit assumes (a play,
then a straight windup), a window whose loads reach 40 N·m reads what one reaching 150 N·m
reads, within their standard errors. Where it is not (a friction loop that does not open at
small loads, a play still being taken up, an effort whose errors grow with the load), the
reading moves with the reach, and the estimate, averaging the windows, is off by more than
its standard error says: third-generator bases and wrists read 17-59 % low at 0.09-0.17
arcmin, their windows reaching furthest 0.3-1.6 arcmin apart from those reaching least.

Measured (``bench_random_forms.py`` seeds 9000, 15000, 17000 and 19000, 160 recordings, and
two of 21000's, re-analysed, 2026-12-08): said of 5 third-generator joints, read 35, 32,
28, 19 and 17 % low (22 at one standard error, 15 of them low, 4 high); of none of the
independent generator's 143 observed joints, not even at one standard error.

:class:`LoadReachCheck` pools, over the stream's recent windows
(:data:`.soft_zone.SHORTFALL_MEMORY`), a straight line of the windows' lost motion against
the largest load of the bins each read it from, weighted by their standard errors and
scaled by the line's own scatter where it exceeds them (the Birge ratio). Where the reading
changes across the loads the windows reach (their 10th to 90th percentile) by as much as a
soft zone must fall short to be said (:data:`.soft_zone.SHORTFALL_RAD`, a
:data:`.soft_zone.SHORTFALL_SHARE` of the mean reading) and by :data:`SIGMAS` standard
errors or more, over :data:`MIN_WINDOWS` windows or more, it is said: the lost motion given
is not settled at these loads, whatever its standard error says. Nothing is changed in the
lost motion given: which reach reads the catalogue's lost motion depends on why the reading
moves, which the windows do not tell.
"""

import math

import numpy as np

from .soft_zone import SHORTFALL_MEMORY, SHORTFALL_RAD, SHORTFALL_SHARE
from .units import ARCMIN

MIN_WINDOWS = 6
"""Windows the line needs: its two coefficients and four degrees of freedom for its scatter."""

SIGMAS = 3.0
"""
Standard errors of the change from which it is said.

The slope's standard error rests on the scatter of a few windows about the line, itself
uncertain: measured on windows reading one lost motion scattered by 1 arcmin (400 draws,
the 0.2-arcmin and one-fifth floors met), a change of one standard error or more is found in
20-42 % of them from 30 down to 4 windows, of two in 3-17 %, of three in 0-10 % (2.3 % from
6 windows, 0.5 % from 12).
"""

KEEP = int(round(SHORTFALL_MEMORY))
"""The latest windows whose reach gives its percentiles (as many as the pools' memory)."""


class LoadReachCheck:
    """Compare the lost motion read by windows whose loads reach differently far."""

    def __init__(self):
        self._fade = 1.0 - 1.0 / SHORTFALL_MEMORY
        self._sums = np.zeros(7)    # n, Σw, Σw·x, Σw·x², Σw·y, Σw·x·y, Σw·y²
        self._reach = []            # the windows' reach [N·m], recent first dropped
        self.windows = 0

    def observe(self, reach, lost_motion, lost_motion_std):
        """
        Add the windows of one batch, in stream order.

        Parameters
        ----------
        reach : ndarray, shape (W,)
            The largest load of the bins each window read its lost motion from [N·m].
        lost_motion, lost_motion_std : ndarray, shape (W,)
            The lost motion each window read and its standard error [rad] (NaN: none).

        """
        for x, y, sd in zip(reach, lost_motion, lost_motion_std):
            if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(sd) and sd > 0.0):
                continue
            w = 1.0 / (sd * sd)
            self._sums = self._fade * self._sums + np.array(
                [1.0, w, w * x, w * x * x, w * y, w * x * y, w * y * y])
            self._reach = (self._reach + [float(x)])[-KEEP:]
            self.windows += 1

    def change(self):
        """
        Return how the lost motion read changes across the loads the windows reach.

        Returns
        -------
        dict or None
            ``change`` (from the 10th to the 90th percentile of the reach) and its
            standard error ``change_sd`` [rad], ``low`` and ``high`` (the line's reading
            there) [rad], ``reach_low`` and ``reach_high`` [N·m], ``mean`` (the windows'
            weighted mean reading) [rad], ``windows``; None before :data:`MIN_WINDOWS`
            windows or without a line.

        """
        n, s0, s1, s2, sy, sxy, syy = self._sums
        det = s0 * s2 - s1 * s1
        if self.windows < MIN_WINDOWS or n < MIN_WINDOWS - 0.5 or not det > 1e-12 * s0 * s2:
            return None
        a, b = (s2 * sy - s1 * sxy) / det, (s0 * sxy - s1 * sy) / det
        rss = max(syy - a * sy - b * sxy, 0.0)
        scale = max(1.0, rss / (n - 2.0))
        lo, hi = np.percentile(self._reach, (10.0, 90.0))
        sd_b = math.sqrt(scale * s0 / det)
        return {'change': b * (hi - lo), 'change_sd': sd_b * (hi - lo),
                'low': a + b * lo, 'high': a + b * hi, 'reach_low': float(lo),
                'reach_high': float(hi), 'mean': sy / s0, 'windows': self.windows}

    def state(self):
        """Return the check's pools as plain JSON-able data, to continue after a restart."""
        return {'sums': self._sums.tolist(), 'reach': list(self._reach),
                'windows': self.windows}

    def continue_from(self, state):
        """
        Continue from :meth:`state` of a check of the same joint.

        Raises
        ------
        ValueError
            If the state is not a check's (wrong sizes, values not finite, a negative
            count); the check is then left as it was.
        KeyError, TypeError
            If a key is missing or a value is of the wrong type.

        """
        sums = np.array(state['sums'], dtype=float)
        reach = [float(x) for x in state['reach']]
        windows = state['windows']
        if not (sums.shape == (7,) and np.all(np.isfinite(sums))
                and len(reach) <= KEEP and all(map(math.isfinite, reach))
                and isinstance(windows, int) and not isinstance(windows, bool)
                and windows >= 0):
            raise ValueError(f'sums must be 7 finite sums, reach at most {KEEP} '
                             'finite loads, windows a count')
        self._sums, self._reach, self.windows = sums, reach, windows

    @property
    def reason(self):
        """
        Say when the lost motion read changes with the loads the windows reach, else None.

        Returns
        -------
        str or None
            One line, or None.

        """
        found = self.change()
        if found is None:
            return None
        change, sd = abs(found['change']), found['change_sd']
        if not (change >= SHORTFALL_RAD and change >= SHORTFALL_SHARE * abs(found['mean'])
                and change >= SIGMAS * sd):
            return None
        more = 'more' if found['change'] > 0.0 else 'less'
        return ("the lost motion read depends on how far the windows' loads reach: "
                f'{found["high"] / ARCMIN:.2f} arcmin where they reach '
                f'{found["reach_high"]:.0f} N·m, {found["low"] / ARCMIN:.2f} where they reach '
                f'{found["reach_low"]:.0f} N·m ({more} by {change / ARCMIN:.2f} +- '
                f'{sd / ARCMIN:.2f} arcmin, {change / sd:.1f} standard errors, over '
                f'{found["windows"]} windows), where a play and a straight windup read the '
                'same: the lost motion given is not settled at these loads, whatever its '
                'standard error says (a friction loop that does not open at small loads, a '
                'play still being taken up, an effort whose errors grow with the load). A '
                'recording whose loads reach further decides')
