"""
The processing stages the nodes share: EstimatorStage, LifeStage and the record helpers.

Windows are synthetic ``te_features`` records: torque uniform in 60-120 % of
rated at the paper's speed for 10 operating hours each, wear grown by
``wear.integrate_wear`` with a hidden rate scale and observed through
``model_tables(params).lost_motion`` with 0.05 arcmin of noise (the set-up of
test_estimator.py, as the live chain delivers it).
"""

import json
import math
from types import SimpleNamespace

import numpy as np
import pytest
from reducer_twin.core import wear
from reducer_twin.core.duty_summary import DutySummary
from reducer_twin.core.errors import InvalidInput, InvalidParameter
from reducer_twin.core.estimator import EstimatorConfig
from reducer_twin.core.life_basis import curve_extrapolation, faster_than_wear, growth_law
from reducer_twin.core.life_basis import implied_log_rate, life_trend_probability
from reducer_twin.core.life_basis import LOG_RATE_PLAUSIBLE, play_limit, rate_resolved
from reducer_twin.core.params import ReducerParams
from reducer_twin.core.pipeline import CLOCK_RESET_S, duty_to_record
from reducer_twin.core.pipeline import EstimatorStage, features_from_record
from reducer_twin.core.pipeline import LifeConfig, LifeStage
from reducer_twin.core.pipeline import reducer_state, state_from_record, taken_off
from reducer_twin.core.pipeline import TimeOffsetCalibration
from reducer_twin.core.transmission_error import model_tables
from reducer_twin.core.units import ARCMIN, HOUR
from reducer_twin.msg_adapters.layouts import REMAINING_LIFE, TE_FEATURES, WEAR_ESTIMATE

PARAMS = ReducerParams()
NOISE = 0.05 * ARCMIN
EXPOSURE = 10.0 * HOUR
WINDOW_S = 2.0


def feature_records(n=40, scale=1.0, seed=3, t0=100.0):
    """
    Return ``n`` te_features records of a reducer wearing with rate ``scale``.

    Returns
    -------
    tuple
        ``(records, true_wear [m])``.

    """
    rng = np.random.default_rng(seed)
    torque = PARAMS.rating.rated_torque * rng.uniform(0.6, 1.2, n)
    speed = np.full(n, wear.reference_speed(PARAMS))
    exposure = np.full(n, EXPOSURE)
    increment = wear.wear_rate(torque, speed, 0.0, PARAMS) * exposure
    true_w = wear.integrate_wear(exposure, torque, speed, PARAMS, rate_scale=scale)
    z = model_tables(PARAMS).lost_motion(true_w) + rng.normal(0.0, NOISE, n)
    records = []
    for k in range(n):
        duty = DutySummary(duration_s=WINDOW_S, exposure_s=EXPOSURE,
                           archard_increment=float(increment[k]),
                           mean_abs_torque=float(torque[k]), mean_abs_speed=float(speed[k]),
                           cubic_mean_torque=float(torque[k]),
                           max_abs_torque=float(1.1 * torque[k]))
        rec = dict.fromkeys(TE_FEATURES.fields, math.nan)
        rec.update({'window_start_s': t0 + k * WINDOW_S, 'window_end_s': t0 + (k + 1) * WINDOW_S,
                    'samples': 2000.0, 'lost_motion_rad': float(z[k]),
                    'lost_motion_std_rad': NOISE})
        rec.update(duty_to_record(duty))
        records.append(rec)
    return records, true_w


@pytest.fixture(scope='module')
def windows():
    return [features_from_record(r) for r in feature_records()[0]]


def run(stage, windows):
    """Step a stage with windows; return the statuses."""
    return [stage.process(f) for f in windows]


# -- record helpers ---------------------------------------------------------------------------


def test_duty_to_record_writes_the_duty_fields_of_the_te_features_layout():
    duty = DutySummary(2.0, 7200.0, 3e-9, 400.0, 1.2, 450.0, 600.0)
    rec = duty_to_record(duty)
    assert set(rec) <= set(TE_FEATURES.fields)
    assert rec == {'duration_s': 2.0, 'exposure_s': 7200.0, 'archard_increment_m': 3e-9,
                   'mean_abs_torque_nm': 400.0, 'mean_abs_speed_rad_s': 1.2,
                   'cubic_mean_torque_nm': 450.0, 'mean_speed_rad_s': 1.2,
                   'max_abs_torque_nm': 600.0}


def test_features_from_record_reads_back_what_the_te_monitor_writes():
    rec = feature_records(n=1)[0][0]
    rec.update({'wear_fit_m': 3e-6, 'wear_fit_std_m': 2e-7, 'lost_motion_std_rad': 1e-5})
    f = features_from_record(rec)
    assert (f.t_start, f.t_end) == (rec['window_start_s'], rec['window_end_s'])
    assert (f.lost_motion, f.lost_motion_std) == (rec['lost_motion_rad'], 1e-5)
    assert (f.wear_fit, f.wear_fit_std) == (3e-6, 2e-7)
    assert duty_to_record(f.duty) == {k: rec[k] for k in duty_to_record(f.duty)}


def test_a_record_round_trip_through_json_keeps_every_value():
    rec = feature_records(n=1)[0][0]
    again = json.loads(json.dumps(duty_to_record(features_from_record(rec).duty)))
    assert again == duty_to_record(features_from_record(rec).duty)


def test_state_from_record_refuses_a_non_finite_state():
    rec = EstimatorStage(PARAMS).record(0.0)
    x, P = state_from_record(rec)
    assert x.shape == (3,) and P.shape == (3, 3)
    rec['var_wear_m2'] = math.nan
    with pytest.raises(InvalidInput, match='non-finite'):
        state_from_record(rec)


