"""
Accuracy of the twin's wear and remaining-life estimates against two generators.

Two sources of truth, neither tuned to the other:

* ``model``: the project's own joint simulator (:mod:`reducer_twin.core.simulator`),
  whose wear follows the twin's Archard law and whose lost motion follows the
  twin's mesh model. Per run a truth is drawn at random: the as-built lost
  motion (0.3-1.0 arcmin, as an equidistant-modification offset), the hidden
  rate scale (log-uniform 0.25-4), the duty (gravity load 0.5-1.4 of rated,
  peak speed 45-120 deg/s) and the effort noise (0.25-3 % of rated torque).
* ``independent``: ``bench/independent_generator.py``, which shares nothing with
  the twin: per-unit new lost motion (0.3-1.0 arcmin) and stiffness (+-15 %),
  lost motion linear or concave in its own Archard-like exposure (torque
  exponent 1-2.5), its own duty cycle and joint kinds, effort noise 1-5 % of
  rated, no run-in. Its truth has no wear, so its "wear" figures are those of
  the estimated lost motion.
* ``third`` (``--generators third``): ``bench/third_generator.py``, unlike both:
  a catalogue torsional curve (soft zone to a knee torque, hysteresis loss),
  efficiency-dependent effort, exposure as sliding distance times pin load,
  run-in plus linear growth with a contamination step, a random (not periodic)
  duty, encoder eccentricity and dropped messages. Drawn like the independent
  truths; its life ends where its own stream's lost motion reaches the limit.
  Printed per joint kind as whole cases.

Every run covers a whole life (to 3 arcmin) in ``--windows`` windows of 2 s of
stream (the aging factor is chosen for it) and goes through the core stages the
nodes and the bag analysis use: TE extraction, window analysis, Kalman filter,
remaining life. Evaluations are the windows between 25 % and 75 % of life.
Three fixed cases go with them: units 3 um looser and 2 um tighter than
nominal (model generator; RUL P50 at 60 % of life) and a used unit (2-10 um of
wear, aging factor 1) met by a twin without state (wear after 20 usable
windows). And per generator, twins met without state part-way through each
observed life (25, 50, 75 %), judged after 10 % and 30 % more of it: the
remaining life of a reducer installed on a robot that has run for years.

Printed per case (issue floors in brackets): wear error (lost motion on the
independent generator), NEES [0.5, 2], NIS, alpha-lambda (alpha 0.2) at lambda
0.5 and 0.75 [>= 95 % model, >= 80 % independent], P10-P90 coverage and both
tails [80 +- 5 %, 10 +- 5 % each], the calibration histogram (where the true RUL
falls among the predicted deciles, 10 % each when calibrated), RUL P50 within
30 % at 60 % of life [>= 90 % of runs]; for the independent generator also per
joint kind and per growth law of the truth (lost motion linear or concave in the
exposure: the total can hide two one-sided tails of opposite sign). Each
generator is run a second time with every usable window's lost motion replaced
by the truth plus 0.02 arcmin ("read right"): it tells the estimator's share of
an error from the window analysis's.

A run whose windows give a lost motion fewer than ``MIN_OBSERVED`` times is one
the twin reports as not observed (a wrist whose load hardly ever passes the
lost-motion test torque on one side): such runs are listed and the case is
printed twice, with them counted as misses and without them; the floors
apply to the runs the twin observed. ``--independent-truths`` (32) draws
enough that 20+ are observed. ``--windows`` sets the data density: a real
twin sees thousands of windows per life, the default 120 are few, and the
white part of the window noise averages down with more (README: figures at
120 and 480).

Generated windows are cached (``--cache``), so the estimator can be compared
before and after a change on the same windows. About 35 s of CPU for 24 truths
per generator (and 3 s per new as-built geometry the first time its mesh table
is built).

Usage: ``python bench/bench_accuracy.py [--truths 24] [--independent-truths 32]
[--windows 120] [--cache DIR]
[--estimator key=value,...] [--no-oracle] [--skip-fixed] [--branches] [--json FILE]``

``--branches`` adds each model's remaining life alone (the growth law's weight forced to 0
and to 1): where the interval's misses come from.
"""

import argparse
from dataclasses import asdict, dataclass, replace
import hashlib
import json
import math
import os
from pathlib import Path
import sys
import time

os.environ.setdefault('OMP_NUM_THREADS', '1')
os.environ.setdefault('OPENBLAS_NUM_THREADS', '1')
sys.path.insert(0, str(Path(__file__).resolve().parent))

import independent_generator as indep  # noqa: E402
import numpy as np  # noqa: E402
from reducer_twin.core.estimator import EstimatorConfig  # noqa: E402
from reducer_twin.core.joint_twin import TwinConfig, TwinFront  # noqa: E402
from reducer_twin.core.life import remaining_life  # noqa: E402
from reducer_twin.core.metrics import alpha_lambda  # noqa: E402
from reducer_twin.core.params import ReducerParams  # noqa: E402
from reducer_twin.core.pipeline import EstimatorStage, features_from_record  # noqa: E402
from reducer_twin.core.pipeline import LifeStage, state_from_record  # noqa: E402
from reducer_twin.core.simulator import JointSimulator, SimConfig  # noqa: E402
from reducer_twin.core.state_space import lost_motion_curve  # noqa: E402
from reducer_twin.core.transmission_error import model_tables  # noqa: E402
from reducer_twin.core.units import ARCMIN, HOUR, UM  # noqa: E402
from reducer_twin.msg_adapters.layouts import TE_FEATURES  # noqa: E402
import third_generator as third  # noqa: E402

WINDOW_S = 2.0
RATE_HZ = 500.0
EVAL_RANGE = (0.25, 0.75)
"""Share of life over which the estimates are evaluated."""

