#!/usr/bin/env python3
"""
The effort check's slope ratio and its 1x allowance on recordings whose effort is known.

Prints, per joint, the median over the judged windows of the slope ratio (the width's
growth with ``2·|T|`` against the model's series compliance, 1 for the torque itself),
of the share an unidentified 1x error of the output angle of up to
``FIRST_ORDER_ALLOWANCE_RAD`` could have taken off it, and of their sum, and what the
twin decided. Recordings: the model's simulator (2 joints, 200 h in 200 s at 1 kHz) read
with its effort times 1, 5, 10 and 0.1 (``effort_scale``: the same as a drive reporting
the effort in other units), and the third generator's robot of seed 1007, whose forearm
(35 arcsec of link eccentricity under 178 N*m of gravity) was refused as an effort 4.2
times the torque before the allowance.

The figures are read from ``EffortCheck._window``'s arguments (wrapped here).

Usage (from the checkout)::

    PYTHONPATH=$PWD:$PWD/bench .venv/bin/python bench/bench_effort_check.py
"""

from dataclasses import replace
from pathlib import Path
import tempfile

import numpy as np
from reducer_twin.analysis.pipeline import analyze_bag
from reducer_twin.analysis.settings import AnalysisSettings
from reducer_twin.analysis.simulate import simulate_bag, SimulationSpec
from reducer_twin.core import effort_check
import third_generator

AGING = 3600.0


def _recorded():
    """Wrap the effort check's per-window step; return the list it fills per analyzer."""
    seen = {}
    step = effort_check.EffortCheck._window

    def recording(self, level, slope, share, offset):
        seen.setdefault(id(self), []).append((slope, share))
        return step(self, level, slope, share, offset)
    effort_check.EffortCheck._window = recording
    return seen


def report(label, bag, out, settings, seen, joints):
    """Analyse one recording, a joint at a time; print each joint's medians and verdict."""
    for name in joints:
        seen.clear()
        joint = analyze_bag(bag, out, replace(settings, joints=(name,)),
                            overwrite=True).joints[name]
        a = np.array([w for windows in seen.values() for w in windows]).reshape(-1, 2)
        judged = a[np.isfinite(a[:, 0])]
        said = joint.summary()['reason'] or 'read'
        if not judged.size:
            print(f'{label:28s} {name}: no judged window; {said[:60]}')
            continue
        print(f'{label:28s} {name}: {len(judged):2d} windows, ratio '
              f'{np.median(judged[:, 0]):6.3f}, share {np.median(judged[:, 1]):6.3f}, '
              f'ratio + share {np.median(judged.sum(axis=1)):6.3f} '
              f'(windows {judged.sum(axis=1).min():.2f}..{judged.sum(axis=1).max():.2f}); '
              f'{said[:60]}')


def main():
    """Run the recordings and print the figures."""
    seen = _recorded()
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        simulate_bag(tmp / 'model', SimulationSpec(hours=200.0, aging_factor=AGING, joints=2,
                                                   seed=7, wear_rate_scales=(10.0, 5.0)))
        for scale in (1.0, 5.0, 10.0, 0.1):
            report(f'model simulator, effort x{scale:g}', tmp / 'model', tmp / 'out',
                   AnalysisSettings(aging_factor=AGING, effort_scale=scale), seen,
                   ('joint_1', 'joint_2'))
        seed = 1007
        spec = third_generator.Spec(
            seed=seed, kinds=('base', 'shoulder', 'forearm'), hours=150.0 / 3600.0,
            aging_factor=1.0, layout='split',
            start_fraction=float(np.random.default_rng([seed, 7]).uniform(0.05, 0.8)))
        third_generator.generate_bag(spec, tmp / 'third')
        report(f'third generator, seed {seed}', tmp / 'third', tmp / 'out',
               AnalysisSettings(), seen, ('joint_1', 'joint_2', 'joint_3'))


if __name__ == '__main__':
    main()
