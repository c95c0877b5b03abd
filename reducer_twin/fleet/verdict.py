"""
What to do with each reducer of a fleet: the verdict rules and the fleet view's rows.

Rules, on the remaining life P10 (operating hours until the lost motion reaches its
limit, 10 % of the estimates earlier) against the life thresholds the reducer was
analysed with (``life.error_s``, ``life.warn_s``; 200 h and 1000 h by default):

* ``REPLACE``: P10 at or below the error threshold, or the lost motion already past
  the limit (remaining life negative: how many operating hours past it);
* ``PLAN``: P10 at or below the warning threshold: order the reducer, plan the stop;
* ``WATCH``: P10 at or below the warning threshold while the unit's own wear rate is not
  yet resolved (``rate_resolved`` false: a reducer met used and seen briefly, without its
  service time): the P10 rests on rates its recordings cannot tell apart, not on its wear;
  record it longer or give its service time. A used unit recorded for minutes in real
  time shows no growth of its lost motion, and its P10 came out at hours (REPLACE for a
  unit halfway to its limit on a fleet's first day);
* ``OK``: P10 above the warning threshold;
* ``NOT OBSERVED``: no bag analysed and no live window since installation, or no window
  whose lost motion the estimator could use (the joint never reversed under load, or no
  window at all): the twin cannot tell, and says why;
* ``RETIRED``: replaced; kept for its history.

Rows are ranked by P10, most urgent first; not observed and retired reducers follow.
"""

import math

import numpy as np
from reducer_twin.core.life_basis import faster_than_wear_words
from reducer_twin.core.pipeline import SOFT_ZONE_KEY
from reducer_twin.core.units import ARCMIN, HOUR, UM
from reducer_twin.fleet.store import iso_from_ns

VERDICTS = ('REPLACE', 'PLAN', 'WATCH', 'OK', 'NOT OBSERVED', 'RETIRED')
"""Verdicts, most urgent first."""

RULES = (
    ('REPLACE', 'remaining life P10 at or below the error threshold (default 200 h), or lost '
                'motion past its limit: replace at the next stop'),
    ('PLAN', 'remaining life P10 at or below the warning threshold (default 1000 h): order '
             'the reducer and plan the replacement'),
    ('WATCH', "remaining life P10 at or below the warning threshold while the unit's own "
              'wear rate is not yet resolved (seen briefly, without its service time): the '
              'P10 rests on rates its recordings cannot tell apart; record it longer or give '
              'its service time'),
    ('OK', 'remaining life P10 above the warning threshold'),
    ('NOT OBSERVED', 'no usable lost-motion observation since installation (no bag, no live '
                     'window, or the joint never reversed under load): the twin cannot tell'),
    ('RETIRED', 'replaced; its history is kept'),
)
"""The rules as the fleet view and the reports state them."""

FIELDS = ('robot', 'joint', 'bags', 'hours_observed', 'last_seen', 'wear_um', 'wear_std_um',
          'lost_motion_arcmin', 'rul_p10_h', 'rul_p50_h', 'rul_p90_h', 'verdict', 'reason')
"""Keys of ``fleet --json`` every row has (the issue's list), in order."""


def overdue_life(state, params, limit_rad, n_samples=2000):
    """
    Remaining life of a reducer already past its limit, negative [s of operation].

    The closed form of :func:`~reducer_twin.core.life.remaining_life` without its clip
    at zero: ``t = (S(w_lim) - S(w))/(s·ȧ)`` with the same draws of ``(w, ln s)`` and the
    recent duty rate, so ``-t`` is how long ago, in operating seconds at the recent duty,
    the limit was crossed.

    Parameters
    ----------
    state : dict
        ``WearEstimator.state_dict()``.
    params : ReducerParams
        Reducer parameters.
    limit_rad : float
        Lost-motion limit [rad].
    n_samples : int
        Draws of the state distribution.

    Returns
    -------
    tuple of float
        P10, P50, P90 [s]; NaN when the duty rate is unknown (no operation yet).

    """
    from reducer_twin.core.state_space import run_in_free_wear
    from reducer_twin.core.life import limit_wear
    # The marginal of (w, ln s): the state may carry more (the unit's as-built offset).
    x = np.asarray(state['x'], dtype=float)[:2]
    P = np.asarray(state['P'], dtype=float)[:2, :2]
    exposure = float(state['duty_exposure'])
    rate = float(state['duty_increment']) / exposure if exposure > 0.0 else 0.0
    if rate <= 0.0:
        return (math.nan,) * 3
    rng = np.random.default_rng(0)
    vals, vecs = np.linalg.eigh(0.5 * (P + P.T))
    root = vecs * np.sqrt(np.maximum(vals, 0.0))
    draws = x + rng.standard_normal((n_samples, 2)) @ root.T
    wp = params.wear
    w_lim = limit_wear(params, limit_rad)
    t = (run_in_free_wear(w_lim, wp) - run_in_free_wear(np.maximum(draws[:, 0], 0.0), wp)) / (
        np.exp(draws[:, 1]) * rate)
    return tuple(float(v) for v in np.quantile(t, [0.1, 0.5, 0.9]))


