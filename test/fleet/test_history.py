"""analyze --store: a reducer's life across bags, in time order, never counted twice."""

import json
import os
from pathlib import Path
import signal
import sqlite3
import subprocess
import sys
import time

from cli_runs import run_cli as _run
import pytest
from reducer_twin.analysis.pipeline import analyze_bag
from reducer_twin.analysis.simulate import simulate_bag, SimulationSpec
from reducer_twin.fleet.store import FleetStore

ROOT = Path(__file__).resolve().parents[2]
# One robot's life in three bags of 2000 h (5000 ticks each at 250 Hz).
LIFE = {'hours': 2000.0, 'aging_factor': 360_000.0, 'joints': 2, 'rate_hz': 250.0,
        'seed': 11}


@pytest.fixture(scope='module')
def bags(tmp_path_factory):
    root = tmp_path_factory.mktemp('life')
    out = {}
    for k, start in enumerate((0.0, 2000.0, 4000.0), 1):
        out[f's{k}'] = str(simulate_bag(root / f's{k}', SimulationSpec(
            start_hours=start, robot='r1', **LIFE)).path)
    out['anonymous'] = str(simulate_bag(root / 'anonymous', SimulationSpec(**LIFE)).path)
    return out


def _fleet(store, capsys):
    code, out, err = _run(['fleet', '--store', store, '--json'], capsys)
    assert code == 0, err
    return json.loads(out)['reducers']


def _analyze(paths, store, out, capsys, *extra):
    return _run(['analyze', *paths, '--store', store, '--out', out, '--json', *extra], capsys)


def test_bags_given_in_any_order_continue_each_reducer_in_time_order(bags, tmp_path, capsys):
    code, out, err = _analyze([bags['s3'], bags['s1'], bags['s2']], tmp_path / 'f.db',
                              tmp_path / 'out', capsys)
    assert code == 0, err
    assert json.loads(out)['engine'] == 'local'
    # The same chain by hand: each bag continues from the state the previous one ended in.
    states = None
    for k in (1, 2, 3):
        result = analyze_bag(bags[f's{k}'], tmp_path / f'hand{k}', initial_states=states)
        states = result.states
    rows = {r['joint']: r for r in _fleet(tmp_path / 'f.db', capsys)}
    for joint, res in result.joints.items():
        s = res.summary()
        assert rows[joint]['bags'] == 3 and rows[joint]['verdict'] == 'OK'
        assert rows[joint]['wear_um'] == pytest.approx(s['wear_um'], rel=1e-12)
        assert rows[joint]['rul_p50_h'] == s['rul_p50_h']
        assert rows[joint]['hours_observed'] == pytest.approx(6000.0, rel=1e-3)
        assert rows[joint]['last_seen'] == '2026-01-01T00:00:59Z'  # 60 s of stream


def test_the_same_bags_again_are_skipped_reported_and_change_nothing(bags, tmp_path, capsys):
    store = tmp_path / 'f.db'
    assert _analyze([bags['s1'], bags['s2']], store, tmp_path / 'a', capsys)[0] == 0
    before = _fleet(store, capsys)
    code, out, err = _analyze([bags['s2'], bags['s1']], store, tmp_path / 'b', capsys)
    assert code == 0, err
    notes = [line for line in err.splitlines() if line.startswith('NOTE:')]
    assert len(notes) == 2 and all('already in the fleet store' in n for n in notes), err
    assert all('skipped' in b for b in json.loads(out)['bags'].values())
    assert _fleet(store, capsys) == before
    assert not (tmp_path / 'b' / 's1').exists()


def test_an_older_bag_is_refused_until_rebuild_takes_it_into_the_history(bags, tmp_path,
                                                                         capsys):
    store = tmp_path / 'f.db'
    assert _analyze([bags['s2'], bags['s3']], store, tmp_path / 'a', capsys)[0] == 0
    code, _, err = _analyze([bags['s1']], store, tmp_path / 'b', capsys)
    errors = [line for line in err.splitlines() if line.startswith('ERROR:')]
    assert code == 1 and len(errors) == 1 and 'before the end of the stored history' in \
        errors[0] and '--rebuild' in errors[0], err
    assert [r['bags'] for r in _fleet(store, capsys)] == [2, 2]
    code, _, err = _analyze([bags['s1']], store, tmp_path / 'c', capsys, '--rebuild')
    assert code == 0, err
    whole = tmp_path / 'whole.db'
    assert _analyze([bags['s1'], bags['s2'], bags['s3']], whole, tmp_path / 'd', capsys)[0] == 0
    assert _fleet(store, capsys) == _fleet(whole, capsys)


