"""
Restarts: the installed wear_estimator and twin_bringup killed with SIGKILL, and started again.

The node programs run as processes of their own (``venv/bin/<exe> --ros-args ...``,
the ROS network settings of the test session inherited); a probe in this process
feeds ``te_features`` windows and listens to the estimates over DDS. The windows are
synthetic but consistent: torque 60-120 % of rated at the paper's speed, 10 operating
hours each, the lost motion of a reducer that wears at 0.8 x the Archard rate (the
model's, plus 0.05 arcmin of noise). What a process that never died would have
estimated is :class:`~reducer_twin.core.pipeline.EstimatorStage` run offline on the
same distinct windows; the node must match it exactly (the state file keeps every
float with ``repr``).
"""

import itertools
import math
import os
import signal
import subprocess

import numpy as np
import pytest
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from reducer_twin.core.errors import StateFileError
from reducer_twin.core.joint_twin import joint_topic
from reducer_twin.core.params import ReducerParams
from reducer_twin.core.pipeline import EstimatorStage, features_from_record
from reducer_twin.core.units import HOUR
from reducer_twin.io.state_file import backup_path, decode_state, load_with_fallback, StateFile
from reducer_twin.msg_adapters.layouts import (
    GROUND_TRUTH, record_values, TE_FEATURES, WEAR_ESTIMATE)
from reducer_twin.msg_adapters.ros import from_multiarray, to_multiarray
from reducer_twin.nodes.qos import stream_qos
from std_msgs.msg import Float64MultiArray
from window_records import feature_records

pytestmark = [pytest.mark.timeout(120, method='thread'), pytest.mark.slow]

PARAMS = ReducerParams()
EXPOSURE = 10.0 * HOUR
WINDOW_S = 2.0
WINDOWS = 12
_ids = itertools.count()

LATE_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1000,
                      reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL)
RECEIVE_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1000,
                         reliability=ReliabilityPolicy.RELIABLE)


@pytest.fixture(scope='module')
def records():
    """Return twelve te_features records of a reducer wearing at 0.8 x the model rate."""
    return feature_records(PARAMS, WINDOWS, seed=23, start_s=9000.0, window_s=WINDOW_S,
                           exposure_s=EXPOSURE)


def offline(records, params=PARAMS, state_path=None):
    """Return the EstimatorStage that stepped ``records`` uninterrupted (and saved them)."""
    stage = EstimatorStage(params, store=StateFile(state_path) if state_path else None)
    for rec in records:
        stage.process(features_from_record(rec))
    return stage


def same_estimate(got, stage):
    """Assert a wear record carries the stage's estimate bit for bit (stamps aside)."""
    want = stage.record(got['stamp_s'])
    for field in WEAR_ESTIMATE.fields:
        if field not in ('stamp_s', 'lost_motion_obs_rad'):
            assert got[field] == want[field], field