def _hours(seconds):
    return None if seconds is None or not math.isfinite(seconds) else seconds / HOUR


def fleet_row(reducer, params):
    """
    One reducer's row of the fleet view, with its verdict and the rule that gave it.

    Parameters
    ----------
    reducer : Reducer
        From :meth:`~reducer_twin.fleet.store.FleetStore.reducers`.
    params : ReducerParams
        Reducer parameters (for the remaining life past the limit).

    Returns
    -------
    dict
        :data:`FIELDS` plus ``windows``, ``installed_at``, ``retired_at``,
        ``lost_motion_limit_arcmin``, ``rul_censored``, ``rule``, ``live_segments``,
        ``hours_live`` (the part of ``hours_observed`` a live ``wear_estimator`` wrote;
        ``bags`` counts recorded bags only), ``rate_resolved`` (False while the
        remaining life is the model's wear rate, not the unit's own; None unknown),
        ``growth_law`` (the observed growth law the remaining life follows, as
        ``analyze --json`` gives it; None otherwise or unknown), ``curve_extrapolation``
        (how far the wear model's curve carries the remaining life beyond the span its
        shape was compared over, as ``analyze --json`` gives it; None otherwise) and
        ``lost_motion_std_arcmin`` (the lost motion's standard deviation, as ``analyze
        --json`` gives it; None where unknown, a store written before it was kept),
        ``service_hours`` (the operating time it had before the twin first saw it, where
        the configuration gave one and it was taken; else None) and ``inputs`` (how the
        latest analysis read its inputs otherwise than published, as ``analyze --json``
        gives them: encoders stamped apart, a play still taken up at the test torque, ...)
        and ``soft_zone`` (the latest analysis's figures of such a play, as ``analyze
        --json`` gives them; else None), ``within_zone`` (its figures of loads within a
        soft zone, likewise) and ``test_torque_check`` (what the latest
        analysis's comparisons of the width at the test torque found, as ``analyze
        --json`` gives it: ``'not compared'`` or ``'unconfirmed'`` where the lost motion
        is the loaded flanks' play; None where unknown).

    """
    r = reducer
    limit = r.lost_motion_limit_rad
    row = dict.fromkeys(FIELDS)
    row.update(robot=r.robot, joint=r.joint, bags=int(r.bags),
               hours_observed=r.exposure_s / HOUR, last_seen=iso_from_ns(r.last_ns),
               windows=int(r.windows), installed_at=iso_from_ns(r.installed_ns),
               retired_at=iso_from_ns(r.retired_ns),
               lost_motion_limit_arcmin=None if limit is None else limit / ARCMIN,
               rul_censored=False, live_segments=int(r.live_segments),
               hours_live=r.live_exposure_s / HOUR)
    state = (r.state or {}).get('estimator')
    summary = r.summary or {}
    row['rate_resolved'] = summary.get('rate_resolved')
    row['growth_law'] = summary.get('growth_law')
    row['curve_extrapolation'] = summary.get('curve_extrapolation')
    row['inputs'] = list(summary.get('inputs') or [])
    row['lost_motion_std_arcmin'] = None
    row['soft_zone'] = summary.get('soft_zone')
    row['within_zone'] = summary.get('within_zone')
    row['test_torque_check'] = summary.get('test_torque_check')
    verdict = (state or {}).get('service_verdict')
    row['service_hours'] = float(state['config']['service_time_s']) / HOUR \
        if verdict is not None and verdict[0] else None
    if state is not None:
        row['wear_um'] = float(state['x'][0]) / UM
        row['wear_std_um'] = math.sqrt(max(float(state['P'][0][0]), 0.0)) / UM
        row['lost_motion_arcmin'] = summary.get('lost_motion_arcmin')
        row['lost_motion_std_arcmin'] = summary.get('lost_motion_std_arcmin')
        for key in ('rul_p10_h', 'rul_p50_h', 'rul_p90_h'):
            row[key] = summary.get(key)
        row['rul_censored'] = bool(summary.get('rul_censored', False))
    updates = int(state['counters']['updates']) if state is not None else 0
    since = f'since its installation at {row["installed_at"]}' if r.installed_ns is not None \
        else 'yet'
    if not r.in_service:
        row['verdict'] = 'RETIRED'
        row['reason'] = f'replaced at {row["retired_at"]}'
    elif (r.bags == 0 and r.live_segments == 0) or state is None:
        row['verdict'] = 'NOT OBSERVED'
        row['reason'] = f'no bag analysed and no live window stored {since}'
        for key in ('wear_um', 'wear_std_um'):
            row[key] = None
    elif updates == 0:
        row['verdict'] = 'NOT OBSERVED'
        # The analysis says why (no effort, too few samples per reversal, frozen stamps...).
        why = summary.get('reason') or ('the joint never reversed under load, or no window '
                                        'at all')
        live = f' and {r.live_segments} live segment(s)' if r.live_segments else ''
        row['reason'] = (f'{r.windows} window(s) over {row["hours_observed"]:.0f} h in '
                         f'{r.bags} bag(s){live}, none with a lost motion the estimator could '
                         f'use: {why}')
        for key in ('wear_um', 'wear_std_um', 'rul_p10_h', 'rul_p50_h', 'rul_p90_h'):
            row[key] = None
    else:
        _judge(row, r, state, params)
    row['rule'] = dict(RULES)[row['verdict']]
    return row