@pytest.mark.parametrize('how', ['flag', 'config', 'none'])
def test_the_robot_comes_from_the_flag_or_the_config_else_a_clear_error(
        bags, tmp_path, capsys, how):
    extra = []
    if how == 'flag':
        extra = ['--robot', 'cell3-r7']
    elif how == 'config':
        config = tmp_path / 'twin.yaml'
        config.write_text('twin:\n  robot: cell3-r7\n')
        extra = ['--config', config]
    code, _, err = _analyze([bags['anonymous']], tmp_path / 'f.db', tmp_path / 'out', capsys,
                            *extra)
    if how == 'none':
        errors = [line for line in err.splitlines() if line.startswith('ERROR:')]
        assert code == 1 and len(errors) == 1 and '--robot' in errors[0] and \
            'twin.robot' in errors[0] and 'Traceback' not in err, err
        return
    assert code == 0, err
    assert {r['robot'] for r in _fleet(tmp_path / 'f.db', capsys)} == {'cell3-r7'}


def test_after_a_replacement_later_bags_continue_the_new_reducer(bags, tmp_path, capsys):
    store = tmp_path / 'f.db'
    assert _analyze([bags['s1']], store, tmp_path / 'a', capsys)[0] == 0
    code, out, err = _run(['replace', '--store', store, '--robot', 'r1', '--joint', 'joint_1',
                           '--note', 'worn'], capsys)
    assert code == 0 and 'replaced at' in out, err
    rows = _fleet(store, capsys)
    new = [r for r in rows if r['joint'] == 'joint_1' and r['verdict'] != 'RETIRED']
    assert [(r['bags'], r['verdict']) for r in new] == [(0, 'NOT OBSERVED')]
    assert _analyze([bags['s2']], store, tmp_path / 'b', capsys)[0] == 0
    rows = {(r['joint'], r['verdict'] == 'RETIRED'): r for r in _fleet(store, capsys)}
    assert rows['joint_1', True]['bags'] == 1 and rows['joint_1', False]['bags'] == 1
    assert rows['joint_2', False]['bags'] == 2
    # The new reducer's history starts at the replacement; joint_2 goes on.
    assert rows['joint_1', False]['hours_observed'] == pytest.approx(2000.0, rel=1e-3)
    assert rows['joint_2', False]['hours_observed'] == pytest.approx(4000.0, rel=1e-3)
    assert rows['joint_1', True]['retired_at'] == rows['joint_1', False]['installed_at']


def test_a_reducer_fitted_by_a_replacement_is_new_whatever_the_service_time_said(
        bags, tmp_path, capsys):
    # The configuration's service time is of the units the twin first met (the robot's
    # hour meter at 2000 h); the reducer fitted later is new.
    store, config = tmp_path / 'f.db', tmp_path / 'twin.yaml'
    config.write_text('service_time_s: {joint_1: 7200000.0, joint_2: 7200000.0}\n')
    code, out, err = _analyze([bags['s2']], store, tmp_path / 'a', capsys, '--config', config)
    assert code == 0, err
    first = json.loads(out)['joints']
    # A short bag: judged once the duty is known, in this bag or the next of the history.
    assert all(first[j]['service']['hours'] == 2000.0 for j in ('joint_1', 'joint_2')), first
    assert _run(['replace', '--store', store, '--robot', 'r1', '--joint', 'joint_1'],
                capsys)[0] == 0
    code, out, err = _analyze([bags['s3']], store, tmp_path / 'b', capsys, '--config', config)
    assert code == 0, err
    later = json.loads(out)['joints']
    assert later['joint_1']['service'] is None
    # joint_2 goes on with its own: these short bags have not yet shown its duty.
    assert later['joint_2']['service']['hours'] == 2000.0
    assert later['joint_2']['service']['taken'] is None
    assert 'service time' not in err


def _cli(args, **kwargs):
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    return subprocess.Popen([sys.executable, '-m', 'reducer_twin.cli', *map(str, args)],
                            env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            start_new_session=True, **kwargs)


