"""
Where windows end (``reducer_twin.core.window_cut``).

Never across a gap; every ``window_s`` in ``'duration'`` mode; after a revolution of
net travel in ``'revolution'`` mode; in ``'auto'`` mode a joint turning on past
``window_s`` ends its window when it stops turning; a window has at least
``min_window_samples`` unless a gap or ``max_window_s`` ends it; the last, partial
window waits for more samples until the stream ends.
"""

import math

import numpy as np
import pytest
from reducer_twin.core.window_cut import cut_windows

RATE = 100.0


def _stream(seconds, speed=0.0, gaps=()):
    t = np.arange(int(seconds * RATE)) / RATE
    for at in gaps:
        t[t >= at] += 5.0          # 5 s without samples
    v = np.broadcast_to(np.asarray(speed, dtype=float), t.shape).copy()
    theta = np.concatenate([[0.0], np.cumsum(v[1:] * np.diff(t))])
    gap = np.concatenate([[0.0], np.diff(t) > 1.0]).astype(float)
    return t, theta, v, gap


def _cut(stream, final=False, mode='duration', window_s=2.0, max_window_s=20.0,
         min_window_samples=50, min_speed=0.01):
    return cut_windows(*stream, final, mode, window_s, max_window_s, min_window_samples,
                       min_speed)


def test_duration_windows_are_window_s_long_and_the_rest_waits():
    cuts = _cut(_stream(7.0))
    assert cuts == [(0, 200, 'duration'), (200, 400, 'duration'), (400, 600, 'duration')]
    assert _cut(_stream(7.0), final=True)[-1] == (600, 700, 'flush')


def test_no_window_spans_a_gap():
    t, theta, v, gap = stream = _stream(5.0, gaps=(3.0,))
    cuts = _cut(stream, final=True)
    assert (200, 300, 'gap') in cuts
    for a, b, _ in cuts:
        assert not gap[a + 1:b].any()


def test_a_revolution_of_net_travel_ends_a_window():
    speed = 2.0 * math.pi / 1.5          # one output turn in 1.5 s
    t, theta, _, _ = stream = _stream(5.0, speed=speed)
    a, b, reason = _cut(stream, mode='revolution')[0]
    assert reason == 'revolution' and b == int(np.searchsorted(theta, 2.0 * math.pi))
    # Without net travel only max_window_s ends it.
    assert _cut(_stream(30.0), mode='revolution')[0] == (0, 2000, 'max')


@pytest.mark.parametrize('mode', ['duration', 'auto'])
def test_too_few_samples_lengthen_a_window_up_to_max_window_s(mode):
    stream = _stream(30.0, speed=0.0)
    first = _cut(stream, mode=mode, min_window_samples=500)[0]
    assert first[1] == 500
    capped = _cut(stream, mode=mode, min_window_samples=5000, max_window_s=12.0)[0]
    assert capped == (0, 1200, 'max')


def test_auto_ends_at_window_s_unless_the_joint_turns_on_then_when_it_stops():
    slow = 0.1                           # far from a revolution in the whole stream
    speed = np.where(np.arange(1000) < 350, slow, 0.0)
    stream = _stream(10.0, speed=speed)
    assert _cut(stream, mode='auto')[0] == (0, 350, 'motion')
    back_and_forth = np.where((np.arange(1000) // 50) % 2 == 0, slow, -slow)
    assert _cut(_stream(10.0, speed=back_and_forth), mode='auto')[0] == (0, 200, 'duration')
