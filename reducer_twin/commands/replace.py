"""
``reducer-twin replace``: record that a reducer was replaced.

Retires the reducer in service at ``--robot``/``--joint`` (its history stays in the
store, marked retired) and installs a new one from ``--at`` (ISO 8601, e.g.
``2026-03-01T08:00:00Z``, or nanoseconds of the bag clock; default just after the
newest analysed data of that reducer). Bags recorded later continue the new reducer;
``fleet`` lists it with 0 bags until then.
"""


def add_parser(sub):
    """Register the subcommand."""
    from reducer_twin.fleet.cli import robot_name
    p = sub.add_parser('replace', help='record a reducer replacement in a fleet store',
                       description=__doc__)
    p.add_argument('--store', required=True, metavar='PATH',
                   help='fleet store written by analyze --store')
    p.add_argument('--robot', required=True, type=robot_name, metavar='R', help='robot name')
    p.add_argument('--joint', required=True, metavar='J', help='joint name')
    p.add_argument('--at', metavar='TIME', default=None,
                   help='when: ISO 8601 or bag-clock nanoseconds (default: just after the '
                        'newest analysed data)')
    p.add_argument('--note', metavar='TEXT', default='', help='free text kept with the event')
    p.set_defaults(run=run)


def run(args):
    """Retire the reducer in service and install a new one."""
    from reducer_twin.fleet.store import FleetStore, iso_from_ns, parse_time
    at_ns = parse_time(args.at) if args.at is not None else None
    with FleetStore(args.store) as store:
        store.lock_for_writing()
        old, new = store.replace(args.robot, args.joint, at_ns, args.note)
    print(f'{args.robot}/{args.joint}: reducer replaced at {iso_from_ns(new.installed_ns)}; '
          f'the retired one keeps its {old.bags} bag(s) and {old.exposure_s / 3600.0:,.0f} h; '
          'later bags continue the new one')
    return 0
