"""The ratio of the motor's moves to the link's, measured from the TE and said when off."""

import math

import numpy as np
import pytest
from reducer_twin.core.te_extraction import compute_te
from reducer_twin.core.travel_ratio import mixed_units, motor_angle_form, RATIO_TOLERANCE
from reducer_twin.core.travel_ratio import TravelRatio

RATIO = 81.0
T = np.arange(20_000) * 1e-3                              # 20 s at 1 kHz
LINK = 0.8 * np.sin(2.0 * math.pi * 0.25 * T)             # back and forth over 1.6 rad


def _te(ratio_true, play_rad=5e-4):
    """TE of a motor turning ``ratio_true`` times the link, with play taken up at reversals."""
    side = np.sign(np.gradient(LINK, T))
    return LINK * (1.0 - ratio_true / RATIO) - 0.5 * play_rad * side


@pytest.mark.parametrize('ratio_true, said', [
    (RATIO, None),
    (RATIO * 1.01, 'the motor encoder turns 81.81 times the link where the configured '
                   'reduction ratio is 81 (+1 %)'),
    (101.0, 'the motor encoder turns 101 times the link where the configured reduction '
            'ratio is 81 (+25 %)'),
])
def test_a_motor_that_turns_another_number_of_times_is_measured_and_said(ratio_true, said):
    travel = TravelRatio(RATIO)
    for part in np.array_split(np.arange(T.size), 40):     # a node's chunks
        travel.observe(T[part], LINK[part], _te(ratio_true)[part])
    assert travel.measured == pytest.approx(ratio_true, rel=1e-3)
    reason = travel.reason()
    assert reason is None if said is None else reason.startswith(said)


def test_a_turn_count_restored_in_the_te_is_no_move_of_the_motor():
    # A wrapped encoder's TE steps by 2 pi / i where a turn count was restored.
    te = _te(RATIO)
    te[7000:] += 2.0 * math.pi / RATIO
    travel = TravelRatio(RATIO)
    travel.observe(T, LINK, te)
    assert abs(travel.measured / RATIO - 1.0) < 0.1 * RATIO_TOLERANCE
    assert travel.reason() is None


def test_a_noisy_link_encoder_reads_the_ratio_it_has():
    # The link's moves are the regressor: 20 arcsec rms of noise on them read 80.58 for 81
    # (-0.52 %, said as another ratio) on an independent-generator shoulder. Its variance
    # is taken off.
    # A joint that moves a quarter of the time: its standing samples' noisy moves weigh.
    t = np.arange(40_000) * 1e-3
    speed = np.where((t % 4.0) < 1.0, 0.6 * np.sin(math.pi * t), 0.0)
    true = np.cumsum(speed) * 1e-3
    link = true + np.random.default_rng(5).normal(0.0, 20.0 * 4.848e-6, t.size)
    travel = TravelRatio(RATIO)
    for part in np.array_split(np.arange(t.size), 40):
        travel.observe(t[part], link[part], (link - true)[part])
    assert abs(travel.measured / RATIO - 1.0) < 0.2 * RATIO_TOLERANCE
    assert travel.reason() is None


def test_nothing_is_judged_before_the_link_has_travelled_enough():
    travel = TravelRatio(RATIO)
    travel.observe(T[:1000], LINK[:1000], _te(101.0)[:1000])    # 1 s: 0.8 rad
    assert travel.measured is None and travel.reason() is None


