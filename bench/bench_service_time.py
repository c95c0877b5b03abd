#!/usr/bin/env python3
"""
Remaining life of used reducers seen briefly, with and without their service time.

A twin started on a robot that has run for years sees each reducer part-way
through its life, and a recording of a few days shows too little growth of
the lost motion to tell the unit's own wear rate: without more, the
remaining life is the model's rate at the duty, which a generator whose lives
do not follow the model (``bench/independent_generator.py``: lives drawn
3 000-30 000 h whatever the duty; ``bench/third_generator.py``: its own
exposure and growth law) contradicts by many times. The robot's hour meter
says how long the reducer has run (``service_time_s`` in the configuration).
The model's own simulator (``reducer-twin simulate``, two joints, each with a
hidden rate scale drawn log-uniform in 1-8, so that its lives span about
3 400-27 000 h as the other generators' do, within the remaining life's
100 000-h horizon) is run the same way: it wears
as the twin's model does, so there the twin's figures say how wide its
intervals are where the model holds.

For ``--seeds`` truths of each generator and each start at ``--fractions`` of
the units' drawn lives, a recording of ``--hours`` of operation (time-compressed
``--aging-factor`` times, three joints: base, shoulder, forearm) is written and
run through ``python -m reducer_twin.cli analyze BAG --config YAML --json`` as
a user would: once without the service time and once with each joint's true
operating hours before the recording. Printed per generator and case: P10-P90
coverage of the true remaining life (below P10 / above P90), median P50 /
true, P50 within 30 % and within a factor 2, and joints whose rate the twin
calls resolved (``rate_resolved``).

Usage::

    .venv/bin/python bench/bench_service_time.py [--seeds 6] [--seed0 1]
        [--fractions 0.25,0.5,0.75] [--hours 150] [--aging-factor 3600]
        [--generators independent,third,model]
"""

import argparse
import json
import math
from pathlib import Path
import shutil
import subprocess
import sys
import tempfile
import time

import independent_generator as gen
import numpy as np
from reducer_twin.core.pipeline import LifeConfig
import third_generator

GENERATORS = {'independent': gen, 'third': third_generator}
HOUR = 3600.0
REPLAY_AGING = 3600.0
"""Aging factor of the model's lives replayed to their start (``simulate --start-hours``)."""

ERROR_H, WARN_H = LifeConfig().error_s / HOUR, LifeConfig().warn_s / HOUR
"""The default error and warning thresholds on the remaining life P10 [h] (fleet verdicts)."""


def analyze(bag, out, config):
    """Run ``reducer-twin analyze`` on ``bag`` with ``config``; return its joints' JSON."""
    proc = subprocess.run([sys.executable, '-m', 'reducer_twin.cli', 'analyze', str(bag),
                           '--out', str(out), '--config', str(config), '--json'],
                          capture_output=True, text=True)
    try:
        return json.loads(proc.stdout)['joints'], proc.returncode
    except (ValueError, KeyError, TypeError):
        return {}, proc.returncode


def write_config(path, aging_factor, service=None):
    """Write an analysis configuration: the aging factor and the joints' service times."""
    lines = ['twin:', f'  aging_factor: {aging_factor!r}']
    if service:
        lines.append('service_time_s:')
        lines += [f'  {joint}: {seconds!r}' for joint, seconds in service.items()]
    Path(path).write_text('\n'.join(lines) + '\n', encoding='utf-8')


def run_one(tmp, source, seed, fraction, hours, aging_factor):
    """
    Generate one recording and analyse it without and with the service times.

    Returns
    -------
    list of dict
        Per joint: ``kind``, ``truth`` (remaining life at the recording's end [h]) and
        per case (``'without'``, ``'with'``) the reported ``p10``, ``p50``, ``p90``,
        ``resolved``.

    """
    spec = source.Spec(seed=seed, kinds=('base', 'shoulder', 'forearm'), hours=hours,
                       aging_factor=aging_factor, start_fraction=fraction)
    bag = tmp / f'bag-{seed}-{fraction}'
    truth = source.generate_bag(spec, bag)
    service = {j: t['start_hours'] * HOUR for j, t in truth['joints'].items()}
    reports = {}
    for case, given in (('without', None), ('with', service)):
        config = tmp / f'{case}.yaml'
        write_config(config, aging_factor, given)
        reports[case], _ = analyze(bag, tmp / f'out-{case}', config)
    truths = {j: (t['kind'], t['remaining_life_end_h']) for j, t in truth['joints'].items()}
    return _rows(truths, reports, [bag, *(tmp / f'out-{case}' for case in reports)])


