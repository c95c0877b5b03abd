"""
A lost motion read below its own bins' width at the test torque (``core/within_zone.py``).

A joint whose loads never leave a soft zone has every bin on a width that grows in
proportion to the load; the flanks' extrapolation to no load reads far below the
catalogue's lost motion there, with a tight standard error. The check compares the two and
says it; it changes no number.
"""

import math

import numpy as np
import pytest
from reducer_twin.core.units import ARCMIN
from reducer_twin.core.within_zone import WithinZoneCheck

TEST_TORQUE = 23.5
STIFFNESS = 196.0 / ARCMIN          # N·m/rad: the catalogue's 196 N·m/arcmin
CENTRES = np.array([16.0, 20.0, 25.0, 31.0, 39.0, 49.0, 61.0])
SD = 0.02 * ARCMIN


def _windows(width_of, read, n=6, seed=0):
    """Return ``n`` windows of bins whose widths follow ``width_of(T)``, each reading ``read``."""
    rng = np.random.default_rng(seed)
    torque = np.tile(CENTRES, (n, 1))
    width = width_of(torque) + rng.normal(0.0, SD, torque.shape)
    return torque, width, np.full(torque.shape, SD), np.ones(torque.shape, bool), \
        np.full(n, read)


def _straight(play):
    return lambda t: play + 2.0 * t / STIFFNESS


def _within_zone(full, knee):
    """Return the widths of a soft zone ``full`` wide, taken up in proportion to the load."""
    return lambda t: full * np.minimum(t / knee, 1.0) + 2.0 * t / STIFFNESS


def test_a_straight_curve_read_at_its_play_says_nothing():
    check = WithinZoneCheck(TEST_TORQUE, STIFFNESS)
    check.observe(*_windows(_straight(1.5 * ARCMIN), 1.5 * ARCMIN))
    found = check.gap()
    assert abs(found['gap']) < 0.02 * ARCMIN
    assert found['slope'] == pytest.approx(1.0, abs=0.1)
    assert check.reason is None


def test_loads_that_never_leave_the_soft_zone_are_said_with_the_width_at_the_test_torque():
    # 3.7 arcmin of zone to a knee at 38 N·m, every bin but the last two below it: 2.29 at
    # the test torque; the flanks read 0.8 (a wrist of the third generator read so).
    check = WithinZoneCheck(TEST_TORQUE, STIFFNESS)
    check.observe(*_windows(_within_zone(3.7 * ARCMIN, 38.0), 0.8 * ARCMIN))
    found = check.gap()
    assert found['width'] / ARCMIN == pytest.approx(3.7 * TEST_TORQUE / 38.0, rel=0.25)
    assert found['slope'] > 3.0
    line = check.reason
    assert line.startswith('the lost motion read from the flanks (0.80 arcmin, their '
                           'extrapolation to no load) is ')
    assert 'less than the width its bins give at the lost-motion test torque (23.5 N·m)' in line
    assert 'bins of 12-59 N·m, 6 windows' in line
    assert line.endswith('A recording whose loads pass the knee decides')


def test_one_window_is_too_few_to_say():
    check = WithinZoneCheck(TEST_TORQUE, STIFFNESS)
    check.observe(*_windows(_within_zone(3.7 * ARCMIN, 38.0), 0.8 * ARCMIN, n=1))
    assert check.gap() is None and check.reason is None


def test_a_gap_under_the_soft_zones_floor_says_nothing():
    # 0.15 arcmin below: under SHORTFALL_RAD, what a straight unit's stiffness 20 % off gives.
    check = WithinZoneCheck(TEST_TORQUE, STIFFNESS)
    check.observe(*_windows(_straight(1.5 * ARCMIN), 1.35 * ARCMIN))
    assert check.gap()['gap'] / ARCMIN == pytest.approx(0.15, abs=0.02)
    assert check.reason is None


def test_a_gap_from_bins_whose_width_does_not_grow_with_the_load_says_nothing():
    # Bins narrowing with the load (their line's scatter, no zone being taken up) put the
    # line's width at the test torque above the reading: the independent generator's
    # forearms at 100 Hz were said so, slopes -5.7 and -1.3, reading 4-10 % low.
    check = WithinZoneCheck(TEST_TORQUE, STIFFNESS)
    check.observe(*_windows(lambda t: 2.5 * ARCMIN - 0.012 * ARCMIN * t, 1.1 * ARCMIN))
    found = check.gap()
    assert found['gap'] > 0.5 * ARCMIN and found['slope'] < 0.0
    assert check.reason is None


def test_a_lost_motion_read_above_the_width_says_nothing():
    # A soft zone reaching beyond the test torque, read at its play: the soft-zone check's.
    check = WithinZoneCheck(TEST_TORQUE, STIFFNESS)
    check.observe(*_windows(_within_zone(2.0 * ARCMIN, 30.0), 2.0 * ARCMIN))
    assert check.gap()['gap'] < 0.0 and check.reason is None


def test_windows_without_a_lost_motion_take_no_part():
    check = WithinZoneCheck(TEST_TORQUE, STIFFNESS)
    torque, width, std, usable, read = _windows(_within_zone(3.7 * ARCMIN, 38.0), math.nan)
    check.observe(torque, width, std, usable, read)
    assert check.windows == 0 and check.gap() is None
