"""
The recent duty's wear rate, and how well the windows know it.

The remaining life extrapolates the wear at the rate of the recent duty: the
run-in-free Archard increment per operating second over the latest windows.
:class:`DutyRate` keeps that rate (exponentially weighted sums) and its
relative standard error from batch means (windows tile a periodic duty, so
they are not independent draws), for :class:`.estimator.WearEstimator`.
"""

import math

DUTY_UNKNOWN_REL_STD = 0.1
"""Relative sd of the duty rate before three batches show it (the twin's former allowance)."""

DUTY_BATCH_WINDOWS = 10
"""Windows per batch of the duty rate's standard error (batch means)."""


class DutyRate:
    """
    The recent duty's Archard rate and its relative standard error.

    Parameters
    ----------
    horizon_s : float
        Operation [s] over which the rate is averaged (time constant).
    min_windows : float
        Fewest windows the average spans when they are longer (a time-compressed
        recording), so that the mean covers many cycles.

    """

    def __init__(self, horizon_s, min_windows):
        self.horizon_s = horizon_s
        self.min_windows = min_windows
        self.restore(0.0, 0.0, [0.0, 0.0, 0], [0.0, 0.0, 0.0, 0.0])

    def restore(self, increment, exposure, batch, sums):
        """
        Set the sums (as :meth:`state` gives them).

        Parameters
        ----------
        increment, exposure : float
            Weighted sums of the Archard increments [m] and of the exposure [s].
        batch : list
            The batch being filled: increment [m], exposure [s], windows.
        sums : list of float
            The batch means' sums: weight, weighted rate, weighted squared rate and
            squared weight.

        """
        self.increment, self.exposure = increment, exposure
        self.batch, self.sums = batch, sums

    def state(self):
        """Return the sums as the estimator's state dict keeps them (``duty_*``)."""
        return {'duty_increment': self.increment, 'duty_exposure': self.exposure,
                'duty_batch': [float(v) for v in self.batch[:2]] + [int(self.batch[2])],
                'duty_batch_sums': [float(v) for v in self.sums]}

    def add(self, exposure, increment):
        """Count one window's exposure [s] and run-in-free Archard increment [m]."""
        # The horizon spans horizon_s of operation, or min_windows windows when they are
        # longer (a time-compressed recording), so that the mean covers many cycles.
        decay = max(math.exp(-exposure / self.horizon_s), 1.0 - 1.0 / self.min_windows)
        self.increment = decay * self.increment + increment
        self.exposure = decay * self.exposure + exposure
        # Batch means (windows tile a periodic duty, so they are not independent draws):
        # the standard error of the recent rate from the scatter of batches of windows.
        batch = self.batch
        batch[0] += increment
        batch[1] += exposure
        batch[2] += 1
        if batch[2] >= DUTY_BATCH_WINDOWS and batch[1] > 0.0:
            rate = batch[0] / batch[1]
            decay_b = max(math.exp(-batch[1] / self.horizon_s),
                          1.0 - DUTY_BATCH_WINDOWS / max(self.min_windows,
                                                         2.0 * DUTY_BATCH_WINDOWS))
            sums = self.sums
            sums[0] = decay_b * sums[0] + batch[1]
            sums[1] = decay_b * sums[1] + batch[1] * rate
            sums[2] = decay_b * sums[2] + batch[1] * rate * rate
            sums[3] = decay_b * decay_b * sums[3] + batch[1] * batch[1]
            self.batch = [0.0, 0.0, 0]

    @property
    def rate(self):
        """
        Return the run-in-free Archard rate of the recent duty [m per operating second].

        Ratio of exponentially weighted sums of ``Δa`` and ``Δe``, time
        constant ``horizon_s`` of operation; 0 before any exposure.
        """
        if self.exposure <= 0.0:
            return 0.0
        return self.increment / self.exposure

    @property
    def rel_std(self):
        """
        Return the relative standard error of the recent duty rate, by batch means.

        Windows are grouped in batches of :data:`DUTY_BATCH_WINDOWS`; with
        ``r_b`` the rate of a batch (weighted by its exposure, exponentially
        forgotten like the duty rate) and ``n_eff`` the effective number of
        batches, ``sqrt(var(r_b)/n_eff)/r̄``: a few per cent for a periodic
        duty, more for a duty that changes. Before three batches the spread is not
        known and :data:`DUTY_UNKNOWN_REL_STD` stands for it (never 0: a duty seen for a
        few windows is no duty known exactly).
        """
        w, wr, wr2, w2 = self.sums
        if w <= 0.0 or wr <= 0.0 or w2 <= 0.0:
            return DUTY_UNKNOWN_REL_STD
        n_eff = w * w / w2
        if n_eff < 2.5:
            return DUTY_UNKNOWN_REL_STD
        mean = wr / w
        var = max(wr2 / w - mean * mean, 0.0)
        return math.sqrt(var / n_eff) / mean
