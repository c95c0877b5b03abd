"""Helpers shared by the subcommands: parameter loading, JSON and tables."""

import json
import math
import sys

from reducer_twin.core.errors import InvalidParameter
from reducer_twin.core.params import ReducerParams
from reducer_twin.io.params_file import read_reducer_params


def add_params_option(parser):
    """
    Add ``--params YAML`` and ``--set section.name=value`` to a parser.

    Parameters
    ----------
    parser : argparse.ArgumentParser
        Subcommand parser.

    """
    parser.add_argument('--params', metavar='YAML',
                        help='reducer parameters (SI units), e.g. config/rv80e.yaml')
    parser.add_argument('--set', metavar='SECTION.NAME=VALUE', action='append', default=[],
                        help='override one reducer parameter (SI units); repeatable')


def load_params(args):
    """
    Build the reducer parameters from ``--params`` and ``--set``.

    Parameters
    ----------
    args : argparse.Namespace
        Parsed arguments.

    Returns
    -------
    ReducerParams
        Validated parameters.

    Raises
    ------
    InvalidParameter
        On a malformed ``--set`` or a value out of range.

    """
    overrides = {}
    for item in getattr(args, 'set', []) or []:
        key, sep, value = item.partition('=')
        if not sep:
            raise InvalidParameter(f'--set expects SECTION.NAME=VALUE, got {item!r}')
        try:
            overrides[key.strip()] = float(value)
        except ValueError:
            raise InvalidParameter(f'--set {key.strip()} expects a number, got {value!r}')
    if getattr(args, 'params', None):
        return read_reducer_params(args.params, overrides)
    return ReducerParams().with_overrides(overrides) if overrides else ReducerParams()


def finite_or_none(x):
    """Return ``x`` as float, or None when it is not finite (JSON has no NaN)."""
    x = float(x)
    return x if math.isfinite(x) else None


def print_json(obj):
    """Print one JSON object on stdout."""
    json.dump(obj, sys.stdout, indent=2, allow_nan=False)
    sys.stdout.write('\n')


def console():
    """Return a rich console on stdout (plain when not a terminal)."""
    from rich.console import Console
    return Console()


MMAP_THRESHOLD = 32 << 20
"""Blocks at least this large [bytes] are mapped from the kernel (glibc's largest)."""

TRIM_THRESHOLD = 1 << 30
"""Free heap memory [bytes] kept by the process before it is returned to the kernel."""


def reuse_freed_memory():
    """
    Let the C allocator reuse freed blocks of a few MB instead of mapping fresh ones.

    A bag analysis allocates and frees arrays of a few MB per chunk and stage. By
    default glibc maps each block above 128 kB fresh from the kernel and unmaps it on
    free, so every chunk pays page faults and zeroing again (a quarter of the CPU time of
    ``analyze`` on a 6-joint bag was spent in the kernel). Raising the mmap and trim
    thresholds keeps such blocks in the heap for reuse; forked worker processes inherit
    the setting. Nothing happens where the C library has no ``mallopt``.

    Returns
    -------
    bool
        True when the thresholds were set.

    """
    import ctypes
    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):
        return False
    m_trim_threshold, m_mmap_threshold = -1, -3     # <malloc.h>
    return bool(mallopt(m_mmap_threshold, MMAP_THRESHOLD)
                and mallopt(m_trim_threshold, TRIM_THRESHOLD))
