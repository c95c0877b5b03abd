"""
A lost motion read that depends on how far the windows' loads reach (``core/load_reach.py``).

Where the reducer's curve is a play and a straight windup, a window reaching 40 N·m reads
what one reaching 150 N·m reads; where the reading moves with the reach (a friction loop
that does not open at small loads), the estimate averaging the windows is unsettled
whatever its standard error says. The check says so; it changes no number.
"""

import json

import numpy as np
import pytest
from reducer_twin.core.load_reach import LoadReachCheck, MIN_WINDOWS, SIGMAS
from reducer_twin.core.units import ARCMIN

SD = 0.1 * ARCMIN


def _observed(reading_of, n=12, seed=0, scatter=SD):
    """Return a check fed ``n`` windows reaching 30-80 N·m, each reading ``reading_of(reach)``."""
    rng = np.random.default_rng(seed)
    reach = np.linspace(30.0, 80.0, n)
    rng.shuffle(reach)
    check = LoadReachCheck()
    check.observe(reach, reading_of(reach) + rng.normal(0.0, scatter, n), np.full(n, SD),
                  2.0 * np.arange(n))
    return check


def test_windows_that_read_the_same_whatever_their_reach_say_nothing():
    check = _observed(lambda x: np.full(x.shape, 1.5 * ARCMIN))
    found = check.change()
    assert abs(found['change']) < 2.0 * found['change_sd']
    assert found['mean'] == pytest.approx(1.5 * ARCMIN, abs=0.1 * ARCMIN)
    assert check.reason is None


def test_a_reading_that_grows_with_the_reach_is_said_with_its_figures():
    # A base whose windows reaching 30 N·m read 1.2 arcmin and those reaching 80 read 2.7:
    # the estimate averaged them to 1.6 with a standard error of 0.09 (truth 2.41).
    check = _observed(lambda x: (1.2 + 1.5 * (x - 30.0) / 50.0) * ARCMIN)
    found = check.change()
    assert found['change'] / ARCMIN == pytest.approx(1.2, abs=0.25)
    line = check.reason
    assert line.startswith("the lost motion read depends on how far the windows' loads reach: ")
    assert 'more by ' in line and 'over 12 windows' in line
    assert line.endswith('A recording whose loads reach further decides')


def test_too_few_windows_to_know_a_line_and_its_scatter_say_nothing():
    check = _observed(lambda x: (1.2 + 1.5 * (x - 30.0) / 50.0) * ARCMIN, n=MIN_WINDOWS - 1)
    assert check.change() is None and check.reason is None


def test_a_change_under_the_soft_zones_floor_says_nothing():
    # 0.15 arcmin across the reach: under SHORTFALL_RAD, however many standard errors.
    check = _observed(lambda x: (1.5 + 0.15 * (x - 30.0) / 50.0) * ARCMIN, n=30, scatter=0.0)
    assert check.change()['change'] / ARCMIN == pytest.approx(0.15 * 0.8, abs=0.03)
    assert check.reason is None


def test_a_change_within_the_windows_own_scatter_says_nothing():
    # Readings scattered by 1 arcmin about a flat line: the Birge ratio widens the slope,
    # and a change of 1.4 of its standard errors is such scatter, not a dependence.
    check = _observed(lambda x: np.full(x.shape, 1.5 * ARCMIN), n=8, seed=0,
                      scatter=1.0 * ARCMIN)
    found = check.change()
    assert found['change_sd'] > 5.0 * SD
    assert 1.0 < found['change'] / found['change_sd'] < SIGMAS
    assert check.reason is None


def test_the_pools_continue_after_a_restart_and_a_broken_state_changes_nothing():
    check = _observed(lambda x: (1.2 + 1.5 * (x - 30.0) / 50.0) * ARCMIN)
    again = LoadReachCheck()
    again.continue_from(json.loads(json.dumps(check.state())))
    assert again.change() == check.change() and again.reason == check.reason
    broken = LoadReachCheck()
    good = check.state()
    for change in ({'plane': {**good['plane'], 'S': [0.0] * 8}}, {'reach': [float('nan')]},
                   {'windows': -1}, {'t0': float('inf')}):
        with pytest.raises(ValueError, match='must be'):
            broken.continue_from({**good, **change})
    assert broken.windows == 0 and broken.change() is None


def test_a_reading_that_grows_in_time_is_not_taken_for_the_reach():
    # A unit wearing while the duty's reach drifts with it (a whole life's windows):
    # the reading's drift in time is fitted beside the reach.
    n = 30
    t = 2.0 * np.arange(n)
    reach = 30.0 + 50.0 * t / t[-1] + np.random.default_rng(1).normal(0.0, 5.0, n)
    check = LoadReachCheck()
    check.observe(reach, (1.0 + 1.5 * t / t[-1]) * ARCMIN, np.full(n, SD), t)
    found = check.change()
    assert abs(found['change']) < 2.0 * found['change_sd'] + 0.02 * ARCMIN
    assert check.reason is None
