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
two of 21000's, re-analysed, 2026-12-08): said of 5 third-generator joints, four read 35,
32, 28 and 17 % low and one 9 % high; of none of the independent generator's 143 observed
joints (a line against the reach alone said none of them either, even at one standard
error, but it takes a reading that grows in time for the reach where the reach drifts with
it: a unit wearing over a whole life's windows).

:class:`LoadReachCheck` pools, over the stream's recent windows
(:data:`.soft_zone.SHORTFALL_MEMORY`), a plane of the windows' lost motion against the
largest load each read it over and against time (so that a unit wearing, or a duty that
changes with time, is not taken for the reach), weighted by their standard errors and
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
from .window_ops import FadedLeastSquares

MIN_WINDOWS = 6
"""Windows the line needs: its three coefficients and three degrees of freedom for its scatter."""

SIGMAS = 3.0
"""
Standard errors of the change from which it is said.

The slope's standard error rests on the scatter of a few windows about the plane, itself
uncertain: measured on windows reading one lost motion scattered by 1 arcmin (400 draws,
the 0.2-arcmin and one-fifth floors met), a change of one standard error or more is found in
19-35 % of them from 30 down to 6 windows, of two in 2-10 %, of three in 0-4 % (4.3 % from
6 windows, 1.3 % from 12).
"""

KEEP = int(round(SHORTFALL_MEMORY))
"""The latest windows whose reach gives its percentiles (as many as the pools' memory)."""


class LoadReachCheck:
    """Compare the lost motion read by windows whose loads reach differently far."""

    def __init__(self):
        self._plane = FadedLeastSquares(3, 1.0 - 1.0 / SHORTFALL_MEMORY)  # u = [1, reach, t]
        self._t0 = None             # the first window's end [s]: times are taken from it
        self._last = 0.0            # the latest window's time from it [s]
        self._reach = []            # the latest KEEP windows' reach [N·m]
        self.windows = 0

    def observe(self, reach, lost_motion, lost_motion_std, t_end):
        """
        Add the windows of one batch, in stream order.

        Parameters
        ----------
        reach : ndarray, shape (W,)
            The largest load each window read its lost motion over [N·m].
        lost_motion, lost_motion_std : ndarray, shape (W,)
            The lost motion each window read and its standard error [rad] (NaN: none).
        t_end : ndarray, shape (W,)
            The windows' ends [s]: the reading's drift in time (the unit wearing) is
            fitted beside the reach, so that it is not taken for it.

        """
        for x, y, sd, t in zip(reach, lost_motion, lost_motion_std, t_end):
            if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(sd) and sd > 0.0
                    and math.isfinite(t)):
                continue
            if self._t0 is None:
                self._t0 = float(t)
            self._last = float(t) - self._t0
            self._plane.add([1.0, float(x), self._last], [y], [1.0 / (sd * sd)])
            self._reach = (self._reach + [float(x)])[-KEEP:]
            self.windows += 1

    def change(self):
        """
        Return how the lost motion read changes across the loads the windows reach.

        Returns
        -------
        dict or None
            ``change`` (from the 10th to the 90th percentile of the reach, at one time)
            and its standard error ``change_sd`` [rad], ``low`` and ``high`` (the line's
            reading there, now) [rad], ``reach_low`` and ``reach_high`` [N·m], ``mean``
            (the windows' weighted mean reading) [rad], ``windows``; None before
            :data:`MIN_WINDOWS` windows or where the reach or the time does not vary.

        """
        fit = self._plane.solve() if self.windows >= MIN_WINDOWS \
            and self._plane.n >= MIN_WINDOWS - 0.5 else None
        if fit is None:
            return None
        beta, cov = fit
        lo, hi = np.percentile(self._reach, (10.0, 90.0))
        sd_b = math.sqrt(cov[1, 1])
        now = beta[0] + beta[2] * self._last
        return {'change': beta[1] * (hi - lo), 'change_sd': sd_b * (hi - lo),
                'low': now + beta[1] * lo, 'high': now + beta[1] * hi,
                'reach_low': float(lo), 'reach_high': float(hi),
                'mean': self._plane.r[0] / self._plane.S[0, 0], 'windows': self.windows}

    def state(self):
        """Return the check's pools as plain JSON-able data, to continue after a restart."""
        return {'plane': self._plane.state(), 't0': self._t0, 'last': self._last,
                'reach': list(self._reach), 'windows': self.windows}

    def continue_from(self, state):
        """
        Continue from :meth:`state` of a check of the same joint.

        Raises as :meth:`.within_zone.WithinZoneCheck.continue_from` does (ValueError for
        values of a wrong size or not finite, KeyError or TypeError for a missing key or a
        wrong type), the check left as it was.
        """
        plane = FadedLeastSquares(3, self._plane.fade)
        plane.continue_from(state['plane'])
        last = float(state['last'])
        t0 = None if state['t0'] is None else float(state['t0'])
        reach = [float(x) for x in state['reach']]
        windows = state['windows']
        if not (math.isfinite(last) and (t0 is None or math.isfinite(t0))
                and len(reach) <= KEEP and all(map(math.isfinite, reach))
                and isinstance(windows, int) and not isinstance(windows, bool)
                and windows >= 0):
            raise ValueError(f'last and t0 must be finite, reach at most {KEEP} finite loads, '
                             'windows a count')
        self._plane, self._last, self._t0 = plane, last, t0
        self._reach, self.windows = reach, windows

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
