"""Command-line options of the fleet: ``analyze --store/--engine``, ``fleet``, ``replace``."""

MAX_ROBOT_NAME = 64


def valid_robot_name(text):
    """Tell whether ``text`` is a robot name: 1 .. 64 printable characters, no spaces."""
    return isinstance(text, str) and 0 < len(text) <= MAX_ROBOT_NAME and not any(
        c.isspace() or not c.isprintable() for c in text)


def robot_name(text):
    """Check a robot name given on the command line (argparse type)."""
    import argparse
    if not valid_robot_name(text):
        raise argparse.ArgumentTypeError(
            f'expected a robot name of 1 .. {MAX_ROBOT_NAME} printable characters without '
            f'spaces, got {text!r}')
    return text


def add_store_options(parser):
    """
    Add the fleet options of ``reducer-twin analyze``.

    Parameters
    ----------
    parser : argparse.ArgumentParser
        The analyze parser.

    """
    parser.add_argument('--store', metavar='PATH', default=None,
                        help='fleet store (SQLite, created if missing): every reducer '
                             'continues from its stored history, bags in time order, a bag '
                             'already stored is skipped')
    parser.add_argument('--robot', metavar='NAME', type=robot_name, default=None,
                        help="robot of the bags (default: the bag's custom_data "
                             'reducer_twin.robot, else twin.robot in --config)')
    parser.add_argument('--rebuild', action='store_true',
                        help="with --store: analyse the robots' stored bags again with the "
                             'given ones (for a bag older than the stored history)')
    parser.add_argument('--engine', choices=('local', 'ray'), default='local',
                        help="'local' processes (default) or 'ray' tasks: robots in "
                             "parallel, each robot's bags in order")
    parser.add_argument('--ray-address', metavar='ADDR', default=None,
                        help='with --engine ray: join this Ray cluster instead of starting '
                             'one of --jobs CPUs on 127.0.0.1')


def check_store_options(args):
    """
    Refuse fleet options that mean nothing together.

    Raises
    ------
    InvalidParameter
        On ``--rebuild`` without ``--store`` or ``--ray-address`` without
        ``--engine ray``.

    """
    from reducer_twin.core.errors import InvalidParameter
    if args.rebuild and args.store is None:
        raise InvalidParameter('--rebuild needs --store PATH (it rebuilds a stored history)')
    if args.ray_address and args.engine != 'ray':
        raise InvalidParameter(f'--ray-address {args.ray_address} needs --engine ray, got '
                               f'--engine {args.engine}')
