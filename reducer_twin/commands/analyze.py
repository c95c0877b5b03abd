"""
``reducer-twin analyze``: the twin's pipeline offline on rosbag2 recordings and ROS 1 bags.

Reads bag directories and bare ``.mcap`` files (split bags, zstd/lz4 chunks, QoS as
integers or strings), sqlite3 ``.db3`` bags of older distributions and ROS 1 ``.bag``
files; finds the JointState (or ros2_control DynamicJointState) topics and motor/link
pairs by the ingestion node's rules (or ``--config``, the bringup YAML); runs the core
stages the live nodes run; writes the derived topics as a rosbag2 MCAP bag (the
rosbag-to-MCAP path, ROS 1 included), so a live recording and an offline analysis look
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
else failed. A recording of several robots (arms) is analysed robot by robot, each joint
named ``<namespace>/<joint>`` by its topic's namespace; with ``twin.joints`` configured, the
joints of the other robots' topics are listed not observed, with the reason. An observed
joint whose lost motion stopped well before the recording did (effort missing, an encoder
that froze), or whose effort is missing from many samples, has ``"partial"`` saying so and a
``WARNING: <joint>: observed in part of ...`` line. Encoders that do not measure the same
motion (a frozen one) give no lost motion; a motor encoder that counts against the link is
read reversed.

Outputs never destroy data: OUT and DIR must be new or empty; ``--overwrite`` replaces a
derived bag reducer-twin wrote (nothing else), DIR may hold a previous report, which is
replaced; an output that is, contains or lies inside a BAG or the ``--config`` file is
refused. Each output is written into a temporary beside it and renamed into place when
complete, by one run at a time; a full disk is one ERROR line with the bytes needed.
"""

import math
import os
from pathlib import Path
import sys

from reducer_twin.commands.common import print_json
from reducer_twin.core.errors import InvalidParameter, ReducerTwinError

MAX_JOBS = 64

EXIT_NOT_OBSERVED = 3
"""Exit status when every bag was analysed but a joint gave no usable window."""


def add_parser(sub):
    """Register the subcommand."""
    p = sub.add_parser('analyze', help='the twin pipeline offline on rosbag2 bags',
                       description=__doc__)
    p.add_argument('bags', nargs='+', metavar='BAG',
                   help='rosbag2 bag directory, .mcap or .db3 file, or ROS 1 .bag file')
    p.add_argument('--out', required=True, metavar='OUT',
                   help='derived bag directory (one BAG) or directory of derived bags')
    p.add_argument('--report', metavar='DIR', default=None,
                   help='write PNG plots and an HTML page per bag into DIR (new, empty or '
                        'holding a previous report)')
    p.add_argument('--config', metavar='YAML', default=None,
                   help='bringup configuration (config/twin.yaml): joints, topics, motor '
                        'suffix, motor angles, DynamicJointState interfaces, aging factor, '
                        "window, life thresholds, reducer per joint, each reducer's "
                        'service time before the bag (service_time_s: the hour meter)')
    p.add_argument('--json', action='store_true', help='print the results as one JSON object')
    p.add_argument('--jobs', type=int, default=1,
                   help=f'bags analysed in parallel processes, 1 .. {MAX_JOBS} (default 1)')
    p.add_argument('--compression', choices=('none', 'zstd', 'lz4'), default='none',
                   help="MCAP chunk compression of the derived bag (default 'none')")
    p.add_argument('--overwrite', action='store_true',
                   help='replace derived bags that reducer-twin wrote in --out (nothing else '
                        'is ever replaced; inputs never)')
    from reducer_twin.fleet.cli import add_store_options
    add_store_options(p)
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
        base = (path.stem if path.suffix in ('.mcap', '.db3', '.bag') else path.name) or 'bag'
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
    from reducer_twin.analysis.forking import run_task, stopping_pool
    with stopping_pool(jobs) as pool:
        futures = {bag: pool.submit(run_task, analyze_bag, bag, out, settings, args.overwrite,
                                    False)
                   for bag, out in zip(args.bags, outs)}
        for bag, future in futures.items():
            results[bag] = _outcome(future, bag)
    return results