class EstimatorProcess:
    """
    The installed ``wear_estimator`` of one joint, and the probe that feeds it.

    Parameters
    ----------
    ros : RosHarness
        The test's harness (the probe spins there).
    program : Path
        ``venv/bin/wear_estimator``.
    state : Path
        The state file.

    """

    def __init__(self, ros, program, state):
        self.ros = ros
        self.program = program
        self.state = state
        self.joint = f'knee{os.getpid()}x{next(_ids)}'
        self.probe = ros.probe()
        self.pub = self.probe.publisher(joint_topic(self.joint, 'te_features'),
                                        Float64MultiArray, stream_qos())
        self.proc = None
        self.wear = []
        self.logs = []

    def _readers(self):
        """Return the gids of the te_features readers in the ROS graph."""
        return {bytes(info.endpoint_gid) for info in
                self.probe.get_subscriptions_info_by_topic(self.pub.topic_name)}

    def start(self):
        """Run the program; return the estimate it publishes first (its restored state)."""
        # A killed process' reader may linger in the graph until its lease ends: wait for
        # the new one, then for the probe's writer to count every reader as matched.
        before = self._readers()
        self.proc = subprocess.Popen(
            [str(self.program), '--ros-args', '-p', f'joint:={self.joint}',
             '-p', f'state_file:={self.state}'],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        self.wear = self.probe.listen(joint_topic(self.joint, 'wear'), Float64MultiArray,
                                      LATE_QOS)
        self.ros.spin_until(lambda: self.wear or self.proc.poll() is not None, timeout=30.0,
                            what='the first estimate of the started wear_estimator')
        assert self.proc.poll() is None, self.stop()
        self.ros.spin_until(
            lambda: (self._readers() - before
                     and self.pub.get_subscription_count() >= len(self._readers())),
            timeout=20.0, what='the te_features reader of the started process to match')
        return self.record(-1)

    def record(self, k):
        """Return received estimate ``k`` as a dict."""
        return from_multiarray(self.wear[k], WEAR_ESTIMATE)

    def send(self, recs):
        """Publish windows one by one, each once the estimate of the previous arrived."""
        for rec in recs:
            heard = len(self.wear)
            self.pub.publish(to_multiarray(TE_FEATURES, record_values(TE_FEATURES, rec)))
            self.ros.spin_until(lambda: len(self.wear) > heard, timeout=20.0,
                                what=f'the estimate of the window ending {rec["window_end_s"]}')
            assert self.record(-1)['stamp_s'] == rec['window_end_s']
        return self.record(-1)

    def kill(self):
        """SIGKILL the process (no handler runs, no queued write is flushed)."""
        self.proc.kill()
        out, err = self.proc.communicate(timeout=20)
        self.logs.append(err)
        assert self.proc.returncode == -signal.SIGKILL
        return err

    def stop(self):
        """Stop the process as Ctrl-C would; return its exit code and stderr."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
        try:
            _, err = self.proc.communicate(timeout=20)
        finally:
            if self.proc.poll() is None:
                self.proc.kill()
                self.proc.communicate()
        self.logs.append(err)
        return self.proc.returncode, err

    def wait_saved(self, t_end):
        """Wait until the state file on disk holds the window ending ``t_end``."""
        def saved():
            try:
                return decode_state(self.state.read_bytes())['t_end'] == t_end
            except (OSError, StateFileError):
                return False
        self.ros.spin_until(saved, timeout=20.0, what=f'the state of the window ending {t_end}')


@pytest.fixture
def estimator(ros, tmp_path, node_program):
    """Return an :class:`EstimatorProcess` on ``tmp_path/knee.json``, stopped at the end."""
    process = EstimatorProcess(ros, node_program('wear_estimator'), tmp_path / 'knee.json')
    yield process
    if process.proc is not None and process.proc.poll() is None:
        process.proc.kill()
        process.proc.communicate()


def test_a_killed_estimator_continues_from_its_state_without_counting_a_window_twice(
        estimator, records):
    first = estimator.start()
    assert first['updates'] == 0 and first['wear_m'] == EstimatorStage(PARAMS).estimator.wear, \
        'the prior of a reducer without state at first start'
    estimator.send(records[:6])
    estimator.wait_saved(records[5]['window_end_s'])
    estimator.kill()                                  # mid-run: windows 7.. never sent

    state = decode_state(estimator.state.read_bytes(), estimator.state)   # checksum holds
    assert state['exposure_s'] == 6 * EXPOSURE
    assert state['counters']['updates'] == offline(records[:6]).estimator.updates

    restored = estimator.start()
    same_estimate(restored, offline(records[:6]))     # continues: no reset to zeros
    # The window the killed process saw last comes again (e.g. replayed upstream): skipped.
    replayed = estimator.send(records[5:6])
    assert replayed['exposure_s'] == 6 * EXPOSURE, 'the replayed window is not counted'
    last = estimator.send(records[6:])
    assert last['exposure_s'] == WINDOWS * EXPOSURE   # every distinct window once
    same_estimate(last, offline(records))             # as if it had never died
    code, err = estimator.stop()
    assert code == 0 and 'Traceback' not in err
    assert f'restored estimator state from {estimator.state}' in err


def _flip(data, seed):
    """Flip one bit inside the state (not the layout) of a state file's bytes."""
    rng = np.random.default_rng(seed)
    start = data.index(b'"x"')
    at = int(rng.integers(start, len(data) - 10))
    out = bytearray(data)
    out[at] ^= 1 << int(rng.integers(0, 8))
    return bytes(out)


@pytest.mark.parametrize('damage', [
    pytest.param(lambda data: data[:len(data) // 2], id='a primary torn in half'),
    pytest.param(lambda data: _flip(data, 1), id='a primary with a flipped bit'),
])
def test_a_damaged_state_file_falls_back_to_the_backup_and_the_node_says_so(
        estimator, records, damage):
    offline(records[:5], state_path=estimator.state)   # primary: 5 windows, backup: 4
    estimator.state.write_bytes(damage(estimator.state.read_bytes()))
    restored = estimator.start()
    same_estimate(restored, offline(records[:4]))
    last = estimator.send(records[4:8])            # the window the backup lacks counts
    same_estimate(last, offline(records[:8]))
    code, err = estimator.stop()
    assert code == 0 and 'Traceback' not in err
    bak = backup_path(estimator.state)
    line = next(x for x in err.splitlines() if 'restored estimator state' in x)
    assert f'from {bak} (primary unusable: ' in line and str(estimator.state) in line


def _foreign_params(path, records):
    offline(records[:3], PARAMS.with_overrides({'geometry.pin_radius': 0.0051}), path)


def _foreign_program(path, records):
    path.write_text('{"format": "some_other_tool.settings", "gain": 3}\n')


@pytest.mark.parametrize('make, reason', [
    (_foreign_params, 'belongs to other reducer parameters'),
    (_foreign_program, "format must be 'reducer_twin.wear_estimator.file'"),
], ids=['state of a reducer with other parameters', 'a file of another program'])
def test_a_foreign_state_file_stops_the_node_with_a_clear_error(
        tmp_path, node_program, records, make, reason):
    state = tmp_path / 'knee.json'
    make(state, records)
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir()}
    result = subprocess.run(
        [str(node_program('wear_estimator')), '--ros-args', '-p', 'joint:=knee',
         '-p', f'state_file:={state}'], capture_output=True, text=True, timeout=60)
    assert result.returncode == 1
    assert 'Traceback' not in result.stderr
    errors = [x for x in result.stderr.splitlines() if x.startswith('ERROR: ')]
    assert len(errors) == 1 and str(state) in errors[0] and reason in errors[0], result.stderr
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir()} == before, \
        'nothing is overwritten: the files stay for a person to look at'


def test_a_state_file_torn_at_any_byte_falls_back_to_the_backup_never_to_zeros(
        tmp_path, records):
    state = tmp_path / 'knee.json'
    offline(records[:5], state_path=state)
    good = state.read_bytes()
    backup = offline(records[:4]).estimator.state_dict()
    assert good.endswith(b'}\n')
    # Every cut is refused by the file's check (cutting the final newline only leaves
    # it intact) ...
    for cut in range(len(good) - 1):
        with pytest.raises(StateFileError):
            decode_state(good[:cut], state)
    # ... and a refused primary is replaced by the backup (loading an estimator takes a
    # few ms: every 61st cut, the first and the last ones).
    for cut in sorted({*range(0, len(good) - 1, 61), 1, len(good) - 2}):
        state.write_bytes(good[:cut])
        loaded = load_with_fallback(state, PARAMS)
        assert loaded.used_backup, cut
        assert loaded.estimator.state_dict() == backup, cut
    # Both copies torn: an error naming both, never a new reducer.
    backup_path(state).write_bytes(backup_path(state).read_bytes()[:40])
    with pytest.raises(StateFileError, match='backup: .*knee.json.bak'):
        EstimatorStage(PARAMS, store=StateFile(state))


BRINGUP_YAML = """twin:
  joints: [{joint}]
  aging_factor: 360000.0
  window_s: 2.0
  state_dir: {state_dir}
  simulate: true
simulator:
  profile: robot
"""


class Bringup:
    """The installed twin_bringup with the simulator, for one joint, and what a probe hears."""

    def __init__(self, ros, program, tmp_path):
        self.ros = ros
        self.program = program
        self.joint = f'hip{os.getpid()}x{next(_ids)}'
        self.state_dir = tmp_path / 'state'
        self.config = tmp_path / 'twin.yaml'
        self.config.write_text(BRINGUP_YAML.format(joint=self.joint, state_dir=self.state_dir))
        self.probe = ros.probe()
        self.proc = None

    def start(self, *extra):
        """Run the bringup; return what the probe hears from it."""
        self.proc = subprocess.Popen(
            [str(self.program), '--ros-args', '-p', f'config:={self.config}', *extra],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        heard = {
            'wear': self.probe.listen(joint_topic(self.joint, 'wear'), Float64MultiArray,
                                      LATE_QOS),
            'truth': self.probe.listen(joint_topic(self.joint, 'ground_truth'),
                                       Float64MultiArray, LATE_QOS),
            'features': self.probe.listen(joint_topic(self.joint, 'te_features'),
                                          Float64MultiArray, RECEIVE_QOS)}
        return heard

    def wait_estimates(self, heard, n):
        """Spin until ``n`` estimates were heard; return them as dicts."""
        self.ros.spin_until(lambda: len(heard['wear']) >= n or self.proc.poll() is not None,
                            timeout=60.0, what=f'{n} estimates of the bringup')
        assert self.proc.poll() is None, self.proc.communicate()[1][-3000:]
        return [from_multiarray(m, WEAR_ESTIMATE) for m in heard['wear']]


def test_a_killed_bringup_restarts_on_its_state_and_the_wear_carries_on(
        ros, tmp_path, node_program):
    twin = Bringup(ros, node_program('twin_bringup'), tmp_path)
    try:
        heard = twin.start()
        twin.wait_estimates(heard, 4)              # three windows estimated (at least)
        twin.proc.kill()
        twin.proc.communicate(timeout=20)
        assert twin.proc.returncode == -signal.SIGKILL
        path = twin.state_dir / f'{twin.joint}.json'
        state = decode_state(path.read_bytes(), path)
        assert state['exposure_s'] > 0.0 and state['t_end'] is not None
        truth = from_multiarray(heard['truth'][-1], GROUND_TRUTH)

        # The restarted simulator carries on with the reducer's wear (a robot that was off).
        heard = twin.start('-p', f'sim.initial_wear_m:={truth["wear_m"]!r}')
        estimates = twin.wait_estimates(heard, 3)
        twin.proc.send_signal(signal.SIGINT)
        _, err = twin.proc.communicate(timeout=20)
        assert twin.proc.returncode == 0 and 'Traceback' not in err
    finally:
        if twin.proc is not None and twin.proc.poll() is None:
            twin.proc.kill()
            twin.proc.communicate()

    # The node restored the killed process's state, not a new reducer.
    line = next(x for x in err.splitlines() if 'restored estimator state from' in x)
    assert f'from {path}: wear {state["x"][0] * 1e6:.3f} um after ' \
        f'{state["exposure_s"] / HOUR:.1f} h' in line
    windows = {from_multiarray(m, TE_FEATURES)['window_end_s']:
               from_multiarray(m, TE_FEATURES) for m in heard['features']}
    first = estimates[0]
    # The estimate published on start is the restored state. It is heard unless the probe
    # matched the restarted node late: then the latest sample (depth 1) is a window's, whose
    # te_features may have gone by before the match (volatile), and whose exposure is more.
    if first['stamp_s'] not in windows and first['exposure_s'] == state['exposure_s']:
        assert first['wear_m'] == state['x'][0]
    # Exposure carries on from the persisted one, each window counted once.
    assert all(e['exposure_s'] >= state['exposure_s'] for e in estimates)
    checked = 0
    for before, after in zip(estimates, estimates[1:]):
        window = windows.get(after['stamp_s'])
        if window is not None:
            assert after['exposure_s'] - before['exposure_s'] == pytest.approx(
                window['exposure_s'], rel=1e-9)
            checked += 1
    assert checked >= 1
    # The estimate carries on from the restored one: never below it by more than its own
    # 3 sd, and its update count goes on (a reset would return to the prior, 0 updates).
    sd = math.sqrt(state['P'][0][0])
    assert all(math.isfinite(e['wear_m']) for e in estimates)
    assert min(e['wear_m'] for e in estimates) >= state['x'][0] - 3.0 * sd
    assert min(e['updates'] for e in estimates) >= state['counters']['updates'] > 0
    final = decode_state(path.read_bytes(), path)   # Ctrl-C wrote the last queued state
    assert final['exposure_s'] >= estimates[-1]['exposure_s']
