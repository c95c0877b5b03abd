"""Run the ``reducer-twin`` command in the test's process or as its own (for test modules)."""

import subprocess
import sys

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
