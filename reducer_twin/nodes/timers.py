"""Periodic timers spread in phase, and timers whose work runs on the background worker."""

import itertools

from reducer_twin.nodes.runtime import WORKER

LISTENERS_PERIOD_S = 0.5
"""How often composed nodes check whether a topic they may skip has subscribers [s]."""

_PHASES = itertools.count(1)
_GOLDEN = (5 ** 0.5 - 1) / 2


def create_spread_timer(node, period_s, callback):
    """
    Create a periodic timer whose phase is spread from the other such timers of the process.

    The bringup's nodes are built within milliseconds of each other, so their
    once-a-second timers (diagnostics of every node, the ground truth,
    subscriber checks) would all fire in the same millisecond and hold the
    executor for the sum of their callbacks, a stall the 1 kHz stream feels.
    Each timer made here starts only after its own fraction of the period
    (a golden-ratio sequence over the process's timers, so any number of
    them stay apart) and then keeps that phase.

    Parameters
    ----------
    node : rclpy.node.Node
        Owner of the timer.
    period_s : float
        Period [s].
    callback : callable
        Called every period.

    Returns
    -------
    rclpy.timer.Timer
        The periodic timer (started after the phase offset).

    """
    phase = (next(_PHASES) * _GOLDEN) % 1.0
    timer = node.create_timer(period_s, callback, autostart=False)

    def start():
        starter.cancel()
        timer.reset()

    starter = node.create_timer(max(phase * period_s, 1e-3), start)
    return timer


def create_background_timer(node, period_s, fn):
    """
    Create a spread periodic timer whose work runs on :data:`WORKER`.

    For the nodes' ``/diagnostics``: building a DiagnosticArray of a dozen
    key/values and publishing it is a millisecond of Python, several with
    the worker busy, and the nodes of a bringup publish twenty a second. On
    the executor thread that is the stream waiting; on the worker the
    executor takes the interpreter back within one switch interval.

    Parameters
    ----------
    node : rclpy.node.Node
        Owner of the timer.
    period_s : float
        Period [s].
    fn : callable
        The work; it may read what the executor thread updates (counters).

    Returns
    -------
    rclpy.timer.Timer
        The timer.

    """
    return create_spread_timer(node, period_s, lambda: WORKER.post(node, fn))
