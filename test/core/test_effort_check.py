"""An effort that is not the output torque in N·m: found, said, and no lost motion read."""

import math

import pytest
from reducer_twin.core.te_extraction import compute_te
from reducer_twin.core.window_analysis import WindowAnalyzer
from te_streams import PARAMS, RATIO, simulated


def _fault_of(batch, effort=1.0, angles=1.0, offset=0.0):
    """Analyse a stream whose effort or angles are scaled, or its effort offset [N·m]."""
    t = batch.t
    stream = compute_te(t, angles * batch.motor_angle, t, angles * batch.link_angle, RATIO)
    analyzer = WindowAnalyzer(PARAMS)
    analyzer.update(stream, effort * batch.effort + offset, angles * batch.link_velocity)
    analyzer.flush()
    return analyzer


@pytest.mark.parametrize('effort, angles, said', [
    (-1.0, 1.0, 'the effort has the opposite sign'),
    (0.1, 1.0, 'the effort is not the output torque'),
    (5.0, 1.0, 'the effort is not the output torque'),
    (10.0, 1.0, 'the effort is not the output torque'),
    (1.0, 180.0 / math.pi, 'the encoders do not read radians'),
], ids=['effort reversed', 'a tenth of the torque', 'five times the torque',
        'ten times the torque', 'angles in degrees'])
def test_an_effort_or_angles_in_other_units_stop_the_lost_motion_with_the_reason(
        effort, angles, said):
    _, b = simulated()
    clean = _fault_of(b)
    assert clean.effort_fault is None and clean.fit.windows_effort_fault == 0
    assert clean.not_observed_reason() is None
    bad = _fault_of(b, effort, angles)
    assert said in bad.effort_fault
    # Not observed, with this reason (angles in degrees may first give windows no reducer
    # has, which are said first).
    reason = bad.not_observed_reason()
    assert reason == bad.effort_fault or (
        angles != 1.0 and 'do not measure the same motion' in reason)
    # From the window that decided it on, none gives a lost motion.
    assert bad.fit.windows_effort_fault >= 1
    assert bad.windows_observed + bad.fit.windows_effort_fault <= bad.windows_emitted


@pytest.mark.parametrize('effort, angles, named', [
    (1.0, 0.5 / math.pi, True), (5.0, 1.0, False), (0.1, 1.0, False),
], ids=['angles in revolutions', 'five times the torque', 'a tenth of the torque'])
def test_angles_in_revolutions_are_named_where_the_effort_reads_as_they_give(
        effort, angles, named):
    # Angles in revolutions grow the TE 2 pi times slower with the torque: without the
    # units named, the only advice was to scale a right effort by 6.2.
    fault = _fault_of(simulated()[1], effort, angles).effort_fault
    assert fault.startswith('the effort is not the output torque')
    assert ('the angles are published in revolutions' in fault) is named


@pytest.mark.parametrize('fraction', [-0.19, -0.1, 0.1, 0.19])
def test_an_effort_offset_from_the_torque_stops_the_lost_motion_and_names_the_offset(fraction):
    # An effort 80 or 150 N·m off the torque read the wear 22-71 % low, or up to 2.8 times
    # high, with nothing said: below the offset both flanks of a bin lie on one side of
    # the play, which shows only where the effort passes the offset.
    _, b = simulated()
    offset = fraction * PARAMS.rating.rated_torque
    bad = _fault_of(b, offset=offset)
    assert bad.effort_fault is not None and 'the effort is offset' in bad.effort_fault
    named = float(bad.effort_fault.split('zero lies about ')[1].split()[0])
    assert named == pytest.approx(abs(offset), rel=0.2)
    assert bad.not_observed_reason() == bad.effort_fault
    assert bad.fit.windows_effort_fault >= 1


def test_an_offset_within_the_takeup_of_the_play_is_no_fault():
    # The lost motion is read at the test torque: an offset of a fraction of it moves the
    # flanks' meeting point less than the bins the check reads.
    _, b = simulated()
    analyzer = _fault_of(b, offset=0.5 * PARAMS.rating.lost_motion_torque_fraction
                         * PARAMS.rating.rated_torque)
    assert analyzer.effort_fault is None and analyzer.windows_observed >= 1
