"""
The ingest stage of a robot's joints (``reducer_twin.core.robot_ingest``).

What ``encoder_ingest`` runs on buffered controller messages: the combined form (one
message with ``<joint>`` and ``<joint>_motor``) and the split form (two topics) give the
same clean pairs of the same samples, and streams whose motor side cannot be told from
the link side are refused naming the setting.
"""

import numpy as np
import pytest
from reducer_twin.core.errors import InvalidParameter
from reducer_twin.core.params import ReducerParams
from reducer_twin.core.robot_ingest import check_streams, RobotIngest
from reducer_twin.core.simulator import joint_state_columns, JointSimulator, SimConfig

RATIO = 81.0


def _messages(batches, split):
    """Return controller messages ``(t_ns, position, velocity, effort)`` as a node buffers."""
    pos, vel, eff, motor = joint_state_columns(batches, split)
    t_ns = np.round(batches[0].t * 1e9).astype(np.int64) + 10**9
    link = [(int(t_ns[i]), pos[i], vel[i], eff[i]) for i in range(t_ns.size)]
    if not split:
        return link, []
    empty = np.full(motor.shape[1], np.nan)
    return link, [(int(t_ns[i]), motor[i], empty, empty) for i in range(t_ns.size)]


def test_the_combined_and_the_split_form_give_the_same_pairs():
    sims = [JointSimulator(ReducerParams(), SimConfig(name=f'j{k}', rate_hz=250.0, seed=k,
                                                      exact_mesh=False)) for k in range(2)]
    batches = [s.step(500) for s in sims]
    found = {}
    for split in (False, True):
        ingest = RobotIngest(['j0', 'j1'], RATIO, split=split, effort_source='link')
        link, motor = _messages(batches, split)
        rows = {k: [] for k in range(2)}
        for start in range(0, 500, 50):       # batches of 50 messages, as a node buffers
            for k, r in ingest.process(link[start:start + 50], motor[start:start + 50]):
                rows[k].append(r)
        found[split] = {k: np.concatenate(r) for k, r in rows.items()}
        assert all(ingest.counts(k)['unpaired'] == 0 for k in range(2))
    for k, b in enumerate(batches):
        combined, split = found[False][k], found[True][k]
        # Split pairing may keep the last link samples back for a later motor partner.
        assert combined.shape[0] == 500 and split.shape[0] >= 490
        np.testing.assert_allclose(split, combined[:split.shape[0]], rtol=0, atol=1e-12)
        np.testing.assert_allclose(combined[:, 2], b.link_angle, rtol=0, atol=1e-12)


@pytest.mark.parametrize('joints, link, motor, suffix, message', [
    ([], '/joint_states', '', '_motor', 'twin.joints must be non-empty names'),
    (['j1', ''], '/joint_states', '', '_motor', 'twin.joints must be non-empty names'),
    (['j1'], '/js', '/js', '_motor', 'twin.motor_topic must differ from twin.link_topic '
     "('/js')"),
    (['j1'], '/js', '', '', 'twin.motor_suffix must not be empty'),
])
def test_streams_whose_sides_cannot_be_told_apart_are_refused(joints, link, motor, suffix,
                                                              message):
    with pytest.raises(InvalidParameter, match=message.replace('(', r'\(').replace(')', r'\)')):
        check_streams(joints, link, motor, suffix, 'twin.')


@pytest.mark.parametrize('split', [False, True], ids=['combined', 'split'])
def test_a_motor_encoder_counting_against_the_link_gives_the_same_pairs_at_direction_minus_1(
        split):
    sim = JointSimulator(ReducerParams(), SimConfig(name='j0', rate_hz=250.0, seed=3,
                                                    exact_mesh=False))
    batches = [sim.step(300)]
    link, motor = _messages(batches, split)
    found = []
    for direction in (1, -1):
        if direction < 0:     # the motor's angle (and its torque) in its own, reversed sense
            if split:
                motor = [(t, -p, v, -e) for t, p, v, e in motor]
            else:
                link = [(t, p * np.array([1.0, -1.0]), v, e * np.array([1.0, -1.0]))
                        for t, p, v, e in link]
        ingest = RobotIngest(['j0'], RATIO, split=split, effort_source='link',
                             motor_direction=direction)
        found.append(np.concatenate([r for _, r in ingest.process(link, motor)]))
    np.testing.assert_allclose(found[1], found[0], rtol=0, atol=1e-12)
    for bad in (0, 2, True, '-1'):
        with pytest.raises(InvalidParameter, match='motor_direction must be 1 .* or -1'):
            RobotIngest(['j0'], RATIO, motor_direction=bad)


@pytest.mark.parametrize('split', [False, True], ids=['combined', 'split'])
@pytest.mark.parametrize('source', ['link', 'motor'])
def test_the_effort_scale_turns_any_effort_into_the_output_torque(split, source):
    sim = JointSimulator(ReducerParams(), SimConfig(name='j0', rate_hz=250.0, seed=3,
                                                    exact_mesh=False))
    link, motor = _messages([sim.step(300)], split)
    found = {}
    for scale in (1.0, -2.5):
        ingest = RobotIngest(['j0'], RATIO, split=split, effort_source=source,
                             motor_effort_units='joint', effort_scale=scale)
        found[scale] = np.concatenate([r for _, r in ingest.process(link, motor)])
    np.testing.assert_array_equal(found[-2.5][:, [0, 1, 2, 4]], found[1.0][:, [0, 1, 2, 4]])
    np.testing.assert_allclose(found[-2.5][:, 3], -2.5 * found[1.0][:, 3], rtol=1e-15)
    for bad in (0, 0.0, 1e9, float('nan'), True, '-1'):
        with pytest.raises(InvalidParameter, match='effort_scale must be a number of '
                                                   'magnitude 1e-6 to 1e6'):
            RobotIngest(['j0'], RATIO, effort_scale=bad)
