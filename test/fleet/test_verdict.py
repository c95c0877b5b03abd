"""Verdicts: what to do with each reducer, by rules stated with the numbers that applied."""

import dataclasses
import math

import numpy as np
import pytest
from reducer_twin.core.estimator import WearEstimator
from reducer_twin.core.life import limit_wear
from reducer_twin.core.params import ReducerParams
from reducer_twin.core.units import ARCMIN, HOUR
from reducer_twin.fleet.store import Reducer
from reducer_twin.fleet.verdict import FIELDS, fleet_row, overdue_life, rank

PARAMS = ReducerParams()
LIMIT = 3.0 * ARCMIN


def _state(wear_m, updates=5, var=1e-16, rate=1e-13):
    state = WearEstimator(PARAMS).state_dict()
    state['x'] = [wear_m, 0.0]
    state['P'] = [[var, 0.0], [0.0, 1e-4]]
    state['counters']['updates'] = updates
    state['duty_increment'], state['duty_exposure'] = rate * 3600.0, 3600.0
    return {'estimator': state}


def _reducer(p10_h, lm=1.0, updates=5, bags=2, retired=None, wear_m=2e-6, joint='joint_1'):
    summary = {'lost_motion_arcmin': lm, 'rul_p10_h': p10_h, 'rul_p50_h': p10_h and p10_h * 2,
               'rul_p90_h': p10_h and p10_h * 3}
    state = _state(wear_m, updates) if bags else None
    return Reducer(1, 'r1', joint, None, retired, state, 10, 1, bags, 40, 4000 * HOUR,
                   summary if bags else None, LIMIT, 1000 * HOUR, 200 * HOUR)


@pytest.mark.parametrize('reducer, verdict, words', [
    (_reducer(150.0), 'REPLACE', '150 h <= 200 h (error threshold)'),
    (_reducer(200.0), 'REPLACE', '<= 200 h'),
    (_reducer(900.0), 'PLAN', '900 h <= 1,000 h (warning threshold)'),
    (_reducer(5000.0), 'OK', '5,000 h > 1,000 h'),
    (_reducer(5000.0, updates=0), 'NOT OBSERVED', 'none with a lost motion'),
    (_reducer(None, bags=0), 'NOT OBSERVED', 'no bag analysed'),
    (_reducer(5000.0, retired=99), 'RETIRED', 'replaced at'),
], ids=['P10 below the error threshold', 'P10 at the error threshold',
        'P10 below the warning threshold', 'P10 above both', 'no accepted observation',
        'no bag since installation', 'replaced'])
def test_each_verdict_follows_its_rule_and_says_why(reducer, verdict, words):
    row = fleet_row(reducer, PARAMS)
    assert row['verdict'] == verdict and words in row['reason'], row
    assert set(FIELDS) <= set(row) and row['rule']
    if verdict == 'NOT OBSERVED':
        assert row['wear_um'] is None and row['rul_p10_h'] is None


def test_the_row_gives_the_lost_motion_with_its_standard_deviation_where_the_store_has_it():
    reducer = _reducer(5000.0)
    assert fleet_row(reducer, PARAMS)['lost_motion_std_arcmin'] is None   # an older store
    reducer.summary['lost_motion_std_arcmin'] = 0.04
    row = fleet_row(reducer, PARAMS)
    assert (row['lost_motion_arcmin'], row['lost_motion_std_arcmin']) == (1.0, 0.04)
    assert fleet_row(_reducer(None, bags=0), PARAMS)['lost_motion_std_arcmin'] is None


def test_past_the_limit_the_remaining_life_is_negative_hours_past_it():
    w_lim = limit_wear(PARAMS, LIMIT)
    reducer = _reducer(0.0, lm=3.4, wear_m=w_lim * 1.1)
    row = fleet_row(reducer, PARAMS)
    assert row['verdict'] == 'REPLACE' and 'past its limit' in row['reason']
    assert row['rul_p10_h'] < row['rul_p50_h'] < row['rul_p90_h'] < 0.0
    assert f'about {-row["rul_p50_h"]:,.0f} h ago' in row['reason']


def test_past_the_limit_with_a_soft_zone_the_limit_was_crossed_by_the_play_later():
    # The lost motion at the test torque is the play less a soft zone's shortfall: the
    # play the estimator follows met the limit stated there that much later.
    w_lim = limit_wear(PARAMS, LIMIT)
    plain = fleet_row(_reducer(0.0, lm=3.4, wear_m=w_lim * 1.3), PARAMS)
    soft = _reducer(0.0, lm=3.4, wear_m=w_lim * 1.3)
    soft.state['soft_zone_shortfall_rad'] = 0.2 * ARCMIN
    row = fleet_row(soft, PARAMS)
    assert row['verdict'] == 'REPLACE' and 'past its limit' in row['reason']
    assert plain['rul_p50_h'] < row['rul_p50_h'] < 0.0


