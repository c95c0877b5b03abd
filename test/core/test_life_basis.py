"""
What a remaining life rests on (``reducer_twin.core.life_basis``): the clause an alarm gets.

The functions of the wear record that read the rate, the growth law and the curve are
specified with the life stage in ``test_pipeline.py``.
"""

import pytest
from reducer_twin.core.life_basis import play_clause, torque_check_lines, TorqueCheckFinding
from reducer_twin.core.units import ARCMIN

LINE = ('no window held the load at the lost-motion test torque (23.5 N·m) long enough '
        'under both signs to compare the width there with the flanks of higher loads: ...')


@pytest.mark.parametrize('check', ['unconfirmed', 'not compared'])
@pytest.mark.parametrize('level', ['WARN', 'ERROR'])
def test_an_alarm_on_the_flanks_play_says_the_test_torque_was_not_compared(level, check):
    assert play_clause(level, check, LINE, {'soft_zone_shortfall_rad': 0.0}) == LINE


@pytest.mark.parametrize('level', ['OK', 'STALE'])
def test_an_answer_without_an_alarm_says_nothing_of_it(level):
    # A short clean recording whose loads seldom dwell at the test torque is common: said
    # there, it was a warning on the model's own simulator's every recording.
    assert play_clause(level, 'not compared', LINE, {}) is None


@pytest.mark.parametrize('check', ['soft zone', 'none found', None])
def test_a_comparison_that_decided_or_none_yet_says_nothing(check):
    assert play_clause('ERROR', check, LINE, {}) is None


def test_a_lost_motion_given_less_a_soft_zone_is_already_the_width_at_the_test_torque():
    # A soft zone carried over from the reducer's last recording (or said earlier live).
    record = {'soft_zone_shortfall_rad': 1.4 * ARCMIN}
    assert play_clause('ERROR', 'not compared', LINE, record) is None


def test_no_line_no_clause():
    assert play_clause('ERROR', 'not compared', None, {}) is None
    assert play_clause('ERROR', 'not compared', '', {}) is None


def test_a_lost_motion_read_within_a_soft_zone_is_said_whatever_the_level():
    # Its error is the optimistic one, the life too long: an OK life says it too.
    within = 'the lost motion read from the flanks ... is less than the width its bins give'
    for level in ('OK', 'WARN', 'ERROR', 'STALE'):
        found = TorqueCheckFinding('not compared', None, within)
        assert torque_check_lines(level, found, {}) == [within]


def test_both_lines_are_said_beside_an_alarm_the_within_zone_line_first():
    found = TorqueCheckFinding('unconfirmed', LINE, 'within')
    assert torque_check_lines('ERROR', found, {}) == ['within', LINE]
    assert torque_check_lines('OK', found, {}) == ['within']


def test_nothing_heard_says_nothing():
    assert torque_check_lines('ERROR', None, {}) == []
    assert torque_check_lines('ERROR', TorqueCheckFinding('none found'), {}) == []
