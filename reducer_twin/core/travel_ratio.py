"""
How many times the motor turns for a turn of the link, measured against the configured ratio.

The TE is the link angle less the motor angle over the configured reduction ratio ``i``. A
motor that turns ``i'`` times the link adds ``(1 - i'/i)`` of every output angle to it: 0.1 %
off reads 3.4 arcmin over a 1 rad move, more than a reducer's whole lost motion, and the
window analysis then refuses the joint for a cause that reads alike ("the effort has the
opposite sign", measured on the model's simulator with its motor angles scaled by 1.001 or
1.01) or, for another ratio of the same frame size (101 for 81), "the encoders do not
measure the same motion". :class:`TravelRatio` measures the ratio the encoders show from the TE
itself, the slope of the motor's moves (the link's less the TE's) on the link's over
:data:`BASELINE_S` (weighted by the link's move, so that the play taken up at a reversal,
a motor move the link does not follow, weighs nothing; a TE step of a turn count restored
at a wrap, far beyond any move, is left out; the link's noise, in the regressor, is taken off
its moves' squares), and says when it differs from the configured one by more than
:data:`RATIO_TOLERANCE`. A motor more than half as far off changes the TE by more than
half of every move, which that gate leaves out: the median ratio of those moves is taken
instead, and a factor of encoders in mixed units or of the other sense is named
(:data:`UNIT_FACTORS`).

Offline, where the motor angles' form and sense are found from the data, a chunk's travels
(:func:`motor_travel_ratio`) are classified by :func:`motor_angle_form` and the motor's
sense is :func:`motor_direction`.
"""

import math

import numpy as np

from .velocity_check import angle_noise, ANGLE_UNITS

BASELINE_S = 0.01
"""Span [s] of the moves compared (a few samples at 100 Hz-1 kHz, quiet of encoder noise)."""

RATIO_TOLERANCE = 0.005
"""
Relative difference from the configured ratio beyond which the measured one is said.

The measurement's own error: the play taken up at each reversal and the twist that
follows a load which changes with the angle (gravity) move the link behind the motor by
arcminutes over moves of a radian. Measured on recordings whose ratio is the configured
one: −0.00…−0.14 % (independent generator, 4 seeds; third generator, 8 recordings with
encoder eccentricity and a motor's once-a-turn error; the model's simulator −0.07 and
−0.09 %). A rated torque of gravity alone twists an RV-80E by 0.12 % of its swing. The
TE is refused from smaller errors (0.1 % reads as an effort of the other sign, which that
refusal now names); this line names the cause of larger ones (1 %: 81.735 read for
81.81; another ratio of the frame, 101 for 81: 100.91).
"""

_PLAY_RAD = 1e-3
"""TE change [rad] a move may carry beside a ratio error: the play of a reversal (3.4 arcmin)."""

JUDGE_TRAVEL_RAD = 3.0
"""Link travel [rad] over compared moves before the ratio is judged."""

_IN_RADIANS = 'publish both angles in radians (REP 103)'

UNIT_FACTORS = (
    *((1.0 / radian, f'a motor angle in {unit} beside a link angle in radians', _IN_RADIANS)
      for unit, (radian, _) in ANGLE_UNITS.items()),
    *((radian, f'a link angle in {unit} beside a motor angle in radians', _IN_RADIANS)
      for unit, (radian, _) in ANGLE_UNITS.items()),
    (-1.0, 'a motor encoder that counts against the link (a negative reduction)',
     'set motor_direction (twin.motor_direction in --config) to -1'))
"""
Measured over configured ratio that encoders in mixed units (or senses) give, what, and the remedy.

A unit of :data:`.velocity_check.ANGLE_UNITS` is ``radian`` radians' worth of its own (pi/180
for degrees, 2 pi for revolutions): a motor in it reads ``1/radian`` of the ratio, a link in
it ``radian``. Such a motor turns the ratio times a units factor "times the link", far beyond the
:data:`RATIO_TOLERANCE` a ratio is measured within; a ratio of another reducer lies within
a factor 0.5-2 of the configured one for the frame sizes' usual ratios (81-185), so none is
taken for units.
"""

