"""
TE extraction and lost-motion recovery on the joint simulator, and throughputs.

For a few seeds, wears and profiles, simulates a joint at fixed wear
(aging 0), extracts the TE with :func:`compute_te` and analyses it with
:class:`WindowAnalyzer`, then prints:

* the TE extraction error against the simulator's true TE, RMS after the
  constant encoder offset is removed, (a) with the link encoder's time
  offset given to ``compute_te`` and (b) with it left out and the fitted
  ``omega·delta`` term removed afterwards;
* the median lost motion of the windows against the truth, its spread over
  windows and the median reported standard error (a clipped fit at zero
  wear can only err upwards);
* the simulator's throughput (exact and tabulated mesh) and the extraction
  throughput (``compute_te`` plus the analyzer) on 1,000,000 samples.

Prints figures; asserts nothing.

Run: ``.venv/bin/python bench/bench_te_extraction.py [--samples N] [--fast]``
"""

import argparse
import os
import time

# One core: BLAS/OpenMP thread pools must be sized before numpy is imported.
for _var in ('OMP_NUM_THREADS', 'OPENBLAS_NUM_THREADS', 'MKL_NUM_THREADS'):
    os.environ[_var] = '1'

import numpy as np  # noqa: E402
from reducer_twin.core.params import ReducerParams  # noqa: E402
from reducer_twin.core.simulator import JointSimulator, SimConfig  # noqa: E402
from reducer_twin.core.te_extraction import compute_te  # noqa: E402
from reducer_twin.core.transmission_error import lost_motion, model_tables  # noqa: E402
from reducer_twin.core.units import ARCMIN, ARCSEC, UM  # noqa: E402
from reducer_twin.core.window_analysis import WindowAnalyzer  # noqa: E402

CASES = (('robot', 'gravity'), ('paper', 'gravity'), ('paper', 'constant'))
WEARS = (0.0, 5e-6, 10e-6, 20e-6, 30e-6)   # m
SEEDS = (1, 2, 3)


def rms_without_offset(err):
    """Return the RMS of ``err`` after removing its mean (NaNs ignored) [same unit]."""
    err = err[np.isfinite(err)]
    return float(np.sqrt(np.mean((err - err.mean()) ** 2)))


def recovery(params, profile, load, wear, seed, samples, exact):
    """
    Simulate at fixed wear and compare extraction with the truth.

    Returns
    -------
    dict
        TE errors [rad], lost motion truth / median / spread / reported std [rad].

    """
    cfg = SimConfig(profile=profile, load=load, initial_wear_m=wear, aging_factor=0.0,
                    seed=seed, exact_mesh=exact, link_zero_offset_rad=0.2 * seed)
    sim = JointSimulator(params, cfg)
    b = sim.step(samples)
    known = compute_te(b.t, b.motor_angle, b.t, b.link_angle, sim.ratio,
                       link_time_offset_s=cfg.time_offset_s)
    blind = compute_te(b.t, b.motor_angle, b.t, b.link_angle, sim.ratio)
    analyzer = WindowAnalyzer(params)
    feats = analyzer.update(blind, b.effort, b.link_velocity) + analyzer.flush()
    delta = finite_stat(np.median, [f.time_offset_s for f in feats])
    fitted = blind.te - (0.0 if np.isnan(delta) else delta) * b.link_velocity
    lm = np.array([f.lost_motion for f in feats])
    std = np.array([f.lost_motion_std for f in feats])
    ok = np.isfinite(lm)
    return {
        'te_known': rms_without_offset(known.te - b.true_te),
        'te_fitted': rms_without_offset(fitted - b.true_te),
        'delta': delta,
        'lm_true': lost_motion(wear, params),
        'lm_median': finite_stat(np.median, lm),
        'lm_spread': finite_stat(np.std, lm) if ok.sum() > 1 else np.nan,
        'lm_std': finite_stat(np.median, std[ok]),
        'windows': len(feats), 'usable': int(ok.sum()),
    }


def finite_stat(fn, values):
    """Apply ``fn`` to the finite values, NaN when there are none."""
    values = np.asarray(values, dtype=float)
    values = values[np.isfinite(values)]
    return float(fn(values)) if values.size else np.nan


