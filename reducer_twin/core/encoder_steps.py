"""
How finely each encoder reports the output angle, judged from its own steps.

A reducer's lost motion is 0.4-3 arcmin, and over a short recording early in a unit's
life it grows by a few hundredths of an arcminute. An encoder whose reading moves in
steps coarser than that is read as it is: each window's lost motion then wanders with
where the joint meets the load by a part of a step that no window's fit reports.
:class:`EncoderSteps` finds the smallest move each encoder reports (the 0.1th percentile
of its nonzero steps between successive samples, the motor's referred to the output) and
says when it is coarser than :data:`COARSE_STEP_RAD` (the lost motion itself uncertain)
or than :data:`GROWTH_STEP_RAD` (an early growth read less surely than its interval
says). The estimate is not changed: a step is a property of the recording, not a fault
the twin could take out.
"""

import math

import numpy as np

COARSE_STEP_RAD = math.radians(0.5 / 60.0)
"""
Encoder step [rad at the output] beyond which a joint's lost motion is said to be uncertain.

Half an arcminute: a reducer's lost motion is 0.4-3 arcmin. A 16-bit link encoder steps by
0.33 arcmin, a 12-bit one by 5.3; motor encoders' steps are divided by the ratio.
"""

GROWTH_STEP_RAD = math.radians(0.1 / 60.0)
"""
Encoder step [rad at the output] beyond which a small growth of the lost motion is said to
be read less surely than its interval says.

A tenth of an arcminute. A 17-bit link encoder steps by 0.165 arcmin: each window's lost
motion then wanders with where the joint meets the load, by a part of a step that no
window's fit reports. Measured (the model's simulator, 300 h from new, three seeds): the
lost motion read within 1-4 %, but its growth, 0.02 arcmin in the recording, read as wear
29-43 % high on 6 of 6 joints, the remaining life 30-75 % short with the truth above P90;
18 and 19 bits read as the stream unquantised, and so did 2^17 on units worn 2.6-13 µm.
"""

JUDGE_STEPS = 1000
"""Nonzero steps of each encoder seen before it is judged (the 0.1th percentile is then a step)."""


class EncoderSteps:
    """
    Judge once, per encoder, the smallest move it reports at the output.

    Parameters
    ----------
    ratio : float
        Reduction ratio ``i``: motor angles [rad at the motor] are referred to the output by it.

    Attributes
    ----------
    step : dict of str to float
        ``'link'``, ``'motor'``: the smallest move reported [rad at the output], once judged.

    """

    def __init__(self, ratio):
        self.ratio = abs(float(ratio))
        self.step = {}
        self._seen = {'link': [], 'motor': []}

    @property
    def decided(self):
        """Whether both encoders have been judged."""
        return len(self.step) == 2

    def observe(self, link_angle, motor_angle):
        """
        Take the steps between successive samples of a chunk until both encoders are judged.

        Parameters
        ----------
        link_angle : ndarray
            Link angles [rad].
        motor_angle : ndarray
            Motor angles [rad at the motor].

        """
        for side, x, scale in (('link', link_angle, 1.0), ('motor', motor_angle, self.ratio)):
            if side in self.step:
                continue
            x = np.asarray(x, dtype=float)
            steps = np.abs(np.diff(x[np.isfinite(x)])) / scale
            seen = self._seen[side]
            seen.append(steps[steps > 0.0])
            if sum(s.size for s in seen) >= JUDGE_STEPS:
                self.step[side] = float(np.percentile(np.concatenate(seen), 0.1))
                self._seen[side] = []

    def reason(self):
        """Say which encoder reports the output angle too coarsely, and what follows, else None."""
        said = []
        for side in ('link', 'motor'):
            step = self.step.get(side)
            if step is None or step <= GROWTH_STEP_RAD:
                continue
            size = f'the {side} encoder moves in steps of {math.degrees(step) * 60:.2g} arcmin'
            if step > COARSE_STEP_RAD:
                said.append(f'{size} at the output, coarser than the '
                            f'{math.degrees(COARSE_STEP_RAD) * 60:g} arcmin the lost motion is '
                            'read to: its lost motion and wear are uncertain by about that much')
            else:
                said.append(f'{size} at the output: a lost motion that grows by less than a '
                            'few steps in the recording (a unit early in its life) has its '
                            'wear and remaining life read less surely than their intervals say')
        return '; '.join(said) or None