FACTOR_TOLERANCE = 0.02
"""Relative difference within which a measured factor is read as one of :data:`UNIT_FACTORS`."""

TRAVEL_TOLERANCE = 0.05
"""
Relative difference within which a motor's travel over its link's is read as a form.

Motor and link travel as their sums of absolute steps, over a chunk of a recording: within
0.2 % of the form on the model's simulator at 250 Hz and 1 kHz (a probe of one bag: 80.88-80.94
for 81; a link in degrees beside a raw motor in radians 1.412 for 1.414; a motor in degrees
4 634-4 637 for 4 641). The forms a raw or an output motor of an 81-ratio reducer gives in
:data:`UNIT_FACTORS`' units lie at least 35 % apart (1 and 1.41, 57.3 and 81, 1/81 and 1/57.3).
"""

WIDE_SPREAD = 0.05
"""
Interquartile range of the left-out moves' ratios, as a share of their median, read from.

Encoders in mixed units (the model's simulator, 1 kHz): 0.2-1 %; a motor in degrees whose
moves the turn counts restored fold: quartiles of the ratio at -359 and 640 for 4641.
"""

_WIDE_MOVES = 100_000
"""Most ratios of moves the TE gate leaves out that are kept (a stream of another ratio)."""


def mixed_units(travel, ratio):
    """
    Name encoders in mixed units from how far the motor travels for the link, or None.

    A raw motor angle in radians travels the reduction ratio ``i`` times its link, one divided
    by the ratio once; a factor of :data:`UNIT_FACTORS` more (a link in degrees beside a motor
    in radians: ``i·pi/180``) is the units of one of the two, which the raw-or-output choice,
    made on the travel, cannot read: a link in degrees beside a raw motor travels 1.41 times
    for ``i = 81`` and was read as an output motor, every sample pair then a spike. Either
    standard form within :data:`TRAVEL_TOLERANCE` is taken first, and a travel beyond
    ``sqrt(i)``, which reads as a raw motor, is never taken for an output motor in other
    units: a reducer of another ratio of the same frame (57 configured as 81) is likelier
    than an output motor in degrees (57.3), and its ratio is said as such
    (:meth:`TravelRatio.reason`).

    Parameters
    ----------
    travel : float
        The motor's travel over the link's (sums of absolute steps).
    ratio : float
        The configured reduction ratio ``i``.

    Returns
    -------
    tuple or None
        ``(factor, what, remedy, raw)``: the factor of :data:`UNIT_FACTORS`, what gives it,
        the remedy, and whether the motor angles are raw (else divided by the ratio).

    """
    if not (math.isfinite(travel) and travel > 0.0):
        return None
    if any(abs(travel / form - 1.0) <= TRAVEL_TOLERANCE for form in (ratio, 1.0)):
        return None
    for value, what, remedy in UNIT_FACTORS:
        if value <= 0.0:
            continue        # the other sense: a travel does not show it
        for raw, form in ((True, ratio * value), (False, value)):
            if abs(travel / form - 1.0) <= TRAVEL_TOLERANCE and \
                    (raw or travel < math.sqrt(ratio)):
                return value, what, remedy, raw
    return None


def motor_angle_form(travel, ratio):
    """
    Read the form of a joint's motor angles from the motor's travel over the link's.

    Raw angles (at the motor) travel about the ratio ``i`` times the link, output angles
    (divided by it) about once; the two are told apart at ``sqrt(i)``. A travel below
    ``1/sqrt(i)`` is a link entry that moves about ``i`` times its motor entry: the two
    entries swapped. Encoders in mixed units (:func:`mixed_units`) are read in the form
    their factor comes with.

    Parameters
    ----------
    travel : float
        The motor's travel over the link's (finite, > 0).
    ratio : float
        The configured reduction ratio ``i``.

    Returns
    -------
    tuple
        ``(form, units)``: ``'raw'``, ``'output'`` or ``'swapped'``, and
        :func:`mixed_units` (None for encoders in one unit).

    """
    units = mixed_units(travel, ratio)
    if units is not None:
        return ('raw' if units[3] else 'output'), units
    if travel < 1.0 / math.sqrt(ratio):
        return 'swapped', None
    return ('raw' if travel > math.sqrt(ratio) else 'output'), None