# -- EstimatorStage ---------------------------------------------------------------------------


def test_a_stage_without_state_file_steps_the_filter_and_records_the_wear_layout(windows):
    stage = EstimatorStage(PARAMS)
    statuses = run(stage, windows[:10])
    assert set(statuses) <= {'accepted', 'skipped'} and statuses.count('accepted') >= 8
    rec = stage.record(windows[9].t_end)
    assert set(rec) == set(WEAR_ESTIMATE.fields)
    assert rec['exposure_s'] == pytest.approx(10 * EXPOSURE)
    assert rec['updates'] == statuses.count('accepted')
    assert rec['lost_motion_obs_rad'] == windows[9].lost_motion
    assert stage.restored_from is None


def test_a_stage_says_once_how_the_service_time_was_taken(windows):
    # A unit the twin meets after 10 000 h: the wear estimator's log says it once, when
    # the duty is known (10 windows) and the service time has been judged.
    lines = []
    stage = EstimatorStage(PARAMS, EstimatorConfig(service_time_s=10000.0 * HOUR),
                           log=lines.append)
    run(stage, windows[:15])
    said = [line for line in lines if line.startswith('service time')]
    assert said == [stage.service_said]
    assert said[0].startswith('service time 10,000 h taken: its wear over it is ')
    assert said[0].endswith(" times the model's rate at this duty")


def test_the_estimate_follows_the_synthetic_truth(windows):
    records, true_w = feature_records()
    stage = EstimatorStage(PARAMS)
    run(stage, windows)
    assert stage.estimator.wear == pytest.approx(true_w[-1], rel=0.15)


@pytest.mark.parametrize('back_s, status', [
    (0.0, 'replay'),
    (CLOCK_RESET_S - 0.5, 'replay'),
    (CLOCK_RESET_S, 'accepted'),
    (10 * CLOCK_RESET_S, 'accepted'),
])
def test_a_window_far_enough_back_is_a_clock_reset_and_is_accepted(windows, back_s, status):
    stage = EstimatorStage(PARAMS)
    run(stage, windows[:5])
    exposure = stage.estimator.exposure_s
    last = windows[4].t_end
    later = features_from_record({**feature_records(n=6)[0][5],
                                  'window_start_s': last - back_s - WINDOW_S,
                                  'window_end_s': last - back_s})
    assert stage.process(later) == status
    grew = stage.estimator.exposure_s > exposure
    assert grew == (status != 'replay')
    if status == 'accepted':
        assert stage.estimator.t_end == last - back_s


# -- LifeStage --------------------------------------------------------------------------------


@pytest.fixture(scope='module')
def worn_record(windows):
    stage = EstimatorStage(PARAMS)
    run(stage, windows)
    return stage.record(windows[-1].t_end)


@pytest.mark.parametrize('warn_h, error_h, level', [
    (1.0, 0.5, 'OK'),
    (1e6, 1.0, 'WARN'),
    (1e6, 1e6, 'ERROR'),
])
def test_life_levels_follow_the_thresholds_on_p10(windows, worn_record, warn_h, error_h, level):
    stage = LifeStage(PARAMS, LifeConfig(warn_s=warn_h * HOUR, error_s=error_h * HOUR))
    stage.observe_duty(windows[-1].duty)
    record, got, message = stage.process(worn_record)
    assert got == level
    assert set(record) == set(REMAINING_LIFE.fields)
    assert 0.0 < record['p10_s'] <= record['p50_s'] <= record['p90_s']
    assert math.isfinite(record['catalogue_life_s'])
    assert 'remaining life P10' in message


@pytest.mark.parametrize('warn_h, error_h', [(1.0, 0.5), (1e6, 1.0), (1e6, 1e6)])
def test_without_a_lost_motion_the_level_is_stale_whatever_the_duty_alone_predicts(
        windows, worn_record, warn_h, error_h):
    # The same prediction with no observation behind it: never OK, WARN or ERROR, and no
    # number in the record (a consumer acting on P10 or threshold_met acts on evidence).
    stage = LifeStage(PARAMS, LifeConfig(warn_s=warn_h * HOUR, error_s=error_h * HOUR))
    stage.observe_duty(windows[-1].duty)
    record, level, message = stage.process({**worn_record, 'updates': 0.0})
    assert level == 'STALE'
    assert message.startswith('not observed: no lost-motion observation yet; from the duty '
                              "alone (the model's wear rate, no evidence): remaining life P10")
    for key in ('p10_s', 'p50_s', 'p90_s', 'mean_s', 'event_state', 'censored_fraction'):
        assert math.isnan(record[key]), key
    assert record['threshold_met'] == record['p10_censored'] == 0.0
    assert math.isfinite(record['catalogue_life_s']) and record['horizon_s'] > 0.0


def test_a_reducer_beyond_the_limit_is_an_error_with_no_life_left(worn_record):
    # Worn out by both models: the wear model's wear and the observed law's lost motion.
    worn_out = {**worn_record, 'wear_m': 200e-6, 'trend_growth_rad': 4.0 * ARCMIN}
    record, level, message = LifeStage(PARAMS).process(worn_out)
    assert level == 'ERROR'
    assert record['p10_s'] == record['p50_s'] == record['p90_s'] == 0.0
    assert record['threshold_met'] == 1.0
    assert 'worn out' in message


def test_the_catalogue_life_needs_a_duty(worn_record):
    record, _, _ = LifeStage(PARAMS).process(worn_record)
    assert math.isnan(record['catalogue_life_s'])


