"""
Live segments: where a live estimator starts, and what it writes when the store is not its alone.

:class:`~reducer_twin.fleet.live.LiveHistory` is fed as the ``wear_estimator`` feeds it
(an :class:`~reducer_twin.core.pipeline.EstimatorStage` stepped with synthetic
``te_features`` windows, 200 operating hours each) and writes a real SQLite store;
the node over DDS is tested in ``test/nodes/test_wear_estimator_store.py``.
"""

import json
import math

import pytest
from reducer_twin.cli import main
from reducer_twin.core.life_basis import TorqueCheckFinding
from reducer_twin.core.params import ReducerParams
from reducer_twin.core.pipeline import EstimatorStage, features_from_record, LifeConfig
from reducer_twin.fleet.live import LiveHistory, read_start
from reducer_twin.fleet.store import FleetStore
from window_records import feature_records

PARAMS = ReducerParams()
T0_S = 1_767_225_600.0
EXPOSURE = 720_000.0


@pytest.fixture(scope='module')
def records():
    """Twelve windows of 2 s from 2026-01-01T00:00:00Z, 200 h each."""
    return feature_records(PARAMS, 12, seed=3, start_s=T0_S, window_s=2.0,
                           exposure_s=EXPOSURE)


class Live:
    """An estimator stage and its live history, as the node holds them."""

    def __init__(self, store, robot='r1', joint='joint_1', file_t_end=None, life=None):
        self.start = read_start(store, robot, joint, file_t_end)
        self.stage = EstimatorStage(PARAMS)
        self.history = LiveHistory(store, robot, joint, PARAMS, life or LifeConfig(),
                                   self.start, 'wear_estimator_test')

    def feed(self, recs):
        for rec in recs:
            features = features_from_record(rec)
            self.stage.process(features)
            self.history.add(rec, self.stage.record(features.t_end),
                             self.stage.estimator.state_dict(), self.stage.last_observation)


def _reducer(store, robot='r1', joint='joint_1'):
    with FleetStore(store) as fs:
        return fs.in_service(robot, joint)


def test_a_live_node_continues_from_the_store_only_when_it_is_newer_than_its_state_file(
        tmp_path, records):
    store = tmp_path / 'f.db'
    start = read_start(store, 'r1', 'joint_1', None)
    assert start.state is None and 'does not exist yet' in start.note
    assert not store.exists(), 'reading where to start writes nothing'
    live = Live(store)
    live.feed(records[:4])
    assert live.history.flush() == 1
    end_4, end_2 = records[3]['window_end_s'], records[1]['window_end_s']
    assert read_start(store, 'r1', 'joint_2', None).state is None, 'another reducer'
    for file_t_end, from_store in ((None, True), (end_2, True), (end_4, False),
                                   (end_4 + 10.0, False)):
        start = read_start(store, 'r1', 'joint_1', file_t_end)
        assert (start.state is not None) == from_store, (file_t_end, start.note)
        assert start.revision == 1 and not start.new_reducer
    assert read_start(store, 'r1', 'joint_1', None).state == _reducer(store).state
    # Replaced after the state file ended: the file's reducer is gone, start a new one.
    assert main(['replace', '--store', str(store), '--robot', 'r1', '--joint', 'joint_1']) == 0
    start = read_start(store, 'r1', 'joint_1', end_4)
    assert start.new_reducer and start.state is None and 'starting a new reducer' in start.note


def test_a_reducer_another_writer_changed_is_never_overwritten_and_the_node_says_so(
        tmp_path, records):
    store = tmp_path / 'f.db'
    live = Live(store)
    live.feed(records[:3])
    assert live.history.flush() == 1
    live.feed(records[3:5])
    # Meanwhile someone records a replacement with the command line.
    assert main(['replace', '--store', str(store), '--robot', 'r1', '--joint', 'joint_1']) == 0
    assert live.history.flush() == 0
    level, values = live.history.status()
    assert level == 'ERROR' and 'restart the node' in values['store_error']
    live.feed(records[5:6])
    assert live.history.flush() == 0 and live.history.pending == 0
    assert live.history.status()[1]['store_windows_not_stored'] == 3
    with FleetStore(store) as fs:
        retired = [r for r in fs.reducers() if not r.in_service]
        assert [r.windows for r in retired] == [3] and fs.in_service('r1', 'joint_1').windows \
            == 0


def test_windows_past_the_memory_bound_leave_the_store_but_their_hours_count(
        tmp_path, records):
    store = tmp_path / 'f.db'
    live = Live(store)
    live.history.max_pending = 3
    live.feed(records[:5])
    assert live.history.pending == 3
    assert live.history.flush() == 1
    reducer = _reducer(store)
    assert reducer.windows == 3 and reducer.exposure_s == pytest.approx(5 * EXPOSURE)
    assert reducer.state['estimator']['exposure_s'] == pytest.approx(5 * EXPOSURE)
    assert live.history.status()[1]['store_windows_not_stored'] == 2