MIN_DETECT_TRAVEL_RAD = 0.05
"""Link travel [rad] a chunk must show before its motor angles are classified."""


def motor_travel_ratio(link, motor):
    """
    Motor travel over link travel (total variation) of one joint in one chunk.

    About the reduction ratio for raw motor angles and about 1 for angles
    already divided by it; NaN when the link moved less than
    :data:`MIN_DETECT_TRAVEL_RAD` (nothing to tell them apart by).

    Parameters
    ----------
    link, motor : ndarray
        Positions of the link and motor entries [rad] (NaN where absent).

    Returns
    -------
    float
        The ratio of travels.

    """
    def travel(x):
        x = x[np.isfinite(x)]
        return float(np.abs(np.diff(x)).sum()) if x.size > 1 else 0.0
    t_link, t_motor = travel(link), travel(motor)
    return t_motor / t_link if t_link >= MIN_DETECT_TRAVEL_RAD else math.nan


def motor_direction(t_link, link, t_motor, motor):
    """
    Whether the motor encoder counts with the link (+1) or against it (-1), in one chunk.

    A gear stage or the encoder's mounting may reverse the motor's sense (ros2_control
    then carries a negative reduction): the motor's steps, taken at the link's stamps,
    then correlate negatively with the link's. NaN when the link moved less than
    :data:`MIN_DETECT_TRAVEL_RAD` or the two do not overlap in time.

    Parameters
    ----------
    t_link, link, t_motor, motor : ndarray
        Stamps [ns] and positions [rad] of the link and motor entries (NaN where absent).

    Returns
    -------
    float
        +1, -1 or NaN.

    """
    lk, mk = np.isfinite(link), np.isfinite(motor)
    t_l, x_l, t_m, x_m = t_link[lk], link[lk], t_motor[mk], motor[mk]
    if x_l.size < 2 or x_m.size < 2 or np.abs(np.diff(x_l)).sum() < MIN_DETECT_TRAVEL_RAD:
        return math.nan
    inside = (t_l >= t_m[0]) & (t_l <= t_m[-1])
    if np.count_nonzero(inside) < 2:
        return math.nan
    order = np.argsort(t_m, kind='stable')
    # Single-turn encoders wrap at +-pi: each side unwrapped before its steps are taken.
    steps_l = np.diff(np.unwrap(x_l)[inside])
    steps_m = np.diff(np.interp(t_l[inside], t_m[order], np.unwrap(x_m[order])))
    product = float(steps_l @ steps_m)
    return math.copysign(1.0, product) if product else math.nan


