"""
Accuracy of the twin against simulated joints whose true wear is known.

For every seed and hidden wear-rate scale (the estimator always starts from
scale 1), one robot joint is simulated over its whole life to the 3 arcmin
lost-motion limit (the aging factor is chosen so a life spans about 150
windows of 2 s of stream) and run through the same core stages the nodes and
the bag analysis use: TE extraction, window analysis, Kalman filter,
remaining life. Printed figures (issue floors in brackets):

* wear estimate relative error after 25 % of life, median and worst [<= 10 %];
* alpha-lambda accuracy (Saxena et al. 2010, alpha = 0.2) of the P50 at
  lambda = 0.5 and 0.75 [>= 95 % of runs];
* P10-P90 coverage of the true remaining life over all evaluations [>= 80 %];
* prognostic horizon and cumulative relative accuracy;
* TE extraction error against the simulator's true TE [<= 1 arcsec RMS].

Usage: ``python bench/bench_accuracy.py [--seeds 20] [--scales 0.5,1,2]``
"""

import argparse
import os
import time

os.environ.setdefault('OMP_NUM_THREADS', '1')
os.environ.setdefault('OPENBLAS_NUM_THREADS', '1')

import numpy as np  # noqa: E402
from reducer_twin.core.kinematics import total_ratio  # noqa: E402
from reducer_twin.core.metrics import alpha_lambda, cumulative_relative_accuracy  # noqa: E402
from reducer_twin.core.metrics import interval_coverage, prognostic_horizon  # noqa: E402
from reducer_twin.core.params import ReducerParams  # noqa: E402
from reducer_twin.core.pipeline import EstimatorStage, LifeStage  # noqa: E402
from reducer_twin.core.pipeline import TimeOffsetCalibration  # noqa: E402
from reducer_twin.core.simulator import JointSimulator, SimConfig  # noqa: E402
from reducer_twin.core.te_extraction import TEExtractor, WindowAnalyzer  # noqa: E402
from reducer_twin.core.units import ARCSEC, HOUR  # noqa: E402

WINDOW_S = 2.0
LOAD_NM = 1.2 * 784.0
"""Gravity-load amplitude of the benchmark joint: a heavily loaded robot axis."""


def simulate_life(params, seed, scale, windows=150, rate_hz=500.0):
    """
    Run one joint through its life; return per-window records and TE errors.

    Parameters
    ----------
    params : ReducerParams
        Reducer parameters.
    seed : int
        Simulator seed.
    scale : float
        Hidden multiplier on the Archard rate.
    windows : int
        Windows of ``WINDOW_S`` that one life spans.
    rate_hz : float
        Encoder rate [Hz].

    Returns
    -------
    tuple
        ``(records, eol_s, te_rms)``: a dict of arrays per window, the true
        end of life [s of operation] and the TE extraction error [rad RMS].

    """
    base = {'profile': 'robot', 'load': 'gravity', 'load_torque_nm': LOAD_NM,
            'rate_hz': rate_hz, 'wear_rate_scale': scale, 'seed': seed, 'exact_mesh': False}
    eol = JointSimulator(params, SimConfig(**base)).truth().limit_time_s
    aging = eol / (windows * WINDOW_S)
    sim = JointSimulator(params, SimConfig(**base, aging_factor=aging))
    extractor = TEExtractor(total_ratio(params.geometry))
    calibration = TimeOffsetCalibration(extractor)
    analyzer = WindowAnalyzer(params, window_s=WINDOW_S, aging_factor=aging)
    est = EstimatorStage(params)
    life = LifeStage(params)
    rows = []
    te_err = []
    stream_end = 1.05 * windows * WINDOW_S
    n_chunk = int(rate_hz)
    while sim.time_s < stream_end:
        b = sim.step(n_chunk)
        stream = extractor.update(b.t, b.motor_angle, b.t, b.link_angle)
        if len(rows) >= 10 and len(te_err) < 20:
            # TE of the extraction vs truth once the encoder time offset is learnt,
            # the constant (encoder zero) offset removed.
            d = (stream.te - b.true_te)[stream.valid]
            te_err.append(d - d.mean())
        for f in analyzer.update(stream, b.effort, b.link_velocity):
            calibration.observe(f)
            est.process(f)
            life.observe_duty(f.duty)
            record, _, _ = life.process(est.record(f.t_end))
            t_op = f.t_end * aging
            rows.append((t_op, est.estimator.wear, est.estimator.wear_std,
                         float(np.interp(f.t_end, b.t, b.true_wear)), record['p10_s'],
                         record['p50_s'], record['p90_s'], eol - t_op))
    cols = np.array(rows)
    names = ('t', 'wear', 'wear_std', 'true_wear', 'p10', 'p50', 'p90', 'true_rul')
    rec = {k: cols[:, i] for i, k in enumerate(names)}
    te_rms = float(np.sqrt(np.mean(np.concatenate(te_err) ** 2)))
    return rec, eol, te_rms