def _judge(row, r, state, params):
    error_h, warn_h = _hours(r.error_s), _hours(r.warn_s)
    lm, limit = row['lost_motion_arcmin'], row['lost_motion_limit_arcmin']
    if lm is not None and limit is not None and lm >= limit:
        # The estimator follows the play: a soft zone beyond the test torque meets the
        # limit stated there that much later (the shortfall its lost motion was given with).
        shortfall = float((r.state or {}).get(SOFT_ZONE_KEY, 0.0))
        p10, p50, p90 = (_hours(v) for v in overdue_life(
            state, params, r.lost_motion_limit_rad + shortfall))
        row.update(rul_p10_h=p10, rul_p50_h=p50, rul_p90_h=p90)
        past = f'about {-p50:,.0f} h ago at the recent duty' if p50 is not None and p50 < 0 \
            else 'now'
        row['verdict'] = 'REPLACE'
        row['reason'] = (f'lost motion {lm:.2f} arcmin is past its limit of {limit:.2f} arcmin '
                         f'(crossed {past})')
        return
    p10 = row['rul_p10_h']
    text = 'beyond the prediction horizon' if row['rul_censored'] or p10 is None \
        else f'{p10:,.0f} h'
    if p10 is not None and p10 <= error_h:
        row['verdict'] = 'REPLACE'
        row['reason'] = f'remaining life P10 {text} <= {error_h:,.0f} h (error threshold)'
    elif p10 is not None and p10 <= warn_h:
        row['verdict'] = 'PLAN'
        row['reason'] = f'remaining life P10 {text} <= {warn_h:,.0f} h (warning threshold)'
    else:
        row['verdict'] = 'OK'
        row['reason'] = f'remaining life P10 {text} > {warn_h:,.0f} h (warning threshold)'
    if row['rate_resolved'] is False:
        # Never an OK that is the physics alone without saying so, nor a REPLACE or PLAN
        # that is the rates a short recording cannot rule out rather than the wear.
        # A unit the twin has known since new only needs watching longer; one met used
        # without its service time may also be told it (the robot's hour meter).
        remedy = 'watch it longer' if r.installed_ns is not None or row['service_hours'] \
            else 'watch it longer, or give its service time: service_time_s, the hour meter'
        if row['verdict'] != 'OK':
            row['verdict'] = 'WATCH'
            if lm is not None and limit is not None:
                row['reason'] += f' with lost motion {lm:.2f} of {limit:.2f} arcmin'
        fast = (r.summary or {}).get('faster_than_wear')
        if fast is not None:
            row['reason'] += (f'; its {faster_than_wear_words(fast)}): a change in what its '
                              'windows read, or damage (inspect it if the lost motion stays '
                              f'high), not a wear rate ({remedy})')
        else:
            row['reason'] += ("; the unit's own wear rate is not yet resolved, so the "
                              'remaining life spans the rates its recordings cannot tell '
                              f"apart, the model's at this duty among them ({remedy})")
    law = row['growth_law']
    if law and law.get('extrapolation'):
        # The law is weighed by predictions a few windows ahead, not by how far it carries.
        row['reason'] += (f"; the remaining life follows the lost motion's observed growth "
                          f"(as exposure^{law['exponent']:.2f}), extrapolated to "
                          f"{law['extrapolation']:,.0f}x the exposure it was learnt on: "
                          'its interval holds only if that law does')
    reach = row['curve_extrapolation']
    if reach:
        # The curve's shape, too, was compared with the growth only over the span seen.
        row['reason'] += ("; the remaining life follows the wear model's curve, extrapolated "
                          f'to {reach:,.0f}x the exposure it was learnt on: its interval holds '
                          'only if the lost motion keeps to that curve')


