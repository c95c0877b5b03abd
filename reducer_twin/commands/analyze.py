"""
``reducer-twin analyze``: the twin's pipeline offline on rosbag2 recordings.

Reads bag directories and bare ``.mcap`` files (split bags, zstd/lz4 chunks, QoS as
integers or strings) and sqlite3 ``.db3`` bags of older distributions; finds the JointState
topics and motor/link pairs by the ingestion node's rules (or ``--config``, the bringup
YAML); runs the core stages the live nodes run; writes the derived topics as a rosbag2
MCAP bag (the rosbag-to-MCAP path), so a live recording and an offline analysis look
alike in a viewer.

Outputs: with one BAG, OUT is the derived bag and ``--report DIR`` the report; with
several, each gets ``OUT/<bag name>/`` and ``DIR/<bag name>/``, and ``--json`` prints
``{"bags": {name: {"joints": ..., "messages_per_s": x, "out": path}}, "messages_per_s":
total}`` (a bag that failed: ``{"error": message}``). Exit 1 when a bag has no
JointState (the ERROR line names the topics found), cannot be read, or was truncated or
corrupt: what was readable is still analysed and written, and a WARNING says at which
byte reading stopped.

Never silent: a joint without a usable window (no effort, too few samples per torque
reversal, stamps that do not advance, ...) is reported with ``"observed": false``, its
``"windows"`` and ``"reason"`` in ``--json`` (and no number for its wear or life), a
``WARNING: <joint>: not observed ...`` line on stderr, and exit status 3 when nothing
else failed.
"""

import math
import os
from pathlib import Path
import sys

from reducer_twin.commands.common import print_json
from reducer_twin.commands.simulate import check_out_dir
from reducer_twin.core.errors import InvalidParameter, ReducerTwinError

MAX_JOBS = 64

EXIT_NOT_OBSERVED = 3
"""Exit status when every bag was analysed but a joint gave no usable window."""


def add_parser(sub):
    """Register the subcommand."""
    p = sub.add_parser('analyze', help='the twin pipeline offline on rosbag2 bags',
                       description=__doc__)
    p.add_argument('bags', nargs='+', metavar='BAG',
                   help='rosbag2 bag directory, .mcap or .db3 file')
    p.add_argument('--out', required=True, metavar='OUT',
                   help='derived bag directory (one BAG) or directory of derived bags')
    p.add_argument('--report', metavar='DIR', default=None,
                   help='write PNG plots and an HTML page per bag into DIR')
    p.add_argument('--config', metavar='YAML', default=None,
                   help='bringup configuration (config/twin.yaml): joints, topics, motor '
                        'suffix, motor angles, aging factor, window, life thresholds, reducer')
    p.add_argument('--json', action='store_true', help='print the results as one JSON object')
    p.add_argument('--jobs', type=int, default=1,
                   help=f'bags analysed in parallel processes, 1 .. {MAX_JOBS} (default 1)')
    p.add_argument('--compression', choices=('none', 'zstd', 'lz4'), default='none',
                   help="MCAP chunk compression of the derived bag (default 'none')")
    p.add_argument('--overwrite', action='store_true',
                   help='replace derived bags already in --out')
    p.add_argument('--stage-process', choices=('auto', 'yes', 'no'), default='auto',
                   help='run the estimator and life stages in a process of their own beside '
                        'the analysing one (auto: one bag at a time on a machine of 2 or more '
                        'cores); yes also reads the bag in a third process')
    p.set_defaults(run=run)


def _names(bags):
    """Distinct output names of the bags (directory name or file stem)."""
    out, seen = [], {}
    for bag in bags:
        path = Path(bag)
        if path.name == 'metadata.yaml':
            path = path.parent
        base = (path.stem if path.suffix in ('.mcap', '.db3') else path.name) or 'bag'
        seen[base] = seen.get(base, 0) + 1
        out.append(base if seen[base] == 1 else f'{base}_{seen[base]}')
    return out


def _use_stage_worker(choice, jobs):
    """Whether the estimator and life stages get their own process (bags one at a time)."""
    if jobs != 1:
        return False
    if choice != 'auto':
        return choice == 'yes'
    return (os.cpu_count() or 1) >= 2


def _analyze_all(args, settings, outs, worker):
    from reducer_twin.analysis.pipeline import analyze_bag
    jobs = min(args.jobs, len(args.bags))
    results = {}
    if jobs == 1:
        for bag, out in zip(args.bags, outs):
            stage = worker if worker is not None and worker.alive else worker is not None
            try:
                # A reading process costs more CPU (the decoded arrays go through a
                # pipe) than it takes off this one: only on request.
                results[bag] = analyze_bag(bag, out, settings, args.overwrite, stage,
                                           reader_process=args.stage_process == 'yes')
            except ReducerTwinError as err:
                results[bag] = err
        return results
    import concurrent.futures
    import multiprocessing
    pool = concurrent.futures.ProcessPoolExecutor(
        jobs, mp_context=multiprocessing.get_context('fork'))
    with pool:
        futures = {bag: pool.submit(analyze_bag, bag, out, settings, args.overwrite, False)
                   for bag, out in zip(args.bags, outs)}
        for bag, future in futures.items():
            try:
                results[bag] = future.result()
            except ReducerTwinError as err:
                results[bag] = err
    return results


