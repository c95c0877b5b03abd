"""A velocity field that is not the link angle's rate: found, said, and the rate used instead."""

import math

import numpy as np
import pytest
from reducer_twin.core.te_extraction import compute_te
from reducer_twin.core.velocity_check import angle_noise, VELOCITY_CHECK_SAMPLES, VelocityCheck
from reducer_twin.core.window_analysis import WindowAnalyzer
from te_streams import PARAMS, RATIO, simulated

RNG = np.random.default_rng(7)
MOVE = np.sin(np.linspace(0.0, 20.0 * math.pi, 4000))      # a joint swinging, rad/s
T = np.arange(MOVE.size) * 1e-3                           # 1 kHz
ANGLE = np.cumsum(MOVE) * 1e-3                            # its link angle, rad


def _verdict(field, t=T, theta=ANGLE, min_speed=0.01):
    check = VelocityCheck(min_speed, RATIO)
    return check, check.check(t, theta, np.asarray(field, dtype=float))


@pytest.mark.parametrize('field, form', [
    (np.zeros_like(MOVE), 'is zero where the link angle turns'),
    (-MOVE, 'the other sense'),
    (np.degrees(MOVE), 'degrees per second'),
    (MOVE * 60.0 / (2.0 * math.pi), 'revolutions per minute'),
    (MOVE * RATIO, "the motor's speed: the ratio is 81"),
    (-MOVE * RATIO, "the motor's speed: the ratio is 81, the other sense"),
    (MOVE / RATIO, 'the speed divided by the reduction ratio'),
    (MOVE * 5.0, 'other units, or another quantity'),
], ids=['zero-filled', 'negated', 'deg/s', 'rpm', "motor's speed", "motor's, reversed",
        'divided by the ratio', 'five times'])
def test_a_field_in_another_form_is_replaced_and_its_form_named(field, form):
    check, replace = _verdict(field)
    assert replace and check.replaced and check.decided
    assert form in check.fault
    assert check.fault.endswith('the rate of the link angle is used instead')
    # Once replaced, it stays replaced: later chunks are not judged again.
    assert check.check(T, ANGLE, MOVE)


@pytest.mark.parametrize('field', [
    MOVE,
    MOVE + RNG.normal(0.0, 0.005, MOVE.size),           # a drive estimate's noise
    np.concatenate([[0.0] * 2, MOVE[:-2]]) * 0.9,      # 2 ms late and filtered
], ids=['the rate', 'noisy', '2 ms late'])
def test_the_link_angles_rate_in_any_honest_form_is_trusted(field):
    check, replace = _verdict(field)
    assert not replace and check.trusted and check.fault is None
    assert 0.5 <= check.scale <= 2.0 and abs(check.lag_s) < 3e-3


@pytest.mark.parametrize('late', [5, 40])
def test_a_field_that_lags_the_angles_rate_is_replaced_and_its_lag_said(late):
    # A drive's filtered or delayed velocity switched the friction taken out of the effort
    # late at each reversal: 20 ms late, the growth law took both joints' remaining life
    # (P50 60-73 % short) on the model's simulator.
    field = np.concatenate([[0.0] * late, MOVE[:-late]]) * 0.9
    check, replace = _verdict(field)
    # The lag to first order in it (the moves at 2.5 Hz: 40 ms reads 47).
    assert replace and check.replaced and check.lag_s == pytest.approx(late * 1e-3, rel=0.2)
    assert f'lags the rate of the link angle by {1e3 * check.lag_s:.1f} ms' in check.fault
    assert check.fault.endswith('the rate of the link angle is used instead')


def test_a_field_far_noisier_than_the_angles_rate_is_replaced_and_said():
    # 0.05 rad/s of noise flips the friction taken out of the effort near each reversal
    # (it switches within 0.01 rad/s): the growth law took a new unit's remaining life.
    check, replace = _verdict(MOVE + RNG.normal(0.0, 0.05, MOVE.size))
    assert replace and check.replaced
    assert check.fault.startswith('the velocity field is noisier than the rate of the link '
                                  'angle: 0.05 rad/s between samples against')
    # Beside an angle whose rate is noisier still (stamps taken on arrival), it is kept.
    t = np.sort(T + RNG.normal(0.0, 0.3e-3, T.size))
    check, replace = _verdict(MOVE + RNG.normal(0.0, 0.05, MOVE.size), t=t)
    assert not replace and check.trusted


def test_a_controllers_backward_difference_at_100_hz_is_trusted():
    # It lags by half a sample, 5 ms at 100 Hz, where the angle's rate is no better.
    t = np.arange(3000) * 0.01
    angle = np.cumsum(np.sin(2.0 * math.pi * 0.2 * t)) * 0.01
    field = np.diff(angle, prepend=angle[0]) / 0.01
    check, replace = _verdict(field, t=t, theta=angle)
    assert not replace and check.trusted
    assert check.lag_s == pytest.approx(5e-3, abs=5e-4)


def test_a_field_at_constant_speed_is_trusted_once_its_lag_cannot_be_told():
    t = np.arange(30_000) * 1e-3
    check, replace = _verdict(np.full(t.size, 0.5), t=t, theta=0.5 * t)
    assert not replace and check.trusted and math.isnan(check.lag_s)


def test_a_true_field_is_trusted_beside_the_noisy_rate_of_scattered_stamps():
    # Stamped on arrival (0.3 ms sd at 1 kHz, before the stream is re-timed): steps of a
    # few microseconds give central differences hundreds of times the speed. Regressed
    # on them, the true field read 0.002 times the rate and was replaced.
    t = np.sort(T + RNG.normal(0.0, 0.3e-3, T.size))
    check, replace = _verdict(MOVE, t=t)
    assert not replace and check.trusted
    assert check.scale == pytest.approx(1.0, abs=0.1)
    rate = np.gradient(ANGLE, t)
    both = np.abs(rate) >= 0.01
    assert np.dot(MOVE[both], rate[both]) / np.dot(rate[both], rate[both]) < 0.5  # regressed


