"""
Whether a joint's velocity field is the rate of its link angle, in rad/s.

The window analysis uses the output speed for the operation it counts (Archard
exposure, the mean speed, turning time) and for the drive friction it takes out of
the effort (``Fc·tanh(omega/0.01) + Fv·omega``). Controllers fill the field in other
forms: zeros where the hardware has no velocity, degrees per second, the motor's
speed, the opposite sense. Read as it is, such a field gives a confident wrong wear
and remaining life (a negated field: a wrist's wear 68 % low, its P10-P90 spanning
94-100 000 h) or no observation with a wrong reason (a zero-filled one: "too few
samples per torque reversal"). :class:`VelocityCheck` compares the field with the
link angle's central differences where the joint moves and, once the evidence
suffices, says in one line what the field is and has the link angle's rate used
in its place. A field that lags the angle's rate (a drive's filtered or delayed
velocity) is found by regressing the rate on the field and the field's own rate
(``rate ≈ h·(field + tau·d(field)/dt)``: a stamp that glitches then disturbs only the
regressed side) and replaced when ``tau`` exceeds
:data:`VELOCITY_LAG_S`: the drive friction taken out of the effort switches sign with
the speed at each reversal, and a field 20 ms late switched it 20 ms late. A field far
noisier between samples than the angle's rate (:data:`VELOCITY_NOISE_RAD_S`) is replaced
for the same reason.

The comparison is the median of the ratio field / rate, not a regression: stamps that
scatter about their period (a driver that stamps a message on arrival, 0.3 ms sd at
1 kHz, before the stream is re-timed) make the central differences noisy, with steps
of a few microseconds giving rates hundreds of times the speed. Regressed on such
rates, a true field read 0.002 times the rate and was replaced; the median ratio is
1 for any noise that leaves the rate's sign and median right.
"""

import math

import numpy as np

from .stamp_clock import median_step

VELOCITY_CHECK_SAMPLES = 200
"""Samples turning at ``min_speed`` or faster (by the link angle's rate) that decide the check."""


VELOCITY_SCALE_RANGE = (0.5, 2.0)
"""
Plausible ratio of the velocity field to the link angle's rate (1 for the same quantity).

A velocity the drive filters keeps less of a fast move (a first-order filter of time
constant ``tau`` keeps ``1/sqrt(1 + (2·pi·f·tau)^2)`` of a move of frequency ``f``: 0.85
for 1 Hz moves and a 100 ms filter; its lag is judged apart, :data:`VELOCITY_LAG_S`); the
forms a controller gets wrong are far outside: 0 (zeros), -1 (the other sense), 9.55
(rev/min), 57.3 (degrees per second), the reduction ratio (the motor's speed).
"""

VELOCITY_LAG_S = 3e-3
"""
Lag of the velocity field behind the link angle's rate [s] beyond which it is replaced.

Also at least one sample period: a controller's backward difference lags by half of one
(5 ms at 100 Hz), which the angle's rate at that rate does no better. Measured (the
model's simulator, 1 kHz, 300 h from new; one-off replays): a field delayed by 20 ms, or
filtered at 20 ms (19 ms of lag), let the observed growth law take both joints' remaining
life, P50 60-73 % short; 5 ms one of two (P50 −54 %); 2 ms and a 5-ms filter (4.5 ms)
read as the true field. The same recordings read with the angle's rate read as without a
field (P50 within 8 % of the truth). The lag is read to 0.4 ms from 200 turning samples
(0.3 s at 1 kHz) and to 0.01 ms from 3 000.
"""

VELOCITY_LAG_SAMPLES = VELOCITY_CHECK_SAMPLES
"""
Turning samples whose acceleration is known from which the field's lag may be judged.

As many as decide its scale, so that the verdict may come before a window is complete,
and every sample's speed, those before it too, is the one the verdict chose.
"""

