"""
Each buffered sample's output speed: the joint's velocity field or the link angle's rate.

The window analysis (:class:`.window_analysis.WindowAnalyzer`) counts the operation
and takes the drive friction out of the effort by the output speed of each sample.
:class:`OutputSpeed` gives it the joint's velocity field where that is the rate of the
link angle, and the link angle's rate where a sample has no field or once
:class:`.velocity_check.VelocityCheck` found the field not to be that rate. Until the
check decides, the link angle's rate of the samples the analysis buffers is held beside
them, so that a field found wrong is replaced in those samples too.
"""

import numpy as np

from .velocity_check import VelocityCheck


def link_rate(stream, use, last_t=None, last_theta=None):
    """
    Return the rate of the unwrapped output angle at the samples in use [rad/s].

    Central differences (one-sided at the ends); the first sample in use reaches back
    to the previous sample when one is given within the stream's ``max_gap_s``.

    Parameters
    ----------
    stream : TEStream
        A chunk of the TE stream.
    use : ndarray of bool
        Its samples whose rate is wanted.
    last_t, last_theta : float, optional
        Stamp [s] and output angle [rad] of the sample before the chunk (None: none).

    Returns
    -------
    ndarray
        One rate per sample in use (0 for a lone sample).

    """
    idx = np.flatnonzero(use)
    t, theta = stream.t[idx], stream.output_angle[idx]
    back = last_t is not None and t.size and t[0] - last_t <= stream.max_gap_s
    if back:
        t = np.concatenate([[last_t], t])
        theta = np.concatenate([[last_theta], theta])
    if t.size >= 2:
        derived = np.gradient(theta, t)
    else:
        derived = np.zeros(t.size)
    return derived[1:] if back else derived


class OutputSpeed:
    """
    The output speed of a joint's samples, chunk by chunk, and the check of its field.

    Parameters
    ----------
    min_speed : float
        Slowest output speed counted as turning [rad/s] (:class:`.velocity_check.VelocityCheck`).
    ratio : float
        Reduction ratio, to name a field that carries the motor's speed.

    Attributes
    ----------
    check : VelocityCheck
        The judgement of the velocity field.
    derived : int
        Samples given the link angle's rate in place of a field.

    """

    def __init__(self, min_speed, ratio):
        self.check = VelocityCheck(min_speed, ratio)
        self.derived = 0
        # Until the check decides: the link angle's rate of the buffered samples (row 0)
        # and whether they carry a field (row 1).
        self._held = None

    def speeds(self, stream, use, velocity, last_t=None, last_theta=None):
        """
        Return the speeds of a chunk's samples and, once the field is replaced, the buffer's.

        Parameters
        ----------
        stream : TEStream
            The chunk.
        use : ndarray of bool
            Its samples that join the buffer.
        velocity : ndarray
            Their velocity field [rad/s] (NaN where absent).
        last_t, last_theta : float, optional
            Stamp [s] and output angle [rad] of the latest buffered sample (None: none
            since the stream started or its clock was reset).

        Returns
        -------
        speed : ndarray
            The field, with the link angle's rate (:func:`link_rate`) in the samples in
            use that have none, or in all of them once the field is replaced (``velocity``
            itself where nothing is filled); counted in :attr:`derived`.
        buffered : ndarray or None
            When this chunk decided that the field is replaced, the link angle's rate of
            every sample buffered before it, to take their speed's place; else None.

        """
        unknown = use & ~np.isfinite(velocity)
        rate = buffered = None
        if not self.check.decided and (use & ~unknown).any():
            # A velocity field: is it the link angle's rate? Until that is decided the rate
            # is held beside the buffered samples, to take the field's place in them too.
            rate = link_rate(stream, use, last_t, last_theta)
            if self.check.check(stream.t[use], stream.output_angle[use], velocity[use]) \
                    and self._held is not None:
                buffered = self._held[0].copy()
                self.derived += int(np.count_nonzero(self._held[1]))
        if self.check.replaced:
            unknown = use
        speed = velocity
        if unknown.any():
            idx = np.flatnonzero(use)
            angle_rate = link_rate(stream, use, last_t, last_theta) if rate is None else rate
            speed = np.array(velocity, dtype=float, copy=True)
            fill = unknown[idx]
            speed[idx[fill]] = angle_rate[fill]
            self.derived += int(np.count_nonzero(fill))
        if self.check.decided:
            self._held = None
        elif use.any():
            if rate is None:    # no field in use: each sample took the angle's rate above
                held = np.vstack([speed[use], np.zeros(int(np.count_nonzero(use)))])
            else:
                held = np.vstack([rate, ~unknown[use]])
            self._held = held if self._held is None else np.hstack([self._held, held])
        return speed, buffered

    def drop(self, count):
        """Forget the rates held beside the first ``count`` buffered samples (cut into windows)."""
        if self._held is not None:
            self._held = self._held[:, count:].copy()

    def restart(self):
        """Forget the rates held beside the buffered samples (the buffer was dropped)."""
        self._held = None
