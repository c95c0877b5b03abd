"""
``reducer-twin demo``: the twin live on simulated robot joints.

Runs the joint simulator and every twin node (ingest, TE monitor, wear
estimator, life publisher) in one process over real DDS, compressing
``--hours`` of reducer operation into ``--duration-s`` of stream (the
simulator's aging factor), with a live table per joint: TE, lost motion,
wear estimate against the simulator's hidden truth, remaining life
P10/P50/P90 and the diagnostics level. At the end it prints a summary and
saves a plot of the wear estimate, its band and the truth: written whole or not
at all, and never over a file a demo did not write (checked before the demo
starts).
"""

import io
import math
import os
import shutil
import signal
import tempfile
import time

from reducer_twin.commands.common import console, print_json
from reducer_twin.core.errors import InvalidParameter, out_of_range
from reducer_twin.core.units import HOUR, m_to_um, rad_to_arcmin

MAX_JOINTS = 12

RATED_TORQUE_NM = 784.0
"""Rated output torque of the RV-80E [N·m] (the paper's; ``params.rating.rated_torque``)."""

DEMO_LOAD_NM = 1.2 * RATED_TORQUE_NM
"""Gravity-load amplitude of the demo joints: a heavily loaded axis that ages visibly."""

PLOT_SOFTWARE = 'reducer-twin demo'
"""The ``Software`` text of the demo's PNG: a plot that says it may be replaced."""

DEFAULT_PLOT = 'reducer-twin-demo.png'


def is_demo_plot(path):
    """Tell whether the file at ``path`` is a plot a demo wrote (it may be replaced)."""
    from reducer_twin.io.outputs import png_text
    return png_text(path).get('Software') == PLOT_SOFTWARE


def add_parser(sub):
    """Register the subcommand."""
    p = sub.add_parser('demo', help='the twin live on simulated joints (simulator + all nodes)',
                       description=__doc__)
    p.add_argument('--hours', type=float, default=6000.0,
                   help='operating hours to simulate (default 6000)')
    p.add_argument('--duration-s', type=float, default=60.0,
                   help='stream seconds they are compressed into (default 60)')
    p.add_argument('--joints', type=int, default=2, help=f'number of joints, 1 .. {MAX_JOINTS}')
    p.add_argument('--wear-rate-scales', default='',
                   help='hidden Archard-rate multiplier per joint, comma-separated '
                        '(default: 1.0, 0.8, 1.25, ... cycling)')
    p.add_argument('--profile', choices=('robot', 'paper'), default='robot',
                   help="joint motion: 'robot' cycle or the paper's constant 90 deg/s")
    p.add_argument('--seed', type=int, default=0, help='seed of the simulator noise')
    p.add_argument('--plot', default=None,
                   help=f'PNG of the wear history (default {DEFAULT_PLOT}; with --json '
                        'only when given); a file there is replaced only when a demo wrote it')
    p.add_argument('--json', action='store_true',
                   help='print the final per-joint summary as JSON, no live table')
    p.set_defaults(run=run)


def _validate(args):
    if not 1 <= args.joints <= MAX_JOINTS:
        raise InvalidParameter(out_of_range('--joints', args.joints, '', f'1 .. {MAX_JOINTS}'))
    if not (math.isfinite(args.hours) and 0.0 < args.hours <= 1e6):
        raise InvalidParameter(out_of_range('--hours', args.hours, 'h', 'in (0, 1e6]'))
    if not (math.isfinite(args.duration_s) and 5.0 <= args.duration_s <= 86400.0):
        raise InvalidParameter(out_of_range('--duration-s', args.duration_s, 's',
                                            'in [5, 86400]'))
    if args.wear_rate_scales:
        try:
            scales = [float(x) for x in args.wear_rate_scales.split(',')]
        except ValueError:
            raise InvalidParameter(f'--wear-rate-scales expects numbers separated by commas, '
                                   f'got {args.wear_rate_scales!r}') from None
        if len(scales) != args.joints or not all(0.0 < s <= 100.0 for s in scales):
            raise InvalidParameter(out_of_range('--wear-rate-scales', args.wear_rate_scales, '',
                                                f'{args.joints} values in (0, 100]'))
    else:
        cycle = (1.0, 0.8, 1.25, 0.6, 1.5, 0.9)
        scales = [cycle[k % len(cycle)] for k in range(args.joints)]
    plot = args.plot or (None if args.json else DEFAULT_PLOT)
    if plot:   # before the run, not after it
        from reducer_twin.io.outputs import check_file_target
        check_file_target(plot, is_demo_plot, '--plot')
    return scales, plot


