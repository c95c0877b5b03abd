"""``reducer-twin paper``: the paper's Tables 2, 4 and 5 next to the model."""

from reducer_twin.commands.common import add_params_option, console, load_params, print_json
from reducer_twin.core import paper


def add_parser(sub):
    """Register the subcommand."""
    p = sub.add_parser('paper', help='reproduce the paper (Tables 2, 4, 5) with the model',
                       description=__doc__)
    p.add_argument('--json', action='store_true', help='print one JSON object')
    add_params_option(p)
    p.set_defaults(run=run)


def run(args):
    """Compute and print the tables."""
    params = load_params(args)
    result = {'table2': paper.table2(params), 'table2_fit': paper.table2_fit(params),
              'table4': paper.table4(params),
              'table5': paper.table5(params), 'explanations': paper.EXPLANATIONS}
    if args.json:
        print_json(result)
        return 0
    _render(result)
    return 0


def _render(result):
    from rich.table import Table
    out = console()
    t = Table(title='Table 2: wear of cycloid disc and pins vs operating hours')
    for col in ('hours', 'paper (mm)', 'model (mm)', 'rel. error', 'integrated (mm)'):
        t.add_column(col, justify='right')
    for r in result['table2']:
        t.add_row(f"{r['hours']:.0f}", f"{r['paper_mm']:.9f}", f"{r['model_mm']:.9f}",
                  f"{r['rel_error'] * 100:+.3f} %", f"{r['integrated_mm']:.6f}")
    out.print(t)
    out.print(result['table2_fit']['note'])
    out.print(result['explanations']['table2'], style='dim')
    t = Table(title='Table 4: speeds at 7290 deg/s input')
    for col in ('quantity', 'model', 'paper theory', 'paper ADAMS', 'ADAMS vs model'):
        t.add_column(col, justify='right')
    for r in result['table4']['rows']:
        t.add_row(r['quantity'], f"{r['model']:.4g}", f"{r['paper_theory']:.4g}",
                  f"{r['paper_simulation']:.4g}", f"{r['simulation_rel_error'] * 100:+.1f} %")
    out.print(t)
    out.print(result['explanations']['table4'], style='dim')
    t = Table(title='Table 5: TE range at rated torque (arcmin), lag positive')
    for col in ('hours', 'wear (um)', 'paper max', 'paper min', 'model max', 'model min',
                'mean shift', 'lost motion'):
        t.add_column(col, justify='right')
    for r in result['table5']:
        t.add_row(f"{r['hours']:.0f}", f"{r['wear_um']:.2f}", f"{r['paper_max_arcmin']:.4f}",
                  f"{r['paper_min_arcmin']:.4f}", f"{r['model_max_arcmin']:.3f}",
                  f"{r['model_min_arcmin']:.3f}", f"{r['model_mean_shift_arcmin']:.3f}",
                  f"{r['model_lost_motion_arcmin']:.3f}")
    out.print(t)
    out.print(result['explanations']['table5'], style='dim')
