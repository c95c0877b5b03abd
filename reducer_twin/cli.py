"""
The ``reducer-twin`` command.

Each subcommand lives in :mod:`reducer_twin.commands` as a module with
``add_parser(subparsers)`` and ``run(args) -> int``. Usage errors exit 2,
invalid values and failed writes (a full disk included) exit 1; both print one
``ERROR: ...`` line, no traceback.
"""

import argparse
import importlib
import os
import sys

# The twin's linear algebra is small (4x4 states, 2x2 per growth exponent) and the
# command forks its own workers: BLAS threads only spin beside them (6 % more CPU on
# a 6-joint analysis). Set before numpy loads; a user's setting is kept.
os.environ.setdefault('OPENBLAS_NUM_THREADS', '1')

from reducer_twin.core.errors import ReducerTwinError  # noqa: E402
from reducer_twin.io import table_cache  # noqa: E402

COMMANDS = ('paper', 'model', 'simulate', 'analyze', 'demo', 'fleet', 'replace')


class _Parser(argparse.ArgumentParser):
    """ArgumentParser whose usage errors read ``ERROR: ...`` and exit 2."""

    def error(self, message):
        self.print_usage(sys.stderr)
        sys.stderr.write(f'ERROR: {message}\n')
        sys.exit(2)


def build_parser():
    """
    Build the argument parser with every available subcommand.

    Returns
    -------
    argparse.ArgumentParser
        The parser.

    """
    parser = _Parser(prog='reducer-twin',
                     description='Digital twin of precision cycloidal (RV) reducers.')
    sub = parser.add_subparsers(dest='command', metavar='COMMAND', parser_class=_Parser)
    sub.required = True
    for name in COMMANDS:
        try:
            module = importlib.import_module(f'reducer_twin.commands.{name}')
        except ModuleNotFoundError as err:
            if err.name != f'reducer_twin.commands.{name}':
                raise
            continue
        module.add_parser(sub)
    return parser


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised where the command is, so that its outputs are cleaned up as at Ctrl-C."""


_sigterm_seen = False
"""Whether SIGTERM came (a library may turn :class:`Terminated` into KeyboardInterrupt)."""


def _on_sigterm(pid):
    """Return a SIGTERM handler raising :class:`Terminated` in process ``pid`` only."""
    import signal

    def handler(signum, frame):
        global _sigterm_seen
        if os.getpid() != pid:      # a forked worker dies as it would have
            signal.signal(signal.SIGTERM, signal.SIG_DFL)
            os.kill(os.getpid(), signal.SIGTERM)
            return
        _sigterm_seen = True
        raise Terminated()
    return handler


def _catch_sigterm():
    """Handle SIGTERM like Ctrl-C when the command runs as its own program."""
    import signal
    import threading
    if threading.current_thread() is threading.main_thread() and \
            signal.getsignal(signal.SIGTERM) is signal.SIG_DFL:
        signal.signal(signal.SIGTERM, _on_sigterm(os.getpid()))


def _stopped(code, argv):
    """
    Return the exit code of a stopped command; run as the program, exit with it at once.

    The stop may have come while the command's thread held a lock of a library's thread
    or queue (a ``multiprocessing`` queue's, a thread pool's): the interpreter's exit
    handlers, which join those threads and flush those queues, would then wait for it
    for ever (an interrupted ``analyze`` was found asleep there). The command's outputs
    were removed and its workers stopped on the way here; nothing is lost by skipping
    the handlers. Called in-process (``argv`` given), the code is returned.
    """
    if argv is not None:
        return code
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):
            pass    # a closed pipe: nothing more can be said
    os._exit(code)


def main(argv=None):
    """
    Run the ``reducer-twin`` command.

    Parameters
    ----------
    argv : list of str, optional
        Arguments (default: ``sys.argv[1:]``, as the program: a stopped command then
        exits at once, see :func:`_stopped`).

    Returns
    -------
    int
        Exit code.

    """
    parser = build_parser()
    args = parser.parse_args(argv)
    table_cache.install()   # the core's tables are kept on disk between runs
    global _sigterm_seen
    _sigterm_seen = False
    if args.command != 'demo':      # the demo's nodes stop on SIGTERM as ROS nodes do
        _catch_sigterm()
    try:
        return int(args.run(args) or 0)
    except ReducerTwinError as err:
        sys.stderr.write(f'ERROR: {err}\n')
        return 1
    except KeyboardInterrupt as err:    # Ray's waits raise it for a SIGTERM too
        if isinstance(err, Terminated) or _sigterm_seen:
            sys.stderr.write('ERROR: terminated (SIGTERM); nothing incomplete was left at '
                             'the outputs\n')
            stopped = 143
        else:
            sys.stderr.write('ERROR: interrupted\n')
            stopped = 130
    except BrokenPipeError:
        return 0
    except OSError as err:   # a file the command did not expect to fail: still one line
        where = f' ({err.filename})' if err.filename else ''
        sys.stderr.write(f'ERROR: {err.strerror or err}{where}\n')
        return 1
    # Out of the handler: the stopped frames are gone, so the generators they held
    # (a Ray engine's) have run their clean-up.
    return _stopped(stopped, argv)


if __name__ == '__main__':
    sys.exit(main())
