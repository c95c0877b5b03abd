"""Rows accumulated in place in one growing array."""

import numpy as np


class RowBuffer:
    """
    Rows accumulated in place in one preallocated array.

    For a node that receives small batches (one row per controller message)
    and processes them later: rows are copied in as they come, and taken out
    as one array, with no list of batch arrays to keep and concatenate.

    Parameters
    ----------
    width : int
        Columns per row.
    capacity : int
        Initial rows; the buffer doubles when it must.

    """

    def __init__(self, width, capacity=1024):
        self._data = np.empty((int(capacity), int(width)))
        self.n = 0

    def extend(self, rows):
        """
        Return a view of ``rows`` new rows at the end, for the caller to fill.

        Parameters
        ----------
        rows : int
            Rows to add.

        Returns
        -------
        ndarray
            Writable ``(rows, width)`` view.

        """
        end = self.n + rows
        if end > self._data.shape[0]:
            grown = np.empty((max(2 * self._data.shape[0], end), self._data.shape[1]))
            grown[:self.n] = self._data[:self.n]
            self._data = grown
        view = self._data[self.n:end]
        self.n = end
        return view

    def append(self, row):
        """
        Add one row.

        Parameters
        ----------
        row : sequence of float
            ``width`` values.

        """
        if self.n == self._data.shape[0]:
            self.extend(1)
            self.n -= 1
        self._data[self.n] = row
        self.n += 1

    def take(self):
        """Return a copy of the rows so far and empty the buffer."""
        out = self._data[:self.n].copy()
        self.n = 0
        return out


class LatencyRing:
    """
    Stamp-to-result latencies of the newest samples, in a preallocated ring.

    Parameters
    ----------
    size : int
        Samples kept (two float64 rings of this length).

    """

    def __init__(self, size=1 << 17):
        self.size = int(size)
        # Filled now: np.zeros would commit pages as they fill, a slow RSS growth.
        self._stamps = np.empty(self.size)     # sample stamps [s]
        self._arrival = np.empty(self.size)    # when their result was computed [s]
        self._stamps.fill(0.0)
        self._arrival.fill(0.0)
        self.n = 0
        self._reported = 0

    def reset(self):
        """Forget the samples so far (a benchmark's warm-up)."""
        self.n = 0
        self._reported = 0

    def record(self, stamps, arrival):
        """Keep the stamps [s] of samples and when their results were computed [s]."""
        k = self.n % self.size
        m = min(stamps.size, self.size - k)
        self._stamps[k:k + m] = stamps[:m]
        self._arrival[k:k + m] = arrival[:m]
        self.n += stamps.size

    def records(self):
        """Return ``(stamps [s], result times [s])`` of the kept samples."""
        n = min(self.n, self.size)
        return self._stamps[:n].copy(), self._arrival[:n].copy()

    def stats(self, last=None):
        """
        Return latency statistics [s].

        Parameters
        ----------
        last : int, optional
            Only the newest ``last`` samples; default every kept sample.

        Returns
        -------
        dict
            ``count``, ``p50``, ``p99``, ``max``.

        """
        kept = min(self.n, self.size)
        n = kept if last is None else max(min(last, kept), 0)
        if n == 0:
            return {'count': 0, 'p50': float('nan'), 'p99': float('nan'), 'max': float('nan')}
        rows = slice(0, n) if last is None else np.arange(self.n - n, self.n) % self.size
        lat = self._arrival[rows] - self._stamps[rows]
        return {'count': self.n if last is None else n,
                'p50': float(np.percentile(lat, 50)), 'p99': float(np.percentile(lat, 99)),
                'max': float(lat.max())}

    def stats_since_report(self):
        """Return :meth:`stats` of the samples since the last call (for ``/diagnostics``)."""
        out = self.stats(last=self.n - self._reported)
        self._reported = self.n
        return out


