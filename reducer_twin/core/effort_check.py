"""
Whether a joint's effort is its reducer's output torque in N·m, window by window.

Beyond the play the loaded flanks part as ``H = L + 2·|T|/k_s``: an effort of the
other sign, in other units or offset from the torque shows in the hysteresis the
window analysis reads. :class:`EffortCheck` judges the latest windows by the
width's sign and level, its slope against the model's compliance and where the
play shows, and says once, in one line, what is wrong; from that window on no
lost motion is read (:class:`.window_analysis.WindowAnalyzer`).
"""

import math

import numpy as np

from .velocity_check import ANGLE_UNITS

PLAUSIBLE_LOST_MOTION_RAD = math.radians(1.0)
"""
Largest lost motion [rad] read as one: 60 arcmin, 20 times the usual wear limit (3 arcmin).

A reading beyond it is an encoder or configuration fault, not a reducer.
"""


EFFORT_CHECK_WINDOWS = 5
"""Windows with two or more hysteresis bins beyond twice the test torque that decide the check."""


EFFORT_CHECK_MEMORY = 50
"""The latest windows of the effort check (its medians)."""


EFFORT_SLOPE_RANGE = (0.25, 4.0)
"""
Plausible ratio of the hysteresis' growth with the effort to the model's (1 for the torque).

Beyond the play, the width between the loaded flanks grows as ``2·|T|/k_s``: an effort in
the output torque's units gives the model's series stiffness within its tolerance. Measured
(median over a joint's windows, bins beyond twice the test torque): 0.95-1.13 on the
independent generator, 0.68-1.18 on the third (catalogue stiffness +-20 %, a soft knee),
1.07-1.08 on the model's simulator; an effort ten times the torque gives 0.11, a tenth of
it 10.4. A ratio outside this range is an effort in other units, not a reducer.
"""


FIRST_ORDER_ALLOWANCE_RAD = math.radians(1.0 / 60.0)
"""
Largest 1x error of the output angle the effort check allows for where the fit cannot see it.

The eccentricity of a link encoder and the reducer's own once-per-turn error: real RV-80E
prototypes measure about +-30 arcsec (physics notes, section 4); the third generator draws
10-40 arcsec. Under gravity the torque follows ``cos(theta)``, so such an error is odd in
the torque, the window fit cannot identify it, and it changes the width's slope: a
third-generator forearm (35 arcsec, 178 N*m of gravity) read a slope ratio of 0.24 and was
refused as an effort 4.2 times the torque; with this allowance its median reaches 1.29
(windows 0.21-1.70). An effort in other units keeps its verdict: the allowance shrinks with
the effort's scale (0.04 on the model's simulator at ten times the torque, whose ratio is
then 0.11; at five times 0.22 + 0.09, below :data:`EFFORT_SLOPE_REACH`;
``bench/bench_effort_check.py``).
"""


TORQUE_SLOPES = (0.68, 1.18)
"""
Slope ratios measured at the torque's own scale, across the three generators (least, most).

The range :data:`EFFORT_SLOPE_RANGE` leaves room around. Angles published in revolutions
(2·pi times smaller than radians) with the effort in N·m read these divided by 2·pi: an
effort 5.3-9.2 times the torque, which the refusal names beside an effort in other units.
"""


EFFORT_SLOPE_REACH = 0.5
"""
Slope ratio a window's 1x allowance must lift a ratio below the range to, to spare it.

Half the model's torsional stiffness: at the torque's own scale the three generators read
0.68-1.18 (catalogue stiffness +-20 %, soft knees), so 0.5 leaves room; an effort five
times the torque reads 0.22 and reaches 0.31 with its allowance.
"""


EFFORT_SLOPE_PRECISION = 0.3
"""
Largest standard error of a window's slope ratio, as a share of the ratio, that the check uses.

A window whose bins beyond twice the test torque lie close together (a base joint loaded by
its accelerations alone) gives a slope the noise decides: a third-generator base read 0.025
(a median over 5 windows) and was refused as an effort 40 times the torque. The error
scales with the ratio when the effort is scaled, so an effort in other units keeps its
windows; their sign and width still count from every window.
"""


