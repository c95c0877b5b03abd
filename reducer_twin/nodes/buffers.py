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
