"""An effort held between updates slower than the stream: found, so that it is said."""

from dataclasses import replace

import numpy as np
import pytest
from reducer_twin.core.held_effort import HELD_MIN_PAIRS, HeldEffort
from te_streams import analyzed, simulated

T = np.arange(5000) * 1e-3                       # 1 kHz
TORQUE = 300.0 * np.sin(2.0 * np.pi * 0.5 * T)
RNG = np.random.default_rng(3)


def _judged(effort, chunks=7):
    held = HeldEffort()
    for part in np.array_split(np.arange(T.size), chunks):
        held.observe(T[part], effort[part])
    return held


def test_an_effort_of_a_100_hz_loop_on_a_1_khz_stream_is_held_at_100_hz():
    noisy = TORQUE + RNG.normal(0.0, 10.0, T.size)
    held = _judged(noisy[(np.arange(T.size) // 10) * 10])
    assert held.held and held.update_hz == pytest.approx(100.0, rel=0.02)
    assert held.hold_samples == 10


@pytest.mark.parametrize('effort', [
    TORQUE + RNG.normal(0.0, 10.0, T.size),     # a motor-current estimate
    np.round(TORQUE + RNG.normal(0.0, 10.0, T.size)),     # quantised under its noise
    np.zeros_like(T),                            # never changes: said as such elsewhere
], ids=['noisy', 'quantised under its noise', 'constant'])
def test_an_effort_fresh_on_every_sample_is_not_held(effort):
    held = _judged(effort)
    assert held.decided and not held.held and held.update_hz is None
    assert held.hold_samples == 1


def test_nothing_is_judged_before_enough_pairs():
    held = HeldEffort()
    held.observe(T[:HELD_MIN_PAIRS], np.zeros(HELD_MIN_PAIRS))
    assert not held.decided and not held.held


def test_the_window_analysis_says_a_held_effort_and_keeps_quiet_about_a_fresh_one():
    _, b = simulated(samples=8000)
    assert analyzed(b).effort_held is None
    held = b.effort[(np.arange(b.effort.size) // 10) * 10]
    said = analyzed(replace(b, effort=held)).effort_held
    assert said.startswith('the effort repeats itself on successive samples: it changes at '
                           'about 100 Hz on a 1000 Hz stream'), said
    assert said.endswith("the lost motion rests on fewer independent samples than the stream's "
                         'rate suggests')


@pytest.mark.parametrize('chunks', [1, 25, 50])
def test_a_held_efforts_rate_is_counted_beyond_the_verdict_whatever_the_pieces(chunks):
    # Judged from the first 200 pairs, 0.1-s pieces counted 20 updates and read 96-99 Hz.
    noisy = TORQUE + RNG.normal(0.0, 10.0, T.size)
    held = _judged(noisy[(np.arange(T.size) // 10) * 10], chunks)
    assert held.held and held.update_hz == pytest.approx(100.0, rel=0.005)
    assert not held.watching