def test_a_window_without_operation_leaves_the_catalogue_life_on_the_previous_duty(
        windows, worn_record):
    # One sample closed by a gap: no duration, so the duty means are NaN (0/0). It must
    # neither stop the remaining life (InvalidInput from the catalogue formula) nor erase
    # the duty seen so far.
    stage = LifeStage(PARAMS)
    stage.observe_duty(windows[-1].duty)
    before, _, _ = stage.process(worn_record)
    empty = SimpleNamespace(duration_s=0.0, exposure_s=0.0, archard_increment=0.0,
                            mean_abs_torque=math.nan, mean_abs_speed=math.nan,
                            cubic_mean_torque=math.nan, mean_speed=math.nan,
                            max_abs_torque=700.0)
    stage.observe_duty(empty)
    after, _, _ = stage.process(worn_record)
    assert after == before
    assert math.isfinite(after['catalogue_life_s'])


def test_predictions_are_repeatable_for_the_same_record(windows, worn_record):
    # Common random numbers: successive predictions differ by the state only.
    stage = LifeStage(PARAMS)
    stage.observe_duty(windows[-1].duty)
    assert stage.process(worn_record) == stage.process(worn_record)


def test_a_soft_zone_gives_the_lost_motion_at_the_test_torque_and_the_limit_met_later(windows):
    # Windows that carry a soft zone's shortfall (its play taken up beyond the test
    # torque): the estimate follows the play as before; the lost motion is given at the
    # test torque, and the limit stated there is met where the play exceeds it by that much.
    shortfall = 0.5 * ARCMIN
    plain, soft = EstimatorStage(PARAMS), EstimatorStage(PARAMS)
    run(plain, windows)
    run(soft, [SimpleNamespace(**{**vars(w), 'soft_zone_shortfall': shortfall})
               for w in windows])
    before, after = (stage.record(windows[-1].t_end) for stage in (plain, soft))
    assert before['soft_zone_shortfall_rad'] == 0.0
    assert after['soft_zone_shortfall_rad'] == shortfall
    assert after['lost_motion_rad'] == pytest.approx(before['lost_motion_rad'] - shortfall)
    assert after['wear_m'] == before['wear_m']
    assert after['lost_motion_obs_rad'] == before['lost_motion_obs_rad']
    stage = LifeStage(PARAMS)
    raised = LifeStage(PARAMS, LifeConfig(lost_motion_limit=stage.limit + shortfall))
    got, expected = stage.prediction(after), raised.prediction(before)
    assert (got.p10, got.p50, got.p90) == (expected.p10, expected.p50, expected.p90)
    assert got.p50 > stage.prediction(before).p50
    # Records with and without one, predicted together, each as alone.
    both = stage.predictions([before, after])
    assert [p.p50 for p in both] == [stage.prediction(before).p50, got.p50]


def _given(windows, shortfall=0.0, width=0.0):
    """Run a stage over ``windows`` carrying a soft-zone shortfall; return it and its record."""
    stage = EstimatorStage(PARAMS)
    run(stage, [SimpleNamespace(**{**vars(w), 'soft_zone_shortfall': shortfall,
                                   'soft_zone_width': width}) for w in windows])
    return stage, stage.record(windows[-1].t_end)


def test_a_soft_zone_is_taken_off_the_play_only_down_to_the_width_at_the_test_torque(
        windows):
    # The estimate follows the play its windows read; where their loads seldom pass the
    # soft zone's knee it lies near the width at the test torque, not at the play of the
    # far flanks. Taken off whole there, a shortfall left a third-generator base 0.02
    # arcmin for a true 1.19 (never below zero, now: no more than down to the width).
    play = _given(windows)[1]['lost_motion_rad']

    def given(shortfall, width):
        return _given(windows, shortfall, width)[1]

    # Windows that read the play of the far flanks: the whole shortfall, as before.
    far = given(0.5 * ARCMIN, play - 0.5 * ARCMIN)
    assert far['lost_motion_rad'] == pytest.approx(play - 0.5 * ARCMIN, abs=1e-3 * ARCMIN)
    assert far['soft_zone_shortfall_rad'] == pytest.approx(0.5 * ARCMIN, abs=1e-3 * ARCMIN)
    # Windows that read between: down to the width, and the limit met where the play
    # exceeds it by what was taken off.
    between = given(1.0 * ARCMIN, play - 0.3 * ARCMIN)
    assert between['lost_motion_rad'] == pytest.approx(play - 0.3 * ARCMIN, abs=1e-3 * ARCMIN)
    assert between['soft_zone_shortfall_rad'] == pytest.approx(0.3 * ARCMIN,
                                                               abs=1e-3 * ARCMIN)
    # Windows that read the width itself or less: nothing taken off, never below zero.
    near = given(1.5 * ARCMIN, play + 0.1 * ARCMIN)
    assert near['lost_motion_rad'] == pytest.approx(play)
    assert near['soft_zone_shortfall_rad'] == 0.0
    assert taken_off(0.5 * ARCMIN, 0.0, lambda: 1 / 0) == 0.5 * ARCMIN   # width not known
    assert taken_off(0.5 * ARCMIN, 1.0 * ARCMIN, lambda: math.nan) == 0.5 * ARCMIN