MIN_OBSERVED = 5
"""Usable windows over a life below which a run counts as not observed."""

GENERATOR_VERSION = 4
"""
Bump when the generation below changes, so cached windows are not reused.

4: the windows carry the width at the test torque (``soft_zone_width_rad``), and a soft
zone's bins at the test torque wait for the stream's first far line.

3: the windows carry the soft zone's shortfall (``soft_zone_shortfall_rad``).

2: the windows come from the twin's own front (:func:`_front`), whose extractor bridges
gaps of up to 50 ms as ``analyze`` and the nodes do; version 1 built its own with 5 ms,
which cut the third generator's streams (0-1 % of messages dropped) at other places.
"""


# --------------------------------------------------------------------------- truths


@dataclass(frozen=True)
class Truth:
    """
    One drawn reducer, its duty and the generator that makes it.

    Attributes
    ----------
    generator : str
        ``'model'``, ``'independent'`` or ``'third'``.
    seed : int
        Seed of the draw and of the noise.
    rate_scale : float
        Hidden multiplier on the Archard rate (model generator).
    as_built_m : float
        Offset of the equidistant modification from nominal [m] (model generator):
        a unit built that much looser, as if it had worn that much.
    load_fraction : float
        Gravity-load amplitude over rated torque (model generator).
    peak_speed_rad_s : float
        Peak output speed (model generator) [rad/s].
    effort_noise_fraction : float
        Effort noise over rated torque (model generator; the independent one draws its own).
    initial_wear_m : float
        Wear when the recording starts [m] (model generator).
    kind : str
        Joint kind (independent generator).
    windows : int
        Windows of 2 s over which the life passes (or the windows recorded, used unit).
    aging : float or None
        Aging factor; None: chosen so that a life spans ``windows`` windows.

    """

    generator: str
    seed: int
    rate_scale: float = 1.0
    as_built_m: float = 0.0
    load_fraction: float = 1.2
    peak_speed_rad_s: float = math.radians(90.0)
    effort_noise_fraction: float = 0.0025
    initial_wear_m: float = 0.0
    kind: str = ''
    windows: int = 120
    aging: float = None

    def key(self):
        """Return a file name for the cached windows of this truth."""
        versions = [GENERATOR_VERSION] + ([third.VERSION] if self.generator == 'third' else [])
        text = json.dumps([*versions, asdict(self)], sort_keys=True)
        return hashlib.sha256(text.encode()).hexdigest()[:20]


def as_built_offset(lost_motion_new, params):
    """Return the modification offset [m] of a unit whose new lost motion is given [rad]."""
    curve = lost_motion_curve(params)
    lm = curve(np.linspace(-3e-6, 20e-6, 2301))
    return float(np.interp(lost_motion_new, lm, np.linspace(-3e-6, 20e-6, 2301)))


def draw_model_truths(n, seed, windows, params):
    """Draw ``n`` truths of the model generator (as-built, rate, duty, noise)."""
    rng = np.random.default_rng([seed, 1])
    out = []
    for k in range(n):
        lm_new = rng.uniform(0.3, 1.0) * ARCMIN
        out.append(Truth(
            'model', seed=1000 * seed + k, rate_scale=float(math.exp(rng.uniform(
                math.log(0.25), math.log(4.0)))),
            as_built_m=round(as_built_offset(lm_new, params) / 1e-8) * 1e-8,
            load_fraction=float(rng.uniform(0.5, 1.4)),
            peak_speed_rad_s=float(math.radians(rng.uniform(45.0, 120.0))),
            effort_noise_fraction=float(rng.uniform(0.0025, 0.03)), windows=windows))
    return out


def draw_independent_truths(n, seed, windows, generator='independent'):
    """Draw ``n`` truths of the independent or the third generator (each draws its unit)."""
    rng = np.random.default_rng([seed, 2 if generator == 'independent' else 3])
    return [Truth(generator, seed=1000 * seed + k, kind=str(rng.choice(indep.KINDS)),
                  windows=windows) for k in range(n)]


# --------------------------------------------------------------------------- generation


@dataclass
class Run:
    """
    Windows of one life and their truth.

    Attributes
    ----------
    truth : Truth
        What was drawn.
    records : ndarray, shape (W, fields)
        ``te_features`` records of the windows.
    t_end : ndarray
        Operating seconds at each window's end [s].
    eol : float
        Operating seconds at the end of life [s] (from the stream start).
    wear, lost_motion : ndarray
        True wear [m] (NaN for the independent generator) and lost motion [rad] at
        each window's end.
    wear_mid : ndarray
        True wear at each window's middle [m].

    """

    truth: Truth
    records: np.ndarray
    t_end: np.ndarray
    eol: float
    wear: np.ndarray
    lost_motion: np.ndarray
    wear_mid: np.ndarray


def _model_params(truth, params):
    if truth.as_built_m == 0.0:
        return params
    g = params.geometry
    return params.with_overrides(
        {'geometry.equidistant_modification': g.equidistant_modification + truth.as_built_m})


def _front(params, aging):
    """
    Return the twin's front (TE extraction, time-offset calibration, window analysis).

    The one the nodes and ``analyze`` run (:class:`.joint_twin.TwinFront`), with the bags'
    window length and this life's aging; the generators' encoders come as two streams,
    so their samples go to its extractor directly rather than paired.
    """
    return TwinFront(params, TwinConfig(window_s=WINDOW_S, aging_factor=aging))