def test_windows_that_go_back_before_the_stored_history_are_refused_clearly(
        tmp_path, records):
    store = tmp_path / 'f.db'
    live = Live(store)
    live.feed(records[4:6])
    assert live.history.flush() == 1
    again = Live(store, file_t_end=None)        # a node whose clock restarted earlier
    again.feed(records[:2])
    assert again.history.flush() == 0
    level, values = again.history.status()
    assert level == 'ERROR' and 'does not end after the stored history' in \
        values['store_error'] and 'clock reset' in values['store_error']
    assert _reducer(store).windows == 2 and again.history.pending == 2


def test_a_live_reducer_that_never_reversed_is_not_observed_with_its_reason(
        tmp_path, records, capsys):
    store = tmp_path / 'f.db'
    live = Live(store)
    live.feed([dict(r, lost_motion_rad=math.nan) for r in records[:3]])
    assert live.history.flush() == 1
    capsys.readouterr()
    assert main(['fleet', '--store', str(store)]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[2].split() == ['r1/joint_1', '0+L', '600', '-', '-', '-/-', 'NOT', 'OBSERVED']
    reason = ' '.join(' '.join(lines[3:6]).split())
    assert reason.startswith('3 window(s) over 600 h in 0 bag(s) and 1 live segment(s), none '
                             'with a lost motion the estimator could use: the joint never '
                             'reversed under load while watched live')
    assert '+L: also watched live (a wear_estimator writes this store)' in lines


def test_a_live_reducer_says_what_its_remaining_life_rests_on_as_a_bag_s_would(
        tmp_path, records, capsys):
    # Three windows of a unit met without its service time: the rate is the model's.
    early = _fleet_row(tmp_path / 'f.db', records[:3], capsys)
    assert early['rate_resolved'] is False and early['curve_extrapolation'] is None
    assert "the unit's own wear rate is not yet resolved" in early['reason']
    assert 'give its service time' in early['reason']
    # Twelve windows: the unit's own rate, the remaining life on the model's curve beyond
    # the span it was compared with the growth over.
    late = _fleet_row(tmp_path / 'g.db', records, capsys)
    assert late['rate_resolved'] is True and late['growth_law'] is None
    assert late['curve_extrapolation'] > 1.0
    assert f"extrapolated to {late['curve_extrapolation']:,.0f}x" in late['reason']
    assert 'wear rate' not in late['reason']


NOT_COMPARED = ('no window held the load at the lost-motion test torque (23.5 N·m) long enough '
                'under both signs to compare the width there with the flanks of higher loads: '
                'the lost motion given is the play those flanks give')


@pytest.mark.parametrize('warn_h, said', [(1e6, True), (1.0, False)], ids=['warn', 'ok'])
def test_a_live_alarm_on_the_flanks_play_says_the_test_torque_was_not_compared(
        tmp_path, records, capsys, warn_h, said):
    # A bag's summary said it beside such an alarm ("inputs"); a live segment's did not.
    life = LifeConfig(warn_s=warn_h * 3600.0, error_s=0.5 * 3600.0)
    row = _fleet_row(tmp_path / 'f.db', records, capsys, life,
                     TorqueCheckFinding('not compared', NOT_COMPARED))
    assert row['test_torque_check'] == 'not compared'
    assert row['inputs'] == ([NOT_COMPARED] if said else [])


WITHIN_ZONE = ('the lost motion read from the flanks (0.65 arcmin, their extrapolation to no '
               'load) is 0.74 +- 0.01 arcmin (104.6 standard errors) less than the width its '
               'bins give at the lost-motion test torque (23.5 N·m) less the windup there')


def test_a_live_reducer_read_within_a_soft_zone_says_so_whatever_its_level(
        tmp_path, records, capsys):
    # A bag's row says it among its inputs (an input warning); a live one did not.
    life = LifeConfig(warn_s=3600.0, error_s=0.5 * 3600.0)
    row = _fleet_row(tmp_path / 'f.db', records, capsys, life,
                     TorqueCheckFinding('not compared', None, WITHIN_ZONE))
    assert row['verdict'] == 'OK' and row['test_torque_check'] == 'not compared'
    assert row['inputs'] == [WITHIN_ZONE]


def test_a_live_segment_without_a_check_heard_says_nothing_of_it(tmp_path, records, capsys):
    row = _fleet_row(tmp_path / 'f.db', records, capsys)
    assert row['test_torque_check'] is None and row['inputs'] == []


def _fleet_row(store, recs, capsys, life=None, check=None):
    """Feed ``recs`` live into ``store`` and return the reducer's ``fleet --json`` row."""
    live = Live(store, life=life)
    live.history.test_torque_check = check
    live.feed(recs)
    assert live.history.flush() == 1
    capsys.readouterr()
    assert main(['fleet', '--store', str(store), '--json']) == 0
    (row,) = json.loads(capsys.readouterr().out)['reducers']
    return row