def _outcome(future, bag):
    """Return the pool's result for ``bag``, or the error that ended it (a worker killed too)."""
    from concurrent.futures.process import BrokenProcessPool
    from reducer_twin.analysis.forking import pool_broken
    try:
        return future.result()
    except ReducerTwinError as err:
        return err
    except BrokenProcessPool:
        return pool_broken(bag)


def _check_outputs(args, names):
    """
    Check every output before any work: never an input, never foreign files.

    Returns
    -------
    tuple of list
        Derived bag directories and report directories, one per bag.

    """
    from reducer_twin.io.outputs import check_target, foreign_bag_entries
    from reducer_twin.io.outputs import refuse_inside_inputs
    inputs = [('input bag', bag) for bag in args.bags]
    if args.config:
        inputs.append(('--config file', args.config))
    flags = [('--out', args.out)] + ([('--report', args.report)] if args.report else [])
    refuse_inside_inputs(flags, inputs)
    if args.report:   # the report and the derived bag each need a place of their own
        try:
            refuse_inside_inputs([('--report', args.report)], [('--out directory', args.out)])
        except InvalidParameter:
            raise InvalidParameter(f'--report {args.report} and --out {args.out} overlap; the '
                                   'report and the derived bag need places of their own') \
                from None
    single = len(args.bags) == 1
    outs = [Path(args.out)] if single else [Path(args.out) / name for name in names]
    reports = [] if not args.report else [Path(args.report)] if single else [
        Path(args.report) / name for name in names]
    if not single:
        out = Path(args.out)
        if out.exists() and not out.is_dir():
            raise InvalidParameter(f'--out {out} exists and is not a directory; expected a '
                                   'directory for the derived bags')
        if out.is_dir() and any(out.iterdir()) and not args.overwrite:
            raise InvalidParameter(f'--out {out} exists and is not empty; expected a new or '
                                   'empty directory, or --overwrite to replace the derived '
                                   'bags of these BAGs in it')
    for out in outs:
        check_target(out, foreign_bag_entries, '--out', args.overwrite,
                     'a bag written by reducer-twin')
    if reports:   # the report's module only when a report is asked for (40 ms)
        from reducer_twin.analysis.report import foreign_report_entries
    for report in reports:
        check_target(report, foreign_report_entries, '--report', True)
    return outs, reports


def _settings(args):
    from reducer_twin.analysis.settings import AnalysisSettings
    try:
        settings = AnalysisSettings.from_config(args.config)
    except InvalidParameter as err:
        raise InvalidParameter(f'--config {err}') from None
    if args.compression != settings.compression:
        from dataclasses import replace
        settings = replace(settings, compression=args.compression)
    return settings


