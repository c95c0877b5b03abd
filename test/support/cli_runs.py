"""Run the ``reducer-twin`` command in the test's process or as its own (for test modules)."""

import os
from pathlib import Path
import signal
import subprocess
import sys
import time

from reducer_twin.cli import main

STOPS = [(signal.SIGTERM, 143, False), (signal.SIGINT, 130, True)]
"""``(signal, exit code, to the process group)`` of the two ways a run is stopped."""
STOP_IDS = ['SIGTERM to the command (a service stopped)', 'SIGINT to its processes (Ctrl-C)']
"""Test ids of :data:`STOPS`."""


def run_cli(argv, capsys):
    """
    Run ``reducer-twin ARGV`` and capture what it printed.

    Parameters
    ----------
    argv : sequence
        Arguments after ``reducer-twin`` (paths allowed).
    capsys : pytest.CaptureFixture
        The test's capture fixture.

    Returns
    -------
    tuple
        ``(exit code, stdout, stderr)``.

    """
    try:
        code = main([str(a) for a in argv])
    except SystemExit as exit_:
        code = exit_.code
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def analyze_process(bag, out, *extra):
    """
    Run ``reducer-twin analyze BAG --out OUT --json EXTRA...`` as a process of its own.

    Returns
    -------
    subprocess.CompletedProcess
        With the text it printed on stdout and stderr.

    """
    return subprocess.run([sys.executable, '-m', 'reducer_twin.cli', 'analyze', str(bag),
                           '--out', str(out), '--json', *map(str, extra)],
                          capture_output=True, text=True)


def program(*args):
    """Return the installed ``reducer-twin`` program with ``args``, as strings."""
    return [str(Path(sys.executable).parent / 'reducer-twin'), *map(str, args)]


def stopped_once(argv, sig, ready, what, env=None, group=False):
    """
    Run the command as from a terminal, send ``sig`` once ``ready()``; return code, stderr.

    A test run started in the background (a shell's background job ignores SIGINT, and a
    child inherits that) would otherwise start it deaf to Ctrl-C. With ``group``, the
    signal goes to the command's process group, as a terminal's Ctrl-C does.
    """
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        proc = subprocess.Popen(argv, env=env, stdout=subprocess.DEVNULL,
                                stderr=subprocess.PIPE, text=True, start_new_session=group)
    finally:
        signal.signal(signal.SIGINT, previous)
    try:
        deadline = time.monotonic() + 120
        seen = False
        while not seen and proc.poll() is None and time.monotonic() < deadline:
            seen = ready()
            time.sleep(0.001)
        assert seen, f'the run ended before {what} was seen'
        if group:
            os.killpg(proc.pid, sig)
        else:
            proc.send_signal(sig)
        _, err = proc.communicate(timeout=60)
    finally:
        proc.kill()
        proc.wait()
    return proc.returncode, err


def several_bags_stopped(tmp_path, sig, group, *extra):
    """
    Analyse four bags in two processes; stop with ``sig`` once a derived bag is written.

    Returns
    -------
    tuple
        ``(out, exit code, stderr)``: the directory of derived bags, as
        :func:`stopped_once` returns the rest.

    """
    from reducer_twin.analysis.simulate import simulate_bag, SimulationSpec
    bags = []
    for k in range(4):
        bags.append(tmp_path / f'rec{k}')
        simulate_bag(bags[-1], SimulationSpec(hours=150.0, aging_factor=3600.0, joints=1,
                                              seed=5))
    out = tmp_path / 'd'
    returncode, err = stopped_once(
        program('analyze', *bags, '--out', out, '--jobs', '2', *extra), sig,
        lambda: out.is_dir() and any(f.stat().st_size > 0 for tmp in out.glob('.rec*')
                                     for f in tmp.glob('*.mcap')),
        'a partial derived bag', group=group)
    return out, returncode, err
