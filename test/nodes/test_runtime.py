"""
The background worker of a node program (``reducer_twin.nodes.runtime``).

It takes window analysis, estimator and remaining-life updates and simulator
blocks off the executor thread, in submission order, resting after each task.
"""

import threading
import time

import pytest
import rclpy.node
from reducer_twin.nodes.runtime import BackgroundWorker

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


def test_a_posted_task_that_fails_is_logged_on_its_nodes_log_and_the_worker_goes_on(
        ros, capfd):
    # Work nobody waits for (a batch's analysis, an estimator update) once failed without a
    # word: its exception stayed in a future no one read.
    node = ros.add(rclpy.node.Node('posting_node', context=ros.context))
    worker = BackgroundWorker(rest_ratio=0.0)

    def analyse_batch(rows):
        raise ValueError(f'cannot read {rows}')

    assert worker.post(node, analyse_batch, 'rows 1-100').result(timeout=10) is None
    assert worker.post(node, lambda x: x + 1, 2).result(timeout=10) == 3
    logged = [x for x in capfd.readouterr().err.splitlines() if 'failed' in x]
    assert len(logged) == 1 and '[ERROR]' in logged[0] and 'posting_node' in logged[0]
    assert "analyse_batch failed: ValueError('cannot read rows 1-100')" in logged[0]