def run(args):
    """Check the request, analyse every bag, write outputs and print the results."""
    if not 1 <= args.jobs <= MAX_JOBS:
        raise InvalidParameter(f'--jobs must be in 1 .. {MAX_JOBS} processes, got {args.jobs}')
    from reducer_twin.fleet.cli import check_store_options
    check_store_options(args)
    missing = [b for b in args.bags if not Path(b).exists()]
    if missing:
        raise InvalidParameter(f'BAG {missing[0]} does not exist; expected a rosbag2 bag '
                               'directory, a .mcap or a .db3 file, or a ROS 1 .bag file')
    from reducer_twin.io.outputs import check_input_kind
    for bag in args.bags:
        check_input_kind(bag)
    single = len(args.bags) == 1
    names = _names(args.bags)
    outs, reports = _check_outputs(args, names)
    # Forked once the analysis is imported: the worker then has every class it is sent
    # (the settings of the joints whose fronts it runs) instead of importing them again.
    import reducer_twin.analysis.pipeline  # noqa: F401
    from reducer_twin.analysis.stages import WorkerBacks
    from reducer_twin.commands.common import reuse_freed_memory
    reuse_freed_memory()
    jobs = min(args.jobs, len(args.bags))
    fleet = args.store is not None or args.engine == 'ray'
    worker = WorkerBacks() if _use_stage_worker(args.stage_process, jobs) and \
        args.engine == 'local' else None
    workers = {}
    from reducer_twin.io.outputs import no_empty_dirs_left
    try:
        settings = _settings(args)
        outs = [str(out) for out in outs]
        with no_empty_dirs_left(outs):
            if fleet:
                from reducer_twin.fleet.history import analyze_into_store
                results, workers = analyze_into_store(args, settings, names, outs, worker)
            else:
                results = _analyze_all(args, settings, outs, worker)
    finally:
        if worker is not None:
            worker.close()
    with no_empty_dirs_left(reports):   # a report parent made, but no report written
        code, blind, summary, failed = _say_results(args, results, names, reports, settings,
                                                    fleet)
    if args.json:
        if single:
            if summary:
                print_json(_with_worker(summary[names[0]].as_json(), args, fleet,
                                        workers.get(args.bags[0])))
            elif fleet:
                note = failed[names[0]]
                print_json({'engine': args.engine,
                            **(note if isinstance(note, dict) else {'error': note})})
        else:
            total = sum(r.messages for r in summary.values())
            seconds = sum(r.seconds for r in summary.values())
            rate = total / seconds if seconds > 0 else float('nan')
            bags = {n: _with_worker({**summary[n].as_json(), 'out': str(summary[n].out)},
                                    args, fleet, workers.get(b))
                    for b, n in zip(args.bags, names) if n in summary}
            bags.update({n: text if isinstance(text, dict) else {'error': text}
                         for n, text in failed.items()})
            extra = {'engine': args.engine} if fleet else {}
            print_json({'bags': {n: bags[n] for n in names},
                        'messages_per_s': rate if math.isfinite(rate) else None, **extra})
    else:
        for name, result in summary.items():
            _print_summary(name, result)
    # 3: everything ran, but some reducer could not be observed (said on stderr and in JSON).
    return EXIT_NOT_OBSERVED if code == 0 and blind else code


def _say_results(args, results, names, reports, settings, fleet):
    """
    Say each bag's outcome on stderr, write its report, and sum up.

    Returns
    -------
    tuple
        ``(exit code so far, whether a joint was not observed, {name: BagResult},
        {name: error text or fleet note})``.

    """
    code = 0
    blind = False
    summary, failed = {}, {}
    for bag, name in zip(args.bags, names):
        result = results[bag]
        if fleet and _fleet_note(result, name, failed):
            continue
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
            elif res.partial:
                sys.stderr.write(f'WARNING: {joint}: observed in part of {name}: '
                                 f'{res.partial}\n')
        for joint, reason in result.plan.not_analysed().items():
            sys.stderr.write(f'WARNING: {joint}: not observed in {name}: {reason}\n')
            blind = True
        if args.report:
            from reducer_twin.analysis.report import write_report
            try:
                page = write_report(result, reports[names.index(name)], life=settings.life)
            except ReducerTwinError as err:
                sys.stderr.write(f'ERROR: {err}\n')
                code = 1
            else:
                if not args.json:
                    print(f'report: {page}')
        summary[name] = result
    return code, blind, summary, failed


def _fleet_note(result, name, failed):
    """Report a bag the fleet store skipped; True when it was one."""
    from reducer_twin.fleet.history import BagSkipped
    if not isinstance(result, BagSkipped):
        return False
    sys.stderr.write(f'NOTE: {result}\n')
    failed[name] = {'skipped': str(result)}
    return True


def _with_worker(record, args, fleet, worker):
    """Add ``engine`` and the bag's ``worker`` to a --json record of a fleet run."""
    if not fleet:
        return record
    record = dict(record, engine=args.engine)
    if worker:
        record['worker'] = {'node': worker['node'], 'pid': worker['pid']}
    return record


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
              f'um, lost motion {_fmt(s["lost_motion_arcmin"], ".3f")} +/- '
              f'{_fmt(s["lost_motion_std_arcmin"], ".3f")} arcmin, remaining life '
              f'P10/P50/P90 {_fmt(s["rul_p10_h"], ",.0f")} / {_fmt(s["rul_p50_h"], ",.0f")} / '
              f'{_fmt(s["rul_p90_h"], ",.0f")} h, {s["rejected"]} samples rejected')
    for joint, reason in result.plan.not_analysed().items():
        print(f'  {joint}: NOT OBSERVED: {reason}')
