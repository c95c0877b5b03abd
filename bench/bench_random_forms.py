#!/usr/bin/env python3
"""
Recordings of random form and truth from the two outside generators, through ``analyze``.

Each run draws, from its seed, a generator (``bench/independent_generator.py`` or
``bench/third_generator.py``), one to three joint kinds, a controller rate (100-2000 Hz),
the layout (one topic, or link and motor topics), the motor angles' form (raw or divided
by the ratio), the entry that carries the effort (link or motor), sometimes no velocity
field and a drawn stamp jitter, and a recording of 20-300 h at aging factor 3600 starting
at 5-80 % of each unit's life. Nothing is configured: ``reducer-twin analyze BAG --out
OUT --json`` is run as a user would run it on a recording it has never seen.

Printed per generator: runs whose command failed (an exit status other than 0 or 3, a
traceback, no JSON), joints observed and not observed (with their reasons' counts),
answers that contradict themselves (:func:`contradictions`: e.g. no life left beside a
lost motion clearly below the limit), joints called worn out whose truth has life left
(and how many of them say their lost motion is the loaded flanks' play, the width at the
test torque not compared: ``test_torque_check``), the joints that say their lost motion
reads below their bins' width at the test torque (:mod:`reducer_twin.core.within_zone`)
and how many of those read 30 % low or more say it, those that say their lost motion
depends on how far the windows' loads reach (:mod:`reducer_twin.core.load_reach`), and
for the observed ones the lost motion's error against the generator's truth at the
recording's end (median, p90 and max of the absolute relative error; the share within
10 %) and where the true remaining life lies against the P10-P90 given (within, below,
above); with ``--verbose`` a line per run.

Usage::

    .venv/bin/python bench/bench_random_forms.py [--runs 40] [--seed0 5000] [--verbose]
"""

import argparse
from collections import Counter
import json
from pathlib import Path
import random
import shutil
import subprocess
import sys
import tempfile

import numpy as np

HERE = Path(__file__).resolve().parent
KINDS = ('base', 'shoulder', 'forearm', 'wrist')


def draw(seed):
    """Return ``(generator, its arguments)`` of run ``seed``."""
    r = random.Random(seed)
    gen = r.choice(['independent', 'third'])
    kinds = ','.join(r.sample(KINDS, r.randint(1, 3)))
    args = ['--seed', str(seed), '--kinds', kinds,
            '--hours', str(r.choice([20, 60, 150, 300])), '--aging-factor', '3600',
            '--start-fraction', str(round(r.uniform(0.05, 0.8), 2)),
            '--rate-hz', str(r.choice([100, 200, 250, 500, 1000, 2000])),
            '--layout', r.choice(['split', 'combined']),
            '--motor-angles', r.choice(['raw', 'output']),
            '--effort-on', r.choice(['link', 'motor'])]
    if r.random() < 0.2:
        args.append('--no-velocity')
    if r.random() < 0.3:
        args += ['--stamp-jitter-us', str(r.choice([0, 50, 300]))]
    return gen, args