def test_loads_within_a_soft_zone_give_the_lost_motion_up_to_the_width_at_the_test_torque(
        windows):
    # A lost motion read below its bins' width at the test torque (core/within_zone.py):
    # the windows carry the gap as a negative shortfall, added no further than that width,
    # and the limit is met that much sooner.
    play = _given(windows)[1]['lost_motion_rad']

    def given(gap, width):
        return _given(windows, -gap, width)

    stage, below = given(0.6 * ARCMIN, play + 0.8 * ARCMIN)
    assert below['lost_motion_rad'] == pytest.approx(play + 0.6 * ARCMIN, abs=1e-3 * ARCMIN)
    assert below['soft_zone_shortfall_rad'] == pytest.approx(-0.6 * ARCMIN, abs=1e-3 * ARCMIN)
    assert play_limit(below, 3.0 * ARCMIN) == pytest.approx(2.4 * ARCMIN, abs=1e-3 * ARCMIN)
    # Up to the width only; nothing where the play followed is already that wide.
    _, near = given(0.6 * ARCMIN, play + 0.2 * ARCMIN)
    assert near['lost_motion_rad'] == pytest.approx(play + 0.2 * ARCMIN, abs=1e-3 * ARCMIN)
    _, wide = given(0.6 * ARCMIN, play - 0.1 * ARCMIN)
    assert wide['lost_motion_rad'] == pytest.approx(play)
    assert wide['soft_zone_shortfall_rad'] == 0.0
    # A later window that no longer says it: the stream's evidence is followed.
    stage.step(windows[-1])
    assert stage.soft_zone_shortfall == 0.0


def test_a_soft_zone_follows_its_stream_and_one_carried_over_stays_until_the_stream_says(
        windows):
    def said(ws, shortfall):
        return [SimpleNamespace(**{**vars(w), 'soft_zone_shortfall': shortfall}) for w in ws]

    # Within a stream the windows' evidence is followed, back to none where it fades.
    stage = EstimatorStage(PARAMS)
    run(stage, said(windows[:10], 0.5 * ARCMIN))
    run(stage, windows[10:12])
    assert stage.record(windows[11].t_end)['soft_zone_shortfall_rad'] == 0.0
    # The next bag's windows say none until their own check has seen enough: the one
    # carried over (TwinBack.restore) stays meanwhile; a new reducer has none.
    stage = EstimatorStage(PARAMS)
    stage.soft_zone_shortfall = 0.5 * ARCMIN
    run(stage, windows[:20])
    assert stage.record(windows[19].t_end)['soft_zone_shortfall_rad'] == 0.5 * ARCMIN
    run(stage, said(windows[20:], 0.3 * ARCMIN))
    assert stage.soft_zone_shortfall == 0.3 * ARCMIN      # this stream's own
    stage.reset('replaced')
    assert stage.record(windows[-1].t_end)['soft_zone_shortfall_rad'] == 0.0


def test_a_stage_continues_from_a_reducer_state_with_its_soft_zone(windows):
    # What a bag (TwinBack.state) or the fleet store's live writer leaves is what the
    # next bag, or a wear_estimator started from the store, continues from.
    stage = EstimatorStage(PARAMS)
    run(stage, [SimpleNamespace(**{**vars(w), 'soft_zone_shortfall': 0.5 * ARCMIN})
                for w in windows[:20]])
    state = json.loads(json.dumps(reducer_state(
        stage.estimator.state_dict(), windows[19].duty, stage.last_observation,
        stage.soft_zone_shortfall)))
    assert state['duty']['exposure_s'] == windows[19].duty.exposure_s
    after = EstimatorStage(PARAMS)
    after.continue_from(state)
    assert after.record(1.0) == {**stage.record(1.0)}
    assert after.soft_zone_shortfall == 0.5 * ARCMIN


def test_a_prediction_does_not_depend_on_the_records_predicted_before(worn_record):
    # The stage draws its random numbers once and reuses them: a record gets the answer of
    # a new stage, whatever the stage predicted before.
    busy = LifeStage(PARAMS)
    for wear_m in (1e-6, 3e-6, 200e-6):
        busy.prediction({**worn_record, 'wear_m': wear_m})
    assert busy.prediction(worn_record) == LifeStage(PARAMS).prediction(worn_record)


def test_a_record_of_the_twin_before_per_unit_states_is_still_assessed(worn_record):
    # A derived bag of an older twin carries [w, ln s] only: a nominal unit, no trend.
    old = {k: worn_record[k] for k in (
        'stamp_s', 'wear_m', 'wear_std_m', 'rate_scale', 'rate_scale_std', 'log_rate_scale',
        'var_wear_m2', 'cov_wear_log_rate_m', 'var_log_rate', 'duty_rate_m_per_s',
        'lost_motion_rad', 'lost_motion_obs_rad', 'exposure_s', 'updates', 'rejected')}
    record, level, _ = LifeStage(PARAMS).process(old)
    assert level in ('OK', 'WARN', 'ERROR')
    assert 0.0 < record['p10_s'] <= record['p50_s'] <= record['p90_s']


def test_the_life_message_says_when_the_prediction_follows_the_observed_trend(worn_record):
    stage = LifeStage(PARAMS)
    _, _, plain = stage.process({**worn_record, 'trend_probability': 0.1})
    assert 'observed trend' not in plain
    _, _, noted = stage.process({**worn_record, 'trend_probability': 0.95,
                                 'trend_exponent': 1.02})
    assert 'grows unlike the wear model (as exposure^1.02, probability 0.95)' in noted
    assert 'the prediction follows the observed trend' in noted


def test_the_life_message_says_how_far_the_observed_trend_is_extrapolated(worn_record):
    # A law learnt on the first 1 % of a life carries a hundredfold: the engineer is told.
    law = {**worn_record, 'trend_probability': 0.98, 'trend_exponent': 1.0,
           'trend_new_rad': 0.45 * ARCMIN, 'trend_growth_rad': 0.05 * ARCMIN, 'updates': 10 ** 6}
    _, _, noted = LifeStage(PARAMS).process(law)
    # (3 - 0.45) / 0.05 = 51 times the exposure seen at exponent 1.
    assert noted.endswith('the prediction follows the observed trend, extrapolated to 51x '
                          'the exposure it was learnt on')
    # Scored over fewer windows than that reach: its weight in the life is said too.
    _, _, short = LifeStage(PARAMS).process({**law, 'updates': 144})
    weight = 0.5 + 0.48 * math.log(144 / 16) / math.log(51.0)
    assert short.endswith(f'learnt on (weighed {weight:.2f}: its score spans less)')
    _, _, past = LifeStage(PARAMS).process({**law, 'trend_growth_rad': 2.6 * ARCMIN})
    assert 'extrapolated' not in past, 'a law already past the limit reaches it now'
    assert growth_law(law, 3.0 * ARCMIN) == pytest.approx(
        {'probability': 0.98, 'weight': 0.98, 'exponent': 1.0, 'extrapolation': 51.0})
    assert growth_law(law)['extrapolation'] is None, 'no limit, no reach'
    assert growth_law({**law, 'trend_probability': 0.4}, 3.0 * ARCMIN) is None


