"""
A window's duty (``reducer_twin.core.duty_summary``): what the estimator's exposure is.

At a constant load the window's figures are the load itself; the exposure and the
Archard increment scale with the aging factor; a joint at rest has no equivalent
torque; each window sums only its own samples.
"""

import math

import numpy as np
import pytest
from reducer_twin.core.duty_summary import duty_summaries
from reducer_twin.core.params import ReducerParams
from reducer_twin.core.wear import wear_rate

PARAMS = ReducerParams()


def test_a_constant_load_gives_its_own_figures_and_the_aging_scales_the_exposure():
    n, dt = 500, 0.002
    torque, speed = np.full(n, -300.0), np.full(n, 0.8)
    (duty,) = duty_summaries(torque, speed, np.full(n, dt), np.array([0]), PARAMS, 3600.0)
    assert duty.duration_s == pytest.approx(n * dt)
    assert duty.exposure_s == pytest.approx(n * dt * 3600.0)
    assert duty.mean_abs_torque == pytest.approx(300.0)
    assert duty.mean_abs_speed == duty.mean_speed == pytest.approx(0.8)
    assert duty.cubic_mean_torque == pytest.approx(300.0)
    assert duty.max_abs_torque == 300.0
    rate = float(wear_rate(300.0, 0.8, 0.0, PARAMS))
    assert duty.archard_increment == pytest.approx(rate * n * dt * 3600.0)


def test_a_joint_at_rest_has_no_equivalent_torque_and_no_wear():
    n = 100
    (duty,) = duty_summaries(np.full(n, 50.0), np.zeros(n), np.full(n, 0.01), np.array([0]),
                             PARAMS, 1.0)
    assert math.isnan(duty.cubic_mean_torque) and duty.archard_increment == 0.0
    assert duty.mean_abs_torque == pytest.approx(50.0)


def test_each_window_sums_its_own_samples():
    torque = np.concatenate([np.full(10, 100.0), np.full(30, 400.0)])
    speed = np.ones(40)
    dt = np.full(40, 0.01)
    dt[10] = 0.0                          # a gap before the second window's first sample
    first, second = duty_summaries(torque, speed, dt, np.array([0, 10]), PARAMS, 1.0)
    assert first.duration_s == pytest.approx(0.1) and first.max_abs_torque == 100.0
    assert second.duration_s == pytest.approx(0.29)
    assert second.mean_abs_torque == pytest.approx(400.0)
