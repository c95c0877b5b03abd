"""How finely each encoder reports the output angle: judged from its steps, said when coarse."""

import math

import numpy as np
import pytest
from reducer_twin.core.encoder_steps import COARSE_STEP_RAD, EncoderSteps, GROWTH_STEP_RAD
from reducer_twin.core.encoder_steps import JUDGE_STEPS

RATIO = 81.0


def _motion(n=4000):
    t = np.arange(n) * 1e-3
    return 0.8 * np.sin(2.0 * math.pi * 0.5 * t)


def _quantised(angle, bits):
    quantum = 2.0 * math.pi / 2 ** bits
    return np.round(angle / quantum) * quantum


@pytest.mark.parametrize('link_bits, motor_bits, said', [
    (12, 20, 'the link encoder moves in steps of 5.3 arcmin at the output, coarser than'),
    (17, 20, 'the link encoder moves in steps of 0.16 arcmin at the output: a lost motion'),
    (19, 20, None),
    (20, 14, None),     # 14 bits at the motor: 0.016 arcmin a step at the output
])
def test_an_encoder_coarser_than_the_lost_motion_or_its_growth_is_said(
        link_bits, motor_bits, said):
    q = _motion()
    steps = EncoderSteps(RATIO)
    steps.observe(_quantised(q, link_bits), _quantised(RATIO * q, motor_bits))
    assert steps.decided
    reason = steps.reason()
    assert reason is None if said is None else reason.startswith(said)


def test_both_encoders_coarse_are_said_in_one_line_each_with_its_step():
    q = _motion()
    steps = EncoderSteps(RATIO)
    steps.observe(_quantised(q, 12), _quantised(RATIO * q, 5))     # 8.3 arcmin at the output
    link, motor = steps.reason().split('; ')
    assert link.startswith('the link encoder moves in steps of 5.3 arcmin')
    assert motor.startswith('the motor encoder moves in steps of 8.3 arcmin')
    assert steps.step['motor'] > COARSE_STEP_RAD > GROWTH_STEP_RAD


def test_encoders_are_judged_only_after_enough_steps_and_a_resting_joint_waits():
    # A joint at rest on a coarse encoder shows no step: nothing is judged, nothing said.
    steps = EncoderSteps(RATIO)
    steps.observe(np.full(5000, 0.3), np.full(5000, 0.3 * RATIO))
    assert not steps.decided and steps.reason() is None
    q = _quantised(_motion(), 12)
    moving = np.flatnonzero(np.diff(q))
    few = q[:moving[JUDGE_STEPS // 2]]
    steps.observe(few, RATIO * few)
    assert not steps.decided
    steps.observe(q, RATIO * q)
    assert steps.decided and 'link encoder moves in steps of 5.3' in steps.reason()