def test_a_law_scored_on_a_short_span_weighs_towards_its_prior_beyond_it(worn_record):
    # The 2-kHz recording of the model's simulator: the law won (0.98) on 144 windows, 128
    # of them scored (ln(144/16) = 2.20 of log-exposure), and reaches the limit at 22 times
    # the exposure seen (ln 22 = 3.10): its weight in the remaining life is
    # 0.5 + 0.48 * 2.20 / 3.10.
    law = {**worn_record, 'trend_probability': 0.98, 'trend_exponent': 1.16,
           'trend_new_rad': 0.44 * ARCMIN, 'trend_growth_rad': 0.07 * ARCMIN, 'updates': 144}
    reach = ((3.0 - 0.44) / 0.07) ** (1.0 / 1.16)
    want = 0.5 + 0.48 * math.log(144 / 16) / math.log(reach)
    assert life_trend_probability(law, 3.0 * ARCMIN) == pytest.approx(want, rel=1e-12)
    assert 0.83 < want < 0.85
    # Scored over a span longer than the extrapolation: the score stands.
    assert life_trend_probability({**law, 'updates': 2000}, 3.0 * ARCMIN) == 0.98
    # A law that never meets the limit is not extrapolated to it: the score stands.
    assert life_trend_probability({**law, 'trend_growth_rad': 0.0}, 3.0 * ARCMIN) == 0.98


def test_the_remaining_life_takes_the_law_at_its_weight_beyond_the_scored_span(worn_record):
    # Nothing scored yet (16 windows): the law weighs its prior, whatever the score says.
    law = {**worn_record, 'trend_exponent': 1.0, 'trend_new_rad': 0.44 * ARCMIN,
           'trend_growth_rad': 0.07 * ARCMIN}
    stage = LifeStage(PARAMS)
    early = stage.prediction({**law, 'trend_probability': 0.99, 'updates': 16})
    prior = stage.prediction({**law, 'trend_probability': 0.5, 'updates': 5000})
    assert (early.p10, early.p50, early.p90) == (prior.p10, prior.p50, prior.p90)
    late = stage.prediction({**law, 'trend_probability': 0.99, 'updates': 5000})
    assert late.p50 != early.p50


def test_the_life_message_says_how_far_the_wear_models_curve_is_extrapolated(worn_record):
    # 300 h of a new unit whose lost motion grows linearly: a tenth of an arcminute of
    # growth does not tell that from the model's curve, which then carries the life 30-100
    # times the exposure seen, its P50 twice the truth (bench_early_life.py): said.
    stage = LifeStage(PARAMS)
    curve = {**worn_record, 'trend_probability': 0.1, 'var_log_rate': 0.1 ** 2,
             'updates': 96}
    life, _, noted = stage.process(curve)
    reach = 1.0 + life['p50_s'] * curve['duty_rate_m_per_s'] / curve['archard_exposure_m']
    assert reach > 96 / 16, 'the fixture is a unit early in its life'
    assert curve_extrapolation(curve, life) == pytest.approx(reach, rel=1e-12)
    assert noted.endswith("; the prediction follows the wear model's curve, extrapolated to "
                          f'{reach:.0f}x the exposure it was learnt on (its shape compared '
                          'with the observed growth over 6x)')
    # Scored over a span as long as the extrapolation (a unit watched since new up to
    # mid-life): nothing to add.
    long = {**curve, 'updates': int(16 * reach) + 16}
    assert curve_extrapolation(long, stage.process(long)[0]) is None
    assert 'curve' not in stage.process(long)[2]
    # The law the likelier, or the rate still the model's: their own clauses say it.
    for other in ({'trend_probability': 0.9, 'trend_exponent': 1.0},
                  {'var_log_rate': 1.83 ** 2}):
        record = {**curve, **other}
        assert curve_extrapolation(record, stage.process(record)[0]) is None
        assert "wear model's curve, extrapolated" not in stage.process(record)[2]


def test_the_law_weight_what_if_gives_each_models_remaining_life_alone(worn_record):
    # Where a miss comes from (bench_accuracy.py --branches): the wear model's curve alone,
    # the observed law alone, and the mixture between them.
    stage = LifeStage(PARAMS)
    law = {**worn_record, 'trend_probability': 0.7, 'trend_exponent': 1.0,
           'trend_new_rad': 0.44 * ARCMIN, 'trend_growth_rad': 0.07 * ARCMIN, 'updates': 5000}
    curve = stage.prediction(law, law_weight=0.0)
    observed = stage.prediction(law, law_weight=1.0)
    # Scored over a span longer than the law's reach, the weight is the probability.
    assert curve == stage.prediction({**law, 'trend_probability': 0.0})
    assert observed == stage.prediction({**law, 'trend_probability': 1.0})
    assert curve.p50 != observed.p50
    mixed = stage.prediction(law)
    assert min(curve.p50, observed.p50) < mixed.p50 < max(curve.p50, observed.p50)
    with pytest.raises(InvalidParameter, match=r'law_weight .*1\.5'):
        stage.prediction(law, law_weight=1.5)


