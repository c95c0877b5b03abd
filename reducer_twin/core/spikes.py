"""
Spike filtering of paired encoder samples (the ingestion stage's last rule).

Once a joint's motor and link samples are paired (:mod:`.pairing`), their TE
(``link - motor/i``) shows a glitch of either encoder, in the live ``encoder_ingest``
node and in the offline bag analysis alike:

================  ==========================================================
reason            what happens
================  ==========================================================
``spike``         a paired sample whose TE (``link - motor/i``) is further
                  than ``spike_te_rad`` from the last accepted TE: dropped
                  (TE is smooth, so a glitch of either encoder shows; the
                  test is causal and adds no delay)
``step``          a second consecutive sample that agrees with the dropped
                  one: the jump is real (re-homing), it is accepted
================  ==========================================================

Counts of each reason are kept for the diagnostics. The threshold is the stage's
(:class:`.ingest.IngestConfig`).
"""

import numpy as np

from .ingest import IngestConfig

SPIKE_REASONS = ('spike', 'step')
"""Reasons a sample is dropped or repaired, in the order of the table above."""


class SpikeFilter:
    """
    Drop paired samples whose TE jumps away from the last accepted TE.

    TE (``link - motor/i``) changes by far less than ``spike_te_rad``
    between samples of a working reducer (lost motion is a few arc minutes,
    traversed over many samples), so a larger jump is an encoder glitch of
    either side. A second consecutive sample that agrees with the dropped one
    (within the threshold) means the jump is real (e.g. re-homing): it is
    accepted and counted as a ``step``. Causal: no sample is held back.

    Parameters
    ----------
    ratio : float
        Reduction ratio ``i``.
    config : IngestConfig
        Thresholds.

    """

    def __init__(self, ratio, config=None):
        self.ratio = float(ratio)
        self.threshold = (config or IngestConfig()).spike_te_rad
        self.counts = dict.fromkeys(SPIKE_REASONS, 0)
        self._last = None       # last accepted TE
        self._rejected = None   # TE of the sample dropped just before

    def keep(self, motor, link):
        """
        Return the mask of samples to keep.

        Parameters
        ----------
        motor, link : ndarray
            Motor (input) and link angles of paired samples [rad].

        Returns
        -------
        ndarray of bool
            True for samples that are not spikes.

        """
        return self.keep_te(link - motor / self.ratio)

    def keep_te(self, te):
        """
        Return the mask of samples to keep, given their TE.

        Parameters
        ----------
        te : ndarray
            TE ``link - motor/i`` of paired samples [rad].

        Returns
        -------
        ndarray of bool
            True for samples that are not spikes.

        """
        n = te.size
        keep = np.ones(n, dtype=bool)
        if n == 0:
            return keep
        prev = np.empty(n)
        prev[0] = te[0] if self._last is None else self._last
        prev[1:] = te[:-1]
        suspects = np.flatnonzero(np.abs(te - prev) > self.threshold)
        if suspects.size == 0 and self._rejected is None:
            self._last = float(te[-1])
            return keep
        # Rare: walk from the first suspect with the true "last accepted" TE.
        start = int(suspects[0]) if suspects.size else 0
        last = self._last if start == 0 else float(te[start - 1])
        # Samples before ``start`` were accepted, which clears a rejection of the last call.
        rejected = self._rejected if start == 0 else None
        thr = self.threshold
        for k in range(start, n):
            x = float(te[k])
            if last is None or abs(x - last) <= thr:
                last, rejected = x, None
            elif rejected is not None and abs(x - rejected) <= thr:
                self.counts['step'] += 1
                last, rejected = x, None
            else:
                keep[k] = False
                self.counts['spike'] += 1
                rejected = x
        self._last, self._rejected = last, rejected
        return keep


class SpikeFilterBank:
    """
    :class:`SpikeFilter` for several joints at once (one column each).

    The common case, no jump anywhere, costs a few array operations for all
    joints together; a column with a suspect goes through its own filter.

    Parameters
    ----------
    ratio : float
        Reduction ratio ``i``.
    columns : int
        Number of joints.
    config : IngestConfig
        Thresholds.

    """

    def __init__(self, ratio, columns, config=None):
        self.ratio = float(ratio)
        self.filters = [SpikeFilter(ratio, config) for _ in range(columns)]
        self.threshold = self.filters[0].threshold
        # Last accepted TE of every column while no filter has a rejection pending (the
        # common case, kept here as one array); None otherwise, the filters then hold it.
        self._last = None

    def keep(self, motor, link, valid):
        """
        Return the mask of paired samples to keep.

        Parameters
        ----------
        motor, link : ndarray, shape (N, K)
            Motor (input) and link angles [rad].
        valid : ndarray of bool, shape (N, K)
            Which entries are paired samples at all.

        Returns
        -------
        ndarray of bool, shape (N, K)
            ``valid`` without the spikes: ``valid`` itself when no sample is
            dropped.

        """
        with np.errstate(invalid='ignore'):
            te = link - motor / self.ratio
        last = self._last
        if last is not None and valid.all():
            if te.shape[0] == 1:
                jumps = np.abs(te[0] - last) > self.threshold
            else:
                jumps = np.abs(np.diff(te, axis=0, prepend=last[None, :])) > self.threshold
            if not jumps.any():
                self._last = te[-1].copy()
                return valid
        filters = self.filters
        if last is not None:
            for f, x in zip(filters, last.tolist()):
                f._last = x
        keep = valid.copy()
        for k, f in enumerate(filters):
            rows = np.flatnonzero(valid[:, k])
            keep[rows, k] = f.keep_te(te[rows, k])
        if all(f._last is not None and f._rejected is None for f in filters):
            self._last = np.array([f._last for f in filters])
        else:
            self._last = None
        return keep

    def counts(self, k):
        """Return the spike/step counts of joint ``k``."""
        return dict(self.filters[k].counts)
