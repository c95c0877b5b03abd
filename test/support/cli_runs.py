"""Run the ``reducer-twin`` command in the test's process or as its own (for test modules)."""

import os
from pathlib import Path
import signal
import subprocess
import sys
import time

from reducer_twin.cli import main


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