def run(args):
    """Run the demo and print the summary."""
    scales, plot = _validate(args)
    # Keep the demo's DDS traffic on this machine unless the user chose otherwise.
    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    import rclpy
    from rclpy.parameter import Parameter
    from rclpy.signals import SignalHandlerOptions
    from reducer_twin.nodes.runtime import close_nodes, make_executor, quiet_gc
    from reducer_twin.nodes.runtime import stop_on_signals
    from reducer_twin.nodes.twin_bringup import all_nodes, build_nodes, load_config
    aging = args.hours * HOUR / args.duration_s
    joints = [f'joint_{k + 1}' for k in range(args.joints)]
    state_dir = tempfile.mkdtemp(prefix='reducer-twin-demo-')
    config = load_config(None)
    config['twin'].update({'joints': joints, 'aging_factor': aging, 'simulate': True,
                           'state_dir': state_dir})
    config['simulator'].update({'profile': args.profile, 'wear_rate_scales': scales})
    if not args.json:
        console().print(f'reducer_twin demo: {args.joints} joint(s) under a gravity load of '
                        f'{DEMO_LOAD_NM / RATED_TORQUE_NM:.1f}x rated torque '
                        f'({DEMO_LOAD_NM:.0f} N*m), aging factor {aging:,.0f}: '
                        f'{args.hours:,g} h in {args.duration_s:g} s of stream', soft_wrap=True)
    # Ctrl-C and SIGTERM stop the loop, then the nodes close in order, as in every node's
    # main(): rclpy's own handlers shut the context down under the running callbacks
    # (tracebacks of the simulator's timer and the executor, exit 1 for SIGTERM).
    history = {j: [] for j in joints}
    with stop_on_signals() as stop:
        built = []
        try:
            rclpy.init(args=['--ros-args', '--log-level', 'warn'],
                       signal_handler_options=SignalHandlerOptions.NO)
            nodes = build_nodes(config, sim_overrides=[
                Parameter('sim.seed', value=args.seed),
                Parameter('sim.load_torque_nm', value=DEMO_LOAD_NM)])
            built = all_nodes(nodes)
            executor = make_executor()
            for node in built:
                executor.add_node(node)
            quiet_gc()
            rows = _spin(executor, nodes, joints, args, history, stop)
            if stop.signum is None:
                summary = _summary(nodes, joints, rows)
        finally:
            close_nodes(built)
            rclpy.try_shutdown()
            shutil.rmtree(state_dir, ignore_errors=True)
    if stop.signum is not None:
        from reducer_twin.cli import Terminated
        raise Terminated() if stop.signum == signal.SIGTERM else KeyboardInterrupt()
    if plot:
        _plot(history, summary, plot, args)
    if args.json:
        print_json({'joints': summary, 'hours': args.hours, 'duration_s': args.duration_s,
                    'aging_factor': aging, 'plot': plot})
    else:
        out = console()
        out.print(_table(summary, 'reducer_twin demo: final state'))
        if plot:
            out.print(f'wear history plot: {plot}', soft_wrap=True)
    return 0


