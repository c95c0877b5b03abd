#!/usr/bin/env python3
"""
Benchmark of ``reducer-twin simulate`` and ``reducer-twin analyze`` (a script, not a test).

Builds the 1,000,000-message JointState bag of the acceptance check (one joint, motor +
link: ``simulate --hours 1000 --aging-factor 3600 --joints 1 --rate-hz 1000 --seed 5``),
or with ``--joints 6 --hours 300`` the 300,000-message bag of a 6-joint robot at 1 kHz
(12 entries per JointState), then in the same run measures:

* ``simulate`` end to end as a subprocess (start-up included) and ``simulate_bag`` in
  this process;
* ``analyze`` end to end as a subprocess (read, decode, clean, TE, windows, estimator,
  life, derived bag written), with the estimator stages in a second process and without;
* ``analyze_bag`` in this process, alone and with the stage worker (the CPU of each of
  the two processes: how evenly the work is shared);
* a full ``rosbags`` read (AnyReader + deserialize of every JointState) of the same bag,
  the baseline of the 3x requirement.

Prints messages per second, CPU seconds, the ratio to rosbags and the load average
(other work on the 2-core machine slows every wall-clock figure).

Usage::

    .venv/bin/python bench/bench_analyze.py [--repeat 3] [--hours 1000] [--joints 1]
    .venv/bin/python bench/bench_analyze.py --joints 6 --hours 300
"""

import argparse
import os
from pathlib import Path
import resource
import shutil
import subprocess
import sys
import tempfile
import time

from reducer_twin.analysis.pipeline import analyze_bag
from reducer_twin.analysis.simulate import simulate_bag, SimulationSpec

SPEC_ARGS = ['--aging-factor', '3600', '--rate-hz', '1000', '--seed', '5']


def _script():
    return str(Path(sys.executable).parent / 'reducer-twin')


def _children_cpu():
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def _self_cpu():
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


def run_timed(argv):
    """Run a command; return (wall seconds, CPU seconds of it and its children)."""
    cpu = _children_cpu()
    start = time.perf_counter()
    subprocess.run(argv, check=True, stdout=subprocess.DEVNULL)
    return time.perf_counter() - start, _children_cpu() - cpu


def time_rosbags(bag):
    """Deserialize every JointState with rosbags; return (seconds, count)."""
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import get_typestore, Stores
    typestore = get_typestore(Stores.ROS2_JAZZY)
    start = time.perf_counter()
    count = 0
    with AnyReader([Path(bag)], default_typestore=typestore) as reader:
        for connection, _, raw in reader.messages():
            if connection.msgtype == 'sensor_msgs/msg/JointState':
                reader.deserialize(raw, connection.msgtype)
                count += 1
    return time.perf_counter() - start, count


def main(argv=None):
    """Run the benchmark and print the figures."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--hours', type=float, default=1000.0,
                        help='hours at aging factor 3600 and 1 kHz: 1000 h = 1M messages')
    parser.add_argument('--joints', type=int, default=1,
                        help='joints per JointState message (motor + link entries each)')
    parser.add_argument('--repeat', type=int, default=3)
    args = parser.parse_args(argv)
    rows = []
    load = os.getloadavg()[0]
    with tempfile.TemporaryDirectory(prefix='bench_analyze_') as tmp:
        tmp = Path(tmp)
        bag = tmp / 'bag'
        sim_runs = []
        for _ in range(args.repeat):
            shutil.rmtree(bag, ignore_errors=True)
            sim_runs.append(run_timed([_script(), 'simulate', '--out', str(bag), '--hours',
                                       str(args.hours), '--joints', str(args.joints),
                                       *SPEC_ARGS]))
        n = SimulationSpec(hours=args.hours).messages
        rows.append(('simulate, end to end (subprocess)', n, sim_runs))
        spec = SimulationSpec(hours=args.hours, seed=5, joints=args.joints)
        simulate_bag(tmp / 'warm', spec)   # imports and the model table, once
        in_process = []
        for k in range(args.repeat):
            cpu, start = time.process_time(), time.perf_counter()
            simulate_bag(tmp / f'sim{k}', spec)
            in_process.append((time.perf_counter() - start, time.process_time() - cpu))
            shutil.rmtree(tmp / f'sim{k}')
        rows.append(('simulate_bag in process', n, in_process))
        os.sync()
        for choice in ('auto', 'yes', 'no'):
            runs = []
            for _ in range(args.repeat):
                shutil.rmtree(tmp / 'derived', ignore_errors=True)
                runs.append(run_timed([_script(), 'analyze', str(bag), '--out',
                                       str(tmp / 'derived'), '--json', '--stage-process',
                                       choice]))
            rows.append((f'analyze, end to end (subprocess, --stage-process {choice})', n,
                         runs))
        analyze_bag(bag, tmp / 'warm_derived')
        in_process = []
        for _ in range(args.repeat):
            shutil.rmtree(tmp / 'derived', ignore_errors=True)
            cpu, start = time.process_time(), time.perf_counter()
            analyze_bag(bag, tmp / 'derived')
            in_process.append((time.perf_counter() - start, time.process_time() - cpu))
        rows.append(('analyze_bag in process (one process)', n, in_process))
        shared = []
        for _ in range(args.repeat):
            shutil.rmtree(tmp / 'derived', ignore_errors=True)
            cpu, worker, start = _self_cpu(), _children_cpu(), time.perf_counter()
            analyze_bag(bag, tmp / 'derived', stage_worker=True)
            shared.append((time.perf_counter() - start, _self_cpu() - cpu,
                           _children_cpu() - worker))
        seconds, count = time_rosbags(bag)
        assert count == n, (count, n)
        rosbags_rate = n / seconds
    print(f'{n:,} JointState messages ({args.joints} joint(s): link + motor each), 1 kHz')
    print(f'{"path":58s} {"first":>10s} {"best":>10s} {"CPU s":>7s}')
    for label, count, runs in rows:
        walls = [wall for wall, _ in runs]
        cpu = min(c for _, c in runs)
        print(f'{label:58s} {count / walls[0]:>10,.0f} {count / min(walls):>10,.0f} '
              f'{cpu:>7.2f}   msg/s')
    print(f'{"rosbags AnyReader + deserialize (baseline)":58s} {rosbags_rate:>10,.0f}')
    wall, here, worker = min(shared)
    print(f'analyze_bag with the stage worker (best of {len(shared)}): {n / wall:,.0f} msg/s, '
          f'CPU {here:.2f} s in the reading process, {worker:.2f} s in the worker')
    for label, count, runs in rows:
        if label.startswith('analyze, end to end (subprocess, --stage-process auto)'):
            best = count / min(wall for wall, _ in runs)
            floor = '(floor 3x; absolute floor 400k msg/s)' if args.joints == 1 else \
                '(floor 4x for 6 joints)'
            print(f'analyze end to end / rosbags deserialize: {best / rosbags_rate:.2f}x '
                  f'{floor}')
    print(f'1-minute load average {load:.2f} before, {os.getloadavg()[0]:.2f} after '
          f'({os.cpu_count()} cores)')
    return 0


if __name__ == '__main__':
    sys.exit(main())
