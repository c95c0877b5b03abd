"""Why a joint gives no lost motion, or stopped giving one: said in one line it can act on."""

from types import SimpleNamespace

import numpy as np
import pytest
from reducer_twin.core.observability import not_observed_reason, SinceLostMotion, stale_reason
from reducer_twin.core.te_extraction import compute_te
from reducer_twin.core.window_analysis import WindowAnalyzer
from te_streams import PARAMS, RATIO, simulated


def test_without_effort_the_analyzer_says_so_instead_of_a_lost_motion():
    _, b = simulated(samples=6000)
    stream = compute_te(b.t, b.motor_angle, b.t, b.link_angle, RATIO)
    analyzer = WindowAnalyzer(PARAMS)
    feats = analyzer.update(stream, np.full_like(b.effort, np.nan), b.link_velocity)
    assert feats == [] and analyzer.windows_observed == 0
    assert analyzer.not_observed_reason('/arm/joint_states').startswith(
        'no effort on /arm/joint_states (6000 of 6000 samples)')


def test_a_joint_that_never_reverses_under_load_is_reported_as_such():
    # Constant load at constant speed: no torque reversal, no lost motion.
    _, b = simulated(profile='paper', load='constant', samples=8000)
    stream = compute_te(b.t, b.motor_angle, b.t, b.link_angle, RATIO)
    analyzer = WindowAnalyzer(PARAMS)
    analyzer.update(stream, b.effort, b.link_velocity)
    analyzer.flush()
    assert analyzer.windows_emitted >= 1 and analyzer.windows_observed == 0
    assert 'no torque reversal' in analyzer.not_observed_reason()


def test_a_recording_too_short_to_learn_an_offset_of_milliseconds_says_so():
    # The motor stamped 20 ms late, four windows: the offset is not learnt (five windows
    # that find it are needed) and no window read with it gives a lost motion.
    _, b = simulated(samples=8000)
    stream = compute_te(b.t + 0.02, b.motor_angle, b.t, b.link_angle, RATIO)
    analyzer = WindowAnalyzer(PARAMS)
    feats = analyzer.update(stream, b.effort, b.link_velocity) + analyzer.flush()
    assert feats and not np.isfinite([f.lost_motion for f in feats]).any()
    reason = analyzer.not_observed_reason()
    assert reason.startswith('the link and motor encoders are stamped up to 2')
    assert 'stamp both encoders on one clock' in reason