VELOCITY_LAG_SD_S = 0.5e-3
"""
Standard error of the lag [s] below which it is judged; until then more samples are taken.

A joint that turns at a steady speed shows no acceleration to tell a lag by. Regressed
the other way round (the field on the angle's rate and its rate), the first 0.3 s of a
used unit's recording on the model's simulator, at a steady speed but for one stamp that
glitched (the rate 4 % off for 10 ms, an acceleration of ±6.5 rad/s² that the field did
not show), read a 20 ms delay as 0.1 ms with a standard error below this.
"""

VELOCITY_NOISE_RAD_S = 0.01
"""
Noise of the velocity field between samples [rad/s] beyond which it may be replaced.

The speed over which the drive friction taken out of the effort switches sign
(``tanh(omega/0.01)``, :mod:`.friction_fit`): a field noisier than that flips the
friction near each reversal. Measured (the model's simulator, 300 h from new; one-off
replays): white noise of 0.05 rad/s on the field let the growth law take both joints'
remaining life (P50 −65 %); 0.01 and 0.02 rad/s read as the true field. Replaced only
where the angle's own rate, which takes its place, is :data:`VELOCITY_NOISE_RATIO` times
quieter (stamps taken on arrival make the angle's rate the noisier one).
"""

VELOCITY_NOISE_RATIO = 3.0
"""How much noisier than the angle's rate a noisy field must be to be replaced."""

VELOCITY_LAG_GIVE_UP = 20 * VELOCITY_LAG_SAMPLES
"""
Turning samples after which a field of plausible scale is trusted though its lag is unknown.

A joint that turns only at constant speed does not tell a lag from a gain.
"""


VELOCITY_CHECK_BASELINE_S = 0.01
"""
Span [s] of the angle differences the field is compared with (centred, in samples).

Single-step central differences carry the encoder's noise and the stamps' jitter over
one period: at 2 kHz (0.5 ms) a standing joint's differences passed ``min_speed`` with
either sign, their ratios to a true field near zero outnumbered the moving ones', and
a true field read -0.02 times the rate and was replaced (independent generator, seed 7).
Over 10 ms the noise is ten times smaller at 2 kHz and the same at 100 Hz (one step).
"""


ANGLE_NOISE_SIGMAS = 4.0
"""
Standard deviations of the angle's rate noise a sample's rate must pass to count as turning.

Where the link encoder is noisy, the rate over :data:`VELOCITY_CHECK_BASELINE_S` of a
standing joint passes ``min_speed`` too: 20 arcsec rms of link noise at 1 kHz gives it 0.014
rad/s. Those samples' field is near zero, and they outnumbered the moving ones: a true field
read 0.33-0.47 times the rate and was replaced as "other units, or another quantity"
(independent generator, one-off probe). The noise is read from the angle's third
differences (:func:`angle_noise`); with the encoders of the generators and the model's
simulator (below 1 arcsec), ``min_speed`` is the larger. The rate asked is at most
:data:`TURNING_SPEED_CAP` times ``min_speed``, whatever the third differences take for
noise (a slow sample rate's jerk): the check then waits for faster samples, never for none.
"""

TURNING_SPEED_CAP = 10.0
"""The most, in ``min_speed``, that the angle's noise may raise the turning speed to."""


def angle_noise(theta):
    """
    Sample noise of an angle [rad], from its third differences.

    ``theta[i+2] - 3·theta[i+1] + 3·theta[i] - theta[i-1]`` removes motion up to its
    acceleration and carries 20 times the samples' noise variance; the median absolute
    value (1.4826 of it is the sd of normal noise) ignores the few samples of a jerk.
    A sample that repeats the one before is left out: a reading held between slower
    updates (:mod:`.held_encoders`) is a staircase whose steps are motion, not noise (held
    for two samples, they read as noise took a link's ratio 3.7 % high), and a noisy
    encoder never repeats.

    Parameters
    ----------
    theta : ndarray
        An angle's samples [rad], in stamp order.

    Returns
    -------
    float
        Its noise sd [rad]; 0 with fewer than four samples.

    """
    theta = theta[np.concatenate([[True], theta[1:] != theta[:-1]])]
    if theta.size < 4:
        return 0.0
    third = theta[3:] - 3.0 * theta[2:-1] + 3.0 * theta[1:-2] - theta[:-3]
    third = third[np.isfinite(third)]
    if not third.size:
        return 0.0
    return 1.4826 * float(np.median(np.abs(third))) / math.sqrt(20.0)