def _spin(executor, nodes, joints, args, history, stop):
    """Spin until the simulator has streamed ``duration_s`` (or a stop); keep the history."""
    from reducer_twin.nodes.runtime import WORKER
    sim = nodes['simulator']
    live = None
    if not args.json and console().is_terminal:
        # Piped or logged, only the final table is printed: a live view redrawn into a file
        # left its last frame unterminated before it.
        from rich.live import Live
        live = Live(console=console(), refresh_per_second=4)
        live.start()
    last_view = last_hist = 0.0
    try:
        while sim.sent < args.duration_s * sim.rate_hz and stop.signum is None:
            executor.spin_once(timeout_sec=0.02)
            now = time.monotonic()
            if now - last_hist >= 0.25:
                last_hist = now
                _record(nodes, joints, history)
            if live is not None and now - last_view >= 0.5:
                last_view = now
                live.update(_table(_summary(nodes, joints, None), _title(sim, args)))
        if stop.signum is not None:
            return None
        # The stream is complete: the simulator stops (left running, it went on through the
        # drain below, and the truth stood hundreds of hours past the estimate). The last
        # samples reach the TE monitors and are analysed; then the windows' estimates and
        # their remaining life (each a DDS hop, then a task on the worker).
        sim.close()
        _spin_for(executor, 1.0)
        for te in nodes['te'].values():
            te.analyze_now()
        for _ in range(2):
            _spin_for(executor, 0.5)
            WORKER.wait_idle()
        _spin_for(executor, 0.3)
        _record(nodes, joints, history)
    finally:
        if live is not None:
            live.stop()
    return None


def _spin_for(executor, seconds):
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        executor.spin_once(timeout_sec=0.02)


def _title(sim, args):
    stream = sim.sent / sim.rate_hz
    hours = stream / args.duration_s * args.hours
    return (f'reducer_twin demo: {hours:,.0f} of {args.hours:,.0f} operating hours '
            f'({stream:.0f}/{args.duration_s:.0f} s of stream)')


def _record(nodes, joints, history):
    truth = nodes['simulator'].truth()
    for j in joints:
        s = nodes['life'][j].summary()
        tr = truth[j]
        history[j].append({
            'exposure_h': tr.exposure_s / HOUR, 'true_wear_um': m_to_um(tr.wear),
            'wear_um': s['wear_um'] if s else float('nan'),
            'wear_std_um': s['wear_std_um'] if s else float('nan'),
            'rul_p10_h': s['rul_p10_h'] if s else float('nan'),
            'rul_p50_h': s['rul_p50_h'] if s else float('nan'),
            'rul_p90_h': s['rul_p90_h'] if s else float('nan'),
            'true_rul_h': tr.true_rul_s / HOUR})


def _summary(nodes, joints, _rows):
    truth = nodes['simulator'].truth()
    counts = nodes['ingest'].counts()
    out = {}
    for k, j in enumerate(joints):
        s = nodes['life'][j].summary() or {}
        tr = truth[j]
        c = counts[j]
        dropped = sum(v for key, v in c.items() if key.endswith('_missing')) + c['unpaired']
        repaired = sum(v for key, v in c.items()
                       if key.split('_', 1)[-1] in ('non_finite', 'duplicate', 'out_of_order',
                                                    'clock_jump', 'spike'))
        rejected = (nodes['ingest'].rejects.total + nodes['te'][j].rejects.total
                    + nodes['estimator'][j].rejects.total + nodes['life'][j].rejects.total
                    + repaired)
        lat = nodes['te'][j].latency_stats()
        nan = float('nan')
        out[j] = {
            'wear_um': s.get('wear_um', nan), 'wear_std_um': s.get('wear_std_um', nan),
            'true_wear_um': m_to_um(tr.wear), 'exposure_h': tr.exposure_s / HOUR,
            'rate_scale': s.get('rate_scale', nan),
            'true_rate_scale': tr.wear_rate_scale,
            'lost_motion_arcmin': s.get('lost_motion_arcmin', nan),
            'lost_motion_obs_arcmin': s.get('lost_motion_obs_arcmin', nan),
            'true_lost_motion_arcmin': rad_to_arcmin(tr.lost_motion),
            'te_pp_arcmin': s.get('te_pp_arcmin', nan),
            'rul_p10_h': s.get('rul_p10_h', nan), 'rul_p50_h': s.get('rul_p50_h', nan),
            'rul_p90_h': s.get('rul_p90_h', nan), 'true_rul_h': tr.true_rul_s / HOUR,
            'catalogue_life_h': s.get('catalogue_life_h', nan),
            'level': s.get('level', 'STALE'), 'updates': s.get('updates', 0),
            'samples': nodes['te'][j].samples, 'windows': nodes['te'][j].windows,
            'dropped': int(dropped), 'rejected': int(rejected),
            'latency_p99_ms': lat['p99'] * 1e3}
    return {j: {k: (None if isinstance(v, float) and not math.isfinite(v) else v)
                for k, v in row.items()} for j, row in out.items()}


