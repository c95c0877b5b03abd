"""
Pairing by controller tick: jittered stamps of one tick paired as they are, true ones not.

A joint swings with link and motor on topics of their own; a :class:`Pairer` given the
ratio lets its :class:`~reducer_twin.core.tick_pairing.TickPairing` decide from the data.
"""

from encoder_streams import CFG, MS, RATIO, T0
import numpy as np
from reducer_twin.core import pairing
from reducer_twin.core.ingest import CleanStream
from reducer_twin.core.pairing import Pairer


def tick_streams(stamps_are_true, n=3000, seed=7, jitter_ns=30_000):
    """
    Return a joint swinging at up to 1.5 rad/s, link and motor on topics of their own.

    ``stamps_are_true=False``: both encoders are read on the controller tick and each
    stamp adds its topic's jitter; True: each is read at its own jittered instant, which
    its stamp gives exactly (1 kHz). ``(link, motor, te_true)``: cleaned streams and the
    true TE at the link samples [rad].
    """
    rng = np.random.default_rng(seed)
    tick = T0 + np.arange(n, dtype=np.int64) * MS
    jit_l, jit_m = (np.round(rng.normal(0.0, jitter_ns, n)).astype(np.int64) for _ in range(2))

    def q(t_ns):
        t = (t_ns - T0) * 1e-9
        return 0.5 * np.sin(3.0 * t) + 0.2 * np.sin(7.0 * t)

    def te(t_ns):
        return 2e-4 * np.sin(q(t_ns))

    at_l, at_m = (tick + jit_l, tick + jit_m) if stamps_are_true else (tick, tick)
    link = q(at_l) + te(at_l) + rng.normal(0.0, 1e-7, n)
    motor = RATIO * q(at_m) + rng.normal(0.0, 2e-6, n)
    nan = np.full(n, np.nan)
    seg = np.zeros(n, np.int64)
    return (CleanStream(tick + jit_l, link, nan, nan, seg),
            CleanStream(tick + jit_m, motor, nan, nan, seg.copy()), te(at_l))


def pair_in_batches(pairer, link, motor, batch=2):
    """Feed both streams in batches of ``batch`` samples, as encoder_ingest does live."""
    out = []
    for a in range(0, len(link), batch):
        idx = np.arange(a, min(a + batch, len(link)))
        pairer.add_link(pairing._take(link, idx))
        pairer.add_motor(pairing._take(motor, idx))
        out.append(pairer.pop())
    out.append(pairer.pop(final=True))
    return (np.concatenate([p.t_ns for p in out]),
            np.concatenate([p.link_angle - p.motor_angle / RATIO for p in out]))


def test_a_pairer_pairs_jittered_stamps_of_one_tick_by_tick_live_batch_by_batch():
    link, motor, te_true = tick_streams(stamps_are_true=False)
    pairer = Pairer(CFG, ratio=RATIO)
    t, te = pair_in_batches(pairer, link, motor)
    assert pairer.ticks.pairing == 'tick'
    facts = pairer.ticks.facts()
    assert facts['pairing'].startswith('tick:') and facts['tick_paired'] > 2500
    rows = np.searchsorted(link.t_ns, t)
    err = (te - te_true[rows])[t > T0 + 500 * MS]     # decided within the first 0.5 s
    # Encoder level (0.1 µrad link noise); interpolation left 30 µrad of jitter noise.
    assert np.std(err) < 0.5e-6
    old = Pairer(CFG)
    t_old, te_old = pair_in_batches(old, link, motor)
    assert np.std((te_old - te_true[np.searchsorted(link.t_ns, t_old)])[t_old > T0 + 500 * MS]) \
        > 10e-6


def test_a_pairer_keeps_interpolating_true_stamps_and_pairs_the_same_samples():
    link, motor, te_true = tick_streams(stamps_are_true=True)
    pairer = Pairer(CFG, ratio=RATIO)
    t, te = pair_in_batches(pairer, link, motor, batch=500)
    assert pairer.ticks.decided == 'interpolate' and pairer.ticks.tick_paired == 0
    t_old, te_old = pair_in_batches(Pairer(CFG), link, motor, batch=500)
    np.testing.assert_array_equal(t, t_old)
    np.testing.assert_array_equal(te, te_old)
    assert np.std(te - te_true[np.searchsorted(link.t_ns, t)]) < 0.5e-6