def simulate_model(truth, params):
    """Run one model-generator life through the TE extraction and window analysis."""
    true_params = _model_params(truth, params)
    base = {'profile': 'robot', 'load': 'gravity',
            'load_torque_nm': truth.load_fraction * params.rating.rated_torque,
            'peak_speed_rad_s': truth.peak_speed_rad_s, 'rate_hz': RATE_HZ,
            'wear_rate_scale': truth.rate_scale, 'seed': truth.seed, 'exact_mesh': False,
            'effort_noise_nm': truth.effort_noise_fraction * params.rating.rated_torque,
            'initial_wear_m': truth.initial_wear_m}
    if truth.aging is None:
        eol1 = JointSimulator(true_params, SimConfig(**base)).truth().limit_time_s
        aging = eol1 / (truth.windows * WINDOW_S)
    else:
        aging = truth.aging
    sim = JointSimulator(true_params, SimConfig(**base, aging_factor=aging))
    eol = sim.truth().limit_time_s
    lm_true = model_tables(true_params).lost_motion
    front = _front(params, aging)
    stream_end = (1.02 * eol / aging) if truth.aging is None else truth.windows * WINDOW_S
    rows, t_end, wear, wear_mid = [], [], [], []
    t_hist, w_hist = [np.zeros(0)], [np.zeros(0)]
    while sim.time_s < stream_end:
        b = sim.step(int(RATE_HZ))
        t_hist = [t_hist[-1][-2 * int(RATE_HZ) * 20:], b.t]
        w_hist = [w_hist[-1][-2 * int(RATE_HZ) * 20:], b.true_wear]
        tt, ww = np.concatenate(t_hist), np.concatenate(w_hist)
        t_hist, w_hist = [tt], [ww]
        stream = front.extractor.update(b.t, b.motor_angle, b.t, b.link_angle)
        for f in front.analyze(stream, b.effort, b.link_velocity):
            rows.append([front.record(f)[k] for k in TE_FEATURES.fields])
            t_end.append(f.t_end * aging)
            wear.append(float(np.interp(f.t_end, tt, ww)))
            wear_mid.append(float(np.interp(0.5 * (f.t_start + f.t_end), tt, ww)))
    wear = np.array(wear)
    return Run(truth, np.array(rows), np.array(t_end), eol, wear, lm_true(wear),
               np.array(wear_mid))


def _window_ends(s, params, aging, link_kept=None, motor_kept=None):
    """
    Walk a generator's stream through the TE extraction and window analysis.

    Parameters
    ----------
    s : stream
        One joint's stream (``link_stamp_ns``, ``motor_stamp_ns``, ``link``, ``motor``,
        ``effort``, ``velocity``; column 0).
    params : ReducerParams
        The twin's parameters.
    aging : float
        Operating seconds per stream second.
    link_kept, motor_kept : ndarray of bool, optional
        Messages that arrived (default: every one).

    Returns
    -------
    tuple
        ``(rows, ends)``: the ``te_features`` records and, per window, the sample
        of the link stream at the window's end.

    """
    t0 = indep.START_S * 10 ** 9
    t_link = (s.link_stamp_ns - t0) * 1e-9
    t_motor = (s.motor_stamp_ns - t0) * 1e-9
    front = _front(params, aging)
    rows, ends = [], []
    chunk = int(RATE_HZ)
    for a in range(0, len(s.t), chunk):
        sl = slice(a, a + chunk)
        lk = np.arange(a, min(a + chunk, len(s.t))) if link_kept is None \
            else a + np.flatnonzero(link_kept[sl])
        mk = lk if motor_kept is None else a + np.flatnonzero(motor_kept[sl])
        stream = front.extractor.update(t_motor[mk], s.motor[mk, 0], t_link[lk], s.link[lk, 0])
        for f in front.analyze(stream, s.effort[lk, 0], s.velocity[lk, 0]):
            rows.append([front.record(f)[k] for k in TE_FEATURES.fields])
            ends.append(min(int(np.searchsorted(t_link, f.t_end)), len(s.t) - 1))
    return rows, np.array(ends, dtype=int)


def _generator_life(gen, truth, lives):
    """
    Generate one joint's life with a truth generator, ``truth.windows`` windows to its drawn life.

    Parameters
    ----------
    gen : module
        ``independent_generator`` or ``third_generator``.
    truth : Truth
        Seed, kind and windows.
    lives : float
        Length of the stream in drawn lives.

    Returns
    -------
    tuple
        ``(stream, life_h, aging)``: the stream (one joint, at :data:`RATE_HZ`, no truth
        topics), the drawn life [h] and the aging factor.

    """
    joints, _ = gen.draw_robot(truth.seed, (truth.kind,))
    life_h = joints[0].life_h
    aging = life_h * HOUR / (truth.windows * WINDOW_S)
    spec = gen.Spec(seed=truth.seed, kinds=(truth.kind,), hours=lives * life_h,
                    aging_factor=aging, rate_hz=RATE_HZ, truth_topics=False)
    return gen.generate(spec), life_h, aging


def simulate_independent(truth, params):
    """Run one independent-generator life through the TE extraction and window analysis."""
    s, life_h, aging = _generator_life(indep, truth, 1.02)
    rows, k = _window_ends(s, params, aging)
    exposure_op = s.exposure[:, 0] / s.exposure_rate[0]  # operating seconds since new
    nan = np.full(len(rows), np.nan)
    return Run(truth, np.array(rows), exposure_op[k], life_h * HOUR, nan,
               s.lost_motion[k, 0], nan)


def simulate_third(truth, params):
    """
    Run one third-generator life through the TE extraction and window analysis.

    The life is the one this stream's own random duty gives (the lost motion's
    crossing of the limit), not the drawn life at the duty's mean rate; the stream
    runs to 1.3 drawn lives so that the crossing is in it.
    """
    s, life_h, aging = _generator_life(third, truth, 1.3)
    rows, k = _window_ends(s, params, aging, s.link_kept, s.motor_kept)
    eol_h = float(s.end_of_life_h()[0])
    if not math.isfinite(eol_h):
        raise RuntimeError(f'third generator seed {truth.seed}: the limit is not reached in '
                           f'{1.3 * life_h:.0f} h')
    nan = np.full(len(rows), np.nan)
    return Run(truth, np.array(rows), s.t[k] * aging, eol_h * HOUR, nan, s.lost_motion[k, 0],
               nan)