def test_a_p10_on_rates_not_yet_resolved_warns_but_is_no_error(windows, worn_record):
    # A used unit recorded for minutes in real time: its P10 spans rates its windows cannot
    # rule out (hours, for a unit halfway to its limit), and /diagnostics said ERROR for
    # every reducer of a robot the twin had just met.
    stage = LifeStage(PARAMS, LifeConfig(warn_s=1e6 * HOUR, error_s=1e6 * HOUR))
    stage.observe_duty(windows[-1].duty)
    unresolved = {**worn_record, 'var_log_rate': 1.83 ** 2, 'trend_probability': 0.1}
    _, level, message = stage.process(unresolved)
    assert level == 'WARN' and 'not yet resolved' in message
    assert stage.process(worn_record)[1] == 'ERROR'
    _, level, _ = stage.process({**unresolved, 'wear_m': 150e-6})
    assert level == 'ERROR', 'a reducer worn out is one, whatever its rate'


def test_the_life_message_says_when_it_is_the_models_rate_not_the_units_own(worn_record):
    # A twin started on a used unit with a short recording: its rate is the prior's
    # (ln s sd near 2) and its remaining life the model's at this duty (P10 24 000 h on a
    # unit with 5 200 h left), which nothing said.
    stage = LifeStage(PARAMS)
    _, _, unresolved = stage.process({**worn_record, 'var_log_rate': 1.83 ** 2,
                                      'trend_probability': 0.1})
    assert unresolved.endswith("; this unit's own wear rate is not yet resolved (ln-rate sd "
                               '1.83, resolved at 0.5): its remaining life spans the rates its '
                               "windows cannot tell apart, the model's at this duty among them")
    assert not rate_resolved({**worn_record, 'var_log_rate': 1.83 ** 2, 'trend_probability': 0.1})
    for resolved in ({'var_log_rate': 0.49 ** 2}, {'var_log_rate': 4.0, 'trend_probability': 0.9}):
        record = {**worn_record, 'trend_exponent': 1.0, **resolved}
        assert rate_resolved(record)
        assert 'not yet resolved' not in stage.process(record)[2]
    # A law that won its score on windows whose growth it cannot tell from none (minutes of
    # a real-time recording: 0.00087 +- 0.00066 arcmin) resolves no rate.
    flat = {'trend_growth_rad': 0.00087 * ARCMIN, 'var_trend_growth_rad2': (0.00066 * ARCMIN) ** 2}
    assert not rate_resolved({**worn_record, 'var_log_rate': 4.0, 'trend_probability': 0.9,
                              **flat})


def test_a_growth_faster_than_wear_resolves_no_rate(worn_record):
    # Used units recorded for 6 minutes in real time (bench_service_time.py --aging-factor 1
    # --hours 0.1): windows whose reading drifted by 0.02 arcmin, or a base whose mix of
    # flanks moved it by arcmin, read as wear at e^10-e^18 times the model's rate; the law
    # (or a rate released to follow it) took that as the unit's own: P50 of minutes to
    # hours, resolved, REPLACE, on units with 1 500-7 000 h left.
    stage = LifeStage(PARAMS, LifeConfig(warn_s=1e6 * HOUR, error_s=1e6 * HOUR))
    # A law the likelier whose growth to date is 3.2 sds above none (as such a base's).
    seen = {'trend_probability': 0.97, 'var_log_rate': 0.3 ** 2,
            'trend_growth_rad': 3.2 * math.sqrt(worn_record['var_trend_growth_rad2'])}
    record = {**worn_record, **seen}
    # The growth to date as a rate on the wear model's curve (its secant from new).
    secant = (record['lost_motion_rad'] - record['lost_motion_new_rad']) / record['wear_m']
    model_growth = secant * record['archard_exposure_m']

    def at(log_rate):
        scale = record['trend_growth_rad'] / model_growth / math.exp(log_rate)
        return {**record, 'archard_exposure_m': record['archard_exposure_m'] * scale}

    fast = at(10.1)
    assert implied_log_rate(fast) == pytest.approx(10.1, abs=1e-9)
    assert faster_than_wear(fast) == pytest.approx(10.1, abs=1e-9)
    assert not rate_resolved(fast)
    _, level, message = stage.process(fast)
    assert level == 'WARN'
    assert message.endswith("; this unit's lost motion reads as growing faster than wear can "
                            "(e^10.1 times the model's wear rate at this duty; its prior allows "
                            'up to e^6): that is a change in what its windows read, or damage '
                            '(a step, not wear; inspect it if the lost motion stays high), not a '
                            'wear rate, so its remaining life spans rates its windows do not '
                            'resolve')
    # The same growth over an exposure that makes it a rate wear can have (the independent
    # generator's fastest units read ln s up to 4.6) resolves it, as before.
    assert faster_than_wear(at(4.6)) is None and rate_resolved(at(4.6))
    # The wear model's own rate, where the law is not the likelier, alike.
    model = {**worn_record, 'trend_probability': 0.1, 'var_log_rate': 0.3 ** 2}
    assert not rate_resolved({**model, 'log_rate_scale': 10.5})
    assert faster_than_wear({**model, 'log_rate_scale': 10.5}) == 10.5
    assert rate_resolved({**model, 'log_rate_scale': 4.6})
    assert LOG_RATE_PLAUSIBLE == pytest.approx(6.0)


