"""Run the ``reducer-twin`` command in the test's own process (shared by several test modules)."""

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
