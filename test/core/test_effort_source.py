"""Where the output torque is read (choose_effort), and a motor torque told by its size."""

from encoder_streams import RATIO
import numpy as np
import pytest
from reducer_twin.core.effort_source import choose_effort, motor_torque_seen


def test_effort_comes_from_the_link_the_motor_side_or_the_link_where_it_is_known():
    link = np.array([1.0, np.nan, 3.0])
    motor = np.array([0.1, 0.2, np.nan])
    np.testing.assert_array_equal(choose_effort(link, motor, 'link', 81.0), link)
    np.testing.assert_allclose(choose_effort(link, motor, 'motor', 10.0),
                               [1.0, 2.0, np.nan])
    np.testing.assert_allclose(choose_effort(link, motor, 'auto', 10.0), [1.0, 2.0, 3.0])


@pytest.mark.parametrize('link, motor, seen', [
    ('none', 'motor torque', True),
    ('none', 'output torque', False),      # reaches the lowest bin: read as it is
    ('none', 'idle', False),               # times the ratio still below: nothing to tell
    ('none', 'beyond', False),             # times the ratio beyond what a reducer takes
    ('output torque', 'motor torque', False),   # the link entry's effort is the one read
    ('none', 'a few samples', False),
])
def test_a_motor_torque_is_told_by_its_size_only_where_output_torque_could_not_be_read(
        link, motor, seen):
    # A drive reporting its motor's torque (load / 81) beside output angles: read in joint
    # units it never reaches the 15.7 N*m the lost motion is read from.
    load = 400.0 * np.sin(np.linspace(0.0, 20.0, 2000))
    efforts = {'none': np.full(2000, np.nan), 'output torque': load,
               'motor torque': load / RATIO, 'idle': load / RATIO / 100.0,
               'beyond': np.full(2000, 15.0), 'a few samples': np.r_[load[:50] / RATIO,
                                                                     np.full(1950, np.nan)]}
    largest = 1000.0 if motor == 'beyond' else 5.0 * 784.0    # 15 N*m x 81: 1215 N*m
    peak = motor_torque_seen(efforts[link], efforts[motor], RATIO, 15.7, largest)
    assert (peak is not None) == seen
    if seen:
        assert peak == pytest.approx(400.0 / RATIO, rel=0.01)