def test_the_overdue_life_is_the_closed_form_at_a_certain_state():
    from reducer_twin.core.state_space import run_in_free_wear
    w_lim = limit_wear(PARAMS, LIMIT)
    state = _state(w_lim * 1.2, var=0.0)['estimator']
    state['P'] = [[0.0, 0.0], [0.0, 0.0]]
    p10, p50, p90 = overdue_life(state, PARAMS, LIMIT)
    wp = PARAMS.wear
    expected = (run_in_free_wear(w_lim, wp) - run_in_free_wear(w_lim * 1.2, wp)) / 1e-13
    np.testing.assert_allclose([p10, p50, p90], [expected] * 3, rtol=1e-12)
    state['duty_exposure'] = 0.0
    assert all(math.isnan(v) for v in overdue_life(state, PARAMS, LIMIT))


def test_the_fleet_is_ranked_by_p10_with_unobserved_and_retired_last():
    rows = [fleet_row(r, PARAMS) for r in (
        _reducer(5000.0, joint='a'), _reducer(None, bags=0, joint='b'),
        _reducer(150.0, joint='c'), _reducer(900.0, joint='d'),
        _reducer(100.0, retired=5, joint='e'))]
    assert [r['joint'] for r in rank(rows)] == ['c', 'd', 'a', 'b', 'e']


def test_the_row_gives_the_service_time_a_reducer_was_taken_with():
    reducer = _reducer(24000.0)
    assert fleet_row(reducer, PARAMS)['service_hours'] is None
    state = reducer.state['estimator']
    state['config']['service_time_s'] = 12000.0 * HOUR
    state['service_verdict'] = [True, 3.2]
    assert fleet_row(reducer, PARAMS)['service_hours'] == 12000.0
    state['service_verdict'] = [False, 3600.0]     # not taken: the row does not claim it
    assert fleet_row(reducer, PARAMS)['service_hours'] is None


def test_an_ok_that_is_the_models_rate_says_so():
    # A fleet met without history: every reducer OK on the physics' wear rate at its duty,
    # its own not yet seen, and the view said nothing of it.
    reducer = _reducer(24000.0)
    reducer.summary['rate_resolved'] = False
    row = fleet_row(reducer, PARAMS)
    assert row['verdict'] == 'OK' and row['rate_resolved'] is False
    assert row['reason'].endswith("; the unit's own wear rate is not yet resolved, so the "
                                  'remaining life spans the rates its recordings cannot tell '
                                  "apart, the model's at this duty among them (watch it longer, "
                                  'or give its service time: service_time_s, the hour meter)')
    reducer.summary['rate_resolved'] = True
    row = fleet_row(reducer, PARAMS)
    assert row['rate_resolved'] is True and 'wear rate' not in row['reason']


@pytest.mark.parametrize('p10_h', [150.0, 900.0])
def test_a_replace_or_plan_on_rates_not_yet_resolved_is_a_watch(p10_h):
    # A used unit recorded for minutes in real time: its lost motion cannot grow in that
    # time, the rates it cannot rule out reach hundreds of times the model's, and its P10
    # came out at hours: REPLACE for a unit halfway to its limit, on a fleet's first day.
    reducer = _reducer(p10_h, lm=1.63)
    reducer.summary['rate_resolved'] = False
    row = fleet_row(reducer, PARAMS)
    assert row['verdict'] == 'WATCH' and row['rul_p10_h'] == p10_h
    assert f'{p10_h:,.0f} h <= ' in row['reason']
    assert "with lost motion 1.63 of 3.00 arcmin; the unit's own wear rate is not yet " \
        'resolved' in row['reason'] and row['reason'].endswith('the hour meter)')
    assert 'record it longer or give its service time' in row['rule']
    # Resolved, the same P10 is the wear's.
    reducer.summary['rate_resolved'] = True
    assert fleet_row(reducer, PARAMS)['verdict'] == ('REPLACE' if p10_h <= 200.0 else 'PLAN')
    # Past its limit, a reducer is replaced whatever its rate.
    past = _reducer(p10_h, lm=3.2)
    past.summary['rate_resolved'] = False
    assert fleet_row(past, PARAMS)['verdict'] == 'REPLACE'