def truth_law(truth):
    """Return the growth law (``indep.LAWS``) an independent generator's truth was drawn with."""
    joints, _ = indep.draw_robot(truth.seed, (truth.kind,))
    return joints[0].law


def generate(truth, params, cache=None):
    """Return the :class:`Run` of a truth, from the cache when there."""
    names = ('records', 't_end', 'eol', 'wear', 'lost_motion', 'wear_mid')
    path = Path(cache) / f'{truth.generator}-{truth.key()}.npz' if cache else None
    if path is not None and path.exists():
        with np.load(path, allow_pickle=False) as data:
            values = {k: data[k] for k in names}
        values['eol'] = float(values['eol'])
        return Run(truth, **values)
    simulate = {'model': simulate_model, 'independent': simulate_independent,
                'third': simulate_third}[truth.generator]
    run = simulate(truth, params)
    if path is not None:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(path.stem + '.tmp.npz')
        np.savez(tmp, **{k: getattr(run, k) for k in names})
        os.replace(tmp, path)
    return run


def window_truth(run, params):
    """Return the true lost motion at each window's middle [rad]."""
    if run.truth.generator == 'model':
        return model_tables(_model_params(run.truth, params)).lost_motion(run.wear_mid)
    ends = run.lost_motion
    return 0.5 * (ends + np.concatenate([ends[:1], ends[:-1]]))


def window_bias(run, params):
    """
    Return the window analysis's bias on one unit: its lost motion's median error [rad].

    Over the usable windows at 25-75 % of life (NaN where there are none): what the
    estimator's ``c`` (``fit_bias_std``) stands for.
    """
    z = run.records[:, TE_FEATURES.fields.index('lost_motion_rad')]
    frac = run.t_end / run.eol
    sel = np.isfinite(z) & (frac >= EVAL_RANGE[0]) & (frac <= EVAL_RANGE[1])
    return float(np.median((z - window_truth(run, params))[sel])) if sel.any() else math.nan


def first_window_error(run, params):
    """
    Return the error of a unit's first usable window [rad] (NaN where there is none).

    The window that anchors the as-built lost motion and the growth law's start, read
    while the window analysis has seen least of the joint.
    """
    z = run.records[:, TE_FEATURES.fields.index('lost_motion_rad')]
    first = np.flatnonzero(np.isfinite(z))[:1]
    return float((z - window_truth(run, params))[first][0]) if first.size else math.nan


def bias_identifiability(params, as_built_m, wear_m, windows=72, scatter=0.03 * ARCMIN):
    """
    Return the sd [rad] of the window fit's bias ``c`` that windows alone give, without a prior.

    Fisher information of ``z_k = h(b + w_k) + c`` in ``(b, s, c)``, ``w_k = s·A_k`` with the
    exposure ``A_k`` even over ``windows`` windows from new to ``wear_m``, each window read
    with ``scatter``: only the curvature of ``h`` tells ``c`` from ``b``.
    """
    curve = lost_motion_curve(params)
    frac = np.linspace(0.0, 1.0, windows)
    u = as_built_m + wear_m * frac
    slope = (curve(u + 1e-9) - curve(u - 1e-9)) / 2e-9
    jac = np.stack([slope, slope * frac * wear_m, np.ones_like(u)], axis=1)
    return float(np.sqrt(np.linalg.inv(jac.T @ jac)[2, 2]) * scatter)


def rate_step(truth):
    """Return whether a third-generator truth's wear rate steps up (contamination)."""
    joint = third.draw_robot(truth.seed, (truth.kind,))[0][0]
    return joint.contamination_factor > 1.0


def with_true_lost_motion(run, params, noise=0.02 * ARCMIN, seed=0):
    """
    Return the run with each usable window's lost motion replaced by the truth.

    The truth at the window's middle plus white noise of ``noise``, reported as
    such: what the estimator does when the window analysis reads the lost
    motion right, the same windows usable.
    """
    fields = TE_FEATURES.fields
    records = run.records.copy()
    z = records[:, fields.index('lost_motion_rad')]
    usable = np.isfinite(z)
    truth = window_truth(run, params)
    rng = np.random.default_rng([seed, run.truth.seed])
    records[usable, fields.index('lost_motion_rad')] = (
        truth[usable] + rng.normal(0.0, noise, usable.sum()))
    records[usable, fields.index('lost_motion_std_rad')] = noise
    records[usable, fields.index('wear_fit_m')] = np.maximum(
        records[usable, fields.index('wear_fit_m')], 1e-9)
    # The truth is the lost motion at the test torque: no soft zone left to take off it.
    records[:, fields.index('soft_zone_shortfall_rad')] = 0.0
    records[:, fields.index('soft_zone_width_rad')] = 0.0
    return Run(run.truth, records, run.t_end, run.eol, run.wear, run.lost_motion, run.wear_mid)


# --------------------------------------------------------------------------- estimation


def unknown_history_config():
    """Estimator tuning for a reducer of unknown history (the default where there is none)."""
    make = getattr(EstimatorConfig, 'unknown_history', None)
    return make() if make is not None else EstimatorConfig()


def _prediction(life, record, law_weight=None):
    """Return the LifePrediction of a wear record, with its samples (the law at a weight)."""
    predict = getattr(life, 'prediction', None)
    if predict is not None:
        if law_weight is not None:
            return predict(record, keep_samples=True, law_weight=law_weight)
        return predict(record, keep_samples=True)
    x, P = state_from_record(record)  # the estimator before per-unit states
    return remaining_life((x, P), float(record['duty_rate_m_per_s']), life.params,
                          limit=life.limit, horizon_s=life.horizon_s,
                          n_samples=life.n_samples, rng=np.random.default_rng(0),
                          duty_rate_rel_std=life.duty_rate_rel_std, keep_samples=True)


