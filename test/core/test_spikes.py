"""
The spike filter of paired samples (SpikeFilter, SpikeFilterBank).

TE built by hand with glitches of either encoder and real steps; hypothesis checks that
the result does not depend on how the pairs are chunked and that the bank of all joints
decides as one filter per joint does.
"""

from encoder_streams import CFG, RATIO
from hypothesis import given, settings
from hypothesis import strategies as st
import numpy as np
from reducer_twin.core.spikes import SpikeFilter, SpikeFilterBank


def spike_input(te):
    """Return (motor, link) angles of paired samples with the given TE."""
    motor = np.linspace(0.0, 8.0, len(te))
    return motor, motor / RATIO + np.asarray(te, dtype=float)


def test_a_single_glitch_of_either_encoder_is_dropped_as_a_spike():
    thr = CFG.spike_te_rad
    motor, link = spike_input(np.zeros(20))
    link[5] += 3 * thr                  # link encoder glitch
    motor[12] += 3 * thr * RATIO        # motor encoder glitch
    spikes = SpikeFilter(RATIO)
    keep = spikes.keep(motor, link)
    np.testing.assert_array_equal(np.flatnonzero(~keep), [5, 12])
    assert spikes.counts == {'spike': 2, 'step': 0}


def test_a_real_step_drops_one_sample_and_is_then_accepted_as_a_step():
    thr = CFG.spike_te_rad
    te = np.where(np.arange(20) < 8, 0.0, 4 * thr)   # re-homing shifts the TE for good
    spikes = SpikeFilter(RATIO)
    keep = spikes.keep(*spike_input(te))
    np.testing.assert_array_equal(np.flatnonzero(~keep), [8])
    assert spikes.counts == {'spike': 1, 'step': 1}


def test_a_slowly_drifting_te_is_never_a_spike():
    te = np.linspace(0.0, 20 * CFG.spike_te_rad, 2000)
    spikes = SpikeFilter(RATIO)
    assert spikes.keep(*spike_input(te)).all()
    assert spikes.counts == {'spike': 0, 'step': 0}


def test_a_spike_in_one_chunk_does_not_excuse_a_spike_in_the_next():
    # After a glitch ends a chunk and clean samples open the next one, a second glitch
    # of the same size is a spike again, not the confirmation of a step.
    thr = CFG.spike_te_rad
    te = np.array([0, 0, 0, 5, 0, 0, 5, 0, 0]) * thr
    whole = SpikeFilter(RATIO)
    expected = whole.keep(*spike_input(te))
    split = SpikeFilter(RATIO)
    motor, link = spike_input(te)
    got = np.concatenate([split.keep(motor[:4], link[:4]), split.keep(motor[4:], link[4:])])
    np.testing.assert_array_equal(got, expected)
    np.testing.assert_array_equal(np.flatnonzero(~got), [3, 6])
    assert split.counts == whole.counts == {'spike': 2, 'step': 0}


@settings(max_examples=60)
@given(seed=st.integers(0, 2 ** 32 - 1), chunk_seed=st.integers(0, 2 ** 32 - 1),
       rate=st.sampled_from([0.01, 0.05, 0.2]))
def test_spike_filtering_does_not_depend_on_how_the_pairs_are_chunked(seed, chunk_seed, rate):
    rng = np.random.default_rng(seed)
    n = 300
    thr = CFG.spike_te_rad
    te = np.cumsum(rng.normal(0.0, 0.05 * thr, n))
    glitch = rng.random(n) < rate
    te[glitch] += rng.choice([-1, 1], int(glitch.sum())) * rng.uniform(1.5, 6.0) * thr
    steps = rng.random(n) < rate / 5
    te += np.cumsum(steps) * 3 * thr
    motor, link = spike_input(te)
    whole = SpikeFilter(RATIO)
    expected = whole.keep(motor, link)
    chunked = SpikeFilter(RATIO)
    sizes = np.random.default_rng(chunk_seed).integers(1, 12, n)
    bounds = np.concatenate([[0], np.cumsum(sizes)])
    bounds = bounds[bounds < n].tolist() + [n]
    got = np.concatenate([chunked.keep(motor[a:b], link[a:b])
                          for a, b in zip(bounds[:-1], bounds[1:])])
    np.testing.assert_array_equal(got, expected)
    assert chunked.counts == whole.counts


@settings(max_examples=40)
@given(seed=st.integers(0, 2 ** 32 - 1), chunk_seed=st.integers(0, 2 ** 32 - 1))
def test_the_spike_bank_gives_what_one_filter_per_joint_gives_in_any_chunks(seed, chunk_seed):
    # The bank keeps the common case as one array for all joints; glitches, steps and
    # unpaired entries (NaN) must come out as each joint's own filter decides.
    rng = np.random.default_rng(seed)
    n, joints = 240, 3
    thr = CFG.spike_te_rad
    te = np.cumsum(rng.normal(0.0, 0.3 * thr, (n, joints)), axis=0)
    glitch = rng.random((n, joints)) < 0.03
    te[glitch] += rng.choice([-1, 1], int(glitch.sum())) * rng.uniform(1.5, 6.0) * thr
    te += np.cumsum(rng.random((n, joints)) < 0.005, axis=0) * 3 * thr
    motor = np.linspace(0.0, 8.0, n)[:, None] + np.zeros((1, joints))
    link = motor / RATIO + te
    valid = rng.random((n, joints)) > 0.02
    expected = np.zeros((n, joints), dtype=bool)
    singles = [SpikeFilter(RATIO) for _ in range(joints)]
    for k, f in enumerate(singles):
        rows = np.flatnonzero(valid[:, k])
        expected[rows, k] = f.keep(motor[rows, k], link[rows, k])
    bank = SpikeFilterBank(RATIO, joints)
    sizes = np.random.default_rng(chunk_seed).choice([1, 1, 1, 2, 5, 17], n)
    bounds = np.concatenate([[0], np.cumsum(sizes)])
    bounds = bounds[bounds < n].tolist() + [n]
    got = np.concatenate([bank.keep(motor[a:b], link[a:b], valid[a:b])
                          for a, b in zip(bounds[:-1], bounds[1:])])
    np.testing.assert_array_equal(got, expected)
    assert [bank.counts(k) for k in range(joints)] == [f.counts for f in singles]
