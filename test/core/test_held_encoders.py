"""An encoder whose reading is held between updates slower than the stream, by its pairs."""

import math

import numpy as np
import pytest
from reducer_twin.core.held_encoders import HELD_MIN_PAIRS, HeldEncoders, STILL_RAD

RATIO = 81.0


def _motion(n=4000, speed=1.0, rate_hz=1000.0):
    """Link and motor angles of a joint swinging at up to ``speed`` [rad/s], fresh both."""
    t = np.arange(n) / rate_hz
    link = speed / 2.0 * np.sin(2.0 * t) + 1e-6 * np.sin(37.0 * t)
    return link, RATIO * (link + 2e-5 * np.sin(3.0 * t))


def _held(angle, k, phase=0):
    """Return the reading of ``angle`` refreshed every ``k`` samples only."""
    idx = np.arange(angle.size)
    return angle[np.maximum(idx - (idx - phase) % k, 0)]


def test_fresh_encoders_are_not_held_nor_is_a_17_bit_link_quantised():
    link, motor = _motion()
    step = 2 * math.pi / 2 ** 17
    for reading, motor_reading in ((link, motor), (np.round(link / step) * step, motor),
                                   (np.round(link / step) * step, np.round(motor / 0.01) * 0.01)):
        held = HeldEncoders(RATIO)
        assert held.stale_mask(reading, motor_reading) is None
        assert held.decided and held.held == {'link': False, 'motor': False, 'both': False}
        assert held.reason(1000.0) is None


@pytest.mark.parametrize('k', [2, 4, 10])
def test_a_link_reading_held_for_k_samples_is_found_and_its_repeats_left_out(k):
    link, motor = _motion()
    reading = _held(link, k)
    held = HeldEncoders(RATIO)
    stale = held.stale_mask(reading, motor)
    assert held.held == {'link': True, 'motor': False, 'both': False}
    assert held.update_share('link') == pytest.approx(1.0 / k, abs=0.02)
    # What is kept pairs an update with the motor at its own stamp, or a repeat over which
    # the joint hardly moved (at a turn): the TE errs there by less than STILL_RAD.
    kept = ~stale
    assert np.abs(reading[kept] - link[kept]).max() < STILL_RAD
    assert stale.sum() == pytest.approx((k - 1) / k * link.size, rel=0.02)
    assert f'updated at about {1000 / k:.0f} Hz on a 1000 Hz stream' in held.reason(1000.0)


def test_a_held_motor_reading_is_found_as_well():
    link, motor = _motion()
    held = HeldEncoders(RATIO)
    stale = held.stale_mask(link, _held(motor, 4, phase=1))
    assert held.held == {'link': False, 'motor': True, 'both': False}
    assert stale is not None and held.reason(1000.0).startswith('the motor encoder repeats')


def test_both_readings_held_on_the_same_samples_are_found_and_left_out_while_moving():
    # Neither encoder moves while the other repeats, so neither is held alone; their TE is
    # right, but as old as the update beside an effort that is not. Their runs end in a
    # step of several samples' motion: those runs' repeats are stale.
    link, motor = _motion()
    held = HeldEncoders(RATIO)
    stale = held.stale_mask(_held(link, 4), _held(motor, 4))
    assert held.held == {'link': False, 'motor': False, 'both': True}
    assert held.update_share('both') == pytest.approx(0.25, abs=0.02)
    assert stale.sum() == pytest.approx(0.75 * link.size, rel=0.03)
    assert held.reason(1000.0).startswith('the link and motor encoders repeat their readings '
                                          'together')
    assert 'updated at about 250 Hz on a 1000 Hz stream' in held.reason(1000.0)


def test_a_joint_at_rest_keeps_its_repeated_readings():
    # Held or not, a reading that stays while the other encoder stands still is right.
    link, motor = _motion()
    rest_link = np.concatenate([link, np.full(3000, link[-1])])
    rest_motor = np.concatenate([motor, np.full(3000, motor[-1])])
    held = HeldEncoders(RATIO)
    stale = held.stale_mask(_held(rest_link, 4), rest_motor)
    assert held.held['link'] and not stale[link.size + 4:].any()


def test_the_judgement_and_the_stale_samples_do_not_depend_on_the_chunks():
    link, motor = _motion(n=6000)
    reading = _held(link, 4, phase=2)
    whole = HeldEncoders(RATIO).stale_mask(reading, motor)
    held = HeldEncoders(RATIO)
    cuts = [0, 7, 150, 151, 1999, 4100, 6000]
    parts = [held.stale_mask(reading[a:b], motor[a:b]) for a, b in zip(cuts[:-1], cuts[1:])]
    chunked = np.concatenate([np.zeros(b - a, bool) if p is None else p
                              for p, a, b in zip(parts, cuts[:-1], cuts[1:])])
    # Before the judgement (HELD_MIN_PAIRS moving pairs) nothing is left out.
    judged = np.flatnonzero(np.cumsum(np.abs(np.diff(motor / RATIO)) > 2e-4) >= HELD_MIN_PAIRS)[0]
    first_chunk_after = next(a for a in cuts if a > judged + 1)
    np.testing.assert_array_equal(chunked[first_chunk_after:], whole[first_chunk_after:])
    assert held.stale == chunked.sum()
