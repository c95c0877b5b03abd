"""The estimator's observation noise, learnt from the scatter of its innovations."""

import numpy as np
from reducer_twin.core.noise_scale import NOISE_MEMORY, NOISE_PRIOR_WINDOWS
from reducer_twin.core.noise_scale import NOISE_SCALE_RANGE, NoiseScale


def _learnt(rho, n=NOISE_MEMORY, seed=0, predicted=0.0):
    """Innovations whose variance is ``rho`` times the reported one (plus ``predicted``)."""
    rng = np.random.default_rng(seed)
    noise = NoiseScale()
    for _ in range(n):
        noise.add(float(rng.normal(0.0, np.sqrt(rho + predicted))), predicted, 1.0)
    return noise


def test_with_fewer_than_three_innovations_the_scale_is_the_prior_1():
    noise = _learnt(16.0, n=2)
    assert noise.fit() == (1.0, NOISE_PRIOR_WINDOWS)
    assert noise.value == 1.0


def test_the_scale_follows_the_ratio_of_the_scatter_to_the_reported_variance():
    # The median of 40 differences is a noisy measure (a factor of about 2 either way per
    # stream, and the prior's 3 windows shrink it towards 1): ratios 16 apart are still told
    # apart on every one of 12 streams, and each ratio's median stream is within a factor 2.
    learnt = {rho: [_learnt(rho, seed=seed).value for seed in range(12)]
              for rho in (1.0 / 16.0, 1.0, 16.0)}
    assert max(learnt[1.0 / 16.0]) < min(learnt[1.0]) and max(learnt[1.0]) < min(learnt[16.0])
    for rho, values in learnt.items():
        assert rho / 2.0 < np.median(values) < rho * 2.0


def test_a_difference_the_prediction_dominates_says_next_to_nothing():
    # Innovations whose variance is mostly the prediction's: their weight is small, and
    # the prior holds the scale near 1 whatever the scatter.
    noise = _learnt(16.0, predicted=1e4)
    rho, weight = noise.fit()
    assert weight < NOISE_PRIOR_WINDOWS + 1.0 and 0.5 < rho < 2.0


def test_the_scale_stays_within_its_range_and_the_memory_keeps_the_latest():
    assert _learnt(1e6).value <= NOISE_SCALE_RANGE[1]
    assert _learnt(1e-8).value >= NOISE_SCALE_RANGE[0]
    noise = _learnt(1.0, n=NOISE_MEMORY + 10)
    assert len(noise.state()) == NOISE_MEMORY