class ArrivalBatches:
    """
    Encoder pairs with their TE computed on arrival, batched for publishing and analysis.

    TE on arrival is ``theta_link - theta_motor/i`` (the pairs are aligned and
    unwrapped already); each row is kept with the time its TE was computed, so
    the stamp-to-TE latency is measured. A batch is due once its oldest row waited
    ``period_s``; taken, its rows also wait for the window analysis.

    Parameters
    ----------
    ratio : float
        Total reduction ratio.
    period_s : float
        Longest wait of a row for its batch while the stream flows [s].
    latency_keep : int
        Latency samples kept (:class:`LatencyRing`).

    """

    def __init__(self, ratio, period_s, latency_keep=1 << 17):
        self.pending = RowBuffer(5, 4096)   # encoder pairs waiting for the window analysis
        self._arrived = RowBuffer(7, 256)   # encoder pair, its TE, when the TE was computed
        self._minus_inv_ratio = -1.0 / ratio
        self.period_s = float(period_s)
        self._first = None
        self.latency = LatencyRing(latency_keep)

    def add(self, rows, now):
        """
        Take ``(n, 5)`` ``encoder_pairs`` rows that arrived at ``now`` [s].

        Returns
        -------
        bool
            Whether a batch is due (:meth:`take`).

        """
        n = rows.shape[0]
        if n == 1:      # the live case, one controller message: cheaper in plain floats
            row = rows[0].tolist()
            row += (row[2] + row[1] * self._minus_inv_ratio, now)
            self._arrived.append(row)
        else:
            out = self._arrived.extend(n)
            out[:, :5] = rows
            te = out[:, 5]
            np.multiply(rows[:, 1], self._minus_inv_ratio, out=te)
            te += rows[:, 2]
            out[:, 6] = now
        if self._first is None:
            self._first = now
            return False
        return now - self._first >= self.period_s

    def take(self):
        """
        Return the waiting rows ``(stamp, motor, link, effort, velocity, TE, computed at)``.

        Their latencies are recorded and their pairs queued for the window analysis
        (:attr:`pending`); None when nothing waits.
        """
        if not self._arrived.n:
            return None
        rows = self._arrived.take()
        self._first = None
        self.latency.record(rows[:, 0], rows[:, 6])
        self.pending.extend(rows.shape[0])[:] = rows[:, :5]
        return rows


class PublishLog:
    """
    When samples were published, by their stamps, in a preallocated ring [ns].

    Parameters
    ----------
    size : int
        Samples kept (a ``(size, 2)`` int64 ring; for latency benchmarks).

    """

    def __init__(self, size=1 << 18):
        # Filled now (np.zeros would commit pages as the ring fills, a slow RSS growth).
        self._log = np.empty((int(size), 2), dtype=np.int64)
        self._log.fill(0)
        self.n = 0

    def add(self, stamp_ns, published_ns):
        """Keep that the sample stamped ``stamp_ns`` was published at ``published_ns``."""
        k = self.n % self._log.shape[0]
        self._log[k, 0], self._log[k, 1] = stamp_ns, published_ns
        self.n += 1

    def publish_times(self, stamps_ns):
        """
        Return when the samples with these stamps were published [ns] (0 if unknown).

        Parameters
        ----------
        stamps_ns : array_like of int
            Header stamps of published samples.

        Returns
        -------
        ndarray of int64
            Wall-clock publish times.

        """
        n = min(self.n, self._log.shape[0])
        log = self._log[:n]
        order = np.argsort(log[:, 0], kind='stable')
        keys, times = log[order, 0], log[order, 1]
        if n == 0:
            return np.zeros(np.shape(stamps_ns), dtype=np.int64)
        # Stamps that travelled as float seconds are off by a fraction of a microsecond.
        stamps = np.asarray(stamps_ns, dtype=np.int64)
        hi = np.clip(np.searchsorted(keys, stamps), 0, n - 1)
        lo = np.clip(hi - 1, 0, n - 1)
        idx = np.where(np.abs(keys[lo] - stamps) < np.abs(keys[hi] - stamps), lo, hi)
        return np.where(np.abs(keys[idx] - stamps) < 1000, times[idx], 0)