def baseline_samples(t, baseline_s=VELOCITY_CHECK_BASELINE_S):
    """
    Return the stamps' median step [s] and the samples ``k`` either side over ``baseline_s``.

    ``k`` is at least 1 (and 1 when the step is not positive); the step is 0 for fewer
    than two stamps.
    """
    step = float(np.median(np.diff(t))) if t.size > 1 else 0.0
    return step, max(1, int(round(0.5 * baseline_s / step))) if step > 0.0 else 1


def baseline_rate(t, theta, baseline_s=VELOCITY_CHECK_BASELINE_S):
    """
    Rate of an angle from differences centred over about ``baseline_s`` [rad/s].

    Parameters
    ----------
    t, theta : ndarray
        Stamps [s] and the unwrapped angle [rad], in stamp order.
    baseline_s : float
        Span of each difference.

    Returns
    -------
    ndarray
        ``(theta[i+k] - theta[i-k]) / (t[i+k] - t[i-k])``, NaN within ``k`` samples of
        either end (``k`` from the median step, at least 1).

    """
    out = np.full(t.size, np.nan)
    if t.size < 3:
        return out
    _, k = baseline_samples(t, baseline_s)
    if t.size <= 2 * k:
        return out
    with np.errstate(invalid='ignore', divide='ignore'):
        out[k:-k] = (theta[2 * k:] - theta[:-2 * k]) / (t[2 * k:] - t[:-2 * k])
    return out


ANGLE_UNITS = {'degrees': (math.pi / 180.0, 'pi/180'), 'revolutions': (2.0 * math.pi, '2 pi')}
"""
Units other than radians a controller may publish its positions in, by the ratio of a
velocity field in radians per second to their rate (and how that ratio is written). The
TE is then in those units too, and the joint is refused for what that TE shows (degrees:
encoders that do not measure one motion; revolutions: an effort 6 times the torque):
:meth:`.joint_twin.TwinFront.refusal` leads with the units.
"""


def angles_in(unit):
    """Return the name of the velocity form of positions published in ``unit``."""
    return f'angles in {unit}, the velocity in radians per second'


_KNOWN_FORMS = ((-1.0, 'the other sense'),
                (60.0 / (2.0 * math.pi), 'revolutions per minute'),
                (180.0 / math.pi, 'degrees per second'),
                *((value, angles_in(unit)) for unit, (value, _) in ANGLE_UNITS.items()))