def evaluate(rec, eol):
    """
    Compute the accuracy figures of one run.

    Parameters
    ----------
    rec : dict
        Output of :func:`simulate_life`.
    eol : float
        True end of life [s].

    Returns
    -------
    dict
        ``wear_err_25``, ``al_50``, ``al_75``, ``covered``, ``evaluations``,
        ``ph_frac``, ``cra``.

    """
    before = rec['t'] < eol
    t, p50, true = rec['t'][before], rec['p50'][before], rec['true_rul'][before]
    k25 = int(np.searchsorted(rec['t'], 0.25 * eol))
    err25 = abs(rec['wear'][k25] - rec['true_wear'][k25]) / rec['true_wear'][k25]
    start = t >= 0.1 * eol
    ts, ps, trs = t[start], p50[start], true[start]
    # Alpha-lambda from the start of life: t_lambda = lambda * EOL.
    t0 = np.concatenate([[0.0], ts])
    p0 = np.concatenate([[np.nan], ps])
    r0 = np.concatenate([[eol], trs])
    lower, upper = rec['p10'][before][start], rec['p90'][before][start]
    n_covered = int(round(interval_coverage(trs, lower, upper) * trs.size))
    return {'wear_err_25': err25,
            'al_50': alpha_lambda(t0, p0, r0, 0.5), 'al_75': alpha_lambda(t0, p0, r0, 0.75),
            'covered': n_covered, 'evaluations': int(trs.size),
            'ph_frac': prognostic_horizon(ts, ps, trs) / eol,
            'cra': cumulative_relative_accuracy(ts, ps, trs)}


def main():
    """Run every seed and scale and print the figures."""
    ap = argparse.ArgumentParser(description='accuracy of wear and remaining-life estimates')
    ap.add_argument('--seeds', type=int, default=20)
    ap.add_argument('--scales', default='0.5,1,2')
    ap.add_argument('--windows', type=int, default=150)
    args = ap.parse_args()
    params = ReducerParams()
    scales = [float(s) for s in args.scales.split(',')]
    start = time.perf_counter()
    results = {s: [] for s in scales}
    te_rms = []
    for scale in scales:
        for seed in range(args.seeds):
            rec, eol, rms = simulate_life(params, seed, scale, windows=args.windows)
            te_rms.append(rms)
            results[scale].append((evaluate(rec, eol), eol))
    print(f'accuracy over {args.seeds} seeds x scales {scales} (estimator starts at scale 1; '
          f'robot joint, gravity load {LOAD_NM:.0f} N*m, {args.windows} windows per life; '
          f'{time.perf_counter() - start:.0f} s)')
    all_rows = [r for rows in results.values() for r, _ in rows]
    for scale, rows in results.items():
        ev = [r for r, _ in rows]
        errs = np.array([r['wear_err_25'] for r in ev])
        print(f'  scale {scale:g}: EOL {np.mean([e for _, e in rows]) / HOUR:,.0f} h; '
              f'wear error at 25 % life median {np.median(errs) * 100:.1f} %, worst '
              f'{errs.max() * 100:.1f} %; alpha-lambda 0.5: '
              f'{np.mean([r["al_50"] for r in ev]) * 100:.0f} %, 0.75: '
              f'{np.mean([r["al_75"] for r in ev]) * 100:.0f} %; P10-P90 coverage '
              f'{sum(r["covered"] for r in ev) / sum(r["evaluations"] for r in ev) * 100:.0f} %')
    errs = np.array([r['wear_err_25'] for r in all_rows])
    al50 = np.mean([r['al_50'] for r in all_rows])
    al75 = np.mean([r['al_75'] for r in all_rows])
    cover = sum(r['covered'] for r in all_rows) / sum(r['evaluations'] for r in all_rows)
    te = np.array(te_rms) / ARCSEC
    print(f'  wear relative error after 25 % of life: median {np.median(errs) * 100:.1f} %, '
          f'worst {errs.max() * 100:.1f} %  [floor <= 10 %]')
    print(f'  alpha-lambda (alpha 0.2) of P50: lambda 0.5 in {al50 * 100:.0f} %, lambda 0.75 in '
          f'{al75 * 100:.0f} % of runs  [floor >= 95 %]')
    print(f'  P10-P90 covers the true remaining life in {cover * 100:.0f} % of '
          f'{sum(r["evaluations"] for r in all_rows)} evaluations  [floor >= 80 %]')
    print(f'  prognostic horizon (alpha 0.2, staying inside): median '
          f'{np.median([r["ph_frac"] for r in all_rows]) * 100:.0f} % of life; cumulative '
          f'relative accuracy median {np.median([r["cra"] for r in all_rows]):.3f}')
    print(f'  TE extraction error vs true TE: median {np.median(te):.3f} arcsec RMS, worst '
          f'{te.max():.3f} arcsec RMS  [floor <= 1 arcsec]')


if __name__ == '__main__':
    main()
