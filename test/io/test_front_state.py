"""
``te_monitor``'s state file: what a joint's front learnt, written atomically with a backup.

The front carries a learnt encoder time offset and a soft-zone check that compared some
windows; every file is read back through the checksummed format.
"""

import json

import numpy as np
import pytest
from reducer_twin.core.errors import StateFileError
from reducer_twin.core.estimator import WearEstimator
from reducer_twin.core.joint_twin import TwinFront
from reducer_twin.core.params import ReducerParams
from reducer_twin.core.transmission_error import model_tables
from reducer_twin.core.units import ARCMIN
from reducer_twin.io.front_state import FrontStateFile
from reducer_twin.io.state_file import backup_path, encode_state, save_estimator

PARAMS = ReducerParams()


def _learnt_front(offset_s=0.002):
    """Return a front with a carried offset and a check that said 0.8 arcmin of soft zone."""
    front = TwinFront(PARAMS)
    front.carry_time_offset(offset_s)
    rated = PARAMS.rating.rated_torque
    torque = np.tile(np.geomspace(0.02, 1.5, 17)[:-1] * rated * 1.145, (4, 1))
    width = (2.0 * ARCMIN * np.minimum(torque / (0.05 * rated), 1.0)
             + 2.0 * torque / model_tables(PARAMS).series_stiffness)
    front.analyzer.fit.soft_zone.observe(torque, width, np.full(torque.shape, 0.01 * ARCMIN),
                                         np.ones(torque.shape, bool))
    assert front.soft_zone is not None
    return front


@pytest.mark.parametrize('background', [False, True])
def test_a_saved_front_is_continued_from_its_file(tmp_path, background):
    path = tmp_path / 'state' / 'joint_1.te_monitor.json'     # the directory is made
    store = FrontStateFile(path, background=background)
    learnt = _learnt_front()
    store.save(learnt.state())
    store.flush()
    assert json.loads(path.read_text())['format'] == 'reducer_twin.front_state.file'
    front = TwinFront(PARAMS)
    used, lines = FrontStateFile(path).restore(front)
    assert used == path and len(lines) == 2 and 'said: 0.80 arcmin' in lines[1]
    assert front.calibration.applied == 0.002 and front.soft_zone == learnt.soft_zone


def test_nothing_saved_yet_is_a_new_start(tmp_path):
    assert FrontStateFile(tmp_path / 'j.te_monitor.json').restore(TwinFront(PARAMS)) is None


def test_a_corrupt_file_falls_back_to_the_previous_good_copy(tmp_path):
    path = tmp_path / 'j.te_monitor.json'
    store = FrontStateFile(path)
    store.save(_learnt_front(0.001).state())
    store.save(_learnt_front(0.002).state())    # the first becomes the backup
    path.write_bytes(path.read_bytes()[:50])     # a crash of the disk, not of the writer
    front = TwinFront(PARAMS)
    used, _ = store.restore(front)
    assert used == backup_path(path) and front.calibration.applied == 0.001


def test_a_file_of_another_kind_or_corrupt_with_its_backup_is_an_error_naming_both(tmp_path):
    path = tmp_path / 'j.te_monitor.json'
    save_estimator(WearEstimator(PARAMS), path)     # the estimator's file given by mistake
    backup_path(path).write_text('{"format": "reducer_twin.front_state.file"')
    front = TwinFront(PARAMS)
    with pytest.raises(StateFileError) as err:
        FrontStateFile(path).restore(front)
    text = str(err.value)
    assert text.startswith('no usable te_monitor state: ') and str(path) in text
    assert "format must be 'reducer_twin.front_state.file'" in text
    assert f'backup: {backup_path(path)} is not valid JSON' in text
    assert front.calibration.applied is None


def test_a_state_whose_values_are_unusable_is_refused_naming_the_file(tmp_path):
    path = tmp_path / 'j.te_monitor.json'
    state = _learnt_front().state()
    state['time_offset_s'] = 5.0
    path.write_bytes(encode_state(state, 'reducer_twin.front_state'))
    with pytest.raises(StateFileError, match='time_offset_s must be null or a finite offset '
                                             r'within \+-1 s, got 5.0'):
        FrontStateFile(path).restore(TwinFront(PARAMS))