def run_one(seed, work):
    """Write run ``seed``'s recording, analyse it; return its outcome."""
    gen, args = draw(seed)
    bag, out = work / f'bag{seed}', work / f'out{seed}'
    made = subprocess.run([sys.executable, str(HERE / f'{gen}_generator.py'), '--out', str(bag),
                           '--json', *args], capture_output=True, text=True)
    if made.returncode:
        raise RuntimeError(f'{gen} generator failed on seed {seed}: {made.stderr[-500:]}')
    truth = json.loads(made.stdout)['joints']
    done = subprocess.run([sys.executable, '-m', 'reducer_twin.cli', 'analyze', str(bag),
                           '--out', str(out), '--json'], capture_output=True, text=True)
    shutil.rmtree(bag, ignore_errors=True)
    shutil.rmtree(out, ignore_errors=True)
    outcome = {'gen': gen, 'args': ' '.join(args), 'exit': done.returncode, 'joints': {}}
    try:
        joints = json.loads(done.stdout)['joints']
    except (ValueError, KeyError):
        joints = None
    outcome['failed'] = (done.returncode not in (0, 3) or 'Traceback' in done.stderr
                         or joints is None)
    if outcome['failed']:
        outcome['stderr'] = done.stderr[-800:]
        return outcome
    for name, got in joints.items():
        true = truth[name]['lost_motion_end_arcmin']
        read = got.get('lost_motion_arcmin')
        life = truth[name]['remaining_life_end_h']
        p10, p90 = got.get('rul_p10_h'), got.get('rul_p90_h')
        outcome['joints'][name] = {
            'kind': truth[name]['kind'], 'observed': got['observed'],
            'error': None if read is None else read / true - 1.0,
            'reason': got.get('reason'),
            # Where the true remaining life lies against P10-P90: -1 below, 0 in, +1 above.
            'life': None if p10 is None or p90 is None else
            (-1 if life < p10 else 1 if life > p90 else 0),
            'contradictions': contradictions(got, limit=LIMIT_ARCMIN),
            # What comparing the width at the test torque found (a lost motion that is the
            # play of the loaded flanks, said, where 'unconfirmed' or 'not compared').
            'check': got.get('test_torque_check'),
            # Called worn out (no life left at all) where the truth has life left.
            'false_worn_out': p90 == 0.0 and life > 0.0,
            # Said that its lost motion reads below its bins' width at the test torque
            # (core/within_zone.py): loads that never leave a soft zone.
            'within_zone': any(WITHIN_ZONE in line for line in got.get('inputs') or ()),
            # Said that its lost motion depends on the windows' reach (core/load_reach.py).
            'load_reach': any(LOAD_REACH in line for line in got.get('inputs') or ())}
    return outcome


LIMIT_ARCMIN = 3.0
"""The twin's default lost-motion limit [arcmin] (``life.lost_motion_limit``)."""

WITHIN_ZONE = 'their extrapolation to no load'
"""A fragment of the line of :attr:`.within_zone.WithinZoneCheck.reason`."""

LOAD_REACH = "depends on how far the windows' loads reach"
"""A fragment of the line of :attr:`.load_reach.LoadReachCheck.reason`."""

LOW = -0.3
"""A lost motion read this far below the truth (relative) or more: the life far too long."""


def contradictions(got, limit):
    """
    Return what one joint's ``--json`` answer says against itself (empty: nothing).

    An observed joint without a lost motion or its standard deviation, a joint not
    observed without a reason, percentiles out of order, no life left at all (P90 0) beside
    a lost motion clearly below the limit, or life left (P10 above 0) beside one at or
    past it. Judged on the answer alone, not on the truth.
    """
    keys = ('lost_motion_arcmin', 'rul_p10_h', 'rul_p50_h', 'rul_p90_h')
    lm, p10, p50, p90 = (got.get(k) for k in keys)
    said = []
    if got.get('observed') and (lm is None or not got.get('lost_motion_std_arcmin')):
        said.append('observed without a lost motion and its sd')
    if not got.get('observed') and not got.get('reason'):
        said.append('not observed without a reason')
    if None not in (p10, p50, p90) and not p10 <= p50 <= p90:
        said.append(f'percentiles out of order ({p10:.0f} / {p50:.0f} / {p90:.0f} h)')
    if lm is not None and p90 is not None and lm < 0.9 * limit and p90 == 0.0:
        said.append(f'no life left at a lost motion of {lm:.2f} arcmin')
    if lm is not None and p10 is not None and lm >= limit and p10 > 0.0:
        said.append(f'P10 {p10:.0f} h at a lost motion of {lm:.2f} arcmin, past the limit')
    return said


