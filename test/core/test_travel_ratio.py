"""The ratio of the motor's moves to the link's, measured from the TE and said when off."""

import math

import numpy as np
import pytest
from reducer_twin.core.travel_ratio import RATIO_TOLERANCE, TravelRatio

RATIO = 81.0
T = np.arange(20_000) * 1e-3                              # 20 s at 1 kHz
LINK = 0.8 * np.sin(2.0 * math.pi * 0.25 * T)             # back and forth over 1.6 rad


def _te(ratio_true, play_rad=5e-4):
    """TE of a motor turning ``ratio_true`` times the link, with play taken up at reversals."""
    side = np.sign(np.gradient(LINK, T))
    return LINK * (1.0 - ratio_true / RATIO) - 0.5 * play_rad * side


@pytest.mark.parametrize('ratio_true, said', [
    (RATIO, None),
    (RATIO * 1.01, 'the motor encoder turns 81.81 times the link where the configured '
                   'reduction ratio is 81 (+1 %)'),
    (101.0, 'the motor encoder turns 101 times the link where the configured reduction '
            'ratio is 81 (+25 %)'),
])
def test_a_motor_that_turns_another_number_of_times_is_measured_and_said(ratio_true, said):
    travel = TravelRatio(RATIO)
    for part in np.array_split(np.arange(T.size), 40):     # a node's chunks
        travel.observe(T[part], LINK[part], _te(ratio_true)[part])
    assert travel.measured == pytest.approx(ratio_true, rel=1e-3)
    reason = travel.reason()
    assert reason is None if said is None else reason.startswith(said)


def test_a_turn_count_restored_in_the_te_is_no_move_of_the_motor():
    # A wrapped encoder's TE steps by 2 pi / i where a turn count was restored.
    te = _te(RATIO)
    te[7000:] += 2.0 * math.pi / RATIO
    travel = TravelRatio(RATIO)
    travel.observe(T, LINK, te)
    assert abs(travel.measured / RATIO - 1.0) < 0.1 * RATIO_TOLERANCE
    assert travel.reason() is None


def test_nothing_is_judged_before_the_link_has_travelled_enough():
    travel = TravelRatio(RATIO)
    travel.observe(T[:1000], LINK[:1000], _te(101.0)[:1000])    # 1 s: 0.8 rad
    assert travel.measured is None and travel.reason() is None