EFFORT_OFFSET_NEAR = (2.0, 4.0)
"""Bins, in lost-motion test torques, where the offset check reads the play near zero effort."""


EFFORT_OFFSET_FAR = 6.0
"""Bins from this many test torques on give the offset check the play far from zero effort."""


EFFORT_OFFSET_SHARE = 0.35
"""
Share of the far play below which the play near zero effort says the effort is offset.

The play near zero effort over that far from it (medians over a joint's windows, the far
bins' compliance error taken off both): 0.68-1.13 on 78 joints of the independent and third
generators (seeds 4-11, 150 and 400 h recordings at 10-90 % of life, soft knees and
stiffness within +-20 % included; one base with 2 such windows 0.41, its near play 1.3
arcmin) and 0.90-0.99 on the model's simulator; an effort offset by 80 N*m (10 % of an
RV-80E's rated torque) 0.20-0.23 where its near bins lie below the offset, by 150 N*m
-0.03-0.03. Offsets within the near bins (40 N*m and less) give 0.89-0.93: undetected, the
wear then reads within 10 % (one remaining-life interval of four missed the truth).
"""


EFFORT_OFFSET_NEAR_MAX_RAD = math.radians(0.2 / 60.0)
"""
Largest play near zero effort [rad] the offset check takes for none (0.2 arcmin).

A reducer's play at its test torque is at least its new lost motion (0.3 arcmin and more);
an offset effort gave -0.01-0.16 arcmin there.
"""


EFFORT_OFFSET_MIN_RAD = math.radians(0.3 / 60.0)
"""Smallest far play [rad] the offset check judges by (a new reducer's least, 0.3 arcmin)."""