def test_a_link_held_between_slower_updates_is_no_noise_to_take_off():
    # Held for two samples, the link angle is a staircase whose steps are motion: read as
    # noise, its variance took the ratio 3.7 % high (83.95 for 81) and said so.
    held = LINK[(np.arange(T.size) // 2) * 2]
    travel = TravelRatio(RATIO)
    for part in np.array_split(np.arange(T.size), 40):
        travel.observe(T[part], held[part], (held - LINK)[part])
    assert travel.measured == pytest.approx(RATIO, rel=1e-4)
    assert travel.reason() is None


@pytest.mark.parametrize('ratio_true, said, remedy', [
    (171.0, 'the motor encoder turns 171 times the link where the configured reduction '
            'ratio is 81 (+1.1e+02 %)', '`reducer` / `reducers` of the configuration'),
    (RATIO * 180.0 / math.pi, 'That is 57.3 times the configured ratio, which a motor angle '
                              'in degrees beside a link angle in radians gives',
     'publish both angles in radians (REP 103)'),
    (RATIO * math.pi / 180.0, 'a link angle in degrees beside a motor angle in radians',
     'publish both angles in radians (REP 103)'),
    (RATIO / (2.0 * math.pi), 'a motor angle in revolutions beside a link angle in radians',
     'publish both angles in radians (REP 103)'),
    (-RATIO, 'That is -1 times the configured ratio, which a motor encoder that counts '
             'against the link (a negative reduction) gives',
     'set motor_direction (twin.motor_direction in --config) to -1'),
], ids=['another frame ratio', 'motor in degrees', 'link in degrees', 'motor in revolutions',
        'motor reversed'])
def test_a_motor_far_off_the_ratio_is_measured_from_the_moves_the_te_gate_leaves_out(
        ratio_true, said, remedy):
    # Such a TE changes by more than half the link's move on every move, which the gate
    # against restored turn counts left out: the joint was refused as encoders that do not
    # measure one motion, with no ratio said.
    travel = TravelRatio(RATIO)
    for part in np.array_split(np.arange(T.size), 40):
        travel.observe(T[part], LINK[part], _te(ratio_true)[part])
    assert travel.measured == pytest.approx(ratio_true, rel=1e-3)
    assert said in travel.reason() and travel.reason().endswith(remedy)


def test_a_motor_whose_moves_fold_into_turns_is_not_given_a_ratio():
    # A motor in degrees moves more than half a "turn" a sample at 1 kHz: unwrapped, its
    # moves fold, their ratios scatter (quartiles -359 and 640 for 4641 on the model's
    # simulator), and the ratio they would give is no measurement.
    motor = RATIO * np.degrees(LINK)
    stream = compute_te(T, motor, T, LINK, RATIO)
    travel = TravelRatio(RATIO)
    for part in np.array_split(np.arange(T.size), 40):
        travel.observe(stream.t[part], stream.output_angle[part], stream.te[part])
    assert travel.measured is None and travel.reason() is None


DEG = math.pi / 180.0


@pytest.mark.parametrize('travel, said, raw', [
    (RATIO * DEG, 'a link angle in degrees beside a motor angle in radians', True),
    (RATIO / DEG, 'a motor angle in degrees beside a link angle in radians', True),
    (RATIO * 2.0 * math.pi, 'a link angle in revolutions beside a motor angle in radians',
     True),
    (DEG, 'a link angle in degrees beside a motor angle in radians', False),
    (1.0 / (2.0 * math.pi), 'a motor angle in revolutions beside a link angle in radians',
     False),
])
def test_encoders_in_mixed_units_are_named_from_their_travel(travel, said, raw):
    factor, what, remedy, got_raw = mixed_units(travel * 1.03, RATIO)   # 3 % off
    assert what == said and got_raw is raw
    assert remedy == 'publish both angles in radians (REP 103)'
    assert travel / factor == pytest.approx(RATIO if raw else 1.0)


@pytest.mark.parametrize('travel', [
    RATIO, 0.97 * RATIO, 1.0, 1.04,     # raw or output angles in radians
    101.0, 57.0,                        # another ratio of the frame: a ratio, said as one
    1.0 / DEG,                          # 57.3: read as raw (a ratio-57 reducer is likelier)
    1.0 / RATIO,                        # link and motor entries swapped
    math.nan, 0.0,                      # nothing travelled
])
def test_travels_of_one_unit_are_not_taken_for_mixed_units(travel):
    assert mixed_units(travel, RATIO) is None


def test_a_reducer_of_ratio_57_reads_raw_not_as_a_motor_in_degrees():
    assert mixed_units(57.0, 57.0) is None and mixed_units(57.0 / DEG, 57.0) is not None


@pytest.mark.parametrize('ratio_true, said', [
    (1.0, 'That is 0.01235 times the configured ratio, which a motor angle already divided '
          'by the ratio but configured as raw gives: set motor_angles (twin.motor_angles in '
          '--config) to output'),
    (RATIO * RATIO, 'That is 81 times the configured ratio, which a raw motor angle configured '
                    'as divided by the ratio gives: set motor_angles (twin.motor_angles in '
                    '--config) to raw'),
])
def test_motor_angles_configured_in_the_other_form_are_named_with_the_setting(ratio_true, said):
    # A live node is told the form (motor_angles); the other one was said as a ratio of
    # another reducer: "give this reducer's geometry ... in its parameter file".
    travel = TravelRatio(RATIO)
    for part in np.array_split(np.arange(T.size), 40):
        travel.observe(T[part], LINK[part], _te(ratio_true)[part])
    assert travel.reason().endswith(said)
    assert 'geometry' not in travel.reason()


@pytest.mark.parametrize('travel, form, mixed', [
    (0.97 * RATIO, 'raw', False), (101.0, 'raw', False), (1.04, 'output', False),
    (1.0 / RATIO, 'swapped', False),                  # the link entry moves 81 times
    (RATIO * DEG, 'raw', True), (DEG, 'output', True),    # a link in degrees
])
def test_the_motor_angles_form_is_read_from_the_travel(travel, form, mixed):
    got, units = motor_angle_form(travel, RATIO)
    assert got == form and (units is not None) is mixed
