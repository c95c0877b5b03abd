"""The recent duty's wear rate and its standard error, as the remaining life takes them."""

import numpy as np
import pytest
from reducer_twin.core.duty_rate import DUTY_BATCH_WINDOWS, DUTY_UNKNOWN_REL_STD, DutyRate

HORIZON_S = 1000.0 * 3600.0


def test_before_any_exposure_the_rate_is_0_and_its_spread_the_unknown_allowance():
    duty = DutyRate(HORIZON_S, 50.0)
    assert duty.rate == 0.0 and duty.rel_std == DUTY_UNKNOWN_REL_STD


def test_a_steady_duty_has_its_rate_and_no_spread_once_three_batches_show_it():
    duty = DutyRate(HORIZON_S, 50.0)
    for k in range(3 * DUTY_BATCH_WINDOWS):
        duty.add(3600.0, 2e-9)
        if k < 3 * DUTY_BATCH_WINDOWS - 1:
            assert duty.rel_std == DUTY_UNKNOWN_REL_STD
    assert duty.rate == pytest.approx(2e-9 / 3600.0, rel=1e-12)
    assert duty.rel_std == 0.0


def test_batches_of_a_random_duty_give_the_standard_error_of_its_mean():
    # 400 windows whose rate scatters by 30 %: batches of 10 average 10 windows each, so the
    # mean of the 40 batches (the horizon keeps them all) is known to about 30 % / 20.
    rng = np.random.default_rng(4)
    duty = DutyRate(1e12, 1e9)
    for rate in rng.normal(1.0, 0.3, 400):
        duty.add(1.0, rate)
    assert duty.rate == pytest.approx(1.0, abs=0.05)
    assert 0.3 / 20 * 0.6 < duty.rel_std < 0.3 / 20 * 1.5


def test_a_restored_state_goes_on_exactly_as_the_original():
    rng = np.random.default_rng(1)
    original = DutyRate(HORIZON_S, 50.0)
    for rate in rng.uniform(0.5, 1.5, 37):
        original.add(3600.0, rate * 1e-9)
    copy = DutyRate(HORIZON_S, 50.0)
    state = original.state()
    copy.restore(state['duty_increment'], state['duty_exposure'], list(state['duty_batch']),
                 list(state['duty_batch_sums']))
    for rate in rng.uniform(0.5, 1.5, 25):
        original.add(3600.0, rate * 1e-9)
        copy.add(3600.0, rate * 1e-9)
    assert copy.state() == original.state()
    assert (copy.rate, copy.rel_std) == (original.rate, original.rel_std)
