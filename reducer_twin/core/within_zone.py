"""
Whether a joint's lost motion is read below its own bins' width at the lost-motion test torque.

A catalogue gives the lost motion as the width of the torsional curve at +-3 % of rated
torque, less the elastic windup there. The window analysis reads it from the flanks of the
TE's hysteresis by extrapolating them to no load (:mod:`.wear_fit`): right where the curve
is straight over the bins. A joint whose loads never leave a soft zone (a wrist loaded by
2-10 % of rated, a knee at 5 % of rated) has every bin on a curve whose width grows in
proportion to the load, and that extrapolation reads far less than the width its bins show
at the test torque: the lost motion and remaining life given are too optimistic, with a
tight standard error. The soft-zone check (:mod:`.soft_zone`) cannot see it: it compares
the bins at the test torque with the straight flanks of loads beyond 2.5 times it, which
such a joint never has.

:class:`WithinZoneCheck` pools, over the stream's recent windows
(:data:`.soft_zone.SHORTFALL_MEMORY`), the bins between :data:`SPAN` times the test torque
into a straight line of width against load, and the windows' lost motion read. Where the
line's width at the test torque, less the catalogue windup, exceeds the lost motion read by
as much as a soft zone must fall short to be said (:data:`.soft_zone.SHORTFALL_RAD`, a
:data:`.soft_zone.SHORTFALL_SHARE` of it, over :data:`.soft_zone.MIN_WINDOWS` windows) and
by :data:`.soft_zone.HINT_SIGMAS` standard error or more (the line gives it), the line's
width growing with the load faster than the windup by as many standard errors: as a soft
zone not yet said is told (:attr:`.soft_zone.SoftZoneCheck.caveat`), since the error it
warns of is the optimistic one, and the floors keep units without a soft zone quiet.
Where it is said, the lost motion and remaining life are given at that width, the
catalogue's definition, as a soft zone's are given at the test torque (the windows carry
the gap as a negative shortfall: :func:`.pipeline.taken_off`, :func:`.life_basis.play_limit`).
It is still short where the friction loop of such small loads has not opened (a wrist of
``bench_random_forms.py`` seed 17038 reads 1.54 arcmin there against a true 2.30, and 0.81
by the flanks), and the line says so.

Measured (one-off scripts over the pooled bins of whole recordings, 2026-12-08): the model's
simulator and the independent generator within 0.03 arcmin of their reading (nine joints,
new and used); on the third generator two wrists read 43 and 65 % low 0.49 and 0.73 arcmin
below their bins' width at the test torque, a base read 59 % low 0.40 +- 0.15, two other
wrists read 37 and 60 % low not at all (their bins as short as their reading), joints read
within 8 % at most 0.02 above.
"""

import math

import numpy as np

from .soft_zone import HINT_SIGMAS, MIN_WINDOWS, SHORTFALL_MEMORY, SHORTFALL_RAD
from .soft_zone import SHORTFALL_SHARE
from .units import ARCMIN
from .window_ops import FadedLeastSquares

SPAN = (0.5, 2.5)
"""Bins from and to these multiples of the test torque give the line read at it."""