def run(args):
    """Check the request, analyse every bag, write outputs and print the results."""
    if not 1 <= args.jobs <= MAX_JOBS:
        raise InvalidParameter(f'--jobs must be in 1 .. {MAX_JOBS} processes, got {args.jobs}')
    missing = [b for b in args.bags if not Path(b).exists()]
    if missing:
        raise InvalidParameter(f'BAG {missing[0]} does not exist; expected a rosbag2 bag '
                               'directory, a .mcap or a .db3 file')
    check_out_dir(args.out, args.overwrite)
    if args.report:
        check_out_dir(args.report, True, '--report')
    from reducer_twin.analysis.stages import defer_filterpy_extras, WorkerBacks
    defer_filterpy_extras()
    from reducer_twin.commands.common import reuse_freed_memory
    reuse_freed_memory()
    # Forked before the rest is imported: the worker loads filterpy meanwhile.
    jobs = min(args.jobs, len(args.bags))
    worker = WorkerBacks() if _use_stage_worker(args.stage_process, jobs) else None
    try:
        from reducer_twin.analysis.pipeline import AnalysisSettings
        settings = AnalysisSettings.from_config(args.config)
        if args.compression != settings.compression:
            from dataclasses import replace
            settings = replace(settings, compression=args.compression)
        single = len(args.bags) == 1
        names = _names(args.bags)
        outs = [args.out] if single else [str(Path(args.out) / n) for n in names]
        results = _analyze_all(args, settings, outs, worker)
    finally:
        if worker is not None:
            worker.close()
    code = 0
    blind = False
    summary, failed = {}, {}
    for bag, name in zip(args.bags, names):
        result = results[bag]
        if isinstance(result, Exception):
            sys.stderr.write(f'ERROR: {result}\n')
            failed[name] = str(result)
            code = 1
            continue
        for warning in result.warnings:
            sys.stderr.write(f'WARNING: {warning.path}: {warning.message}\n')
        if result.damaged:
            code = 1
        for joint, res in result.joints.items():
            if not res.observed:
                sys.stderr.write(f'WARNING: {joint}: not observed in {name}: '
                                 f'{res.reason or "no usable window"}\n')
                blind = True
        if args.report:
            from reducer_twin.analysis.report import write_report
            page = write_report(result, Path(args.report) if single else
                                Path(args.report) / name)
            if not args.json:
                print(f'report: {page}')
        summary[name] = result
    if args.json:
        if single:
            if summary:
                print_json(summary[names[0]].as_json())
        else:
            total = sum(r.messages for r in summary.values())
            seconds = sum(r.seconds for r in summary.values())
            rate = total / seconds if seconds > 0 else float('nan')
            bags = {n: {**r.as_json(), 'out': str(r.out)} for n, r in summary.items()}
            bags.update({n: {'error': text} for n, text in failed.items()})
            print_json({'bags': {n: bags[n] for n in names},
                        'messages_per_s': rate if math.isfinite(rate) else None})
    else:
        for name, result in summary.items():
            _print_summary(name, result)
    # 3: everything ran, but some reducer could not be observed (said on stderr and in JSON).
    return EXIT_NOT_OBSERVED if code == 0 and blind else code


def _fmt(value, spec):
    return '-' if value is None else format(value, spec)


def _print_summary(name, result):
    print(f'{name}: {result.messages:,} JointState messages in {result.seconds:.2f} s '
          f'({result.messages_per_s:,.0f} msg/s), aging factor {result.aging_factor:g}; '
          f'derived bag {result.out}')
    for joint, res in result.joints.items():
        s = res.summary()
        if not s['observed']:
            print(f'  {joint}: NOT OBSERVED: {s["reason"]}')
            continue
        print(f'  {joint}: wear {_fmt(s["wear_um"], ".3f")} +/- {_fmt(s["wear_std_um"], ".3f")} '
              f'um, lost motion {_fmt(s["lost_motion_arcmin"], ".3f")} arcmin, remaining life '
              f'P10/P50/P90 {_fmt(s["rul_p10_h"], ",.0f")} / {_fmt(s["rul_p50_h"], ",.0f")} / '
              f'{_fmt(s["rul_p90_h"], ",.0f")} h, {s["rejected"]} samples rejected')
