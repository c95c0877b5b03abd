"""A drive's first-order torque filter, undone on the effort the window analysis buffers."""

import numpy as np
import pytest
from reducer_twin.core.effort_lag import EffortLag
from reducer_twin.core.torque_smoothing import TorqueSmoothing

TAU_S = 0.03            # the filter's time constant [s]
SLOPE = 100.0           # the load's ramp [N·m/s]
PERIOD_S = 1e-3         # 1 kHz
SMOOTHING = TorqueSmoothing(0.03, 3.0, 15.68, 784.0)    # the analysis's default average


def _filtered_ramp(t):
    """Return the load ``SLOPE·t`` and a first-order filter's output of it from rest."""
    # tau·dE/dt = T - E, E(0) = 0: E = a·(t - tau·(1 - exp(-t/tau))).
    return SLOPE * t, SLOPE * (t - TAU_S * (1.0 - np.exp(-t / TAU_S)))


def test_the_filter_undone_on_a_filtered_ramp_gives_back_the_ramp():
    t = np.arange(0.0, 1.0, PERIOD_S)
    load, effort = _filtered_ramp(t)
    torque = EffortLag(TAU_S, SMOOTHING).torque(t, effort, np.zeros(t.size), PERIOD_S)
    faded = t >= 10 * TAU_S       # the filter's start from rest has faded
    # Published, the effort lags the load by SLOPE·TAU_S = 3 N·m; undone, within 1e-4 N·m
    # (the rate over the average's half-width either side, 15 samples at 1 kHz).
    assert np.abs(effort - load)[faded].min() > 2.99
    np.testing.assert_allclose(torque[faded], load[faded], rtol=0.0, atol=1e-4)


def test_a_gap_is_never_bridged_each_run_reads_as_if_alone():
    # A gap of 0.1 s with the effort 200 N·m higher after it: each side's rate is its own.
    t = np.concatenate([np.arange(0.0, 0.5, PERIOD_S), np.arange(0.6, 1.0, PERIOD_S)])
    effort = _filtered_ramp(t)[1] + np.where(t >= 0.6, 200.0, 0.0)
    gap = np.where(np.r_[0.0, np.diff(t)] > 0.05, 1.0, 0.0)
    lag = EffortLag(TAU_S, SMOOTHING)
    torque = lag.torque(t, effort, gap, PERIOD_S)
    before = t < 0.55
    for run in (before, ~before):
        alone = lag.torque(t[run], effort[run], np.zeros(run.sum()), PERIOD_S)
        np.testing.assert_array_equal(torque[run], alone)


def test_a_sample_waits_for_the_samples_its_rate_reaches_and_a_cut_keeps_those_before():
    t = np.arange(0.0, 1.0, PERIOD_S)
    effort = _filtered_ramp(t)[1] + np.random.default_rng(7).normal(0.0, 2.0, t.size)
    no_gap = np.zeros(t.size)
    whole = EffortLag(TAU_S, SMOOTHING).torque(t, effort, no_gap, PERIOD_S)
    lag = EffortLag(TAU_S, SMOOTHING)
    first = t < 0.4             # the samples that have come
    done = lag.complete(t[first], PERIOD_S)
    assert done == first.sum() - 15         # the last 15 wait for the samples after them
    torque = lag.torque(t[first], effort[first], no_gap[first], PERIOD_S)
    np.testing.assert_array_equal(torque[:done], whole[:done])
    lag.keep(t[first], effort[first], done, PERIOD_S)      # the samples before cut off
    rest = lag.torque(t[done:], effort[done:], no_gap[done:], PERIOD_S)
    np.testing.assert_array_equal(rest, whole[done:])
    lag.restart()               # the stream starts over: nothing before it
    alone = lag.torque(t[done:], effort[done:], no_gap[done:], PERIOD_S)
    assert not np.array_equal(alone[:15], whole[done:done + 15])


@pytest.mark.parametrize('period_s', [PERIOD_S, None], ids=['rate known', 'rate unknown'])
def test_without_a_lag_the_effort_is_read_as_published(period_s):
    t = np.arange(0.0, 0.2, PERIOD_S)
    effort = _filtered_ramp(t)[1]
    lag = EffortLag(0.0, SMOOTHING)
    assert lag.torque(t, effort, np.zeros(t.size), period_s) is effort
    assert lag.complete(t, period_s) == t.size


def test_the_rate_spans_the_torque_averages_half_width_and_at_least_a_sample():
    t = np.arange(0.0, 0.2, PERIOD_S)
    assert EffortLag(TAU_S, SMOOTHING).reach(t, None) == (15, PERIOD_S)   # nominal step
    assert EffortLag(TAU_S, TorqueSmoothing(0.0, 3.0, 15.68, 784.0)).reach(t, 0.01) == (1, 0.01)
