"""The output speed the window analysis buffers: the velocity field, or the link angle's rate."""

import math

import numpy as np
from reducer_twin.core.output_speed import link_rate, OutputSpeed
from reducer_twin.core.te_extraction import compute_te
from te_streams import RATIO

MOVE = np.sin(np.linspace(0.0, 20.0 * math.pi, 4000))      # a joint swinging, rad/s
T = np.arange(MOVE.size) * 1e-3                           # 1 kHz
ANGLE = np.cumsum(MOVE) * 1e-3                            # its link angle, rad
STREAM = compute_te(T, ANGLE * RATIO, T, ANGLE, RATIO)
CHUNK, CUT = 150, 100     # samples fed per update; samples cut into windows after each


def _speeds_as_cut(field):
    """
    Feed the joint in chunks, cutting the buffer's oldest samples after each as windows.

    Return each sample's speed as it left the buffer (or at the end), the OutputSpeed,
    and the samples cut before the chunk that decided the field was replaced.
    """
    speed = OutputSpeed(0.01, RATIO)
    left, buffer, last, cut_before = [], np.empty(0), (None, None), None
    for a in range(0, T.size, CHUNK):
        part = STREAM.part(slice(a, a + CHUNK))
        v, buffered = speed.speeds(part, part.valid, field[a:a + CHUNK], *last)
        if buffered is not None:
            buffer, cut_before = buffered, sum(x.size for x in left)
        buffer = np.concatenate([buffer, v[part.valid]])
        last = (part.t[-1], part.output_angle[-1])
        left.append(buffer[:CUT])
        buffer = buffer[CUT:]
        speed.drop(CUT)
    return np.concatenate(left + [buffer]), speed, cut_before


def test_without_a_field_every_sample_gets_the_link_angles_rate():
    speeds, speed, _ = _speeds_as_cut(np.full(T.size, np.nan))
    assert speed.derived == T.size and not speed.check.decided
    # The swing's speed to within 0.02 rad/s (its angle is the speed summed at 1 kHz: the
    # differences lag it by half a step, by one at a chunk's end: the next has not come).
    np.testing.assert_allclose(speeds, MOVE, rtol=0.0, atol=2e-2)
    interior = np.ones(T.size, dtype=bool)
    interior[CHUNK - 1::CHUNK] = False
    np.testing.assert_allclose(speeds[interior], np.gradient(ANGLE, T)[interior],
                               rtol=0.0, atol=1e-12)


def test_a_field_found_wrong_gives_the_samples_still_buffered_the_rate_too():
    without, _, _ = _speeds_as_cut(np.full(T.size, np.nan))
    speeds, speed, cut_before = _speeds_as_cut(-MOVE)
    assert speed.check.replaced and 0 < cut_before < T.size // 2
    # Samples cut into windows before the verdict were read with the field; every later
    # one, those buffered before the verdict too, has the speed of a stream without one.
    np.testing.assert_array_equal(speeds[:cut_before], -MOVE[:cut_before])
    np.testing.assert_array_equal(speeds[cut_before:], without[cut_before:])
    assert speed.derived == T.size - cut_before


def test_a_true_field_is_kept_as_it_is():
    speeds, speed, cut_before = _speeds_as_cut(MOVE)
    assert speed.check.trusted and cut_before is None
    np.testing.assert_array_equal(speeds, MOVE)
    assert speed.derived == 0


def test_the_rate_reaches_back_to_the_previous_sample_within_the_largest_gap_only():
    a = 1000
    part = STREAM.part(slice(a, a + 10))
    back = link_rate(part, part.valid, T[a - 1], ANGLE[a - 1])
    assert back[0] == np.gradient(ANGLE, T)[a]              # central, across the chunks
    beyond = link_rate(part, part.valid, T[a - 1] - STREAM.max_gap_s, ANGLE[a - 1])
    assert beyond[0] == link_rate(part, part.valid)[0]      # one-sided: a gap between
