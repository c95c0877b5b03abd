"""Counting rejected messages by reason, with throttled warnings."""

import time

from reducer_twin.core.errors import InvalidInput


class RejectCounter:
    """
    Count rejected messages by reason and warn, throttled.

    Parameters
    ----------
    node : rclpy.node.Node
        Node whose logger is used.
    period_s : float
        Shortest interval between two warnings [s].

    """

    def __init__(self, node, period_s=5.0):
        self.node = node
        self.period_s = period_s
        self.counts = {}
        self.last = None        # what was wrong with the latest one
        self._last_warn = -1e18

    @property
    def total(self):
        """Return the number of rejected messages."""
        return sum(self.counts.values())

    def reject(self, reason, detail):
        """
        Count one rejected message and warn at most once per period.

        Parameters
        ----------
        reason : str
            Short reason key (e.g. ``'bad_layout'``).
        detail : str
            What was wrong, for the log.

        """
        self.counts[reason] = self.counts.get(reason, 0) + 1
        self.last = detail
        now = time.monotonic()
        if now - self._last_warn >= self.period_s:
            self._last_warn = now
            self.node.get_logger().warning(
                f'dropped a message ({reason}): {detail} [{self.total} dropped so far: '
                f'{self.counts}]')

    def guard(self, task, reason, fn, *args):
        """
        Run ``fn(*args)`` for a background task; count what fails instead of losing it.

        An :class:`~reducer_twin.core.errors.InvalidInput` is counted as
        ``reason``; any other exception is logged as an error and counted as
        ``'<task>_error'`` (a worker's failure must be seen, not vanish in a
        future).

        Parameters
        ----------
        task : str
            Short name of the task, for the log and the count (e.g. ``'estimator'``).
        reason : str
            Reason key of invalid input.
        fn : callable
            The task.
        *args
            Its arguments.

        Returns
        -------
        tuple
            ``(True, result)``, or ``(False, None)`` when it failed.

        """
        try:
            return True, fn(*args)
        except InvalidInput as err:
            self.reject(reason, str(err))
        except Exception as err:  # noqa: B902 - counted and logged, the node goes on
            self.node.get_logger().error(f'{task} failed: {err!r}')
            self.reject(f'{task}_error', repr(err))
        return False, None