def rank(rows):
    """
    Order fleet rows: observed reducers by P10 (lowest first), then the rest.

    Parameters
    ----------
    rows : list of dict
        From :func:`fleet_row`.

    Returns
    -------
    list of dict
        The same rows, most urgent first.

    """
    def key(row):
        group = VERDICTS.index(row['verdict'])
        observed = row['verdict'] in ('REPLACE', 'PLAN', 'WATCH', 'OK')
        p10 = row['rul_p10_h']
        return (0 if observed else group, p10 if observed and p10 is not None else math.inf,
                row['robot'], row['joint'], row['installed_at'] or '')
    return sorted(rows, key=key)


def bag_rows(result, life=None, params=None):
    """
    Judge every joint of one analysed bag (the single-bag report's table).

    Parameters
    ----------
    result : BagResult
        Output of :func:`~reducer_twin.analysis.pipeline.analyze_bag`.
    life : LifeConfig, optional
        Limit and thresholds it was analysed with (default the defaults).
    params : ReducerParams, optional
        Reducer parameters.

    Returns
    -------
    list of dict
        :func:`fleet_row` rows (robot ''), ranked.

    """
    from reducer_twin.msg_adapters.layouts import REMAINING_LIFE, TE_FEATURES
    from reducer_twin.core.params import ReducerParams
    from reducer_twin.core.pipeline import LifeConfig
    from reducer_twin.fleet.store import Reducer
    life = life or LifeConfig()
    params = params or ReducerParams()
    exposure = TE_FEATURES.fields.index('exposure_s')
    censored = REMAINING_LIFE.fields.index('p10_censored')
    rows = []
    for joint, res in result.joints.items():
        state = (result.states or {}).get(joint)
        summary = res.summary()
        has_life = res.life is not None and len(res.life)
        summary['rul_censored'] = bool(has_life and res.life[-1][censored] > 0)
        feats = res.features if res.features is not None else np.zeros((0, exposure + 1))
        reducer = Reducer(0, '', joint, None, None, state, None, 0, 1, len(feats),
                          float(np.sum(feats[:, exposure])) if len(feats) else 0.0, summary,
                          life.lost_motion_limit, life.warn_s, life.error_s)
        rows.append(fleet_row(reducer, params))
    plan = getattr(result, 'plan', None)
    if plan is not None and plan.others:     # another robot of the recording: never left out
        listed = result.as_json()['joints']
        for joint, reason in plan.not_analysed().items():
            summary = dict(listed[joint], rul_censored=False)
            reducer = Reducer(0, '', joint, None, None, None, None, 0, 1, 0, 0.0, summary,
                              life.lost_motion_limit, life.warn_s, life.error_s)
            rows.append(dict(fleet_row(reducer, params), reason=reason))
    return rank(rows)