def _fmt(value, spec):
    # NaN: no number stands for the reducer (a remaining life before any lost motion).
    return '-' if value is None or not math.isfinite(value) else format(value, spec)


def _table(summary, title):
    from rich import box
    from rich.table import Table
    # Fits 80 columns: short headers, the units once in the caption, joint names never cut.
    dropped = sum(int(r['dropped']) for r in summary.values())
    t = Table(title=title, box=box.SIMPLE_HEAD, padding=(0, 1), pad_edge=False,
              show_edge=False, collapse_padding=True, caption=(
        f'arcmin: TE p-p, LM (lost motion); um: wear; h: RUL; {dropped} dropped'),
        caption_justify='left')
    t.add_column('joint', no_wrap=True, min_width=7)
    for col in ('TE p-p', 'LM', 'wear', 'true', 'RUL P10/P50/P90', 'true RUL', 'health'):
        t.add_column(col, justify='right', no_wrap=True)
    styles = {'OK': 'green', 'WARN': 'yellow', 'ERROR': 'bold red', 'STALE': 'dim'}
    for j, r in summary.items():
        wear = (f"{_fmt(r['wear_um'], '.2f')}±{_fmt(r['wear_std_um'], '.2f')}")
        rul = '/'.join(_fmt(r[k], ',.0f') for k in ('rul_p10_h', 'rul_p50_h', 'rul_p90_h'))
        t.add_row(j, _fmt(r['te_pp_arcmin'], '.3f'), _fmt(r['lost_motion_arcmin'], '.2f'), wear,
                  _fmt(r['true_wear_um'], '.2f'), rul, _fmt(r['true_rul_h'], ',.0f'),
                  f"[{styles.get(r['level'], '')}]{r['level']}[/]")
    return t


def _plot(history, summary, path, args):
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    import numpy as np
    fig, (ax_w, ax_r) = plt.subplots(2, 1, figsize=(9, 7), sharex=True)
    for j, rows in history.items():
        if not rows:
            continue
        h = np.array([r['exposure_h'] for r in rows])
        w = np.array([r['wear_um'] for r in rows], dtype=float)
        s = np.array([r['wear_std_um'] for r in rows], dtype=float)
        line, = ax_w.plot(h, w, drawstyle='steps-post', label=f'{j} estimate (per window)')
        ax_w.fill_between(h, w - 2 * s, w + 2 * s, step='post', color=line.get_color(),
                          alpha=0.2)
        ax_w.plot(h, [r['true_wear_um'] for r in rows], '--', color=line.get_color(),
                  label=f'{j} truth')
        p50 = np.array([r['rul_p50_h'] for r in rows], dtype=float)
        ax_r.plot(h, p50, color=line.get_color(), label=f'{j} P50')
        ax_r.fill_between(h, [r['rul_p10_h'] for r in rows], [r['rul_p90_h'] for r in rows],
                          color=line.get_color(), alpha=0.2)
        ax_r.plot(h, [r['true_rul_h'] for r in rows], '--', color=line.get_color(),
                  label=f'{j} truth')
    ax_w.set_ylabel('combined wear (um), band = ±2σ')
    ax_w.legend(fontsize=8)
    ax_w.grid(alpha=0.3)
    ax_r.set_ylabel('remaining life (h), band = P10–P90')
    ax_r.set_xlabel('operating hours')
    ax_r.set_ylim(bottom=0, top=max(2.0 * args.hours, 1.0))
    ax_r.legend(fontsize=8)
    ax_r.grid(alpha=0.3)
    fig.suptitle(f'reducer_twin demo: {args.hours:,.0f} h in {args.duration_s:.0f} s of stream')
    fig.tight_layout()
    buffer = io.BytesIO()
    fig.savefig(buffer, format='png', dpi=110, metadata={'Software': PLOT_SOFTWARE})
    plt.close(fig)
    from reducer_twin.io.outputs import write_file
    write_file(path, buffer.getvalue(), is_demo_plot, "the demo's plot", '--plot')
