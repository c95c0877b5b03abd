"""Background threads: results in order, errors where awaited, and never a wait on a stop."""

import subprocess
import sys
import textwrap
import threading

import pytest
from reducer_twin.io.background import Background


def test_results_come_back_as_submitted_from_several_threads():
    release = threading.Event()

    def job(k):
        if k == 0:
            release.wait(5)     # the first job ends last
        return k * k
    with Background(3, 'test') as pool:
        pending = [pool.submit(job, k) for k in range(12)]
        assert [p.result() for p in pending[1:]] == [k * k for k in range(1, 12)]
        release.set()
        assert pending[0].result() == 0
        assert pending[0].result() == 0, 'a result is kept once awaited'


def test_a_job_s_error_is_raised_where_its_result_is_awaited_and_the_threads_go_on():
    def job(k):
        if k == 1:
            raise OSError(28, 'No space left on device')
        return k
    with Background(1, 'test') as pool:
        first, failed, after = (pool.submit(job, k) for k in range(3))
        assert first.result() == 0
        with pytest.raises(OSError, match='No space left'):
            failed.result()
        assert after.result() == 2


def test_at_least_one_thread():
    with pytest.raises(ValueError, match='threads must be at least 1, got 0'):
        Background(0, 'test')


def test_the_threads_end_once_closed():
    pool = Background(2, 'closing')
    assert pool.submit(sum, (1, 2)).result() == 3
    pool.close()
    for thread in threading.enumerate():
        if thread.name.startswith('closing-'):
            thread.join(5)
            assert not thread.is_alive()


def test_a_program_stopped_with_a_job_in_flight_exits_without_waiting_for_it():
    # A thread pool's threads are joined when the interpreter exits: a job that never
    # ends (or a pool thread waiting for a lock the interrupt left taken) held the
    # program for ever.
    program = textwrap.dedent("""
        import threading
        from reducer_twin.io.background import Background
        pool = Background(2, 'stuck')
        started = threading.Event()
        pending = pool.submit(lambda: (started.set(), threading.Event().wait()))
        started.wait()
        pool.close()
        raise SystemExit(130)
    """)
    done = subprocess.run([sys.executable, '-c', program], timeout=60)
    assert done.returncode == 130
