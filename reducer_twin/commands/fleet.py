"""
``reducer-twin fleet``: every reducer of a fleet store, ranked, with what to do.

Lists robot, joint, hours observed, bags, last seen, wear ± σ, lost motion against its
limit, remaining life P10/P50/P90 (past the limit: negative, how many hours past) and a
verdict with the rule that gave it: REPLACE (P10 at or below the error threshold, or
past the limit), PLAN (at or below the warning threshold), OK, NOT OBSERVED (with the
reason), RETIRED (replaced), ranked by P10. Reducers a live ``wear_estimator`` writes
(its ``store`` parameter) show ``+L`` after their bags. ``--json`` prints
``{"reducers": [...]}``;
``--report DIR`` writes one self-contained HTML page with the table and every
reducer's lost-motion and remaining-life trend across its bags.
"""

import textwrap

from reducer_twin.commands.common import print_json


def add_parser(sub):
    """Register the subcommand."""
    p = sub.add_parser('fleet', help='every reducer of a fleet store, ranked, with verdicts',
                       description=__doc__)
    p.add_argument('--store', required=True, metavar='PATH',
                   help='fleet store written by analyze --store')
    p.add_argument('--json', action='store_true',
                   help='print {"reducers": [{robot, joint, bags, hours_observed, last_seen, '
                        'wear_um, wear_std_um, lost_motion_arcmin, rul_p10_h, rul_p50_h, '
                        'rul_p90_h, verdict, reason}, ...]}')
    p.add_argument('--report', metavar='DIR', default=None,
                   help='write the fleet report (index.html, self-contained) into DIR')
    p.set_defaults(run=run)


def fleet_rows(store):
    """Return the ranked rows of every reducer of an open store."""
    from reducer_twin.core.params import ReducerParams
    from reducer_twin.fleet.verdict import fleet_row, rank
    params = ReducerParams()
    return rank([fleet_row(r, params) for r in store.reducers()])


def run(args):
    """Read the store, judge every reducer, print and write the report."""
    from reducer_twin.fleet.store import FleetStore
    with FleetStore(args.store) as store:
        rows = fleet_rows(store)
        page = None
        if args.report:
            from reducer_twin.fleet.report import write_fleet_report
            page = write_fleet_report(store, rows, args.report)
    if args.json:
        print_json({'reducers': rows})
        return 0
    print_table(rows, args.store)
    if page:
        print(f'report: {page}')
    return 0


def _num(value, spec, none='-'):
    return none if value is None else format(value, spec)


def print_table(rows, store_path):
    """Print the fleet view in 80 columns: one line per reducer, the reason beneath."""
    from reducer_twin.fleet.verdict import RULES
    print(f'fleet store {store_path}: {len(rows)} reducer(s), most urgent first')
    live = any(r.get('live_segments') for r in rows)
    print(f'{"robot/joint":<18} {"bags":>4} {"hours":>6} {"wear um":>11} {"LM arcmin":>9} '
          f'{"RUL P10/P50 h":>13} verdict')
    for r in rows:
        name = f'{r["robot"]}/{r["joint"]}'
        if len(name) > 18:     # never cut: two arms' joints differ only at the end
            print(name)
            name = ''
        wear = '-' if r['wear_um'] is None else \
            f'{r["wear_um"]:.2f}±{_num(r["wear_std_um"], ".2f")}'
        rul = f'{_num(r["rul_p10_h"], ".0f")}/{_num(r["rul_p50_h"], ".0f")}'
        bags = f'{r["bags"]}+L' if r.get('live_segments') else str(r['bags'])
        print(f'{name:<18} {bags:>4} {r["hours_observed"]:>6.0f} {wear:>11} '
              f'{_num(r["lost_motion_arcmin"], ".2f"):>9} {rul:>13} {r["verdict"]}')
        print(textwrap.fill(r['reason'], 79, initial_indent='    ', subsequent_indent='    '))
    if live:
        print('+L: also watched live (a wear_estimator writes this store)')
    print('rules:')
    for verdict, rule in RULES:
        print(textwrap.fill(f'{verdict}: {rule}', 79, initial_indent='  ',
                            subsequent_indent='    '))
