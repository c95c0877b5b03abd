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
:data:`RATIO_TOLERANCE`.
"""

import numpy as np

from .velocity_check import angle_noise

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
        d_link, d_motor = d_link[ok], d_link[ok] - d_te[ok]     # the motor's, over i
        # The link's noise is in the regressor: its variance (twice the samples') is taken
        # off the moves' squares, or a noisy link encoder reads a ratio too low.
        noise = 2.0 * angle_noise(link_angle) ** 2 * d_link.size
        self._sums += [d_link @ d_motor, d_link @ d_link - noise, np.abs(d_link).sum() / k]
        if self._sums[2] >= JUDGE_TRAVEL_RAD and self._sums[1] > 0.0:
            self.measured = float(self.ratio * self._sums[0] / self._sums[1])

    def reason(self):
        """Say when the motor turns another number of times than the ratio, else None."""
        if self.measured is None or abs(self.measured / self.ratio - 1.0) <= RATIO_TOLERANCE:
            return None
        off = 100.0 * (self.measured / self.ratio - 1.0)
        return (f'the motor encoder turns {self.measured:.5g} times the link where the '
                f'configured reduction ratio is {self.ratio:g} ({off:+.2g} %): the '
                'transmission error then grows with the angle by that share of it, which no '
                "reducer's play or twist does; give this reducer's geometry, whose tooth "
                'counts set the ratio (i = 1 + Zpl/Zs*Zp), in its parameter file or in '
                '`reducer` / `reducers` of the configuration')