def summary(outcomes, gen):
    """Print one generator's figures."""
    runs = [o for o in outcomes if o['gen'] == gen]
    failed = [o for o in runs if o['failed']]
    joints = [j for o in runs if not o['failed'] for j in o['joints'].values()]
    seen = [j for j in joints if j['observed'] and j['error'] is not None]
    reasons = Counter(' '.join((j['reason'] or 'no lost motion').split()[:6])
                      for j in joints if j not in seen)
    print(f'{gen} generator: {len(runs)} runs, {len(failed)} failed (exit other than 0/3, '
          f'a traceback or no JSON); {len(joints)} joints, {len(seen)} observed')
    if seen:
        err = np.abs([j['error'] for j in seen])
        print(f'  lost motion vs truth: median |rel| {100 * np.median(err):.1f} %, p90 '
              f'{100 * np.percentile(err, 90):.1f} %, max {100 * err.max():.0f} %; within '
              f'10 % {100 * np.mean(err <= 0.1):.0f} %')
        side = np.array([j['life'] for j in seen if j['life'] is not None])
        if side.size:
            print(f'  true remaining life within P10-P90: {100 * np.mean(side == 0):.0f} % '
                  f'(below P10 {100 * np.mean(side < 0):.0f} %, above P90 '
                  f'{100 * np.mean(side > 0):.0f} %; a recording of 20-300 h, no history)')
        for check in ('none found', 'soft zone', 'unconfirmed', 'not compared'):
            k = np.array([j['error'] for j in seen if j['check'] == check])
            if k.size:
                print(f'  test torque {check}: {k.size} joints, median |rel| '
                      f'{100 * np.median(np.abs(k)):.1f} %, signed {100 * np.median(k):+.1f} %')
        false = [(o['args'].split()[1], name, j) for o in runs if not o['failed']
                 for name, j in o['joints'].items()
                 if j['observed'] and j['error'] is not None and j['false_worn_out']]
        print(f'  called worn out with life left: {len(false)} ('
              f'{sum(j["check"] in ("unconfirmed", "not compared") for *_, j in false)} of '
              "them saying their lost motion may be the loaded flanks' play)")
        for seed, name, j in false:
            print(f'    seed {seed} {name} ({j["kind"]}): {100 * j["error"]:+.0f} %, test '
                  f'torque {j["check"]}')
        said = [j['error'] for j in seen if j['within_zone']]
        low = [j for j in seen if j['error'] <= LOW]
        print(f"  said to read below its bins' width at the test torque: {len(said)} joints"
              + (f', signed errors {", ".join(f"{100 * e:+.0f} %" for e in sorted(said))}'
                 if said else '')
              + f'; of the {len(low)} read {-100 * LOW:.0f} % low or more, '
              f'{sum(j["within_zone"] for j in low)} say it')
        reach = [j['error'] for j in seen if j['load_reach']]
        print("  said to depend on how far the windows' loads reach: "
              f'{len(reach)} joints'
              + (f', signed errors {", ".join(f"{100 * e:+.0f} %" for e in sorted(reach))}'
                 if reach else ''))
        for kind in KINDS:
            k = np.abs([j['error'] for j in seen if j['kind'] == kind])
            if k.size:
                print(f'    {kind}: {k.size} joints, median |rel| {100 * np.median(k):.1f} %, '
                      f'max {100 * k.max():.0f} %')
    for reason, count in reasons.most_common():
        print(f'  not observed ({count}): {reason} ...')
    odd = [(o['args'].split()[1], name, said) for o in runs if not o['failed']
           for name, j in o['joints'].items() for said in j['contradictions']]
    print(f'  answers that contradict themselves: {len(odd)}')
    for seed, name, said in odd:
        print(f'    seed {seed} {name}: {said}')
    for o in failed:
        print(f'  FAILED: {o["args"]} (exit {o["exit"]}): {o["stderr"]}')


def main():
    p = argparse.ArgumentParser(description=__doc__.split('\n\n')[0].strip())
    p.add_argument('--runs', type=int, default=40)
    p.add_argument('--seed0', type=int, default=5000)
    p.add_argument('--verbose', action='store_true', help='a line per run')
    args = p.parse_args()
    outcomes = []
    with tempfile.TemporaryDirectory(prefix='bench-forms-') as tmp:
        for seed in range(args.seed0, args.seed0 + args.runs):
            outcome = run_one(seed, Path(tmp))
            outcomes.append(outcome)
            if args.verbose:
                joints = ', '.join(
                    f'{j["kind"]} ' + (f'{100 * j["error"]:+.1f} %' if j['observed'] and
                                       j['error'] is not None else 'not observed')
                    for j in outcome['joints'].values())
                print(f'{seed} {outcome["gen"]} {outcome["args"]}: exit {outcome["exit"]}; '
                      f'{joints}', flush=True)
    for gen in ('independent', 'third'):
        summary(outcomes, gen)


if __name__ == '__main__':
    main()