def estimate(run, params, config=None, law_weight=None):
    """
    Step the estimator and the life stage through a run's windows.

    ``law_weight`` (0 to 1) forces the observed growth law's weight in the remaining life
    (``LifeStage.prediction``'s what-if): 0 the wear model's curve alone, 1 the law alone.

    Returns
    -------
    dict of ndarray
        Per window: ``wear``, ``wear_std``, ``lm``, ``lm_std`` (estimated lost
        motion), ``p10``, ``p50``, ``p90``, ``pit`` (share of predicted lives
        below the true one), ``nis`` (NaN when not updated), ``usable``; and ``rho``
        and ``forecast``, the learnt noise scale and the forecast scale after the last
        window (one value each).

    """
    stage = EstimatorStage(params, config)
    life = LifeStage(params)
    curve = lost_motion_curve(params)
    out = {k: [] for k in ('wear', 'wear_std', 'lm', 'lm_std', 'p10', 'p50', 'p90', 'pit',
                           'nis', 'usable', 'scale', 'rho_w')}
    out['rho'] = []
    fields = TE_FEATURES.fields
    for row, t_op in zip(run.records, run.t_end):
        f = features_from_record(dict(zip(fields, row)))
        result = stage.step(f)
        record = stage.record(f.t_end)
        life.observe_duty(f.duty)
        pred = _prediction(life, record, law_weight)
        out['wear'].append(record['wear_m'])
        out['wear_std'].append(record['wear_std_m'])
        lm = record['lost_motion_rad']
        lm_std = record.get('lost_motion_std_rad')
        if lm_std is None:
            w = max(record['wear_m'], 0.0)
            lm_std = abs(float(curve(w + 0.05 * UM) - curve(w - 0.05 * UM)) / (0.1 * UM)) \
                * record['wear_std_m']
        out['lm'].append(lm)
        out['lm_std'].append(lm_std)
        for q in ('p10', 'p50', 'p90'):
            out[q].append(getattr(pred, q))
        true_rul = run.eol - t_op
        out['pit'].append(float(np.mean(pred.samples < true_rul)))
        out['nis'].append(result.nis if result.status in ('accepted', 'recovered') else np.nan)
        out['usable'].append(np.isfinite(f.lost_motion))
        out['scale'].append(record.get('forecast_scale', stage.estimator.forecast_scale))
        out['rho_w'].append(stage.estimator.noise_scale)
    out['rho'] = [stage.estimator.noise_scale]
    out['forecast'] = [getattr(stage.estimator, 'forecast_scale', math.nan)]
    return {k: np.array(v, dtype=float) for k, v in out.items()}


# --------------------------------------------------------------------------- evaluation


def evaluate(run, est):
    """
    Figures of one life.

    Returns
    -------
    dict
        Per-evaluation arrays (``err``, ``rel_err``, ``nees``, ``below``, ``above``,
        ``pit``) over 25-75 % of life, the run's ``nis`` values, ``al50``, ``al75``,
        ``p50_60`` (relative P50 error at 60 % of life).

    """
    frac = run.t_end / run.eol
    sel = (frac >= EVAL_RANGE[0]) & (frac <= EVAL_RANGE[1])
    if run.truth.generator == 'model':
        truth, value, sd = run.wear, est['wear'], est['wear_std']
    else:
        truth, value, sd = run.lost_motion, est['lm'], est['lm_std']
    true_rul = run.eol - run.t_end
    err = (value - truth)[sel]
    out = {'err': err, 'rel_err': err / truth[sel], 'nees': (err / sd[sel]) ** 2,
           'below': (true_rul < est['p10'])[sel], 'above': (true_rul > est['p90'])[sel],
           'pit': est['pit'][sel], 'nis': est['nis'][np.isfinite(est['nis'])],
           'scale': est['scale'][sel], 'rho_w': est['rho_w'][sel]}
    before = true_rul > 0.0
    t, p50, r = run.t_end[before], est['p50'][before], true_rul[before]
    t0 = np.concatenate([[0.0], t])
    p0 = np.concatenate([[np.nan], p50])
    r0 = np.concatenate([[run.eol], r])
    out['al50'] = alpha_lambda(t0, p0, r0, 0.5)
    out['al75'] = alpha_lambda(t0, p0, r0, 0.75)
    k60 = int(np.searchsorted(frac, 0.6))
    k60 = min(k60, len(frac) - 1)
    out['p50_60'] = (est['p50'][k60] - true_rul[k60]) / true_rul[k60]
    out['usable'] = int(est['usable'].sum())
    out['rho'] = float(est['rho'][-1]) if 'rho' in est else math.nan
    out['forecast'] = float(est['forecast'][-1]) if 'forecast' in est else math.nan
    out['windows'] = int(est['usable'].size)
    return out


def observed(result):
    """
    Whether the twin read the run's lost motion often enough to be judged on it.

    A joint whose windows give a lost motion in fewer than :data:`MIN_OBSERVED`
    of them is one the twin reports as not observed (or as an interval from 0
    to the horizon): no estimator can follow a history it does not see.
    Such runs are counted and listed, never dropped silently.
    """
    return result['usable'] >= MIN_OBSERVED


def _pct(x):
    return f'{100.0 * x:.0f} %'