def throughput(fn, n):
    """Return samples per second of the best of three calls of ``fn`` (``n`` samples each)."""
    best = np.inf
    for _ in range(3):
        start = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - start)
    return n / best


def main():
    """Print the figures."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--samples', type=int, default=60_000,
                        help='samples per recovery case (default 60000 = 60 s at 1 kHz)')
    parser.add_argument('--fast', action='store_true',
                        help='tabulated mesh in the recovery cases (default: exact mesh)')
    args = parser.parse_args()
    params = ReducerParams()
    model_tables(params)

    print(f'TE extraction and lost-motion recovery, {args.samples} samples per case, '
          f'{"tabulated" if args.fast else "exact"} mesh, seeds {SEEDS}')
    print(f'{"profile":>8} {"load":>8} {"wear um":>7} | {"TE err (arcsec RMS)":>20} | '
          f'{"delta us":>8} | {"LM true":>7} {"LM med":>7} {"err %":>6} {"spread":>6} '
          f'{"rep.std":>7} (arcmin) | windows usable')
    worst_te, worst_lm = 0.0, 0.0
    for profile, load in CASES:
        for wear in WEARS:
            rows = [recovery(params, profile, load, wear, seed, args.samples, not args.fast)
                    for seed in SEEDS]
            te_k = max(r['te_known'] for r in rows) / ARCSEC
            te_f = max(r['te_fitted'] for r in rows) / ARCSEC
            worst_te = max(worst_te, te_k, te_f)
            lm_true = rows[0]['lm_true']
            med = np.array([r['lm_median'] for r in rows])
            err = np.abs(100.0 * (med - lm_true) / lm_true)
            worst_lm = max(worst_lm, finite_stat(np.max, err) if np.isfinite(err).any() else 0.0)
            print(f'{profile:>8} {load:>8} {wear / UM:7.1f} | known {te_k:5.2f} '
                  f'fitted {te_f:5.2f} | '
                  f'{finite_stat(np.median, [r["delta"] for r in rows]) * 1e6:8.2f} | '
                  f'{lm_true / ARCMIN:7.3f} {finite_stat(np.median, med) / ARCMIN:7.3f} '
                  f'{finite_stat(np.max, err):6.2f} '
                  f'{finite_stat(np.mean, [r["lm_spread"] for r in rows]) / ARCMIN:6.3f} '
                  f'{finite_stat(np.mean, [r["lm_std"] for r in rows]) / ARCMIN:7.3f} | '
                  f'{sum(r["windows"] for r in rows):5d} {sum(r["usable"] for r in rows):5d}')
    print(f'worst TE extraction error {worst_te:.2f} arcsec RMS (target <= 1); worst lost-motion '
          f'error (median of windows, per seed) {worst_lm:.2f} % (target: a few %)')

    n = 1_000_000
    for exact in (False, True):
        count = n if not exact else 200_000
        rate = throughput(lambda: JointSimulator(
            params, SimConfig(exact_mesh=exact, aging_factor=3600.0)).step(count), count)
        print(f'simulator, {"exact" if exact else "tabulated"} mesh: {rate / 1e6:.2f} M samples/s '
              f'({6 * 1000 / rate * 100:.2f} % of a core for 6 joints at 1 kHz)')
    sim = JointSimulator(params, SimConfig(exact_mesh=False, aging_factor=3600.0))
    b = sim.step(n)

    def extract():
        stream = compute_te(b.t, b.motor_angle, b.t, b.link_angle, sim.ratio)
        analyzer = WindowAnalyzer(params, aging_factor=3600.0)
        analyzer.update(stream, b.effort, b.link_velocity)
        analyzer.flush()

    te_rate = throughput(lambda: compute_te(b.t, b.motor_angle, b.t, b.link_angle, sim.ratio), n)
    print(f'compute_te: {te_rate / 1e6:.2f} M samples/s')
    rate = throughput(extract, n)
    print(f'compute_te + WindowAnalyzer (robot profile, 2 s windows): {rate / 1e6:.2f} M samples/s'
          f' = {n / rate:.2f} s per 1,000,000 samples')


if __name__ == '__main__':
    main()
