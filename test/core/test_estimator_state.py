"""The wear estimator's state as JSON-able data: it continues exactly, and bad states are named."""

from dataclasses import replace
import json

import numpy as np
import pytest
from reducer_twin.core.errors import StateFileError
from reducer_twin.core.estimator import EstimatorConfig, params_fingerprint, WearEstimator
from reducer_twin.core.estimator_state import estimator_state, restore_estimator
from reducer_twin.core.params import ReducerParams
from reducer_twin.core.units import ARCMIN, HOUR
from wear_windows import synthetic_run, WINDOW


@pytest.fixture(scope='module')
def params():
    return ReducerParams()


def stepped_estimator(params, n=60, seed=2, config=None):
    features, _, _ = synthetic_run(params, 0.8, seed=seed)
    est = WearEstimator(params, config)
    for f in features[:n]:
        est.step(f)
    return est, features


def test_a_state_survives_a_json_round_trip_bit_for_bit(params):
    est, features = stepped_estimator(params)
    est.update(replace(features[60], lost_motion=features[60].lost_motion + 2.0 * ARCMIN))
    est.reset('drill: state round trip')
    for f in features[60:70]:
        est.step(f)
    restored = restore_estimator(params, json.loads(json.dumps(estimator_state(est))))
    assert estimator_state(restored) == est.state_dict()
    for f in features[70:90]:
        est.step(f)
        restored.step(f)
        assert np.array_equal(restored.x, est.x) and np.array_equal(restored.P, est.P)
        assert restored.trend_probability == est.trend_probability
        assert restored.forecast_scale == est.forecast_scale


def test_a_state_with_a_service_time_taken_continues_with_it(params):
    est, features = stepped_estimator(params, n=20,
                                      config=EstimatorConfig(service_time_s=100 * WINDOW))
    state = json.loads(json.dumps(est.state_dict()))
    assert state['service_pending'] is False and state['service_verdict'][0] is True
    restored = restore_estimator(params, state)
    assert restored.service_verdict == est.service_verdict
    assert restored.growth_trend()[3] == est.growth_trend()[3]


def test_a_state_of_other_parameters_is_refused(params):
    assert params_fingerprint(params) == params_fingerprint(ReducerParams())
    with pytest.raises(StateFileError, match='other reducer parameters'):
        restore_estimator(params.with_overrides({'rating.rated_torque': 800.0}),
                          WearEstimator(params).state_dict())


@pytest.mark.parametrize('change, message', [
    ({'kind': 'something else'}, "state kind must be 'reducer_twin.wear_estimator'"),
    ({'version': 7}, 'state version must be 1 or 2, got 7'),
    ({'components': [[0.0, [1.0], [1.0]]]}, 'state is malformed: ValueError'),
    ({'service_verdict': 'yes'}, 'state is malformed'),
    ({'score_settle': 99}, 'score_settle must be 0 .. 9, got 99'),
    ({'forecast_errors': [1.0, -2.0]}, 'forecast_errors must be two finite sums >= 0'),
])
def test_a_malformed_state_is_refused_naming_what_is_wrong(params, change, message):
    state = {**WearEstimator(params).state_dict(), **change}
    with pytest.raises(StateFileError, match=message):
        restore_estimator(params, state)


def test_a_state_from_before_the_service_time_restores_as_taken_or_not_given(params):
    state = WearEstimator(params, EstimatorConfig(service_time_s=1000 * HOUR)).state_dict()
    for key in ('service_pending', 'service_verdict'):
        del state[key]
    restored = restore_estimator(params, state)
    assert not restored.service_pending and restored.service_verdict is None


def test_a_state_from_before_the_lagged_errors_were_kept_starts_them_afresh(params):
    est, _ = stepped_estimator(params)
    state = json.loads(json.dumps(est.state_dict()))
    assert state['forecast_errors'][0] > 0.0
    del state['forecast_errors']
    restored = restore_estimator(params, state)
    assert restored._scoring.forecast == [0.0, 0.0] and restored.forecast_scale == 1.0