def _coverage_by(cat, key, name, edges):
    """
    Print P10-P90 coverage and NEES of the evaluations binned by one of the twin's signals.

    Whether a signal the twin has at the time (the forecast scale, the learnt noise
    scale) tells the evaluations whose interval misses from those whose does not: a
    calibrated interval covers 80 % in every bin.
    """
    for lo, hi in zip(edges, edges[1:] + (math.inf,)):
        k = (cat[key] >= lo) & (cat[key] < hi)
        if k.any():
            below, above = cat['below'][k].mean(), cat['above'][k].mean()
            print(f'  {name} {lo:g}-{hi:g}: {_pct(k.mean())} of evaluations, P10-P90 coverage '
                  f'{_pct(1.0 - below - above)} (below {_pct(below)}, above {_pct(above)}), '
                  f'NEES {np.mean(cat["nees"][k]):.2f}')


def report_case(name, results, unit_name):
    """Print the figures of one case; return them as a dict."""
    cat = {k: np.concatenate([r[k] for r in results]) for k in
           ('err', 'rel_err', 'nees', 'below', 'above', 'pit', 'nis', 'scale', 'rho_w')}
    al50 = np.mean([r['al50'] for r in results])
    al75 = np.mean([r['al75'] for r in results])
    p50_60 = np.array([r['p50_60'] for r in results])
    within30 = np.mean(np.abs(p50_60) <= 0.3)
    below, above = cat['below'].mean(), cat['above'].mean()
    hist = np.histogram(np.clip(cat['pit'], 0.0, 1.0), bins=10, range=(0.0, 1.0))[0]
    hist = hist / max(hist.sum(), 1)
    abs_rel = np.abs(cat['rel_err'])
    scale = 1e6 if unit_name == 'wear' else 1.0 / ARCMIN
    unit = 'um' if unit_name == 'wear' else 'arcmin'
    print(f'{name}: {len(results)} truths, {cat["err"].size} evaluations at 25-75 % of life')
    print(f'  {unit_name} error: median |rel| {_pct(np.median(abs_rel))}, 90th pct '
          f'{_pct(np.quantile(abs_rel, 0.9))}; mean {np.mean(cat["err"]) * scale:+.3f} {unit}, '
          f'{_pct(np.mean(cat["err"] < 0))} below truth; inside +-2 sd '
          f'{_pct(np.mean(cat["nees"] <= 4.0))}')
    bias = np.array([r.get('bias', math.nan) for r in results])
    seen = np.isfinite(bias)
    if seen.any():
        print(f'  window lost-motion bias per unit (median error at 25-75 % of life): RMS '
              f'{np.sqrt(np.mean(bias[seen] ** 2)) / ARCMIN:.3f} arcmin, 90th pct |.| '
              f'{np.quantile(np.abs(bias[seen]), 0.9) / ARCMIN:.3f} arcmin (fit_bias_std 0.05); '
              'largest: ' + ', '.join(
                  f'{results[i]["label"]} {bias[i] / ARCMIN:+.3f}'
                  for i in np.argsort(-np.where(seen, np.abs(bias), -1.0))[:3] if seen[i]))
    first = np.abs([r.get('first', math.nan) for r in results])
    first = first[np.isfinite(first)]
    if first.size:
        print(f"  a unit's first usable window: |error| median {np.median(first) / ARCMIN:.3f}, "
              f'90th pct {np.quantile(first, 0.9) / ARCMIN:.3f} arcmin')
    rho = np.array([r.get('rho', math.nan) for r in results])
    rho = rho[np.isfinite(rho)]
    if rho.size:
        print(f'  learnt noise scale (observed over reported window variance) at the end of '
              f'life: median {np.median(rho):.2f}, {np.min(rho):.2f}-{np.max(rho):.2f}')
    scale = np.array([r.get('forecast', math.nan) for r in results])
    scale = scale[np.isfinite(scale)]
    if scale.size:
        print(f"  forecast scale (lagged predictions' squared error in their sds, at least 1) at "
              f'the end of life: median {np.median(scale):.2f}, 90th pct '
              f'{np.quantile(scale, 0.9):.2f}, {np.min(scale):.2f}-{np.max(scale):.2f}')
    _coverage_by(cat, 'scale', 'forecast scale', (1.0, 1.5, 2.0, 3.0))
    _coverage_by(cat, 'rho_w', 'noise scale', (0.0, 1.5, 2.5, 4.0))
    print(f'  NEES mean {np.mean(cat["nees"]):.2f} (median {np.median(cat["nees"]):.2f}) '
          f'[0.5, 2]; NIS mean {np.mean(cat["nis"]):.2f} (median {np.median(cat["nis"]):.2f}, '
          f'{cat["nis"].size} updates)')
    print(f'  alpha-lambda (alpha 0.2): lambda 0.5 {_pct(al50)}, 0.75 {_pct(al75)}; '
          f'RUL P50 within 30 % at 60 % of life in {_pct(within30)} of runs '
          f'(median error {np.median(p50_60) * 100:+.0f} %)')
    print(f'  P10-P90 coverage {_pct(1.0 - below - above)} [80 +- 5]; below P10 {_pct(below)}, '
          f'above P90 {_pct(above)} [10 +- 5 each]')
    print('  calibration (true RUL among predicted deciles, 10 % each): '
          + ' '.join(f'{100 * h:.0f}' for h in hist))
    return {'truths': len(results), 'median_abs_rel_err': float(np.median(abs_rel)),
            'mean_err': float(np.mean(cat['err'])), 'nees': float(np.mean(cat['nees'])),
            'nis': float(np.mean(cat['nis'])), 'al50': float(al50), 'al75': float(al75),
            'p50_within_30_at_60': float(within30), 'coverage': float(1.0 - below - above),
            'below_p10': float(below), 'above_p90': float(above),
            'calibration': [float(h) for h in hist]}


MID_LIFE_STARTS = (0.25, 0.5, 0.75)
"""Shares of life at which a twin without state is started on a unit (mid-life case)."""

MID_LIFE_SPANS = (0.1, 0.3)
"""Shares of life it then watches before its remaining life is judged."""