def test_a_growth_faster_than_wear_is_a_watch_that_says_so():
    # A third-generator base recorded for 6 minutes in real time: its windows' mix of
    # flanks read as 2.7 arcmin of growth, e^16.5 times the model's rate; P50 8 minutes,
    # REPLACE, on a unit with 2 800 h left.
    reducer = _reducer(0.07, lm=1.50)
    reducer.summary.update(rate_resolved=False, faster_than_wear=16.54)
    row = fleet_row(reducer, PARAMS)
    assert row['verdict'] == 'WATCH'
    assert row['reason'].endswith('with lost motion 1.50 of 3.00 arcmin; its lost motion reads '
                                  "as growing faster than wear can (e^16.5 times the model's "
                                  'wear rate at this duty): a change in what its windows read, '
                                  'or damage (inspect it if the lost motion stays high), not a '
                                  'wear rate (watch it longer, or give its service time: '
                                  'service_time_s, the hour meter)')


def test_a_life_that_follows_the_observed_growth_says_how_far_it_is_extrapolated():
    # A 300-h recording of a 25 000-h life: the law that won on predictions a few windows
    # ahead carries the remaining life twenty times the exposure it was learnt on.
    reducer = _reducer(24000.0)
    reducer.summary['growth_law'] = {'probability': 0.98, 'exponent': 1.16,
                                     'extrapolation': 21.8}
    row = fleet_row(reducer, PARAMS)
    assert row['reason'].endswith("the remaining life follows the lost motion's observed "
                                  'growth (as exposure^1.16), extrapolated to 22x the '
                                  'exposure it was learnt on: its interval holds only if '
                                  'that law does')
    reducer.summary['growth_law'] = None
    assert 'observed growth' not in fleet_row(reducer, PARAMS)['reason']


def test_a_life_that_follows_the_models_curve_far_says_how_far_it_is_extrapolated():
    # The same recording of a unit whose lost motion grows linearly: the model's curve,
    # never told from a straight law on 300 h, carries its life 98 times further.
    reducer = _reducer(24000.0)
    reducer.summary['curve_extrapolation'] = 98.4
    row = fleet_row(reducer, PARAMS)
    assert row['reason'].endswith("the remaining life follows the wear model's curve, "
                                  'extrapolated to 98x the exposure it was learnt on: its '
                                  'interval holds only if the lost motion keeps to that curve')
    reducer.summary['curve_extrapolation'] = None
    assert "model's curve" not in fleet_row(reducer, PARAMS)['reason']


def test_a_unit_known_since_new_is_only_told_to_be_watched_longer():
    # Fitted by a recorded replacement: its service time is known (none), so the hour
    # meter is no remedy.
    reducer = dataclasses.replace(_reducer(24000.0), installed_ns=10 ** 18)
    reducer.summary['rate_resolved'] = False
    assert fleet_row(reducer, PARAMS)['reason'].endswith('at this duty among them (watch it '
                                                         'longer)')


def test_the_row_carries_how_the_latest_analysis_read_the_inputs():
    # A reducer whose play is still taken up at the test torque reads pessimistic: the
    # line the analysis gave it stays with its row, where a fleet view ranks it.
    reducer = _reducer(5000.0)
    assert fleet_row(reducer, PARAMS)['inputs'] == []
    line = ("the transmission error's hysteresis at the lost-motion test torque (23.5 N·m) "
            'is 1.48 arcmin narrower than the flanks of higher loads give (7 windows): ...')
    reducer.summary['inputs'] = [line]
    assert fleet_row(reducer, PARAMS)['inputs'] == [line]


def test_the_row_carries_the_soft_zones_figures_of_the_latest_analysis():
    # The width at the test torque, the catalogue's lost motion, beside the play the twin
    # reads: a fleet view can compare it with a limit stated at the test torque.
    reducer = _reducer(5000.0)
    assert fleet_row(reducer, PARAMS)['soft_zone'] is None
    figures = {'width_arcmin': 1.59, 'play_arcmin': 2.99, 'shortfall_arcmin': 1.40,
               'shortfall_sd_arcmin': 0.05, 'windows': 10}
    reducer.summary['soft_zone'] = figures
    assert fleet_row(reducer, PARAMS)['soft_zone'] == figures
    assert fleet_row(reducer, PARAMS)['within_zone'] is None
    reducer.summary['within_zone'] = {'gap_arcmin': 0.65}
    assert fleet_row(reducer, PARAMS)['within_zone'] == {'gap_arcmin': 0.65}


def test_the_row_says_what_the_comparisons_at_the_test_torque_found():
    # 'not compared': the lost motion the row gives is the loaded flanks' play; a store
    # written before the analysis said so gives None (unknown), never a verdict.
    reducer = _reducer(5000.0)
    assert fleet_row(reducer, PARAMS)['test_torque_check'] is None
    reducer.summary['test_torque_check'] = 'not compared'
    assert fleet_row(reducer, PARAMS)['test_torque_check'] == 'not compared'
