"""Forked workers: they end when told, and a stopped pool starts nothing more."""

import multiprocessing
import os
from pathlib import Path
import signal
import time

import pytest
from reducer_twin.analysis.forking import end_process, run_task, stopping_pool


def _deaf_to_sigterm(ready):
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    ready.set()
    while True:
        time.sleep(1)


def test_a_worker_that_does_not_answer_sigterm_is_killed():
    ctx = multiprocessing.get_context('fork')
    ready = ctx.Event()
    proc = ctx.Process(target=_deaf_to_sigterm, args=(ready,), daemon=True)
    proc.start()
    assert ready.wait(30)
    end_process(proc, wait_s=0.5)
    assert not proc.is_alive() and proc.exitcode == -signal.SIGKILL


def _write_then_wait(marks, name):
    (Path(marks) / name).write_text(str(os.getpid()))
    try:
        time.sleep(60)
    except KeyboardInterrupt:
        (Path(marks) / f'{name}.cleaned').write_text('')
        raise
    return name


def test_a_stopped_pool_interrupts_its_tasks_and_starts_none_of_the_queued(tmp_path):
    with pytest.raises(KeyboardInterrupt), stopping_pool(2) as pool:
        futures = [pool.submit(run_task, _write_then_wait, str(tmp_path), f'bag{k}')
                   for k in range(5)]
        deadline = time.monotonic() + 60
        while len(list(tmp_path.glob('bag?'))) < 2 and time.monotonic() < deadline:
            time.sleep(0.01)
        raise KeyboardInterrupt()     # Ctrl-C in the command
    started = sorted(p.name for p in tmp_path.glob('bag?'))
    assert started == ['bag0', 'bag1']
    assert sorted(p.name for p in tmp_path.glob('*.cleaned')) == ['bag0.cleaned',
                                                                  'bag1.cleaned']
    for future in futures[:2]:
        with pytest.raises(KeyboardInterrupt):
            future.result(timeout=30)
    assert sorted(p.name for p in tmp_path.glob('bag?')) == started, 'nothing started later'
