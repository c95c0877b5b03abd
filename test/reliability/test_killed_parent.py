"""
Forked workers end by themselves when the process that forked them is killed.

``reducer-twin analyze`` forks a stage worker and a reading process (one bag at a time)
or a process per bag (``--jobs``). Killed with SIGKILL, the command cannot stop them:
each must notice that its parent is gone and end within seconds, holding neither the
output's lock nor anything else (the stage worker slept on, reparented to pid 1, for
minutes). Real programs, real bags; children found through ``/proc``.
"""

import fcntl
import os
from pathlib import Path
import signal
import subprocess
import sys
import textwrap
import time

import pytest
from reducer_twin.analysis.simulate import simulate_bag, SimulationSpec
from reducer_twin.io.outputs import TEMP_TAG

pytestmark = pytest.mark.timeout(300, method='thread')

ENDS_WITHIN_S = 5.0
"""How soon a worker must end after its parent was killed [s]."""


@pytest.fixture(scope='module')
def bag(tmp_path_factory):
    """Simulate 300 s of one joint at 1 kHz (about a second of analysis)."""
    out = tmp_path_factory.mktemp('killed') / 'rec'
    simulate_bag(out, SimulationSpec(hours=300.0, aging_factor=3600.0, joints=1, seed=5))
    return out


def children(pid):
    """Return the pids of the processes ``pid`` forked that still run (``/proc``)."""
    out = set()
    for task in Path(f'/proc/{pid}/task').glob('*'):
        try:
            out.update(int(c) for c in (task / 'children').read_text().split())
        except OSError:     # the thread ended meanwhile
            pass
    return out


def running(pid):
    """Whether process ``pid`` runs (neither gone nor a zombie awaiting its reaper)."""
    try:
        stat = Path(f'/proc/{pid}/stat').read_text()
    except OSError:
        return False
    return stat.rsplit(')', 1)[1].split()[0] != 'Z'


def still_running_after(pids, seconds):
    """Return those of ``pids`` that still run ``seconds`` later (and end them then)."""
    deadline = time.monotonic() + seconds
    left = set(pids)
    while left and time.monotonic() < deadline:
        left = {pid for pid in left if running(pid)}
        time.sleep(0.05)
    for pid in left:    # not left behind by a failed test
        os.kill(pid, signal.SIGKILL)
    return left


def partial_bags(root):
    """Return the temporaries under ``root`` that hold a partial derived bag already."""
    return {tmp for tmp in Path(root).rglob(f'*{TEMP_TAG}-incomplete-*')
            if any(f.stat().st_size > 0 for f in tmp.glob('*.mcap'))}


def lock_is_free(path):
    """Whether another run could take the output lock at ``path`` now."""
    fd = os.open(path, os.O_RDWR)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        return True
    except BlockingIOError:
        return False
    finally:
        os.close(fd)


@pytest.mark.parametrize('options, bags', [
    (['--stage-process', 'yes'], 1),
    (['--jobs', '2'], 2),
], ids=['a stage worker and a reading process', 'a process per bag (--jobs 2)'])
def test_analyze_killed_with_sigkill_leaves_none_of_its_forked_processes_running(
        bag, tmp_path, options, bags):
    out = tmp_path / 'd'
    argv = [str(Path(sys.executable).parent / 'reducer-twin'), 'analyze', *[str(bag)] * bags,
            '--out', str(out), *options]
    proc = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 120
        forked = set()
        while len(partial_bags(tmp_path)) < bags and proc.poll() is None and \
                time.monotonic() < deadline:
            forked |= children(proc.pid)
            time.sleep(0.001)
        forked |= children(proc.pid)
        assert len(partial_bags(tmp_path)) == bags, 'the run ended before it wrote its bags'
        assert len(forked) >= 2, f'expected the workers of {options}, found {forked}'
        proc.send_signal(signal.SIGKILL)
    finally:
        proc.kill()
        proc.wait()
    assert still_running_after(forked, ENDS_WITHIN_S) == set(), \
        f'forked by the killed run and still running {ENDS_WITHIN_S} s later'
    locks = list(tmp_path.rglob(f'*{TEMP_TAG}.lock'))
    assert locks and all(lock_is_free(lock) for lock in locks), 'a worker holds an output'


@pytest.mark.parametrize('where', ['the main thread', 'a thread that stays'])
def test_an_idle_stage_worker_ends_when_its_parent_is_killed(where):
    # Idle, the worker waits on its queue: it never learns from the queue that the
    # process feeding it is gone.
    script = textwrap.dedent(f"""
        import threading
        import time
        from reducer_twin.analysis.stages import WorkerBacks
        made = []
        if {where == 'the main thread'}:
            made.append(WorkerBacks())
        else:
            threading.Thread(target=lambda: (made.append(WorkerBacks()), time.sleep(600)),
                             daemon=True).start()
            while not made:
                time.sleep(0.01)
        print(made[0]._proc.pid, flush=True)
        time.sleep(600)
    """)
    proc = subprocess.Popen([sys.executable, '-c', script], stdout=subprocess.PIPE, text=True)
    try:
        worker = int(proc.stdout.readline())
        assert running(worker)
        proc.send_signal(signal.SIGKILL)
    finally:
        proc.kill()
        proc.wait()
    assert still_running_after({worker}, ENDS_WITHIN_S) == set()


def test_a_stage_worker_outlives_the_thread_that_forked_it():
    # Linux's parent-death signal comes when the forking *thread* ends: a worker forked
    # from a thread that ended must go on serving the process.
    script = textwrap.dedent("""
        import threading
        import time
        from reducer_twin.analysis.stages import WorkerBacks
        made = []
        thread = threading.Thread(target=lambda: made.append(WorkerBacks()))
        thread.start()
        thread.join()
        time.sleep(1.0)
        backs = made[0]
        alive = backs.alive
        backs.configure(None, None)
        backs.finish()
        backs.close()
        print(alive, flush=True)
    """)
    result = subprocess.run([sys.executable, '-c', script], capture_output=True, text=True,
                            timeout=120)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == 'True'