def mid_life_starts(runs, params, config=None, service=False):
    """
    Figures of twins started without state on units already part-way through life.

    Most twins meet their reducer used: installed on a robot that has run for years, a
    recording analysed without the state of earlier ones. Each run is met at
    :data:`MID_LIFE_STARTS` of its life by an estimator with the default prior (new with
    probability 0.9, else of unknown history) and judged after it has seen
    :data:`MID_LIFE_SPANS` of the life (starts whose span would pass the end are left
    out): where the true remaining life falls against P10, P50 and P90. With ``service``
    the estimator is told the unit's operating time before the start (its service time,
    ``EstimatorConfig.service_time_s``), as a robot's hour meter would.

    Returns
    -------
    dict
        Per span: ``starts``, ``coverage``, ``below_p10``, ``above_p90``,
        ``p50_ratio`` (median P50 / true), ``p50_within_30``.

    """
    out = {}
    for span in MID_LIFE_SPANS:
        rows = []
        for run in runs:
            frac = run.t_end / run.eol
            for start in MID_LIFE_STARTS:
                k0 = int(np.searchsorted(frac, start))
                k1 = int(np.searchsorted(frac, start + span))
                if k1 >= frac.size or k1 <= k0:
                    continue
                sl = slice(k0, k1 + 1)
                part = Run(run.truth, run.records[sl], run.t_end[sl], run.eol, run.wear[sl],
                           run.lost_motion[sl], run.wear_mid[sl])
                told = config
                if service and k0 > 0:
                    told = replace(config or EstimatorConfig(),
                                   service_time_s=float(run.t_end[k0 - 1]))
                est = estimate(part, params, told)
                true_rul = run.eol - part.t_end[-1]
                rows.append((true_rul < est['p10'][-1], true_rul > est['p90'][-1],
                             est['p50'][-1] / true_rul))
        if not rows:
            continue
        below, above, ratio = (np.array(x, dtype=float) for x in zip(*rows))
        out[span] = {'starts': len(rows), 'coverage': float(1.0 - below.mean() - above.mean()),
                     'below_p10': float(below.mean()), 'above_p90': float(above.mean()),
                     'p50_ratio': float(np.median(ratio)),
                     'p50_within_30': float(np.mean(np.abs(ratio - 1.0) <= 0.3))}
        f = out[span]
        told = ', told its service time' if service else ''
        print(f'  met without state at 25/50/75 % of life{told}, judged after {_pct(span)} more: '
              f'{f["starts"]} starts, P10-P90 coverage {_pct(f["coverage"])} (below P10 '
              f'{_pct(f["below_p10"])}, above P90 {_pct(f["above_p90"])}), P50 / true '
              f'median {f["p50_ratio"]:.2f}, within 30 % in {_pct(f["p50_within_30"])}')
    return out


def fixed_as_built(params, offset_m, seeds, windows, cache):
    """P50 errors at 60 % of life of units built ``offset_m`` looser than nominal."""
    errors = []
    for seed in seeds:
        truth = Truth('model', seed=seed, as_built_m=offset_m, load_fraction=1.2,
                      windows=windows, rate_scale=1.0)
        run = generate(truth, params, cache)
        errors.append(evaluate(run, estimate(run, params))['p50_60'])
    return np.array(errors)


def used_unit(params, seeds, cache, usable=20):
    """Relative wear errors after ``usable`` usable windows of a used unit, aging factor 1."""
    rng = np.random.default_rng(7)
    errors = []
    for seed in seeds:
        w0 = float(rng.uniform(2.0, 10.0)) * UM
        truth = Truth('model', seed=seed, initial_wear_m=round(w0 / 1e-8) * 1e-8,
                      load_fraction=1.2, windows=int(2.5 * usable), aging=1.0)
        run = generate(truth, params, cache)
        est = estimate(run, params, unknown_history_config())
        k = int(np.flatnonzero(np.cumsum(est['usable']) >= usable)[0])
        errors.append((est['wear'][k] - run.wear[k]) / run.wear[k])
    return np.array(errors)


def _by_law(results, truths):
    """Print coverage and alpha-lambda of independent-generator results per truth law."""
    laws = [truth_law(t) for t in truths]
    for law in indep.LAWS:
        pick = [r for r, t_law in zip(results, laws) if t_law == law]
        if pick:
            below = np.concatenate([r['below'] for r in pick]).mean()
            above = np.concatenate([r['above'] for r in pick]).mean()
            print(f'    lost motion {law} in the exposure: {len(pick)} truths, P10-P90 '
                  f'coverage {_pct(1.0 - below - above)} (below {_pct(below)}, above '
                  f'{_pct(above)}), alpha-lambda 0.5 '
                  f'{_pct(np.mean([r["al50"] for r in pick]))}')