def test_the_record_widens_the_rate_by_how_far_the_lagged_predictions_fell_short(windows):
    # Where both models' predictions eight windows ahead miss by more than they claim
    # (trend_score.TrendScore.forecast_scale), the remaining life extrapolates with the
    # rate's variance times that factor, its correlations kept; the wear stays the filter's.
    stage = EstimatorStage(PARAMS)
    run(stage, windows[:30])
    est = stage.estimator
    assert est.forecast_scale == 1.0
    calibrated = stage.record(windows[29].t_end)
    assert calibrated['var_log_rate'] == pytest.approx(est.P[1, 1])
    est._scoring.forecast = [40.0, 4.0 * 40.0 + 3.0 * 8.0]     # a mean of 4 with the prior
    assert est.forecast_scale == pytest.approx(4.0)
    wide = stage.record(windows[29].t_end)
    assert wide['var_log_rate'] == pytest.approx(4.0 * calibrated['var_log_rate'])
    assert wide['cov_wear_log_rate_m'] == pytest.approx(2.0 * calibrated['cov_wear_log_rate_m'])
    assert wide['var_wear_m2'] == calibrated['var_wear_m2']
    assert wide['rate_scale_std'] > calibrated['rate_scale_std']
    # The wear model's share of the remaining life is the wider (the growth law's is not
    # widened: here the model's alone, its score spanning more than the extrapolation).
    life = LifeStage(PARAMS)
    alone = {'trend_probability': 0.0, 'updates': 10 ** 6}
    narrow, _, _ = life.process({**calibrated, **alone})
    widened, _, _ = life.process({**wide, **alone})
    assert widened['p90_s'] - widened['p10_s'] > 1.3 * (narrow['p90_s'] - narrow['p10_s'])


def test_the_duty_uncertainty_of_the_record_widens_the_interval(worn_record):
    stage = LifeStage(PARAMS)
    narrow, _, _ = stage.process({**worn_record, 'duty_rate_rel_std': 0.0})
    wide, _, _ = stage.process({**worn_record, 'duty_rate_rel_std': 0.3})
    assert wide['p90_s'] - wide['p10_s'] > narrow['p90_s'] - narrow['p10_s']
    with pytest.raises(InvalidInput, match='duty_rate_rel_std'):
        stage.process({**worn_record, 'duty_rate_rel_std': -0.1})


@pytest.mark.parametrize('values, name', [
    ({'warn_s': -1.0}, 'life.warn_s'),
    ({'error_s': math.nan}, 'life.error_s'),
    ({'warn_s': 10.0 * HOUR, 'error_s': 20.0 * HOUR}, 'life.error_s'),
    ({'lost_motion_limit': 0.0}, 'life.lost_motion_limit'),
    ({'lost_motion_limit': 0.2}, 'life.lost_motion_limit'),
    ({'horizon_s': 0.0}, 'life.horizon_s'),
    ({'n_samples': 99}, 'life.n_samples'),
    ({'n_samples': 2500.5}, 'life.n_samples'),
    ({'duty_rate_rel_std': True}, 'life.duty_rate_rel_std'),
    ({'duty_rate_rel_std': -0.1}, 'life.duty_rate_rel_std'),
])
def test_bad_life_config_values_raise_invalid_parameter_naming_them(values, name):
    with pytest.raises(InvalidParameter, match=name):
        LifeConfig(**values)


def test_life_config_error_above_warn_names_both_thresholds():
    with pytest.raises(InvalidParameter, match=r'life\.error_s .* must not exceed life\.warn_s'):
        LifeConfig(warn_s=10.0 * HOUR, error_s=20.0 * HOUR)


def test_a_non_finite_wear_record_raises_invalid_input(worn_record):
    with pytest.raises(InvalidInput):
        LifeStage(PARAMS).process({**worn_record, 'wear_m': math.inf})


def _fits(offsets_s, start_s=0.0, window_s=2.0):
    """Windows' fitted time offsets, one window every ``window_s`` from ``start_s``."""
    return [SimpleNamespace(time_offset_s=v, t_end=start_s + window_s * (k + 1))
            for k, v in enumerate(offsets_s)]


def test_the_time_offset_is_learnt_once_from_the_first_windows_and_can_be_learnt_again():
    # The median of the first windows' fits goes into the link stamps once. Learnt from a
    # TE later found wrong (an encoder found held), it is taken back and learnt again.
    extractor = SimpleNamespace(link_time_offset_s=10e-6)
    calibration = TimeOffsetCalibration(extractor, windows=3)
    fits = _fits([40e-6, math.nan, 60e-6, 50e-6])
    assert [calibration.observe(f) for f in fits] == [False, False, False, True]
    assert calibration.applied == pytest.approx(50e-6)
    assert extractor.link_time_offset_s == pytest.approx(60e-6)
    assert not calibration.observe(fits[0])        # once
    calibration.restart()
    assert calibration.applied is None and extractor.link_time_offset_s == pytest.approx(10e-6)
    assert [calibration.observe(f) for f in fits] == [False, False, False, True]


def test_an_offset_of_milliseconds_is_refined_by_later_windows_until_what_is_left_is_linear():
    # Windows whose TE carries milliseconds read them less exactly (a shoulder at 20 ms:
    # its first five fits gave a median of 18.8 ms, and the 1.2 ms left withheld every
    # later window). The next windows' median is added while beyond TIME_OFFSET_LINEAR_S.
    extractor = SimpleNamespace(link_time_offset_s=0.0)
    calibration = TimeOffsetCalibration(extractor, windows=5)
    first = _fits([8.96e-3, 19.70e-3, 10.32e-3, 18.84e-3, 19.27e-3])
    assert [calibration.observe(f) for f in first] == [False] * 4 + [True]
    assert calibration.delta == pytest.approx(18.84e-3) and not calibration.settled
    left = _fits([1.18e-3, 1.14e-3, 1.16e-3, 1.2e-3, 1.1e-3], 10.0)
    assert [calibration.observe(f) for f in left] == [False] * 4 + [True]
    assert calibration.delta == pytest.approx(1.16e-3)
    assert extractor.link_time_offset_s == pytest.approx(20.0e-3)
    assert calibration.applied == pytest.approx(20.0e-3) and not calibration.settled
    small = _fits([2e-5, -1e-5, 0.0, 1e-5, 3e-5], 20.0)
    assert not any(calibration.observe(f) for f in small)
    assert calibration.settled and extractor.link_time_offset_s == pytest.approx(20.0e-3)
    assert calibration.drift is None and 'drift' not in calibration.reason