class WithinZoneCheck:
    """
    Compare the lost motion read with the width its bins give at the test torque.

    Parameters
    ----------
    takeup_torque : float
        The catalogue's lost-motion test torque [N·m].
    series_stiffness : float
        The reducer's catalogue stiffness [N·m/rad]: the windup ``2·T/k`` is taken off.

    """

    def __init__(self, takeup_torque, series_stiffness):
        self.takeup_torque = float(takeup_torque)
        self.series_stiffness = float(series_stiffness)
        self._fade = 1.0 - 1.0 / SHORTFALL_MEMORY
        self._line = FadedLeastSquares(2, self._fade)     # the bins' width against the load
        self._read = np.zeros(3)    # n, Σ lost motion, Σ lost motion²
        self.windows = 0

    def observe(self, torque_b, width_b, std_b, usable, lost_motion):
        """
        Add the windows of one batch, in stream order.

        Parameters
        ----------
        torque_b, width_b, std_b, usable : ndarray, shape (W, B)
            Per bin, as :meth:`.soft_zone.SoftZoneCheck.observe` takes them: the mean load
            [N·m], the hysteresis width and its standard error [rad], the bins of the lost
            motion.
        lost_motion : ndarray, shape (W,)
            The lost motion each window read [rad] (NaN: none).

        """
        lo, hi = (s * self.takeup_torque for s in SPAN)
        inside = usable & (torque_b >= lo) & (torque_b <= hi)
        for k in range(torque_b.shape[0]):
            if not math.isfinite(lost_motion[k]) or not inside[k].any():
                continue
            t = torque_b[k, inside[k]]
            self._line.add(np.column_stack([np.ones(t.size), t]), width_b[k, inside[k]],
                           1.0 / std_b[k, inside[k]] ** 2)
            z = float(lost_motion[k])
            self._read = self._fade * self._read + np.array([1.0, z, z * z])
            self.windows += 1

    def state(self):
        """
        Return the check's pools as plain JSON-able data, to continue after a restart.

        Returns
        -------
        dict
            ``bins`` (the line's 7 weighted sums), ``read`` (the readings' 3), ``windows``.

        """
        return {'line': self._line.state(), 'read': self._read.tolist(),
                'windows': self.windows}

    def continue_from(self, state):
        """
        Continue from :meth:`state` of a check of the same reducer.

        Raises
        ------
        ValueError
            If the state is not a check's (wrong sizes, values not finite, a negative
            count); the check is then left as it was.
        KeyError, TypeError
            If a key is missing or a value is of the wrong type.

        """
        line = FadedLeastSquares(2, self._fade)
        line.continue_from(state['line'])
        read = np.array(state['read'], dtype=float)
        windows = state['windows']
        if not (read.shape == (3,) and np.all(np.isfinite(read)) and isinstance(windows, int)
                and not isinstance(windows, bool) and windows >= 0):
            raise ValueError('read must be 3 finite sums, windows a count')
        self._line, self._read, self.windows = line, read, windows

    def gap(self):
        """
        Return the width at the test torque less the windup, the lost motion read, and the gap.

        Returns
        -------
        dict or None
            ``width`` (the line's, less the catalogue windup), ``read`` (the windows'
            mean), ``gap`` (``width - read``) and its standard error ``gap_sd`` [rad] (the
            line's residual scatter and the windows' counted), ``slope`` (the line's
            slope over the catalogue windup's, ``2/k``) and its standard error
            ``slope_sd``, ``windows``; None before
            :data:`.soft_zone.MIN_WINDOWS` windows or without a line.

        """
        # Scaled by the line's own scatter where it exceeds the bins' standard errors.
        fit = self._line.solve() if self.windows >= MIN_WINDOWS and self._line.n >= 3 else None
        if fit is None:
            return None
        (a, b), cov = fit
        tt = self.takeup_torque
        var_line = cov[0, 0] + 2.0 * tt * cov[0, 1] + tt * tt * cov[1, 1]
        m, z1, z2 = self._read
        read = z1 / m
        var_read = max(z2 / m - read * read, 0.0) / max(m - 1.0, 1.0)
        width = a + b * tt - 2.0 * tt / self.series_stiffness
        k2 = self.series_stiffness / 2.0
        return {'width': width, 'read': read, 'gap': width - read,
                'gap_sd': math.sqrt(var_line + var_read),
                'slope': b * k2, 'slope_sd': math.sqrt(cov[1, 1]) * k2,
                'windows': self.windows}

    @property
    def said(self):
        """
        Return the gap's figures (:meth:`gap`) where it is said, else None.

        The lost motion is then given at the width (the windows carry ``-gap`` as their
        soft-zone shortfall, :func:`.pipeline.taken_off`).
        """
        found = self.gap()
        if found is None:
            return None
        gap, sd, width = found['gap'], found['gap_sd'], found['width']
        # A zone being taken up widens the curve faster than the windup (slope above 1): a
        # gap from bins whose width does not grow so is no soft zone but the line's scatter
        # (independent-generator forearms, slopes -5.7 and -1.3 at 1.4-1.8 standard errors).
        steep = found['slope'] - 1.0 >= HINT_SIGMAS * found['slope_sd']
        if not (steep and gap >= SHORTFALL_RAD and gap >= SHORTFALL_SHARE * width
                and gap >= HINT_SIGMAS * sd):
            return None
        return found

    @property
    def reason(self):
        """
        Say when the lost motion read falls short of the bins' width at the test torque.

        Returns
        -------
        str or None
            One line, or None.

        """
        found = self.said
        if found is None:
            return None
        gap, sd, width = found['gap'], found['gap_sd'], found['width']
        lo, hi = (s * self.takeup_torque for s in SPAN)
        return (f'the lost motion read from the flanks ({found["read"] / ARCMIN:.2f} arcmin, '
                'their extrapolation to no load) is '
                f'{gap / ARCMIN:.2f} +- {sd / ARCMIN:.2f} arcmin ({gap / sd:.1f} standard errors) '
                'less than the width its bins '
                f'give at the lost-motion test torque ({self.takeup_torque:.1f} N·m) less the '
                f'windup there ({width / ARCMIN:.2f} arcmin; bins of {lo:.0f}-{hi:.0f} N·m, '
                f'{found["windows"]} windows): the width grows with the load '
                f'{found["slope"]:.1f} times as fast as the stiffness of the reducer gives, the '
                'play still being taken up across these loads (a soft zone whose knee lies '
                'beyond them): the lost motion and remaining life are given no lower than that '
                'width from here on; where the friction loop of such small loads has not '
                'opened, the lost motion is more than that width too. A recording whose loads '
                'pass the knee decides')
