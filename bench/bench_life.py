"""
Time the remaining-life sampler and one estimator step; print the figures.

A script, not a test: nothing is asserted. Run with
``.venv/bin/python bench/bench_life.py``.
"""

from dataclasses import dataclass
import math
import time

import numpy as np

from reducer_twin.core import wear
from reducer_twin.core.estimator import WearEstimator
from reducer_twin.core.life import remaining_life
from reducer_twin.core.params import ReducerParams
from reducer_twin.core.transmission_error import model_tables
from reducer_twin.core.units import ARCMIN, HOUR


@dataclass(frozen=True)
class Duty:
    """The two duty fields the estimator reads."""

    exposure_s: float
    archard_increment: float


@dataclass(frozen=True)
class Features:
    """The window fields the estimator reads."""

    t_end: float
    lost_motion: float
    lost_motion_std: float
    duty: Duty


def best_of(fn, repeat):
    """Return the smallest wall time of ``repeat`` calls of ``fn`` [s]."""
    best = math.inf
    for _ in range(repeat):
        start = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - start)
    return best


def main():
    """Print the timings."""
    params = ReducerParams()
    start = time.perf_counter()
    model_tables(params)
    print(f'model tables (once per parameter set): {time.perf_counter() - start:.2f} s')
    rate = float(wear.wear_rate(params.rating.rated_torque, wear.reference_speed(params), 0.0,
                                params))
    x = np.array([5e-6, 0.0])
    P = np.array([[1e-12, 2e-8], [2e-8, 0.09]])
    remaining_life((x, P), rate, params)  # warm caches
    for n in (1000, 2000, 10000):
        seconds = best_of(lambda: remaining_life((x, P), rate, params, n_samples=n), 50)
        life = remaining_life((x, P), rate, params, n_samples=n)
        print(f'remaining_life n_samples={n:6d}: {seconds * 1e3:7.3f} ms '
              f'(p10/p50/p90 = {life.p10 / HOUR:.0f}/{life.p50 / HOUR:.0f}/'
              f'{life.p90 / HOUR:.0f} h)')
    est = WearEstimator(params)
    z = float(model_tables(params).lost_motion(0.0))
    features = Features(0.0, z, 0.05 * ARCMIN, Duty(10.0 * HOUR, rate * 10.0 * HOUR))
    seconds = best_of(lambda: est.step(features), 200)
    print(f'WearEstimator.step (predict + update): {seconds * 1e3:.3f} ms')


if __name__ == '__main__':
    main()