def _consistent(store_path):
    """Check what a crash may never leave: a broken file or a state without its segments."""
    conn = sqlite3.connect(store_path)
    assert conn.execute('PRAGMA integrity_check').fetchone()[0] == 'ok'
    conn.close()
    with FleetStore(store_path) as store:
        for reducer in store.reducers():
            exposure = reducer.state['estimator']['exposure_s'] if reducer.state else 0.0
            assert exposure == pytest.approx(reducer.exposure_s, rel=1e-9, abs=1e-6)
            assert reducer.bags == len(store.segment_bags(reducer.row_id)) <= 3
        return sum(r.bags for r in store.reducers())


def _stored_bags(path):
    """Bags a store holds now, as another reader sees it (-1 while there is no store)."""
    if not path.exists():
        return -1
    try:
        conn = sqlite3.connect(f'file:{path}?mode=ro', uri=True, timeout=0.05)
        try:
            return conn.execute('SELECT count(*) FROM bags').fetchone()[0]
        finally:
            conn.close()
    except sqlite3.Error:
        return -1


def test_kill_9_at_any_moment_leaves_a_consistent_store_that_a_rerun_completes(
        bags, tmp_path, capsys):
    reference = tmp_path / 'clean.db'
    assert _analyze([bags['s1'], bags['s2'], bags['s3']], reference, tmp_path / 'c',
                    capsys)[0] == 0
    full = _consistent(reference)
    seen = set()
    # Killed as soon as the store holds 0, 1 and 2 of the 3 bags: before, between and
    # after the transactions (polled, not timed, so a fast machine cannot outrun it).
    for k, stored in enumerate((0, 1, 2)):
        store = tmp_path / f'k{k}.db'
        proc = _cli(['analyze', bags['s1'], bags['s2'], bags['s3'], '--store', store, '--out',
                     tmp_path / f'k{k}'])
        while proc.poll() is None and _stored_bags(store) < stored:
            time.sleep(0.002)
        os.killpg(proc.pid, signal.SIGKILL)
        proc.communicate()
        assert proc.returncode == -signal.SIGKILL, 'the run ended before it was killed'
        seen.add(_consistent(store) if store.exists() else 0)
        code, _, err = _analyze([bags['s1'], bags['s2'], bags['s3']], store,
                                tmp_path / f'r{k}', capsys)
        assert code == 0, err
        assert _fleet(store, capsys) == _fleet(reference, capsys)
    assert min(seen) < full, f'no kill landed before the last bag was stored: {seen}'


def test_two_writers_at_once_serialise_and_count_every_bag_once(bags, tmp_path, capsys):
    store = tmp_path / 'f.db'
    procs = [_cli(['analyze', bags['s1'], bags['s2'], bags['s3'], '--store', store, '--out',
                   tmp_path / f'w{k}']) for k in range(2)]
    outputs = [p.communicate(timeout=300) for p in procs]
    for proc, (_, err) in zip(procs, outputs):
        assert proc.returncode == 0, err.decode()
    notes = sum(err.decode().count('already in the fleet store') for _, err in outputs)
    assert notes == 3
    assert [r['bags'] for r in _fleet(store, capsys)] == [3, 3]


def test_a_fleet_first_recorded_in_real_time_is_watched_not_called_worn_out(tmp_path, capsys):
    # A used unit (6.8 um, 17 500 h left) recorded for 6 minutes in real time, the usual
    # first bag of a robot: its lost motion cannot grow measurably in that time, so its
    # remaining life spans the rates the recording cannot rule out, P10 some 100 h. That
    # P10 made it REPLACE, a unit halfway to its lost-motion limit.
    spec = SimulationSpec(hours=0.1, aging_factor=1.0, joints=1, seed=3, robot='r1',
                          start_wear_um=6.8)
    truth = simulate_bag(tmp_path / 'rt', spec).truth['joint_1']['true_rul_h']
    code, out, err = _analyze([str(tmp_path / 'rt')], tmp_path / 'f.db', tmp_path / 'd',
                              capsys)
    assert code == 0, err
    (row,) = _fleet(tmp_path / 'f.db', capsys)
    assert row['verdict'] == 'WATCH' and row['rate_resolved'] is False
    assert row['rul_p10_h'] <= 200.0 and row['rul_p10_h'] < truth < row['rul_p90_h']
    assert 'with lost motion 1.6' in row['reason'] and 'give its service time' in row['reason']
