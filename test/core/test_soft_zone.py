"""A play still being taken up at the lost-motion test torque: found from the windows, and said."""

import numpy as np
import pytest
from reducer_twin.core.soft_zone import SoftZoneCheck
from reducer_twin.core.te_extraction import TEStream
from reducer_twin.core.transmission_error import model_tables
from reducer_twin.core.units import ARCMIN
from reducer_twin.core.window_analysis import WindowAnalyzer
from te_streams import PARAMS, soft_zone_swing

RATED = PARAMS.rating.rated_torque
TEST_TORQUE = PARAMS.rating.lost_motion_torque_fraction * RATED
STIFFNESS = model_tables(PARAMS).series_stiffness
CENTRES = np.geomspace(0.02, 1.5, 17)[:-1] * RATED * 1.145   # near the analysis' bin centres


def _catalogue_bins(zone_arcmin, knee_fraction, windows=4, stiffness=STIFFNESS):
    """Bins of windows whose curve is a soft zone to a knee, then a straight spring."""
    torque = np.tile(CENTRES, (windows, 1))
    width = (zone_arcmin * ARCMIN * np.minimum(torque / (knee_fraction * RATED), 1.0)
             + 2.0 * torque / stiffness)
    return torque, width, np.full(torque.shape, 0.01 * ARCMIN), np.ones(torque.shape, bool)


def _checked(*bins):
    check = SoftZoneCheck(TEST_TORQUE, STIFFNESS)
    check.observe(*bins)
    return check


def test_a_knee_above_the_test_torque_is_said_with_the_width_there():
    # 2 arcmin of soft zone to a knee at 5 % of rated: at the 3 % test torque 3/5 of it
    # is taken up. The lost motion is read from the loaded flanks (the whole zone); the
    # line says so, and gives the catalogue's width at the test torque.
    check = _checked(*_catalogue_bins(2.0, 0.05))
    short, _, play = check.shortfall
    assert play == pytest.approx(2.0 * ARCMIN, rel=0.01)
    assert short == pytest.approx(0.8 * ARCMIN, rel=0.05)
    assert 'narrower' in check.reason and 'knee lies above the test torque' in check.reason
    assert 'about 1.2' in check.reason     # 2 arcmin x 3/5
    said = check.said       # the line's numbers
    assert said['width'] == pytest.approx(1.2 * ARCMIN, rel=0.05)
    assert said['play'] - said['shortfall'] == said['width'] and said['windows'] == 4
    assert said['shortfall'] >= 5.0 * said['shortfall_sd']


@pytest.mark.parametrize('knee', [0.01, 0.025])
def test_a_play_taken_up_below_the_test_torque_is_not_said(knee):
    check = _checked(*_catalogue_bins(2.0, knee))
    assert abs(check.shortfall[0]) < 0.01 * ARCMIN
    assert check.reason is None and check.said is None


@pytest.mark.parametrize('wear', [0.0, 2e-6, 10e-6])
def test_the_models_own_curve_new_or_worn_is_not_a_soft_zone(wear):
    # The model's contacts stiffen with the load, most on a new unit; its curve falls
    # short of a straight line by less than the rule's floor.
    tables = model_tables(PARAMS)
    torque = np.tile(CENTRES, (4, 1))
    width = tables.hysteresis(torque, np.full(torque.shape, wear))
    check = _checked(torque, width, np.full(torque.shape, 0.01 * ARCMIN),
                     np.ones(torque.shape, bool))
    assert check.reason is None


def test_one_window_or_a_small_zone_is_not_enough():
    assert _checked(*_catalogue_bins(2.0, 0.05, windows=1)).reason is None
    assert _checked(*_catalogue_bins(2.0, 0.05, windows=1)).said is None
    # A knee above the test torque on a small zone: short by 0.15 arcmin, below 0.2.
    assert _checked(*_catalogue_bins(0.3, 0.06)).reason is None


def test_a_width_at_the_test_torque_of_none_or_less_is_no_soft_zone():
    # Bins at the test torque narrower than no hysteresis at all are misread bins (the
    # load's sign mistaken there), not a play still being taken up: taken off the play,
    # such a shortfall would leave a lost motion of zero or less.
    torque, width, std, usable = _catalogue_bins(2.0, 0.05)
    near = np.abs(torque - TEST_TORQUE) <= 0.15 * TEST_TORQUE
    assert near.any()
    width[near] = -0.2 * ARCMIN + 2.0 * torque[near] / STIFFNESS
    check = _checked(torque, width, std, usable)
    assert check.shortfall[0] > check.shortfall[2] > 0.0
    assert check.said is None and check.reason is None


def test_a_window_at_the_test_torque_is_compared_with_the_line_of_recent_windows():
    # A window with loads at the test torque seldom has loads far beyond it too: it is
    # compared with the straight line the windows before it pooled. Unused bins may hold
    # NaN; a window with nothing at the test torque only adds to the line.
    torque, width, std, usable = _catalogue_bins(2.0, 0.05, windows=5)
    torque[:, -3:] = width[:, -3:] = np.nan
    usable[:, -3:] = False
    usable[0] = CENTRES < 2.0 * TEST_TORQUE      # no line yet: not compared
    usable[2] = CENTRES > 2.0 * TEST_TORQUE      # nothing at the test torque
    usable[3] = CENTRES < 2.0 * TEST_TORQUE      # compared with windows 1 and 2
    check = _checked(torque, width, std, usable)
    assert check.windows == 3
    assert check.shortfall[0] == pytest.approx(0.8 * ARCMIN, rel=0.05)


def _swinging_joint(zone_arcmin, knee_fraction):
    """Return the analyzer after :func:`te_streams.soft_zone_swing`, and its usable windows."""
    t, theta, omega, te, effort = soft_zone_swing(zone_arcmin, knee_fraction)
    analyzer = WindowAnalyzer(PARAMS, friction=False)
    stream = TEStream(t, te, theta, np.ones(t.size, dtype=bool), 0.005)
    windows = analyzer.update(stream, effort, omega) + analyzer.flush()
    return analyzer, [w for w in windows if np.isfinite(w.lost_motion)]


def test_a_joint_whose_knee_lies_above_the_test_torque_says_so_and_one_below_does_not():
    # Through the whole window analysis: 1.5 arcmin of zone to a knee at 5 % of rated
    # (0.9 arcmin at the test torque) is read as more than its width there (1.01 arcmin:
    # the bin at the test torque pulls the windows that have it down) and said; the same
    # zone taken up by 1 % of rated is read right and nothing is said.
    analyzer, windows = _swinging_joint(1.5, 0.05)
    assert np.median([w.lost_motion for w in windows]) > 1.05 * 0.9 * ARCMIN
    assert analyzer.soft_zone is not None
    assert analyzer.soft_zone_said['width'] == pytest.approx(0.9 * ARCMIN, rel=0.15)
    analyzer, windows = _swinging_joint(1.5, 0.01)
    assert np.median([w.lost_motion for w in windows]) == pytest.approx(1.5 * ARCMIN, rel=0.05)
    assert analyzer.soft_zone is None and analyzer.soft_zone_said is None
