"""
The nodes' shared helpers: the background worker, the in-place row buffer, spread timers.

The worker takes window analysis, estimator and remaining-life updates and
simulator blocks off the executor thread (``reducer_twin.nodes.base``).
"""

import threading
import time

import numpy as np
import pytest
from rclpy.node import Node
from reducer_twin.nodes.base import BackgroundWorker, create_background_timer
from reducer_twin.nodes.base import create_spread_timer, RowBuffer

pytestmark = pytest.mark.timeout(30, method='thread')


def test_tasks_run_in_submission_order_on_one_thread():
    worker = BackgroundWorker(rest_ratio=0.0)
    seen = []
    futures = [worker.submit(lambda k=k: seen.append((k, threading.get_ident())))
               for k in range(50)]
    worker.wait_idle(timeout=10)
    assert all(f.done() for f in futures)
    assert [k for k, _ in seen] == list(range(50))
    assert len({ident for _, ident in seen}) == 1
    assert seen[0][1] != threading.get_ident()


def test_a_failing_task_hands_its_error_to_the_future_and_the_worker_goes_on():
    worker = BackgroundWorker(rest_ratio=0.0)
    failed = worker.submit(lambda: 1 / 0)
    after = worker.submit(lambda x, y=0: x + y, 2, y=3)
    with pytest.raises(ZeroDivisionError):
        failed.result(timeout=10)
    assert after.result(timeout=10) == 5


def test_the_worker_rests_after_a_task_in_proportion_to_it():
    busy_s = 0.02

    def busy():
        end = time.perf_counter() + busy_s
        while time.perf_counter() < end:
            pass
        return time.perf_counter()

    worker = BackgroundWorker(rest_ratio=1.0, max_rest_s=1.0)
    first = worker.submit(busy)
    second = worker.submit(time.perf_counter)
    # The second task starts only after the first one's rest: as long again as it ran.
    assert second.result(timeout=10) - first.result(timeout=10) >= busy_s * 0.9


def test_a_row_buffer_keeps_rows_in_order_across_growth_and_empties_on_take():
    buf = RowBuffer(3, capacity=4)
    rows = np.arange(30.0).reshape(10, 3)
    buf.extend(3)[:] = rows[:3]
    buf.extend(7)[:] = rows[3:]          # past the capacity: the buffer grows
    np.testing.assert_array_equal(buf.take(), rows)
    assert buf.n == 0 and buf.take().shape == (0, 3)
    buf.extend(2)[:] = rows[:2]
    taken = buf.take()
    buf.extend(2)[:] = -1.0               # reusing the space leaves the taken copy alone
    np.testing.assert_array_equal(taken, rows[:2])


def test_a_row_buffer_takes_single_rows_across_growth():
    buf = RowBuffer(3, capacity=2)
    rows = np.arange(15.0).reshape(5, 3)
    buf.extend(1)[:] = rows[:1]
    for row in rows[1:]:
        buf.append(row.tolist())        # the third row is past the capacity
    np.testing.assert_array_equal(buf.take(), rows)


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
