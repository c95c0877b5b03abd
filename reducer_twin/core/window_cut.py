"""
Where a TE stream's windows end.

The window analysis (:mod:`.window_analysis`) reads its health indicators window by
window; :func:`cut_windows` says where the windows of its buffered samples end, and
why. Windows never span a gap of the stream. ``'duration'`` cuts every ``window_s``
of stream; ``'revolution'`` after each output revolution of net travel (or
``max_window_s``); ``'auto'`` after one revolution while the joint turns continuously
in one direction, otherwise after ``window_s`` (a window that turned continuously
past ``window_s`` ends when continuous motion stops). A window that ends by
revolution, duration or motion holds at least ``min_window_samples`` (at 100 Hz a
2 s window holds too few samples per torque bin and sign): it is lengthened, up to
``max_window_s``.
"""

import numpy as np

from .te_extraction import TWO_PI

WINDOW_MODES = ('auto', 'revolution', 'duration')
"""How windows end (see the module)."""


def cut_windows(t, theta, speed, gap, final, mode, window_s, max_window_s,
                min_window_samples, min_speed):
    """
    Return ``[(start, end, reason)]`` of the windows complete in a stream's samples.

    Parameters
    ----------
    t : ndarray, shape (N,)
        Sample stamps [s], increasing.
    theta : ndarray, shape (N,)
        Unwrapped output angle [rad].
    speed : ndarray, shape (N,)
        Output speed [rad/s].
    gap : ndarray, shape (N,)
        Nonzero where a gap of the stream precedes the sample.
    final : bool
        Close the last, partial window too (reason ``'flush'``).
    mode : str
        One of :data:`WINDOW_MODES`.
    window_s, max_window_s : float
        Window length and longest window [s].
    min_window_samples : int
        Fewest samples of a window that ends by revolution, duration or motion.
    min_speed : float
        Slowest output speed counted as turning [rad/s].

    Returns
    -------
    list of tuple
        ``(start, end, reason)``: sample indices ``[start, end)`` and why it ended
        (``'gap'``, ``'max'``, ``'duration'``, ``'revolution'``, ``'motion'``, or
        ``'flush'`` at the end with ``final``); the samples after the last end wait
        for more.

    """
    n = t.size
    gaps = np.flatnonzero(gap)
    cuts, s = [], 0
    while s < n:
        g = gaps[np.searchsorted(gaps, s, side='right')] if gaps.size and gaps[-1] > s else n
        x = min(int(np.searchsorted(t, t[s] + max_window_s)), g)
        d = int(np.searchsorted(t, t[s] + window_s))
        cand = [(g, 'gap'), (x, 'max')]
        if mode == 'duration':
            cand.append((d, 'duration'))
        else:
            # Searched in growing blocks from about one window; the turn only up to
            # where the window ends anyway: a revolution found later is never the end.
            shortest = s + min_window_samples
            block = max(d, shortest) - s + 2
            turn_until = x
            if mode == 'auto':
                direction = np.sign(speed[s])

                def stopped(a, b):
                    v = speed[a:b]
                    return ~((np.abs(v) >= min_speed) & (np.sign(v) == direction))
                c = _first_index(stopped, s, x, block, n)
                last = (d, 'duration') if c <= d else (c, 'motion')
                turn_until = min(x, max(last[0], shortest) + 1)
            start_theta = theta[s]
            r = _first_index(lambda a, b: np.abs(theta[a:b] - start_theta) >= TWO_PI,
                             s, turn_until, block, n)
            cand.append((r, 'revolution'))
            if mode == 'auto':
                cand.append(last)
        # Too few samples (a low rate) for the torque bins: the window goes on.
        shortest = s + min_window_samples
        cand = [(c if r in ('gap', 'max') else max(c, shortest), r) for c, r in cand]
        end, reason = min(cand, key=lambda item: item[0])
        if end >= n:
            if not final:
                break
            end, reason = n, 'flush'
        cuts.append((s, end, reason))
        s = end
    return cuts


def _first_index(test, start, stop, block, default):
    """
    First index in ``[start, stop)`` where ``test(a, b)`` (a mask of ``[a, b)``) holds.

    Blocks of ``block`` samples, four times longer each time, are tested in turn, so a
    hit near ``start`` does not cost a test of the whole span; ``default`` if none.
    """
    a = start
    while a < stop:
        b = min(stop, a + block)
        hit = np.flatnonzero(test(a, b))
        if hit.size:
            return a + int(hit[0])
        a, block = b, 4 * block
    return default
