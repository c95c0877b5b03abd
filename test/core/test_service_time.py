"""
A used reducer's service time (``reducer_twin.core.service_time``), without the estimator.

The hour meter tells the rate: with the wear known, the pseudo-observation moves each
component's ``θ`` to ``ln(S(w)/(r·H + a))`` by as much as its noise lets it; a past duty
of unknown ratio to today's (a wide ``σ``) tells nearly nothing; the components whose
rate explains the wear gain weight. The note names a time in hours given as seconds.
"""

import math

import numpy as np
import pytest
from reducer_twin.core.gaussian_sum import UnscentedTransform
from reducer_twin.core.service_time import (
    implied_rate_scale, service_note, SERVICE_RATE_LIMIT, service_update)
from reducer_twin.core.units import HOUR

UT = UnscentedTransform(2, 1.0, 2.0, 0.0)
WEAR = 4e-6
EXPOSURE = 2e-6


def _free(w):
    return 1.5 * np.asarray(w)          # any increasing run-in-free map


def _components(thetas, wear_sd=1e-9, theta_sd=0.3):
    m = np.array([[WEAR, t] for t in thetas])
    P = np.tile(np.diag([wear_sd ** 2, theta_sd ** 2]), (len(thetas), 1, 1))
    return np.full(len(thetas), -math.log(len(thetas))), m, P


def test_the_implied_rate_is_the_wear_over_the_exposure():
    assert implied_rate_scale(_free(WEAR), EXPOSURE) == pytest.approx(3.0)


def test_a_known_wear_moves_the_rate_to_what_the_hour_meter_says():
    lw, m, P = _components([math.log(2.5)])       # within the prior's reach of the truth
    lw2, m2, P2 = service_update(UT, lw, m, P, _free, 0.9 * EXPOSURE, EXPOSURE, 0.05)
    assert m2[0, 1] == pytest.approx(math.log(3.0), abs=0.05)
    assert P2[0, 1, 1] < 0.1 * P[0, 1, 1]
    assert m2[0, 0] == pytest.approx(WEAR, rel=1e-3)
    np.testing.assert_allclose(P2[0], P2[0].T)


def test_a_past_duty_of_unknown_ratio_tells_little():
    lw, m, P = _components([0.0])
    _, m2, P2 = service_update(UT, lw, m, P, _free, 0.9 * EXPOSURE, EXPOSURE, 20.0)
    assert abs(m2[0, 1]) < 0.05 and P2[0, 1, 1] > 0.9 * P[0, 1, 1]


def test_the_components_whose_rate_explains_the_wear_gain_weight():
    lw, m, P = _components([0.0, math.log(3.0), 3.0])
    lw2, _, _ = service_update(UT, lw, m, P, _free, 0.9 * EXPOSURE, EXPOSURE, 0.3)
    assert np.exp(lw2).sum() == pytest.approx(1.0)
    assert int(np.argmax(lw2)) == 1


def test_the_note_says_what_was_taken_and_names_hours_given_as_seconds():
    taken = service_note((True, 2.5), 6000.0 * HOUR)
    assert taken.startswith('service time 6,000 h taken') and '2.5 times' in taken
    refused = service_note((False, 3 * SERVICE_RATE_LIMIT), 6000.0)
    assert 'not taken' in refused and '6000 h would be 2.16e+07 s' in refused