class EffortCheck:
    """
    The effort checks of one joint over its latest windows.

    Parameters
    ----------
    tables : ModelTables
        The reducer's model tables (its series stiffness).
    takeup_torque : float
        The catalogue's lost-motion test torque [N·m].

    Attributes
    ----------
    effort_fault : str or None
        Why the effort is not the output torque, once found (it stays).

    """

    def __init__(self, tables, takeup_torque):
        self.tables = tables
        self.takeup_torque = takeup_torque
        self.effort_fault = None
        self._effort_checks = []        # (width [rad], slope ratio, 1x share) of the latest
        self._offset_checks = []        # (near, far [rad], step [N·m]) of the latest

    def restart(self):
        """Judge afresh from the next window (the windows judged read a TE since found wrong)."""
        self.effort_fault = None
        self._effort_checks = []
        self._offset_checks = []

    def check(self, torque_b, width, std, usable, odd):
        """
        Check, window by window, that the effort is the output torque in N·m.

        Beyond the play the loaded flanks part as ``H = L + 2·|T|/k``: the width is
        positive (the twist follows the torque) and grows with the model's series
        compliance ``1/k_s``. Per window with two or more usable bins beyond twice
        the lost-motion test torque: the median width and the weighted slope of the
        width on ``2·|T|`` times ``k_s`` (where the bins determine it,
        :data:`EFFORT_SLOPE_PRECISION`). Over the latest :data:`EFFORT_CHECK_MEMORY`
        such windows (at least :data:`EFFORT_CHECK_WINDOWS`), a median width beyond
        :data:`PLAUSIBLE_LOST_MOTION_RAD` is encoders in other units (degrees), a
        negative one an effort of the opposite sign, a median slope ratio outside
        :data:`EFFORT_SLOPE_RANGE` an effort in other units, and a play that shows
        only far from zero effort an effort with an offset (:meth:`_offset_check`):
        :attr:`effort_fault` says which, once, and that window and every later one
        give no lost motion.

        A 1x error of the output angle that the window fit could not identify is left
        in the width: under gravity, where the torque follows ``cos(theta)``, it is odd
        in the torque and its slope adds to the ratio. Its share is bounded by the
        slope of the flanks' ``sin/cos(theta)`` difference (``odd``) times
        :data:`FIRST_ORDER_ALLOWANCE_RAD`; a ratio below the range is an effort in
        other units only if it stays below with that share added (:meth:`_fault`).

        Parameters
        ----------
        torque_b, width, std : ndarray, shape (W, B)
            Bin torques [N·m], widths and their standard errors [rad].
        usable : ndarray of bool, shape (W, B)
            Bins that take part.
        odd : ndarray, shape (W, B, 2)
            Per bin, the difference between the flanks' mean ``sin(theta)`` and
            ``cos(theta)``, as the width takes them; zero for a term the fit removed.

        Returns
        -------
        ndarray of bool, shape (W,)
            Windows from which on the effort is known not to be the torque.

        """
        n_win = usable.shape[0]
        if self.effort_fault is not None:
            return np.ones(n_win, dtype=bool)
        faulty = np.zeros(n_win, dtype=bool)
        beyond = usable & (np.nan_to_num(torque_b) >= 2.0 * self.takeup_torque)
        level = np.full(n_win, np.nan)
        ratio = np.full(n_win, np.nan)
        share = np.zeros(n_win)
        rows = np.flatnonzero(beyond.sum(axis=1) >= 2)
        if rows.size:
            b = beyond[rows]
            w = np.where(b, 1.0 / np.where(b, std[rows], 1.0) ** 2, 0.0)
            x = np.where(b, 2.0 * torque_b[rows], 0.0)
            sw = w.sum(axis=1)
            x0 = (w * x).sum(axis=1) / sw
            sxx = (w * (x - x0[:, None]) ** 2).sum(axis=1)
            k_s = self.tables.series_stiffness

            def slope(y):   # weighted slope of y on 2|T| over the bins, per window
                y = np.where(b, y, 0.0)
                y0 = (w * y).sum(axis=1) / sw
                return (w * (x - x0[:, None]) * (y - y0[:, None])).sum(axis=1) / sxx
            with np.errstate(invalid='ignore', divide='ignore'):
                found = slope(width[rows]) * k_s
                # Bins close together leave the slope to the noise: not judged by it.
                error = k_s / np.sqrt(sxx)
                share[rows] = FIRST_ORDER_ALLOWANCE_RAD * k_s * np.hypot(
                    slope(odd[rows, :, 0]), slope(odd[rows, :, 1]))
            ratio[rows] = np.where(error <= EFFORT_SLOPE_PRECISION * np.abs(found), found,
                                   np.nan)
            level[rows] = np.nanmedian(np.where(b, width[rows], np.nan), axis=1)
        offsets = self._offset_check(torque_b, width, beyond)
        for row in np.flatnonzero(np.isfinite(level) | np.isfinite(offsets[0])).tolist():
            fault = self._window(level[row], ratio[row], share[row], offsets[:, row])
            if fault is not None:
                self.effort_fault = fault
                faulty[row:] = True
                break
        return faulty

    def _window(self, level, slope, share, offset):
        """Add one window to the effort checks; return the fault they find, or None."""
        fault = None
        checks = self._effort_checks
        if math.isfinite(level):
            checks.append((level, slope, share))
            del checks[:-EFFORT_CHECK_MEMORY]
            if len(checks) >= EFFORT_CHECK_WINDOWS:
                levels, slopes, shares = np.array(checks).T
                judged = np.isfinite(slopes)
                slope = reach = math.nan
                if judged.sum() >= EFFORT_CHECK_WINDOWS:
                    slope = float(np.median(slopes[judged]))
                    reach = float(np.median(slopes[judged] + shares[judged]))
                fault = self._fault(float(np.median(levels)), slope, len(checks), reach)
        offsets = self._offset_checks
        if fault is None and np.isfinite(offset).all():
            offsets.append(offset.tolist())
            del offsets[:-EFFORT_CHECK_MEMORY]
            if len(offsets) >= EFFORT_CHECK_WINDOWS:
                fault = self._offset_fault(*np.median(np.array(offsets), axis=0).tolist(),
                                           len(offsets))
        return fault

    def _offset_check(self, torque_b, width, beyond):
        """
        Where each window's play shows: the residual width near and far from zero effort.

        The width less the model's windup, ``r = H - 2·|T|/k_s``, is the lost motion
        wherever the play is taken up on both flanks, plus ``2·|T|`` times the unit's
        compliance error (its stiffness within tolerance of the catalogue's); larger
        in a soft zone. An effort whose zero is ``δ`` away from the torque's puts both
        flanks of a bin below ``|δ|`` on one side of the play: there ``r`` is the
        compliance error's alone, and the lost motion appears at ``|T| ≈ |δ|``. Per
        window: a straight line ``r = L + s·|T|`` through the bins from
        :data:`EFFORT_OFFSET_FAR` test torques on (``s = 0`` with one bin), its level
        ``L``, the median of ``r - s·|T|`` over the bins at :data:`EFFORT_OFFSET_NEAR`
        test torques, and the effort where ``r - s·|T|`` first reaches ``L/2``
        (interpolated between bins).

        Returns
        -------
        ndarray, shape (3, W)
            The near play, ``L`` [rad] and the step's effort [N·m]; NaN where a window
            lacks near or far bins.

        """
        n_win = width.shape[0]
        out = np.full((3, n_win), np.nan)
        torque = np.nan_to_num(torque_b)
        lo, hi = EFFORT_OFFSET_NEAR
        near = beyond & (torque <= hi * self.takeup_torque) & (torque >= lo * self.takeup_torque)
        far = beyond & (torque >= EFFORT_OFFSET_FAR * self.takeup_torque)
        rows = np.flatnonzero(near.any(axis=1) & far.any(axis=1))
        if rows.size == 0:
            return out
        t, m = torque[rows], far[rows]
        r = np.where(beyond[rows], width[rows] - 2.0 * t / self.tables.series_stiffness, 0.0)
        n = m.sum(axis=1)
        t0 = (m * t).sum(axis=1) / n
        r0 = (m * r).sum(axis=1) / n
        stt = (m * (t - t0[:, None]) ** 2).sum(axis=1)
        with np.errstate(invalid='ignore', divide='ignore'):
            slope = np.where(stt > 0.0, (m * (t - t0[:, None]) * (r - r0[:, None])).sum(axis=1)
                             / np.where(stt > 0.0, stt, 1.0), 0.0)
        level = r0 - slope * t0
        r = r - slope[:, None] * t
        out[0, rows] = np.nanmedian(np.where(near[rows], r, np.nan), axis=1)
        out[1, rows] = level
        half = 0.5 * level
        for k, row in enumerate(rows.tolist()):
            bins = np.flatnonzero(beyond[row])
            above = np.flatnonzero(r[k, bins] >= half[k])
            if above.size == 0:
                continue
            i = bins[above[0]]
            step = t[k, i]
            if above[0] > 0:
                j = bins[above[0] - 1]
                share = (half[k] - r[k, j]) / (r[k, i] - r[k, j])
                step = t[k, j] + share * (t[k, i] - t[k, j])
            out[2, row] = step
        return out

    def _fault(self, level, slope, windows, reach=math.nan):
        """
        Say how the effort differs from the torque (medians of the check), or None.

        ``reach`` is the median slope ratio with the share an unidentified 1x error of
        the output angle may have taken off it: a slope below the plausible range counts
        unless that share could lift it to :data:`EFFORT_SLOPE_REACH` (half the
        torsional stiffness the model gives; 0.68 is the lowest ratio measured at the
        torque's own scale). Above the range the share is not taken: it grows as the
        effort shrinks against the torque (a motor current in A reads far below it), so
        it would hide exactly that fault, and at the torque's own scale it stays far
        below the 3 it would need (1.1 for a forearm with 35 arcsec under 178 N·m of
        gravity).
        """
        beyond = f'{2.0 * self.takeup_torque:.3g} N*m'
        if abs(level) > PLAUSIBLE_LOST_MOTION_RAD:     # a width no reducer has
            return (f'the encoders do not read radians at the output: in {windows} windows '
                    f'the hysteresis beyond {beyond} is {math.degrees(abs(level)) * 60:.4g} '
                    f'arcmin wide and grows {slope:.3g} times as fast with the torque as the '
                    "reducer's torsional stiffness gives (a reducer's lost motion is below "
                    f'{math.degrees(PLAUSIBLE_LOST_MOTION_RAD) * 60:g} arcmin): positions in '
                    'degrees (57.3 times radians) or in counts, or a wrong reduction ratio')
        if level < 0.0:
            # A ratio off the configured one reads so too (the model's simulator, a used
            # unit's motor angles scaled by 1.001 or 1.01: 0.87 and 19 arcmin "below").
            return (f'the effort has the opposite sign of the torque the reducer carries: '
                    f'in {windows} windows the transmission error under positive effort '
                    f'beyond {beyond} lies {math.degrees(-level) * 60:.3g} arcmin below the '
                    'one under negative effort, where a twist follows its torque (a drive '
                    'that reports its effort with the other sign): set effort_scale '
                    '(twin.effort_scale in --config) to -1; if its sign is right, check the '
                    'reduction ratio: one 0.1 % off the configured ratio grows the '
                    'transmission error with the angle and reads so')
        lo, hi = EFFORT_SLOPE_RANGE
        if not math.isfinite(slope) or lo <= slope <= hi:
            return None     # (NaN: too few windows measure the slope)
        if slope < lo and reach >= EFFORT_SLOPE_REACH:
            return None     # an unidentified 1x error of the angle may have lowered it
        if slope <= 0.0:
            return None     # a width that does not grow: no verdict on the units
        return (f'the effort is not the output torque in N*m: in {windows} windows the '
                f'transmission error grows with it {slope:.3g} times as fast as the '
                "reducer's torsional stiffness gives (plausible "
                f'{lo:g}-{hi:g}), so the effort reads about {1.0 / slope:.3g} times the '
                'torque (a motor current in A, or a motor torque taken for joint units or '
                'the other way round: motor_effort_units): set effort_scale '
                '(twin.effort_scale in --config) to the torque per unit of effort'
                + _in_revolutions(slope))

    def _offset_fault(self, near, far, step, windows):
        """Say that the effort is offset from the torque (medians of the check), or None."""
        if not (far >= EFFORT_OFFSET_MIN_RAD and near < EFFORT_OFFSET_NEAR_MAX_RAD
                and near < EFFORT_OFFSET_SHARE * far):
            return None
        arcmin = math.degrees(1.0) * 60.0
        return (f'the effort is offset from the torque the reducer carries: in {windows} '
                f'windows the hysteresis shows a play of {far * arcmin:.2g} arcmin beyond '
                f'{EFFORT_OFFSET_FAR * self.takeup_torque:.3g} N*m of effort but '
                f'{near * arcmin:.2g} arcmin at {EFFORT_OFFSET_NEAR[0] * self.takeup_torque:.3g}'
                f'-{EFFORT_OFFSET_NEAR[1] * self.takeup_torque:.3g} N*m, where a reducer has '
                f"taken its play up (at {self.takeup_torque:.3g} N*m): the effort's zero lies "
                f"about {step:.3g} N*m from the torque's (a drive's current or torque sensor "
                'offset, or a load taken off the effort); zero the effort at the drive')


def _in_revolutions(slope):
    """Name angles in revolutions where a slope ratio reads as they give (else '')."""
    turn = ANGLE_UNITS['revolutions'][0]
    least, most = (r / turn for r in TORQUE_SLOPES)
    if not least <= slope <= most:
        return ''
    return ('; or, if the effort is in N*m, the angles are published in revolutions (a '
            'transmission error in revolutions grows 2*pi = 6.28 times slower with the '
            'torque than in radians, and reads so): positions are read in radians (REP '
            '103), publish them in radians')