def test_windows_that_disagree_through_a_change_of_load_do_not_move_a_learnt_offset():
    # A third-generator shoulder (offset -0.6 ms) found -0.1, 0, 2.2, 1.6, 1.6 ms through
    # a change of its load: taken, their median sent the offset 1.6 ms off and back.
    extractor = SimpleNamespace(link_time_offset_s=0.0)
    calibration = TimeOffsetCalibration(extractor, windows=5)
    for f in _fits([-0.58e-3, -0.55e-3, -0.41e-3, -0.63e-3, -0.63e-3]):
        calibration.observe(f)
    assert calibration.applied == pytest.approx(-0.58e-3) and calibration.settled
    transient = _fits([-0.09e-3, -0.02e-3, 2.15e-3, 1.56e-3, 1.6e-3], 10.0)
    assert not any(calibration.observe(f) for f in transient)
    assert calibration.applied == pytest.approx(-0.58e-3) and calibration.settled


def test_a_drifting_clock_is_followed_between_the_windows_and_said():
    # Two clocks 100 ppm apart: every five 2-s windows find 1 ms more. Once three
    # corrections agree, the offset follows the drift between them, and it is said.
    extractor = SimpleNamespace(link_time_offset_s=0.0)
    calibration = TimeOffsetCalibration(extractor, windows=5)
    t = 0.0
    for group in range(4):
        for f in _fits([0.9e-3, 1.0e-3, 1.0e-3, 1.1e-3, 1.0e-3], t):
            calibration.observe(f)
        t += 10.0
    assert calibration.drift == pytest.approx(1e-4, rel=0.01)
    assert extractor.link_time_offset_s == pytest.approx(4e-3)
    # The last correction holds at the middle of its windows (36 s): 5 s on, 0.5 ms more.
    delta = calibration.follow(t - 4.0 + 5.0)
    assert delta == pytest.approx(0.5e-3, rel=0.02)
    assert extractor.link_time_offset_s == pytest.approx(4.5e-3, rel=0.01)
    assert 'drift by 6 ms a minute (100 ppm' in calibration.reason


def test_an_offset_carried_from_the_last_stream_is_applied_and_checked_by_the_windows():
    # A reducer's next bag starts from the offset its last ended with: applied at once,
    # not settled until the windows' median confirms it; a wrong one is corrected as a
    # first median would be. A drifting offset is not carried (the clocks moved on).
    extractor = SimpleNamespace(link_time_offset_s=0.0)
    calibration = TimeOffsetCalibration(extractor, windows=5)
    calibration.carry(5e-3)
    assert extractor.link_time_offset_s == 5e-3 and not calibration.settled
    assert 'carried over from the reducer' in calibration.reason
    assert not any(calibration.observe(f) for f in _fits([1e-5, -2e-5, 0.0, 2e-5, 1e-5]))
    assert calibration.settled and calibration.to_carry == 5e-3
    wrong = TimeOffsetCalibration(SimpleNamespace(link_time_offset_s=0.0), windows=5)
    wrong.carry(5e-3)
    assert [wrong.observe(f) for f in _fits([-5.1e-3, -4.9e-3, -5e-3, -5e-3, -5e-3])] \
        == [False] * 4 + [True]
    assert wrong.applied == pytest.approx(0.0, abs=1e-9) and not wrong.settled
    assert not any(wrong.observe(f) for f in _fits([1e-5, -2e-5, 0.0, 2e-5, 1e-5], 10.0))
    assert wrong.settled and wrong.reason is None       # 0 ms apart after all
    assert TimeOffsetCalibration(extractor).to_carry is None       # nothing learnt
    drifting = TimeOffsetCalibration(SimpleNamespace(link_time_offset_s=0.0), windows=5)
    for group in range(4):
        for f in _fits([1e-3] * 5, 10.0 * group):
            drifting.observe(f)
    assert drifting.drift is not None and drifting.to_carry is None


def test_a_microsecond_offset_is_learnt_once_and_settled():
    calibration = TimeOffsetCalibration(SimpleNamespace(link_time_offset_s=0.0), windows=2)
    for f in _fits([50e-6, 52e-6]):
        calibration.observe(f)
    assert calibration.settled and calibration.delta == pytest.approx(51e-6)


def test_encoders_stamped_milliseconds_apart_are_said_before_and_after_the_offset_is_learnt():
    calibration = TimeOffsetCalibration(SimpleNamespace(link_time_offset_s=0.0), windows=2)
    calibration.observe(_fits([2.5e-3])[0])
    assert calibration.reason is None               # within what a window fit reads wrong
    calibration = TimeOffsetCalibration(SimpleNamespace(link_time_offset_s=0.0), windows=2)
    for f in _fits([-10.1e-3, -10.3e-3]):
        calibration.observe(f)
    assert 'stamped 10.2 ms apart' in calibration.reason
    assert 'removed from then on' in calibration.reason
    assert calibration.reason.endswith('stamp both encoders on one clock')
    pending = TimeOffsetCalibration(SimpleNamespace(link_time_offset_s=0.0), windows=5)
    pending.observe(_fits([30e-3])[0])
    assert 'stamped 30.0 ms apart' in pending.reason and 'not yet removed' in pending.reason