def _rows(truths, reports, scratch):
    """Return a row per joint (kind, true life, each case's reported life); remove scratch."""
    out = []
    for joint, (kind, life) in truths.items():
        row = {'kind': kind, 'truth': life}
        for case, joints in reports.items():
            r = joints.get(joint, {})
            # A joint not observed has no remaining life (None in --json).
            row[case] = {k: math.nan if r.get(f'rul_{k}_h') is None else r[f'rul_{k}_h']
                         for k in ('p10', 'p50', 'p90')}
            row[case]['resolved'] = bool(r.get('rate_resolved'))
        out.append(row)
    for path in scratch:
        shutil.rmtree(path, ignore_errors=True)
    return out


def run_model(tmp, seed, fraction, hours, aging_factor):
    """
    :func:`run_one` on the model's simulator: two joints, rate scales drawn in 1-8.

    The life at each scale is read from a first, one-hour recording (its remaining life
    plus the hour); the recording then starts at ``fraction`` of the shorter life. Below
    :data:`REPLAY_AGING` (a life too long to replay sample by sample: ``simulate`` refuses
    it) the joints' wear at the start is read from a one-hour recording ending there at
    that aging factor, and the recording meets them at it (``--start-wear-um``).
    """
    scales = np.exp(np.random.default_rng([seed, 11]).uniform(0.0, math.log(8.0), 2))
    common = ['--joints', '2', '--seed', str(seed),
              '--wear-rate-scale', ','.join(f'{k:.4f}' for k in scales), '--json']

    def simulate(out, run_hours, start, aging=aging_factor, wear=None):
        where = ['--start-hours', repr(start)] if wear is None else \
            ['--start-wear-um', ','.join(f'{w!r}' for w in wear)]
        proc = subprocess.run([sys.executable, '-m', 'reducer_twin.cli', 'simulate', '--out',
                               str(out), '--hours', repr(run_hours), '--aging-factor',
                               repr(aging), *where, *common], capture_output=True, text=True,
                              check=True)
        return json.loads(proc.stdout)['joints']

    probe = simulate(tmp / 'life', 1.0, 0.0, REPLAY_AGING)
    shutil.rmtree(tmp / 'life', ignore_errors=True)
    start = fraction * min(1.0 + j['true_rul_h'] for j in probe.values())
    bag = tmp / f'model-{seed}-{fraction}'
    if aging_factor >= REPLAY_AGING:
        truth = simulate(bag, hours, start)
    else:
        # The last hour before the start, replayed to it (not written): its end is the start.
        before = simulate(tmp / 'before', 1.0, max(start - 1.0, 0.0), REPLAY_AGING)
        shutil.rmtree(tmp / 'before', ignore_errors=True)
        truth = simulate(bag, hours, 0.0, wear=[j['true_wear_um'] for j in before.values()])
    reports = {}
    for case, given in (('without', None), ('with', {j: start * HOUR for j in truth})):
        config = tmp / f'{case}.yaml'
        write_config(config, aging_factor, given)
        reports[case], _ = analyze(bag, tmp / f'out-{case}', config)
    truths = {j: ('model', t['true_rul_h']) for j, t in truth.items()}
    return _rows(truths, reports, [bag, *(tmp / f'out-{case}' for case in reports)])