def test_a_true_field_of_a_joint_that_mostly_stands_is_trusted_at_2_khz():
    # A standing joint's one-step differences carry the encoder's noise over 0.5 ms:
    # they passed min_speed with either sign and a true field read -0.02 times the rate.
    t = np.arange(40_000) * 0.5e-3
    speed = np.where((t % 4.0) < 0.5, np.sin(2.0 * math.pi * t), 0.0)     # moves 1/8
    angle = np.cumsum(speed) * 0.5e-3 + RNG.normal(0.0, 1.5e-5, t.size)    # 3 arcsec
    check, replace = _verdict(speed, t=t, theta=angle)
    assert not replace and check.trusted
    one_step = np.gradient(angle, t)
    moving = np.abs(one_step) >= 0.01
    assert np.median(speed[moving] / one_step[moving]) < 0.5    # what one step gave


@pytest.mark.parametrize('field, replaced', [(None, False), ('degrees', True)],
                         ids=['true field', 'degrees per second'])
def test_a_noisy_link_encoder_standing_still_is_no_turning_joint(field, replaced):
    # 20 arcsec rms on the link angle: over 10 ms its rate at rest passes min_speed (0.014
    # rad/s of noise), the field there is near zero, and a true field read 0.33-0.47 times
    # the rate, replaced as "other units". The angle's noise (its third differences) now
    # raises the speed a sample must reach to count as turning.
    t = np.arange(40_000) * 1e-3
    speed = np.where((t % 4.0) < 1.0, np.sin(2.0 * math.pi * t), 0.0)     # moves 1/4
    angle = np.cumsum(speed) * 1e-3 + RNG.normal(0.0, 20.0 * 4.848e-6, t.size)
    check, replace = _verdict(speed if field is None else np.degrees(speed), t=t,
                              theta=angle)
    assert replace is replaced and check.decided
    assert check.scale == pytest.approx(1.0 if field is None else 57.3, rel=0.1)


def test_an_angles_noise_is_read_from_its_third_differences():
    noise = 20.0 * 4.848e-6
    angle = ANGLE + RNG.normal(0.0, noise, ANGLE.size)
    assert angle_noise(angle) == pytest.approx(noise, rel=0.1)
    assert angle_noise(ANGLE) < 0.01 * noise      # the swing itself is no noise
    assert angle_noise(ANGLE[:3]) == 0.0


def test_nothing_is_decided_until_the_joint_has_turned_enough():
    check = VelocityCheck(0.01, RATIO)
    t = np.arange(10_000) * 1e-3
    assert not check.check(t, 0.001 * t, np.zeros_like(t))   # below min_speed: standing
    assert not check.decided and math.isnan(check.scale)
    # Differences over 10 ms leave 5 samples at either end of a chunk out.
    t = np.arange(VELOCITY_CHECK_SAMPLES + 9) * 1e-3
    assert not check.check(t, t, np.zeros_like(t))
    assert not check.decided and check.turning == VELOCITY_CHECK_SAMPLES - 1
    assert check.check(t[:11], t[:11], np.zeros(11))     # the sample that decides


def _same(a, b):
    """Equal bit for bit, NaN equal to NaN, through dicts and nested dataclasses."""
    if hasattr(a, '__dataclass_fields__'):
        return all(_same(getattr(a, k), getattr(b, k)) for k in a.__dataclass_fields__)
    if isinstance(a, dict):
        return a.keys() == b.keys() and all(_same(a[k], b[k]) for k in a)
    if isinstance(a, str):
        return a == b
    return bool(np.array_equal(a, b, equal_nan=True))


def _analyzer(batch, velocity, pieces=400):
    """Feed a simulated stream in pieces (as a node does), with this velocity field."""
    stream = compute_te(batch.t, batch.motor_angle, batch.t, batch.link_angle, RATIO)
    analyzer = WindowAnalyzer(PARAMS)
    windows = []
    for sl in np.array_split(np.arange(batch.t.size), pieces):
        part = slice(sl[0], sl[-1] + 1)
        windows += analyzer.update(stream.part(part), batch.effort[part], velocity[part])
    return analyzer, windows + analyzer.flush()


@pytest.mark.parametrize('form', ['zeros', 'degrees', 'negated'])
def test_the_window_analysis_of_a_replaced_field_is_that_of_a_stream_without_one(form):
    _, b = simulated()
    field = {'zeros': np.zeros_like(b.link_velocity),
             'degrees': np.degrees(b.link_velocity),
             'negated': -b.link_velocity}[form]
    without, expected = _analyzer(b, np.full_like(b.link_velocity, np.nan))
    analyzer, got = _analyzer(b, field)
    assert analyzer.velocity_fault is not None
    assert without.velocity_fault is None and math.isnan(without.velocity_scale)
    assert len(got) == len(expected) > 5
    for g, e in zip(got, expected):     # every feature, bit for bit: the first samples too
        assert _same(g, e)
    assert analyzer.derived_velocity == without.derived_velocity == analyzer.samples_seen


def test_a_true_field_is_used_as_it_is():
    _, b = simulated()
    analyzer, _ = _analyzer(b, b.link_velocity)
    assert analyzer.velocity_fault is None and analyzer.derived_velocity == 0
    assert analyzer.velocity_scale == pytest.approx(1.0, abs=0.05)
