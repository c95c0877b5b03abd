"""
A full disk under the live estimator: the previous good state stays, diagnostics say ERROR.

Offline, with ENOSPC injected where the state file is written (any machine): the error
names the file and the bytes needed, the state file and its backup keep their previous
good content, no temporary is left, and the next write after space returns succeeds.
Live, over DDS, with a real tmpfs filled to the last byte (root): ``wear_estimator``
keeps running, keeps its previous state file, publishes ERROR with the reason on
``/diagnostics``, and recovers (OK, the new state written) once space is freed.
"""

import os

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from full_disk import fill, FillingFile, small_tmpfs
import pytest
from rclpy.parameter import Parameter
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from reducer_twin.core.errors import StateFileError
from reducer_twin.core.joint_twin import joint_topic
from reducer_twin.core.params import ReducerParams
from reducer_twin.core.pipeline import EstimatorStage, features_from_record
from reducer_twin.core.units import HOUR
from reducer_twin.io.state_file import backup_path, decode_state, encode_state, StateFile
from reducer_twin.msg_adapters.layouts import record_values, TE_FEATURES
from reducer_twin.msg_adapters.ros import to_multiarray
from reducer_twin.nodes.qos import stream_qos
from reducer_twin.nodes.wear_estimator import WearEstimatorNode
from std_msgs.msg import Float64MultiArray
from window_records import feature_records

pytestmark = pytest.mark.timeout(120, method='thread')

PARAMS = ReducerParams()
RECORDS = feature_records(PARAMS, 8, seed=5, start_s=100.0, window_s=2.0,
                          exposure_s=10.0 * HOUR)


def _windows(records):
    return [features_from_record(r) for r in records]


def _no_space(monkeypatch):
    """Make every state-file write fail as on a full disk (at the write itself)."""
    monkeypatch.setattr(os, 'fdopen', FillingFile(0).opener)


def test_a_full_disk_keeps_the_previous_state_and_names_the_file_and_the_bytes(
        tmp_path, monkeypatch):
    path = tmp_path / 'joint_1.json'
    stage = EstimatorStage(PARAMS, store=StateFile(path))
    for window in _windows(RECORDS[:3]):
        stage.process(window)
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir()}
    with monkeypatch.context() as patch:
        _no_space(patch)
        with pytest.raises(StateFileError) as err:
            stage.process(_windows(RECORDS[3:4])[0])
    needed = len(encode_state(stage.estimator.state_dict()))
    text = str(err.value)
    assert f'no space left writing the estimator state {path}' in text
    assert f'{needed:,} bytes needed' in text and 'previous state file is kept' in text
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir()} == before, \
        'state and backup unchanged, no temporary left'
    stage.process(_windows(RECORDS[4:5])[0])     # space is back
    assert decode_state(path.read_bytes(), path)['t_end'] == RECORDS[4]['window_end_s']


def test_the_background_writer_reports_the_full_disk_and_recovers(tmp_path, monkeypatch):
    path = tmp_path / 'joint_1.json'
    stage = EstimatorStage(PARAMS, store=StateFile(path, background=True))
    for window in _windows(RECORDS[:2]):
        stage.process(window)
    stage.flush()
    good = path.read_bytes()
    with monkeypatch.context() as patch:
        _no_space(patch)
        stage.process(_windows(RECORDS[2:3])[0])
        stage.flush()
    writer = stage.store.writer
    assert isinstance(writer.error, StateFileError) and writer.failures == 1
    assert path.read_bytes() == good
    stage.process(_windows(RECORDS[3:4])[0])
    stage.flush()
    assert stage.store.writer.error is None and stage.store.writer.recoveries == 1
    assert decode_state(path.read_bytes(), path)['t_end'] == RECORDS[3]['window_end_s']


def test_the_live_estimator_on_a_full_tmpfs_says_error_keeps_its_state_and_recovers(
        ros, tmp_path):
    with small_tmpfs(tmp_path / 'state', 256 * 1024) as disk:
        node = ros.add(WearEstimatorNode(
            'wear_estimator_full', params=PARAMS, context=ros.context, parameter_overrides=[
                Parameter('joint', value='full'), Parameter('state_dir', value=str(disk)),
                Parameter('diagnostics_period_s', value=0.1)]))
        probe = ros.probe()
        pub = probe.publisher(joint_topic('full', 'te_features'), Float64MultiArray,
                              stream_qos())
        diagnostics = probe.listen('/diagnostics', DiagnosticArray, QoSProfile(
            history=HistoryPolicy.KEEP_LAST, depth=100,
            reliability=ReliabilityPolicy.RELIABLE))
        ros.wait_matched(pub)
        state = disk / 'full.json'

        def send(rec):
            done = sum(node.statuses.values()) + 1
            pub.publish(to_multiarray(TE_FEATURES, record_values(TE_FEATURES, rec)))
            ros.spin_until(lambda: sum(node.statuses.values()) >= done,
                           what='the estimator to step a window')
            node.stage.flush()

        for rec in RECORDS[:3]:
            send(rec)
        good = state.read_bytes()
        filler = fill(disk)
        send(RECORDS[3])
        name = 'reducer_twin: full wear estimator'
        status = ros.wait_status(diagnostics, name, lambda s: s.level == DiagnosticStatus.ERROR)
        values = ros.key_values(status)
        assert 'no space left' in values['state_write_error'], values
        assert 'bytes needed' in values['state_write_error']
        assert 'the previous state file is kept' in status.message
        assert state.read_bytes() == good, 'the previous good state stays on disk'
        assert node.stage.estimator.updates == 4, 'the estimate goes on in memory'
        filler.unlink()
        send(RECORDS[4])
        status = ros.wait_status(diagnostics, name,
                                 lambda s: s.level == DiagnosticStatus.OK and
                                 ros.key_values(s)['state_writes_recovered'] == '1')
        assert 'state_write_error' not in ros.key_values(status)
        saved = decode_state(state.read_bytes(), state)
        assert saved['t_end'] == RECORDS[4]['window_end_s']
        assert backup_path(state).exists()
        ros.remove(node)