def summarise(name, rows):
    """Print the calibration of both cases over ``rows``."""
    print(f'\n== {name}: {len(rows)} joints ==')
    for case in ('without', 'with'):
        seen = [r for r in rows if all(math.isfinite(r[case][k]) for k in ('p10', 'p50', 'p90'))]
        if not seen:
            print(f'  {case:7s} service time: no joint with a remaining life')
            continue
        truth = np.array([r['truth'] for r in seen])
        p10, p50, p90 = (np.array([r[case][k] for r in seen]) for k in ('p10', 'p50', 'p90'))
        below, above = np.mean(truth < p10), np.mean(truth > p90)
        ratio = p50 / truth
        print(f'  {case:7s} service time: {len(seen)} joints ({len(rows) - len(seen)} not '
              f'observed, left out); P10-P90 coverage '
              f'{100 * (1 - below - above):3.0f} % (below P10 {100 * below:.0f} %, above P90 '
              f'{100 * above:.0f} %) [80 +- 5; 10 +- 5 each]; P50 / true median '
              f'{np.median(ratio):.2f} (10-90 %: {np.percentile(ratio, 10):.2f}-'
              f'{np.percentile(ratio, 90):.2f}); within 30 % '
              f'{100 * np.mean(abs(ratio - 1) <= 0.3):.0f} %, '
              f'within a factor 2 {100 * np.mean((ratio >= 0.5) & (ratio <= 2)):.0f} %; rate '
              f'resolved {100 * np.mean([r[case]["resolved"] for r in seen]):.0f} %')
        # A REPLACE the truth does not call for: P10 at or below the fleet's error
        # threshold on a unit with more than the warning threshold left, its rate resolved
        # (unresolved, the fleet says WATCH).
        healthy = truth > WARN_H
        low = healthy & (p10 <= ERROR_H)
        resolved = np.array([r[case]['resolved'] for r in seen])
        print(f'           P10 <= {ERROR_H:g} h on {np.sum(low)} of {np.sum(healthy)} joints with '
              f'more than {WARN_H:g} h left: {np.sum(low & resolved)} with the rate resolved '
              f'(REPLACE), {np.sum(low & ~resolved)} not (WATCH)')
    for kind in ('base', 'shoulder', 'forearm', 'model'):
        part = [r for r in rows if r['kind'] == kind and math.isfinite(r['with']['p50'])]
        if part:
            ratio = np.array([r['with']['p50'] / r['truth'] for r in part])
            print(f'    {kind:8s} with: P50 / true median {np.median(ratio):.2f} '
                  f'({ratio.min():.2f}-{ratio.max():.2f})')


def main(argv=None):
    """Run the benchmark and print its figures."""
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--seeds', type=int, default=6, help='truths per generator (default 6)')
    ap.add_argument('--seed0', type=int, default=1, help='first seed (default 1)')
    ap.add_argument('--fractions', default='0.25,0.5,0.75',
                    help="starts, as fractions of each unit's drawn life")
    ap.add_argument('--hours', type=float, default=150.0, help='operating hours recorded')
    ap.add_argument('--aging-factor', type=float, default=3600.0,
                    help='operating seconds per stream second (default 3600)')
    ap.add_argument('--generators', default='independent,third,model')
    args = ap.parse_args(argv)
    fractions = [float(f) for f in args.fractions.split(',')]
    t0, cpu0 = time.perf_counter(), time.process_time()
    with tempfile.TemporaryDirectory(prefix='bench-service-') as tmp:
        for name in args.generators.split(','):
            rows = []
            for seed in range(args.seed0, args.seed0 + args.seeds):
                for fraction in fractions:
                    if name == 'model':
                        rows += run_model(Path(tmp), seed, fraction, args.hours,
                                          args.aging_factor)
                    else:
                        rows += run_one(Path(tmp), GENERATORS[name], seed, fraction,
                                        args.hours, args.aging_factor)
            summarise(f'{name} generator, {args.hours:g} h recorded at '
                      f'{"/".join(f"{100 * f:g}" for f in fractions)} % of life', rows)
    print(f'\n({time.perf_counter() - t0:.0f} s wall, {time.process_time() - cpu0:.0f} s of '
          'CPU in this process)')
    return 0


if __name__ == '__main__':
    sys.exit(main())