@pytest.mark.parametrize('rate_hz', [1000, 200])
def test_an_effort_filled_with_zeros_is_named_as_such_at_any_rate(rate_hz):
    # A controller without an effort interface that fills zeros: at 200 Hz the joint was
    # "not observed: 200 Hz: too few samples per torque reversal", which sends the
    # engineer to the recording's rate instead of the effort.
    _, b = simulated(samples=8000)
    keep = slice(None, None, 1000 // rate_hz)
    stream = compute_te(b.t[keep], b.motor_angle[keep], b.t[keep], b.link_angle[keep], RATIO)
    analyzer = WindowAnalyzer(PARAMS)
    analyzer.update(stream, np.zeros(stream.t.size), b.link_velocity[keep])
    analyzer.flush()
    assert analyzer.windows_emitted >= 1 and analyzer.windows_observed == 0
    reason = analyzer.not_observed_reason('/arm/joint_states')
    assert reason == (f'the effort on /arm/joint_states is zero in every sample that carries '
                      f'one ({stream.t.size}): a controller that fills zeros where it has no '
                      'effort; the lost motion needs the torque')


def test_an_effort_too_small_to_read_is_named_as_such_not_as_a_joint_without_reversals():
    # A motor torque reported beside motor angles divided by the ratio is taken for the
    # output torque: the effort is 1/ratio of it and never reaches the lowest torque bin.
    # The twin said "the joint did not reverse under load", which sends the engineer to
    # the robot's motion instead of the effort's units.
    _, b = simulated(samples=8000)
    stream = compute_te(b.t, b.motor_angle, b.t, b.link_angle, RATIO)
    analyzer = WindowAnalyzer(PARAMS)
    analyzer.update(stream, b.effort / RATIO, b.link_velocity)
    analyzer.flush()
    assert analyzer.windows_emitted >= 1 and analyzer.windows_observed == 0
    reason = analyzer.not_observed_reason('/arm/joint_states')
    assert reason.startswith('the effort on /arm/joint_states stays within +-')
    assert 'below the 15.7 N*m (2 % of the rated torque)' in reason
    assert 'motor_effort_units' in reason
    # The same effort in output torque is read.
    analyzer = WindowAnalyzer(PARAMS)
    analyzer.update(stream, b.effort, b.link_velocity)
    analyzer.flush()
    assert analyzer.windows_observed >= 1 and analyzer.not_observed_reason() is None


@pytest.mark.parametrize('fault', ['motor reversed', 'motor frozen'])
def test_encoders_that_do_not_measure_the_same_motion_give_no_lost_motion_and_say_so(fault):
    # Read as a reducer, a reversed or frozen motor encoder gave lost motions of thousands
    # of arcminutes and a remaining life of 0 h.
    _, b = simulated(samples=8000)
    motor = -b.motor_angle if fault == 'motor reversed' else np.full_like(b.motor_angle,
                                                                          b.motor_angle[0])
    stream = compute_te(b.t, motor, b.t, b.link_angle, RATIO)
    analyzer = WindowAnalyzer(PARAMS)
    feats = analyzer.update(stream, b.effort, b.link_velocity) + analyzer.flush()
    assert feats and all(not np.isfinite(f.lost_motion) for f in feats)
    assert analyzer.fit.windows_implausible >= 1 and analyzer.windows_observed == 0
    reason = analyzer.not_observed_reason()
    assert reason.startswith('the motor and link encoders do not measure the same motion')
    assert 'frozen encoder' in reason and 'counts against the link' in reason
    # The same stream with the encoders right is read.
    analyzer = WindowAnalyzer(PARAMS)
    analyzer.update(compute_te(b.t, b.motor_angle, b.t, b.link_angle, RATIO), b.effort,
                    b.link_velocity)
    analyzer.flush()
    assert analyzer.windows_observed >= 1 and analyzer.fit.windows_implausible == 0


def test_a_lost_motion_that_stops_with_the_effort_is_said_with_its_cause():
    # Observed for 8 s, then the effort goes missing for 12 s: the estimate stands as of
    # the last lost motion, and the reason is the effort, not the joint's motion.
    _, b = simulated(samples=20000)
    stream = compute_te(b.t, b.motor_angle, b.t, b.link_angle, RATIO)
    effort = b.effort.copy()
    effort[8000:] = np.nan
    analyzer = WindowAnalyzer(PARAMS)
    analyzer.update(stream, effort, b.link_velocity)
    analyzer.flush()
    assert analyzer.windows_observed >= 1 and not_observed_reason(analyzer) is None
    gap, cause, faulty = stale_reason(analyzer, 5.0, '/arm/joint_states')
    assert gap > 10.0 and faulty
    assert cause.startswith('no effort on /arm/joint_states in ')
    assert stale_reason(analyzer, 30.0) is None      # not yet that long
    assert analyzer.stale_reason(5.0, '/arm/joint_states') == (gap, cause, faulty)


def _window(t_end, lost_motion=np.nan, implausible=False):
    return SimpleNamespace(t_end=t_end, lost_motion=lost_motion, implausible=implausible)


def test_the_counts_since_a_lost_motion_start_at_its_end_and_count_what_came_after():
    since = SinceLostMotion()
    since.samples(np.arange(0.0, 10.0), np.array([1.0, 2.0]))     # 10 fresh, 2 without effort
    since.windows([_window(4.0), _window(7.0, implausible=True)])
    assert since.counts == {'seen': 10, 'without_effort': 2, 'implausible': 1, 'windows': 2}
    since.samples(np.arange(10.0, 20.0), np.array([15.0, 16.0, 17.0]))
    # A lost motion at 14 s: of this update's samples, 5 came after it, 3 of them without
    # an effort; the windows after it count afresh.
    since.windows([_window(12.0), _window(14.0, lost_motion=1e-4), _window(18.0)])
    assert since.counts == {'seen': 5, 'without_effort': 3, 'implausible': 0, 'windows': 1}