class TravelRatio:
    """
    Measure once the ratio of the motor's moves to the link's.

    Parameters
    ----------
    ratio : float
        The configured reduction ratio ``i`` (motor angles are raw, at the motor).

    Attributes
    ----------
    measured : float or None
        The ratio the encoders show, once judged.

    """

    def __init__(self, ratio):
        self.ratio = float(ratio)
        self.measured = None
        self._sums = np.zeros(3)     # Σ Δl·Δm, Σ Δl², Σ |Δl|
        self._wide = []              # Δm/Δl of moves the TE gate leaves out (None: scattered)
        self._wide_travel = 0.0      # Σ |Δl| of those

    def observe(self, t, link_angle, te):
        """
        Take a chunk of the TE stream until the ratio is judged.

        Parameters
        ----------
        t : ndarray
            Stamps [s].
        link_angle, te : ndarray
            Unwrapped link angles and the TE ``theta_link - theta_motor/i`` [rad] (NaN
            where not valid).

        """
        if self.measured is not None or t.size < 3:
            return
        step = float(np.median(np.diff(t)))
        k = max(1, int(round(BASELINE_S / step))) if step > 0.0 else 1
        if t.size <= k:
            return
        d_link = link_angle[k:] - link_angle[:-k]
        d_te = te[k:] - te[:-k]
        with np.errstate(invalid='ignore'):
            ok = np.abs(d_te) <= 0.5 * np.abs(d_link) + _PLAY_RAD    # NaN: not valid
        wide = ~ok & (np.abs(d_link) > _PLAY_RAD)
        self._left_out(d_link[wide], d_te[wide], k)
        d_link, d_motor = d_link[ok], d_link[ok] - d_te[ok]     # the motor's, over i
        # The link's noise is in the regressor: its variance (twice the samples') is taken
        # off the moves' squares, or a noisy link encoder reads a ratio too low.
        noise = 2.0 * angle_noise(link_angle) ** 2 * d_link.size
        self._sums += [d_link @ d_motor, d_link @ d_link - noise, np.abs(d_link).sum() / k]
        if self._sums[2] >= JUDGE_TRAVEL_RAD and self._sums[1] > 0.0:
            self.measured = float(self.ratio * self._sums[0] / self._sums[1])
        elif self._wide is not None and self._wide_travel >= JUDGE_TRAVEL_RAD and \
                self._wide_travel > 2.0 * self._sums[2]:
            # Most moves change the TE by more than half the link's: a motor that turns
            # another number of times by far (another frame's ratio, angles in other
            # units). Their median ratio, which the turn counts restored at wraps (a few
            # moves) do not move; none where they scatter (a motor in degrees moves by
            # more than half a turn a sample, and the turn counts restored fold it).
            ratios = np.concatenate(self._wide)
            quartiles = np.percentile(ratios, [25.0, 50.0, 75.0])
            if quartiles[2] - quartiles[0] <= WIDE_SPREAD * abs(quartiles[1]):
                self.measured = float(self.ratio * quartiles[1])
            elif ratios.size >= _WIDE_MOVES:
                self._wide = None     # as many as are kept, and scattered: never judged

    def _left_out(self, d_link, d_te, k):
        """Keep the ratios of moves beyond the play that the TE gate leaves out."""
        finite = np.isfinite(d_te)
        if self._wide is None or not finite.any() or \
                sum(a.size for a in self._wide) >= _WIDE_MOVES:
            return
        d_link, d_te = d_link[finite], d_te[finite]
        self._wide.append(1.0 - d_te / d_link)
        self._wide_travel += float(np.abs(d_link).sum()) / k

    def _angle_forms(self):
        """
        Factors that motor angles taken in the other form give, what, and the remedy.

        Live, ``motor_angles`` is configured (offline it is found from the data): output
        angles taken as raw turn once per link turn, raw angles taken as output the ratio
        squared times; the ratio line then pointed at the reducer's geometry.
        """
        return ((1.0 / self.ratio, 'a motor angle already divided by the ratio but configured '
                 'as raw', 'set motor_angles (twin.motor_angles in --config) to output'),
                (self.ratio, 'a raw motor angle configured as divided by the ratio',
                 'set motor_angles (twin.motor_angles in --config) to raw'))

    def reason(self):
        """Say when the motor turns another number of times than the ratio, else None."""
        if self.measured is None or abs(self.measured / self.ratio - 1.0) <= RATIO_TOLERANCE:
            return None
        factor = self.measured / self.ratio
        off = 100.0 * (factor - 1.0)
        said = (f'the motor encoder turns {self.measured:.5g} times the link where the '
                f'configured reduction ratio is {self.ratio:g} ({off:+.2g} %): the '
                'transmission error then grows with the angle by that share of it, which no '
                "reducer's play or twist does")
        for value, what, remedy in (*self._angle_forms(), *UNIT_FACTORS):
            if abs(factor / value - 1.0) <= FACTOR_TOLERANCE:
                return (f'{said}. That is {value:.4g} times the configured ratio, which '
                        f'{what} gives: {remedy}')
        return (f"{said}; give this reducer's geometry, whose tooth counts set the ratio "
                '(i = 1 + Zpl/Zs*Zp), in its parameter file or in `reducer` / `reducers` of '
                'the configuration')
