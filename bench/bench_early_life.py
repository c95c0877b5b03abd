#!/usr/bin/env python3
"""
Remaining life from a short recording early in a reducer's life, at several sample rates.

A twin is most often given a recording that covers a small part of a reducer's life: 300
h of a 25 000-h life is 1 %. Its remaining life is then an extrapolation a hundred times
over, and the choice between the wear model's curve and the observed growth law
(:mod:`reducer_twin.core.trend_score`) rests on how each predicted the recording's own
windows a few windows ahead. ``bench_accuracy.py`` judges the twin over 25-75 % of whole
lives and does not see this regime.

For ``--seeds`` seeds and each rate of ``--rates``, a recording of ``--hours`` of
operation from new (time-compressed ``--aging-factor`` times) is written by the model's
simulator (``reducer-twin simulate``, two joints: it wears as the twin's model does, so
the twin's model holds) and by the independent generator (``bench/independent_generator.
py``, three joints: base, shoulder, forearm; its own lives and growth laws), and run
through ``python -m reducer_twin.cli analyze BAG --json`` as a user would. Printed per
generator and rate: joints, P10-P90 coverage of the true remaining life at the
recording's end (below P10 / above P90), median P50 / true, P50 within 30 %, and the
joints whose remaining life follows the observed growth law (its probability above 0.5
in the derived bag's last ``wear`` record, read back with the ``rosbags`` library); for the
independent generator also split by the truth's own law (lost motion linear or concave in
its exposure), which the twin's two models err on in opposite directions; and for each
generator split by whether the analysis says its remaining life follows the wear model's
curve beyond the span the curve's shape was compared over (``curve_extrapolation`` in
``--json``): how much that warning tells.

Usage::

    .venv/bin/python bench/bench_early_life.py [--seeds 5] [--seed0 3]
        [--rates 1000,2000,4000] [--hours 300] [--aging-factor 3600]
        [--generators model,independent] [--effort-noise-band 5-50] [--velocity-filter-ms 20]

``--effort-noise-band`` band-limits the independent generator's effort noise (same RMS):
a current loop's ripple, which neighbouring samples do not show. ``--velocity-filter-ms``
passes its velocity field through a first-order filter (a drive's filtered velocity).
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
from rosbags.highlevel import AnyReader
from rosbags.typesys import get_typestore, Stores

KINDS = ('base', 'shoulder', 'forearm')
"""Joints of an independent-generator recording."""


def cli(*argv):
    """Run ``python -m reducer_twin.cli`` with ``argv``; return its stdout as JSON and rc."""
    proc = subprocess.run([sys.executable, '-m', 'reducer_twin.cli', *map(str, argv)],
                          capture_output=True, text=True)
    try:
        return json.loads(proc.stdout), proc.returncode
    except ValueError:
        return {}, proc.returncode


def law_probability(derived):
    """Return per joint the growth law's probability in the derived bag's last ``wear``."""
    out = {}
    with AnyReader([Path(derived)], default_typestore=get_typestore(Stores.ROS2_JAZZY)) as r:
        wear = [c for c in r.connections if c.topic.endswith('/wear')]
        for c, _, raw in r.messages(connections=wear):
            msg = r.deserialize(raw, c.msgtype)
            fields = msg.layout.dim[-1].label.split(',')
            out[c.topic.split('/')[2]] = float(msg.data[fields.index('trend_probability')])
    return out


def run_model(tmp, seed, rate, hours, aging):
    """One model-simulator recording; return rows per joint."""
    bag = tmp / f'model-{seed}-{rate}'
    truth, rc = cli('simulate', '--out', bag, '--joints', 2, '--rate-hz', rate, '--hours', hours,
                    '--aging-factor', aging, '--seed', seed, '--json')
    if rc != 0:
        raise RuntimeError(f'simulate seed {seed} at {rate} Hz failed (exit {rc})')
    truths = {j: t['true_rul_h'] for j, t in truth['joints'].items()}
    return _analysed(tmp, bag, truths)


def run_independent(tmp, seed, rate, hours, aging, band_hz=None, velocity_filter_s=None):
    """One independent-generator recording from new; return rows per joint."""
    spec = gen.Spec(seed=seed, kinds=KINDS, hours=hours, aging_factor=aging, rate_hz=rate,
                    start_fraction=0.0, effort_noise_band_hz=band_hz,
                    velocity_filter_s=velocity_filter_s)
    bag = tmp / f'independent-{seed}-{rate}'
    truth = gen.generate_bag(spec, bag)
    truths = {j: t['remaining_life_end_h'] for j, t in truth['joints'].items()}
    laws = {j: t['law'] for j, t in truth['joints'].items()}
    return _analysed(tmp, bag, truths, laws)


def _analysed(tmp, bag, truths, laws=None):
    out = tmp / (bag.name + '-derived')
    result, _ = cli('analyze', bag, '--out', out, '--json')
    law = law_probability(out) if out.exists() else {}
    rows = []
    for joint, life in truths.items():
        r = result.get('joints', {}).get(joint, {})
        row = {k: math.nan if r.get(f'rul_{k}_h') is None else r[f'rul_{k}_h']
               for k in ('p10', 'p50', 'p90')}
        row.update(truth=life, law=law.get(joint, math.nan), observed=bool(r.get('observed')),
                   truth_law=(laws or {}).get(joint),
                   curve_far=r.get('curve_extrapolation') is not None)
        rows.append(row)
    shutil.rmtree(bag, ignore_errors=True)
    shutil.rmtree(out, ignore_errors=True)
    return rows


def report(name, rows):
    """Print the figures of one generator and rate."""
    t = np.array([r['truth'] for r in rows])
    p10, p50, p90 = (np.array([r[k] for r in rows]) for k in ('p10', 'p50', 'p90'))
    seen = np.array([r['observed'] for r in rows]) & np.isfinite(p50)
    below, above = np.mean(t[seen] < p10[seen]), np.mean(t[seen] > p90[seen])
    ratio = p50[seen] / t[seen]
    law = np.array([r['law'] for r in rows])[seen]
    print(f'{name}: {seen.sum()} of {len(rows)} joints observed; P10-P90 holds the true '
          f'remaining life in {100 * (1 - below - above):.0f} % (below P10 {100 * below:.0f} %, '
          f'above P90 {100 * above:.0f} %); P50 / true median {np.median(ratio):.2f} '
          f'({np.min(ratio):.2f}-{np.max(ratio):.2f}), within 30 % in '
          f'{100 * np.mean(np.abs(ratio - 1) <= 0.3):.0f} %; following the growth law '
          f'{np.sum(law > 0.5)}')


def main(argv=None):
    """Run the benchmark and print its figures."""
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--seeds', type=int, default=5)
    ap.add_argument('--seed0', type=int, default=3)
    ap.add_argument('--rates', default='1000,2000,4000')
    ap.add_argument('--hours', type=float, default=300.0)
    ap.add_argument('--aging-factor', type=float, default=3600.0)
    ap.add_argument('--generators', default='model,independent')
    ap.add_argument('--effort-noise-band', type=gen.band_hz, metavar='LOW-HIGH',
                    help="the independent generator's effort noise band-limited to LOW-HIGH "
                    "Hz (a current loop's ripple; default white)")
    ap.add_argument('--velocity-filter-ms', type=float, metavar='MS',
                    help="the independent generator's velocity field through a first-order "
                    "filter of MS ms (a drive's filtered velocity; default unfiltered)")
    args = ap.parse_args(argv)
    band = args.effort_noise_band
    tau = None if args.velocity_filter_ms is None else 1e-3 * args.velocity_filter_ms
    if (band is not None or tau is not None) and 'model' in args.generators.split(','):
        ap.error("--effort-noise-band, --velocity-filter-ms: the model's simulator has "
                 'neither; give --generators independent')
    runners = {'model': run_model,
               'independent': lambda *a: run_independent(*a, band_hz=band,
                                                         velocity_filter_s=tau)}
    start = time.time()
    with tempfile.TemporaryDirectory(prefix='bench-early-') as tmp:
        for name in args.generators.split(','):
            every = []
            for rate in (float(r) for r in args.rates.split(',')):
                rows = []
                for seed in range(args.seed0, args.seed0 + args.seeds):
                    rows += runners[name](Path(tmp), seed, rate, args.hours, args.aging_factor)
                noise = '' if band is None else f', effort noise in {band[0]:g}-{band[1]:g} Hz'
                noise += '' if tau is None else f', velocity filtered at {1e3 * tau:g} ms'
                report(f'{name} at {rate:g} Hz, {args.hours:g} h from new{noise}', rows)
                every += rows
            report(f'{name}, every rate', every)
            for law in sorted({r['truth_law'] for r in every} - {None}):
                report(f'  {name}, every rate, units whose lost motion grows {law} in their '
                       'exposure', [r for r in every if r['truth_law'] == law])
            for far, said in ((True, 'says'), (False, 'does not say')):
                pick = [r for r in every if r['curve_far'] == far]
                if pick:
                    report(f'  {name}, every rate, joints whose life {said} it follows the '
                           "wear model's curve beyond its scored span", pick)
    print(f'({time.time() - start:.0f} s)')


if __name__ == '__main__':
    main()