def main(argv=None):
    """Run every case and print the figures."""
    ap = argparse.ArgumentParser(description='accuracy of wear and remaining-life estimates')
    ap.add_argument('--truths', type=int, default=24, help='random truths, model generator')
    ap.add_argument('--independent-truths', type=int, default=32,
                    help='random truths, independent generator (about a quarter are wrists '
                    'too lightly loaded to be observed)')
    ap.add_argument('--windows', type=int, default=120, help='windows of 2 s per life')
    ap.add_argument('--seed', type=int, default=1, help='seed of the truth draws')
    ap.add_argument('--generators', default='model,independent')
    ap.add_argument('--cache', default=None, help='directory to keep generated windows in')
    ap.add_argument('--json', default=None, help='write the figures to this file')
    ap.add_argument('--skip-fixed', action='store_true', help='only the random truths')
    ap.add_argument('--no-oracle', dest='oracle', action='store_false',
                    help='skip the pass with the true lost motion in place of the window fits')
    ap.add_argument('--estimator', default='', help='estimator settings, key=value,... (SI)')
    ap.add_argument('--branches', action='store_true',
                    help="also each model's remaining life alone: the growth law weighed 0 "
                    "(the wear model's curve) and 1 (the observed law)")
    args = ap.parse_args(argv)
    config = EstimatorConfig(**{k: float(v) for k, v in (
        item.split('=') for item in args.estimator.split(',') if item)})
    params = ReducerParams()
    start = time.process_time()
    figures = {}
    gens = args.generators.split(',')
    for gen in gens:
        truths = (draw_model_truths(args.truths, args.seed, args.windows, params)
                  if gen == 'model' else
                  draw_independent_truths(args.independent_truths, args.seed, args.windows,
                                          gen))
        results, oracle, runs = [], [], []
        for truth in truths:
            run = generate(truth, params, args.cache)
            runs.append(run)
            results.append(evaluate(run, estimate(run, params, config)))
            results[-1].update(bias=window_bias(run, params),
                               first=first_window_error(run, params),
                               label=f'{truth.kind or truth.generator} {truth.seed}')
            if args.oracle:
                exact = with_true_lost_motion(run, params)
                oracle.append(evaluate(exact, estimate(exact, params, config)))
        unit = 'wear' if gen == 'model' else 'lost motion'
        seen = [observed(r) for r in results]
        blind = [f'{t.kind or t.generator} seed {t.seed} ({r["usable"]} of '
                 f'{r["windows"]} windows)'
                 for t, r, s in zip(truths, results, seen) if not s]
        if blind:
            print(f'{gen} generator: {len(blind)} of {len(results)} truths not observed (lost '
                  f'motion in fewer than {MIN_OBSERVED} windows; the twin says so), left out of '
                  'the figures below: ' + ', '.join(blind))
            everything = report_case(f'{gen} generator, every truth (not observed counted)',
                                     results, unit)
            figures[gen + ' (every truth)'] = everything
        results = [r for r, s in zip(results, seen) if s]
        oracle = [r for r, s in zip(oracle, seen) if s]
        truths = [t for t, s in zip(truths, seen) if s]
        figures[gen] = report_case(f'{gen} generator', results, unit)
        watched = [r for r, s in zip(runs, seen) if s]
        figures[gen]['mid_life'] = {f'{span:g}': f for span, f in mid_life_starts(
            watched, params, config).items()}
        figures[gen]['mid_life_service'] = {f'{span:g}': f for span, f in mid_life_starts(
            watched, params, config, service=True).items()}
        if gen == 'third':
            for kind in third.KINDS:
                pick = [r for r, t in zip(results, truths) if t.kind == kind]
                if pick:
                    figures[f'{gen} {kind}'] = report_case(f'  {gen} generator, {kind}', pick,
                                                           unit)
        if gen == 'independent':
            for kind in indep.KINDS:
                pick = [r for r, t in zip(results, truths) if t.kind == kind]
                if pick:
                    print(f'    {kind}: {len(pick)} truths, alpha-lambda 0.5 '
                          f'{_pct(np.mean([r["al50"] for r in pick]))}, RUL P50 within 30 % '
                          f'at 60 % {_pct(np.mean([abs(r["p50_60"]) <= 0.3 for r in pick]))}')
            _by_law(results, truths)
        if args.branches:
            for weight, label in ((0.0, "the wear model's curve alone"),
                                  (1.0, 'the observed growth law alone')):
                alone = [evaluate(run, estimate(run, params, config, weight))
                         for run in watched]
                figures[f'{gen} ({label})'] = report_case(
                    f'{gen} generator, remaining life from {label}', alone, unit)
                if gen == 'independent':
                    _by_law(alone, truths)
        if args.oracle:
            figures[gen + ' (true lost motion)'] = report_case(
                f'{gen} generator, windows read right (true lost motion + 0.02 arcmin)',
                oracle, unit)
        if args.oracle and gen == 'third':
            for label, pick in (('with', True), ('without', False)):
                errs = [r['p50_60'] for r, t in zip(oracle, truths) if rate_step(t) == pick]
                if errs:
                    print(f'    read right, {len(errs)} units {label} a rate step: RUL P50 at '
                          f'60 % of life {100 * min(errs):+.0f} .. {100 * max(errs):+.0f} %, '
                          f'more than 30 % long in {sum(e > 0.3 for e in errs)}')
        if gen == 'model':
            sds = [bias_identifiability(params, b * UM, 13.0 * UM) / ARCMIN for b in (0.3, 1.7)]
            print(f"  the windows alone tell the fit's bias to {min(sds):.3f}-{max(sds):.3f} "
                  'arcmin (72 windows to 13 um, 0.03 arcmin scatter, as-built 0.3-1.7 um, no '
                  'prior; fit_bias_std 0.05)')
    if not args.skip_fixed:
        seeds = range(900, 905)
        for label, offset in (('3 um looser', 3.0 * UM), ('2 um tighter', -2.0 * UM)):
            err = fixed_as_built(params, offset, seeds, args.windows, args.cache)
            figures[label] = err.tolist()
            print(f'unit {label} than nominal (model generator, {len(err)} runs): RUL P50 at '
                  f'60 % of life off by ' + ', '.join(f'{100 * e:+.0f} %' for e in err)
                  + ' [within 30 %]')
        err = used_unit(params, range(950, 960), args.cache)
        figures['used unit'] = err.tolist()
        print(f'used unit (2-10 um, aging factor 1, no state, {len(err)} runs): wear after 20 '
              f'usable windows off by median {np.median(np.abs(err)) * 100:.1f} %, worst '
              f'{np.max(np.abs(err)) * 100:.1f} % [within 15 %]')
    print(f'({time.process_time() - start:.0f} s of CPU)')
    if args.json:
        Path(args.json).write_text(json.dumps(figures, indent=1))


if __name__ == '__main__':
    main()
