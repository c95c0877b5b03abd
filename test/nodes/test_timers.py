"""Spread and background timers of the nodes (``reducer_twin.nodes.timers``)."""

import threading

import numpy as np
import pytest
from rclpy.node import Node
from reducer_twin.nodes.timers import create_background_timer, create_spread_timer

pytestmark = pytest.mark.timeout(30, method='thread')


def test_spread_timers_of_one_period_start_at_phases_apart_and_keep_firing(ros):
    # Five nodes' 1 s timers made at once would fire in the same millisecond. Spread, each
    # waits for its own golden-ratio phase (a starter timer) before it runs at all: the
    # closest two phases are about a tenth of the period apart.
    node = ros.add(Node('spread_timers', context=ros.context))
    calls = [[] for _ in range(5)]
    timers = [create_spread_timer(node, 1.0, lambda k=k: calls[k].append(k))
              for k in range(5)]
    assert all(t.is_canceled() for t in timers)
    starters = [t for t in node.timers if all(t is not p for p in timers)]
    phases = sorted(t.timer_period_ns * 1e-9 for t in starters)
    assert len(phases) == 5 and phases[-1] < 1.0
    assert min(np.diff(phases)) > 0.05
    ros.spin_until(lambda: all(len(c) >= 2 for c in calls), timeout=5.0,
                   what='two calls of every spread timer')
    assert all(t.is_canceled() for t in starters)


def test_a_background_timer_runs_its_work_on_the_worker_and_goes_on_after_a_failure(ros):
    # /diagnostics is built off the executor thread; a report that fails is logged and
    # the next period runs again.
    node = ros.add(Node('background_timer', context=ros.context))
    threads = []

    def report():
        threads.append(threading.current_thread().name)
        if len(threads) == 1:
            raise RuntimeError('first report fails')

    create_background_timer(node, 0.05, report)
    ros.spin_until(lambda: len(threads) >= 3, what='three background reports')
    assert set(threads) == {'reducer-twin-worker'}