class VelocityCheck:
    """
    Judge a joint's velocity field against the rate of its link angle, pooled over its stream.

    Parameters
    ----------
    min_speed : float
        Slowest output speed counted as turning [rad/s]: only such samples (by the
        angle's rate) take part.
    ratio : float
        Reduction ratio, to name a field that carries the motor's speed.

    Attributes
    ----------
    scale : float
        Median ratio of the field to the angle's rate [-], NaN before any turning sample.
    turning : int
        Turning samples pooled.
    replaced : bool
        True once the field was found not to be the angle's rate: from then on the
        window analysis uses the rate of the link angle.
    trusted : bool
        True once the field was found to be the angle's rate, in time.
    lag_s : float
        The field's lag behind the angle's rate [s], NaN until judged.
    fault : str or None
        Why the field was replaced, in one line.

    """

    def __init__(self, min_speed, ratio):
        self.min_speed = float(min_speed)
        self.ratio = float(ratio)
        self._ratios = []           # field / rate of the turning samples, until decided
        self._scale = None
        self.turning = 0
        self.replaced = False
        self.trusted = False
        self.lag_s = math.nan
        self.fault = None
        self._lag_sums = np.zeros(6)    # f·f, f·d, d·d, r·f, r·d, r·r (d: the field's rate)
        self._lag_samples = 0
        self._period_s = None
        self._jumps = {'field': [], 'rate': []}   # |second differences| of turning samples

    @property
    def leads(self):
        """
        Say when the field leads the link angle's rate by :data:`VELOCITY_LAG_S` or more.

        And by one sample period or more: a field taken as a forward difference leads by
        half of one.

        A field kept while the angle lags it: the link reading is older than the rest of
        its message (latched late), or the field is a commanded velocity. In the first
        case the transmission error, once the encoders' offset is removed, is the link's
        time and the effort the message's: misaligned, as a torque filter would misalign
        them (the third generator with its link read 2-20 ms late: joints off by up to
        +23 % at 4 ms and +80 % at 20 ms). Not corrected; said.
        """
        period = self._period_s or 0.0     # a forward difference leads by half of one
        if self.replaced or not self.lag_s <= -max(VELOCITY_LAG_S, period):
            return None
        lead = -1e3 * self.lag_s
        return (f"the velocity field leads the link angle's rate by {lead:.1f} ms: the link "
                'reading is older than the rest of its message (latched late), or the field '
                'is a commanded velocity; in the first case the effort and the transmission '
                f'error are about {lead:.0f} ms apart, which misreads the lost motion (not '
                'corrected): read the link encoder with the motor encoder and the effort')

    @property
    def decided(self):
        """Return whether the field was trusted or replaced (no further samples are pooled)."""
        return self.replaced or self.trusted

    @property
    def scale(self):
        """Median ratio of the velocity field to the link angle's rate, NaN before turning."""
        if self._scale is None:
            self._scale = float(np.median(np.concatenate(self._ratios))) if self.turning \
                else math.nan
        return self._scale

    def check(self, t, theta, field):
        """
        Pool the samples of a chunk; return whether the field is to be replaced.

        Parameters
        ----------
        t, theta : ndarray
            Stamps [s] and the unwrapped link angle [rad] of the samples in use.
        field : ndarray
            Their velocity field [rad/s, as published] (NaN where absent).

        Returns
        -------
        bool
            True when the field is not the angle's rate (:attr:`fault` says why): the
            caller uses the angle's rate in its place.

        """
        if self.decided:
            return self.replaced
        t = np.asarray(t, dtype=float)
        theta = np.asarray(theta, dtype=float)
        rate = baseline_rate(t, theta)
        with np.errstate(invalid='ignore'):
            both = np.isfinite(field) & (np.abs(rate) >= self._turning_speed(t, theta))
        n = int(np.count_nonzero(both))
        if n:
            self._ratios.append(field[both] / rate[both])
            self.turning += n
            self._scale = None
            self._pool_lag(t, rate, field, both)
            self._pool_noise(t, theta, field, both)
        if self.turning < VELOCITY_CHECK_SAMPLES:
            return False
        scale = self.scale
        lo, hi = VELOCITY_SCALE_RANGE
        if lo <= scale <= hi:
            return self._judge_noise() or self._judge_lag()
        self._ratios = [np.array([scale])]       # decided: the median is all that is kept
        self.replaced = True
        if scale == 0.0:
            seen = f'is zero where the link angle turns ({self.turning} samples)'
        else:
            seen = (f'reads {scale:.3g} times the rate of the link angle over '
                    f'{self.turning} turning samples ({self._form(scale)})')
        self.fault = f'the velocity field {seen}: the rate of the link angle is used instead'
        return True

    def _turning_speed(self, t, theta):
        """Return the rate a sample must reach to count as turning [rad/s] (see the constants)."""
        noise = angle_noise(theta)
        if noise <= 0.0:
            return self.min_speed
        step, k = baseline_samples(t)
        rate_noise = math.sqrt(2.0) * noise / (2 * k * step) if step > 0.0 else 0.0
        return min(max(self.min_speed, ANGLE_NOISE_SIGMAS * rate_noise),
                   TURNING_SPEED_CAP * self.min_speed)

    def _pool_lag(self, t, rate, field, both):
        """Add a chunk's turning samples to the regression of the rate on the field, its rate."""
        if self._period_s is None and t.size >= 3:    # a node's chunks may be a few samples
            self._period_s = median_step(t)
        slope = baseline_rate(t, np.where(np.isfinite(field), field, np.nan))
        ok = both & np.isfinite(slope)
        f, d, r = field[ok], slope[ok], rate[ok]
        self._lag_sums += [f @ f, f @ d, d @ d, r @ f, r @ d, r @ r]
        self._lag_samples += int(f.size)

    def _pool_noise(self, t, theta, field, both):
        """Keep the second differences of the field and of the angle's one-step rate."""
        if t.size < 3:
            return
        with np.errstate(invalid='ignore', divide='ignore'):
            step = np.gradient(theta, t)     # the rate the window analysis would use
        inner = both[1:-1] & np.isfinite(field[:-2]) & np.isfinite(field[2:])
        for name, x in (('field', field), ('rate', step)):
            jump = np.abs(x[1:-1] - 0.5 * (x[:-2] + x[2:]))[inner]
            self._jumps[name].append(jump[np.isfinite(jump)])

    def _judge_noise(self):
        """Replace a field far noisier than the angle's rate (:data:`VELOCITY_NOISE_RAD_S`)."""
        noise = {name: 1.4826 * float(np.median(np.concatenate(j))) / math.sqrt(1.5)
                 if sum(a.size for a in j) else math.nan for name, j in self._jumps.items()}
        if not (noise['field'] > VELOCITY_NOISE_RAD_S
                and noise['field'] > VELOCITY_NOISE_RATIO * noise['rate']):
            return False
        self._ratios = [np.array([self.scale])]
        self.replaced = True
        self.fault = ('the velocity field is noisier than the rate of the link angle: '
                      f"{noise['field']:.2g} rad/s between samples against "
                      f"{noise['rate']:.2g} over {self.turning} turning samples (the drive "
                      'friction taken out of the effort switches sign within '
                      f'{VELOCITY_NOISE_RAD_S:g} rad/s of a reversal): the rate of the link '
                      'angle is used instead')
        return True

    def _judge_lag(self):
        """Trust a field of plausible scale, or replace it when it lags; False while unknown."""
        if self._lag_samples < VELOCITY_LAG_SAMPLES:
            return False
        ff, fd, dd, rf, rd, rr = self._lag_sums
        det = ff * dd - fd * fd
        gain = (rf * dd - rd * fd) / det if det > 1e-9 * ff * dd else 0.0
        n = self._lag_samples
        if gain > 0.0:
            coef = (rd * ff - rf * fd) / det
            residual = max(rr - gain * rf - coef * rd, 0.0) / max(n - 2, 1)
            self.lag_s = float(coef / gain)
            known = math.sqrt(residual * ff / det) / gain <= VELOCITY_LAG_SD_S
        else:
            known = False
        if not known:        # too little acceleration yet to tell a lag by
            self.lag_s = math.nan
            self.trusted = self.turning >= VELOCITY_LAG_GIVE_UP
            if self.trusted:
                self._ratios = [np.array([self.scale])]
            return False
        limit = max(VELOCITY_LAG_S, self._period_s or 0.0)
        self._ratios = [np.array([self.scale])]     # decided: the median is all that is kept
        if not self.lag_s > limit:
            self.trusted = True
            return False
        self.replaced = True
        self.fault = (f'the velocity field lags the rate of the link angle by '
                      f'{1e3 * self.lag_s:.1f} ms over {self._lag_samples} turning samples (a '
                      'filtered or delayed velocity; the drive friction switches with the '
                      'speed at each reversal): the rate of the link angle is used instead')
        return True

    def _form(self, scale):
        """Name the form a velocity field of this ratio most likely has."""
        forms = _KNOWN_FORMS + ((self.ratio, f"the motor's speed: the ratio is {self.ratio:.4g}"),
                                (1.0 / self.ratio, 'the speed divided by the reduction ratio'))
        for value, name in forms:
            if abs(scale - value) <= 0.1 * abs(value):
                return name
        for value, name in forms:
            if value and abs(scale + value) <= 0.1 * abs(value):
                return f'{name}, the other sense'
        return 'other units, or another quantity'
