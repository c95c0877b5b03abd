#!/usr/bin/env python3
"""
Benchmark of a fleet's bags into a store (a script, not a test).

Simulates 4 robots x 6 consecutive bags x 6 joints (``simulate --robot rK --start-hours``,
1 kHz, ``--seconds`` of stream per bag covering 1500 operating hours each, wear-rate
scales that differ per joint so the verdicts differ), then analyses all 24 bags,
shuffled, into a fresh fleet store with:

* ``analyze --engine local --jobs 1`` (one chain after the other, the stage worker and
  the reader in processes of their own, as by default);
* ``analyze --engine local --jobs 2`` (robots' chains in two processes);
* ``analyze --engine ray --jobs 2`` (a local Ray of 2 CPUs started on demand, its
  start-up included);

each end to end as a subprocess. Prints bags/s, recorded joint-hours/s (hours of
recording x joints analysed per wall second: what a real fleet's 1 h/day/robot is
measured in) and messages/s, checks that the three stores give the same fleet view,
and the store's size per window and per reducer-year (a 2 s window per 2 s of
recording, 1 h of recording a day). With ``--screenshot PNG`` it writes the fleet
report of the last store and renders it with headless Chromium.

Usage::

    .venv/bin/python bench/bench_fleet.py [--seconds 60] [--screenshot docs/fleet_report.png]
"""

import argparse
import json
import os
from pathlib import Path
import random
import shutil
import subprocess
import sys
import tempfile
import time

ROBOTS, BAGS, JOINTS = 4, 6, 6
HOURS_PER_BAG = 1500.0
"""Operating hours of life each bag covers (the aging factor follows from --seconds)."""

SCALES = ('1,1.2,0.8,1,1.5,1', '2,1,1,3,1,0.7', '1,4,1,1,6,2.5', '8,1,1.3,1,1,1')
"""Hidden wear-rate scale of every joint, per robot."""


def _script():
    return str(Path(sys.executable).parent / 'reducer-twin')


def simulate(root, seconds):
    """Write the fleet's bags; return their paths."""
    hours = HOURS_PER_BAG
    aging = hours * 3600.0 / seconds
    paths = []
    for r in range(ROBOTS):
        for k in range(BAGS):
            out = root / f'r{r + 1}_{k + 1}'
            subprocess.run([_script(), 'simulate', '--out', str(out), '--robot', f'r{r + 1}',
                            '--start-hours', str(k * hours), '--hours', str(hours),
                            '--aging-factor', str(aging), '--joints', str(JOINTS),
                            '--rate-hz', '1000', '--seed', str(100 * (r + 1)),
                            '--wear-rate-scale', SCALES[r]],
                           check=True, stdout=subprocess.DEVNULL)
            paths.append(str(out))
    return paths


def analyse(root, bags, name, extra):
    """Analyse every bag into a new store; return (seconds, store, --json)."""
    store = root / f'{name}.db'
    start = time.perf_counter()
    done = subprocess.run([_script(), 'analyze', *bags, '--store', str(store), '--out',
                           str(root / f'out-{name}'), '--json', *extra],
                          check=True, capture_output=True, text=True)
    seconds = time.perf_counter() - start
    return seconds, store, json.loads(done.stdout)


def fleet(store):
    """Return the fleet view of a store."""
    done = subprocess.run([_script(), 'fleet', '--store', str(store), '--json'], check=True,
                          capture_output=True, text=True)
    return json.loads(done.stdout)['reducers']


def main():
    """Run the benchmark and print its figures."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--seconds', type=float, default=60.0,
                        help='stream seconds per bag (default 60)')
    parser.add_argument('--screenshot', default=None, metavar='PNG',
                        help='render the fleet report into this PNG with headless Chromium')
    args = parser.parse_args()
    root = Path(tempfile.mkdtemp(prefix='bench-fleet-'))
    try:
        start = time.perf_counter()
        bags = simulate(root, args.seconds)
        print(f'simulated {len(bags)} bags ({ROBOTS} robots x {BAGS} bags x {JOINTS} joints, '
              f'{args.seconds:g} s at 1 kHz each) in {time.perf_counter() - start:.1f} s; '
              f'load {os.getloadavg()[0]:.1f}')
        random.Random(1).shuffle(bags)
        messages = len(bags) * int(args.seconds * 1000)
        joint_hours = len(bags) * JOINTS * args.seconds / 3600.0
        views = {}
        for name, extra in (('local-1', ['--engine', 'local', '--jobs', '1']),
                            ('local-2', ['--engine', 'local', '--jobs', '2']),
                            ('ray-2', ['--engine', 'ray', '--jobs', '2'])):
            seconds, store, out = analyse(root, bags, name, extra)
            pids = {b['worker']['pid'] for b in out['bags'].values() if 'worker' in b}
            views[name] = fleet(store)
            print(f'{name:8s}: {seconds:6.1f} s, {len(bags) / seconds:5.2f} bags/s, '
                  f'{joint_hours / seconds:7.3f} recorded joint-hours/s '
                  f'({joint_hours * 3600 / seconds:,.0f} x real time), '
                  f'{messages / seconds:,.0f} msg/s, {len(pids)} worker process(es); '
                  f'load {os.getloadavg()[0]:.1f}')
        same = all(v == views['local-1'] for v in views.values())
        print(f'fleet views of the three stores identical: {same}')
        rows = views['ray-2']
        verdicts = {}
        for row in rows:
            verdicts[row['verdict']] = verdicts.get(row['verdict'], 0) + 1
        print(f'verdicts: {verdicts}')
        size = store.stat().st_size + (Path(str(store) + '-wal').stat().st_size
                                       if Path(str(store) + '-wal').exists() else 0)
        windows = sum(r.get('windows', 0) for r in rows)
        per_window = size / max(windows, 1)
        year = 365 * 3600 / 2.0   # windows of 2 s in 1 h of recording a day
        print(f'store: {size / 1e6:.2f} MB for {len(rows)} reducers, {windows} windows: '
              f'{per_window:.0f} B per window, {per_window * year / 1e6:.0f} MB per '
              'reducer-year at 1 h of recording a day')
        if args.screenshot:
            # One reducer replaced after the last bag: shown retired, its successor not
            # observed yet.
            subprocess.run([_script(), 'replace', '--store', str(store), '--robot', 'r2',
                            '--joint', 'joint_6', '--note', 'bench'], check=True,
                           stdout=subprocess.DEVNULL)
            report = root / 'report'
            subprocess.run([_script(), 'fleet', '--store', str(store), '--report', str(report)],
                           check=True, stdout=subprocess.DEVNULL)
            chromium = shutil.which('chromium') or '/usr/bin/chromium'
            subprocess.run([chromium, '--headless', '--no-sandbox', '--disable-gpu',
                            '--disable-background-networking', '--disable-component-update',
                            '--disable-sync', '--no-first-run', '--hide-scrollbars',
                            f'--user-data-dir={root / "profile"}', '--window-size=1200,1500',
                            f'--screenshot={Path(args.screenshot).resolve()}',
                            (report / 'index.html').as_uri()],
                           check=True, capture_output=True, timeout=120)
            print(f'fleet report rendered into {args.screenshot}')
    finally:
        shutil.rmtree(root, ignore_errors=True)


if __name__ == '__main__':
    main()
