"""
Estimator state files: written atomically with a backup, restored exactly, never trusted blindly.

The estimator is stepped with synthetic ``te_features`` windows of a reducer whose wear is
known (:mod:`window_records`); every file is read back through the checksummed format.
"""

import gc
import json
import math
import re
from types import SimpleNamespace

import pytest
from reducer_twin.core.errors import StateFileError
from reducer_twin.core.estimator import EstimatorConfig, params_fingerprint, WearEstimator
from reducer_twin.core.params import ReducerParams
from reducer_twin.core.pipeline import EstimatorStage, features_from_record, SOFT_ZONE_KEY
from reducer_twin.core.units import ARCMIN, HOUR
from reducer_twin.io.state_file import (
    backup_path, decode_state, encode_state, load_estimator, load_with_fallback, save_estimator,
    StateFile)
from window_records import feature_records

PARAMS = ReducerParams()
EXPOSURE = 10.0 * HOUR
WINDOW_S = 2.0


@pytest.fixture(scope='module')
def params():
    return PARAMS


@pytest.fixture(scope='module')
def windows():
    return [features_from_record(r)
            for r in feature_records(PARAMS, 40, 3, 100.0, WINDOW_S, EXPOSURE, rate_scale=1.0)]


def run(stage, windows):
    """Step a stage with windows; return the statuses."""
    return [stage.process(f) for f in windows]


def stepped_estimator(params, n=60, seed=2):
    """Return an estimator stepped with ``n`` windows, and the windows (100 of them)."""
    features = [features_from_record(r)
                for r in feature_records(params, 100, seed, 0.0, WINDOW_S, EXPOSURE)]
    est = WearEstimator(params)
    for f in features[:n]:
        est.step(f)
    return est, features


# --------------------------------------------------------------------------- the file format


def test_save_and_load_restore_exactly_and_keep_the_previous_copy(params, tmp_path):
    est, features = stepped_estimator(params)
    path = tmp_path / 'wear_state.json'
    save_estimator(est, path)
    first = est.state_dict()
    est.step(features[60])
    save_estimator(est, path)
    assert load_estimator(path, params).state_dict() == est.state_dict()
    assert load_estimator(backup_path(path), params).state_dict() == first
    assert [p.name for p in tmp_path.iterdir() if p.name.endswith('.tmp')] == []


def test_a_state_file_is_written_without_leaving_reference_cycles(params):
    # An estimator writes its file after every window for months: the encoding must leave
    # nothing for the cycle collector (the indenting json encoder leaves ~30 objects a call).
    est, _ = stepped_estimator(params, n=5)
    gc.collect()
    gc.disable()
    try:
        data = [encode_state(est.state_dict()) for _ in range(20)]
        assert gc.collect() == 0
    finally:
        gc.enable()
    lines = data[0].decode().splitlines()
    assert [line.split(':')[0] for line in lines[1:4]] == [' "format"', ' "sha256"', ' "state"']
    assert json.loads(data[0])['state'] == est.state_dict()


def corrupt_flip_digit(data):
    """Change the first digit of the wear in x: valid JSON, wrong checksum."""
    text = data.decode()
    i = text.index('"x":[')
    i += next(k for k, c in enumerate(text[i:]) if c in '123456789')
    return (text[:i] + ('1' if text[i] != '1' else '2') + text[i + 1:]).encode()


def reencode_with(data, **changes):
    state = json.loads(data)['state']
    state.update(changes)
    return encode_state(state)


@pytest.mark.parametrize('mangle, message', [
    (lambda d: d[:len(d) // 2], 'not valid JSON'),
    (lambda d: b'', 'not valid JSON'),
    (lambda d: b'\xff\xfe garbage', 'not valid JSON'),
    (corrupt_flip_digit, 'checksum mismatch'),
    (lambda d: reencode_with(d, version=99), 'version'),
    (lambda d: reencode_with(d, params_sha256='0' * 64), 'other reducer parameters'),
    (lambda d: reencode_with(d, components=[[0.0, [1.0], [1.0]]]), 'malformed'),
    (lambda d: reencode_with(d, growth={'sxx': [[1.0]]}), 'malformed'),
    (lambda d: reencode_with(d, counters={}), 'malformed'),
    (lambda d: json.dumps({'format': 'something else'}).encode(), 'format'),
    (lambda d: b'[1, 2, 3]', 'format'),
])
def test_a_bad_state_file_raises_state_file_error(params, tmp_path, mangle, message):
    est, _ = stepped_estimator(params, n=5)
    path = tmp_path / 'state.json'
    save_estimator(est, path)
    path.write_bytes(mangle(path.read_bytes()))
    with pytest.raises(StateFileError, match=message):
        load_estimator(path, params)


def test_a_state_of_another_reducer_is_detected_as_foreign(params, tmp_path):
    other = params.with_overrides({'geometry.equidistant_modification': 0.04e-3})
    assert params_fingerprint(other) != params_fingerprint(params)
    est, _ = stepped_estimator(params, n=5)
    save_estimator(est, tmp_path / 'state.json')
    with pytest.raises(StateFileError, match='other reducer parameters'):
        load_estimator(tmp_path / 'state.json', other)


def test_a_missing_file_raises_state_file_error(params, tmp_path):
    with pytest.raises(StateFileError, match='cannot read'):
        load_estimator(tmp_path / 'absent.json', params)


def test_a_corrupt_primary_falls_back_to_the_backup_and_says_so(params, tmp_path):
    est, features = stepped_estimator(params)
    path = tmp_path / 'state.json'
    save_estimator(est, path)
    good = est.state_dict()
    est.step(features[60])
    save_estimator(est, path)
    path.write_bytes(path.read_bytes()[:100])
    loaded = load_with_fallback(path, params)
    assert loaded.used_backup and loaded.path == backup_path(path)
    assert 'not valid JSON' in loaded.primary_error
    assert loaded.estimator.state_dict() == good
    # Saving over the corrupt primary must not overwrite the good backup with it.
    save_estimator(loaded.estimator, path)
    assert load_estimator(backup_path(path), params).state_dict() == good


def test_fallback_without_a_usable_file_raises_naming_both(params, tmp_path):
    path = tmp_path / 'state.json'
    path.write_bytes(b'{"truncated')
    with pytest.raises(StateFileError, match='no usable estimator state.*backup'):
        load_with_fallback(path, params)


def test_an_intact_primary_is_used_without_fallback(params, tmp_path):
    est, _ = stepped_estimator(params, n=5)
    save_estimator(est, tmp_path / 'state.json')
    loaded = load_with_fallback(tmp_path / 'state.json', params)
    assert not loaded.used_backup and loaded.primary_error is None


def test_a_state_of_the_two_state_estimator_is_converted_on_load(params, tmp_path):
    est, features = stepped_estimator(params)
    old = est.state_dict()
    old.update(version=1, x=[3e-6, 0.2], P=[[1e-14, 0.0], [0.0, 0.01]])
    for key in ('components', 'noise', 'trend', 'growth', 'archard_exposure', 'trend_score',
                'duty_batch', 'duty_batch_sums'):
        del old[key]
    path = tmp_path / 'old.json'
    path.write_bytes(encode_state(old))
    loaded = load_estimator(path, params)
    assert loaded.wear == pytest.approx(3e-6) and loaded.x[1] == pytest.approx(0.2)
    assert loaded.components == 1 and loaded.baseline == 0.0
    loaded.step(features[60])
    assert math.isfinite(loaded.wear)


# ---------------------------------------------------------------- EstimatorStage with a StateFile


def test_a_restored_stage_continues_exactly_where_the_saved_one_stopped(windows, tmp_path):
    path = tmp_path / 'joint_1.json'
    logs = []
    first = EstimatorStage(PARAMS, store=StateFile(path), log=logs.append)
    assert 'starting from a new reducer' in logs[0]
    run(first, windows[:15])
    second = EstimatorStage(PARAMS, store=StateFile(path), log=logs.append)
    assert second.restored_from == str(path)
    assert 'restored estimator state' in logs[-1]
    assert second.estimator.state_dict() == first.estimator.state_dict()
    reference = EstimatorStage(PARAMS)
    run(reference, windows)
    run(second, windows[15:])
    assert second.estimator.state_dict() == reference.estimator.state_dict()
    assert decode_state(path.read_bytes(), path) == reference.estimator.state_dict()


def test_a_window_seen_again_after_a_restart_is_skipped_as_a_replay(windows, tmp_path):
    path = tmp_path / 'joint_1.json'
    stage = EstimatorStage(PARAMS, store=StateFile(path))
    run(stage, windows[:6])
    saved = path.read_bytes()
    restarted = EstimatorStage(PARAMS, store=StateFile(path))
    assert run(restarted, windows[4:6]) == ['replay', 'replay']
    assert restarted.skipped_replays == 2
    assert restarted.estimator.exposure_s == stage.estimator.exposure_s
    assert path.read_bytes() == saved, 'a replay changes nothing, not even the file'
    assert run(restarted, windows[6:7]) != ['replay']


def test_a_corrupt_state_file_falls_back_to_its_backup(windows, tmp_path):
    path = tmp_path / 'joint_1.json'
    stage = EstimatorStage(PARAMS, store=StateFile(path))
    run(stage, windows[:5])
    previous = decode_state(backup_path(path).read_bytes())
    path.write_bytes(path.read_bytes()[:40])     # a crash mid-write of some other tool
    logs = []
    restored = EstimatorStage(PARAMS, store=StateFile(path), log=logs.append)
    assert restored.restored_from == str(backup_path(path))
    assert restored.estimator.state_dict() == previous
    assert 'primary unusable' in logs[0]
    assert restored.estimator.updates == stage.estimator.updates - 1


def test_a_corrupt_state_file_without_backup_refuses_to_start_naming_the_file(tmp_path):
    path = tmp_path / 'joint_1.json'
    path.write_text('{"format": "reducer_twin.wear_estimator.file", "sha256": "0"')
    with pytest.raises(StateFileError, match=str(path)):
        EstimatorStage(PARAMS, store=StateFile(path))


def test_the_state_directory_is_created_when_missing(windows, tmp_path):
    path = tmp_path / 'state' / 'reducer_twin' / 'joint_1.json'
    stage = EstimatorStage(PARAMS, store=StateFile(path))
    run(stage, windows[:1])
    assert decode_state(path.read_bytes())['t_end'] == windows[0].t_end


def test_a_state_directory_that_cannot_be_made_refuses_to_start(tmp_path):
    blocker = tmp_path / 'file'
    blocker.write_text('not a directory')
    with pytest.raises(StateFileError, match='directory'):
        EstimatorStage(PARAMS, store=StateFile(blocker / 'joint_1.json'))


def test_reset_returns_to_a_new_reducer_and_saves_the_event(windows, tmp_path):
    path = tmp_path / 'joint_1.json'
    stage = EstimatorStage(PARAMS, store=StateFile(path))
    run(stage, windows[:10])
    assert stage.estimator.wear > 0.0
    stage.reset('maintenance: reducer replaced')
    assert stage.estimator.wear == EstimatorConfig().initial_wear
    state = decode_state(path.read_bytes())
    assert state['events'][-1]['reason'] == 'maintenance: reducer replaced'
    assert state['exposure_since_reset_s'] == 0.0
    assert state['exposure_s'] == pytest.approx(10 * EXPOSURE)


def test_a_background_writer_saves_the_same_state_in_order(windows, tmp_path):
    path = tmp_path / 'bg.json'
    stage = EstimatorStage(PARAMS, store=StateFile(path, background=True))
    run(stage, windows[:10])
    stage.flush()
    saved = decode_state(path.read_bytes(), path)
    assert saved == stage.estimator.state_dict()
    assert stage.store.writer.written == 10 and stage.store.writer.failures == 0


def test_a_failing_background_write_is_counted_and_the_stage_keeps_running(windows, tmp_path):
    path = tmp_path / 'state' / 'bg.json'
    stage = EstimatorStage(PARAMS, store=StateFile(path, background=True))
    run(stage, windows[:3])
    stage.flush()
    # The directory vanishes and a file takes its name (a full or broken disk).
    for f in path.parent.iterdir():
        f.unlink()
    path.parent.rmdir()
    path.parent.write_text('not a directory')
    run(stage, windows[3:6])
    stage.flush()
    assert stage.store.writer.failures == 3
    assert isinstance(stage.store.writer.error, StateFileError)
    assert math.isfinite(stage.estimator.wear)


def _with_shortfall(windows, shortfall):
    """Return the windows as a stream whose soft-zone check says ``shortfall`` [rad]."""
    return [SimpleNamespace(**{**vars(w), 'soft_zone_shortfall': shortfall}) for w in windows]


def test_a_restarted_stage_keeps_giving_the_lost_motion_at_the_test_torque(windows, tmp_path):
    # The shortfall of a soft zone the stream said is written with the estimator's state,
    # so a restarted wear_estimator gives the lost motion and remaining life at the test
    # torque at once (not the play until te_monitor says it again), and says so. It is
    # carried as from an earlier bag: kept until the new stream's own check says one.
    path = tmp_path / 'joint_1.json'
    shortfall = 0.8 * ARCMIN
    stage = EstimatorStage(PARAMS, store=StateFile(path))
    run(stage, _with_shortfall(windows[:8], shortfall))
    assert decode_state(path.read_bytes(), path)[SOFT_ZONE_KEY] == shortfall
    logs = []
    restarted = EstimatorStage(PARAMS, store=StateFile(path), log=logs.append)
    assert restarted.soft_zone_shortfall == shortfall
    assert 'soft zone an earlier recording of this reducer found' in logs[-1]
    assert restarted.estimator.state_dict() == stage.estimator.state_dict()
    stamp = windows[7].t_end
    assert restarted.record(stamp)['lost_motion_rad'] == stage.record(stamp)['lost_motion_rad']
    run(restarted, windows[8:10])
    assert restarted.soft_zone_shortfall == shortfall
    # A reset (a new reducer) forgets it, in the file too.
    restarted.reset('maintenance: reducer replaced')
    assert SOFT_ZONE_KEY not in decode_state(path.read_bytes(), path)
    assert EstimatorStage(PARAMS, store=StateFile(path)).soft_zone_shortfall == 0.0


def test_a_lost_motion_given_more_for_loads_within_a_soft_zone_survives_a_restart(
        windows, tmp_path):
    # Loads within a soft zone: the windows carry the gap to the width at the test torque
    # as a negative shortfall (core/within_zone.py), added no further than that width.
    path = tmp_path / 'joint_1.json'
    stage = EstimatorStage(PARAMS, store=StateFile(path))
    run(stage, [SimpleNamespace(**{**vars(w), 'soft_zone_shortfall': -0.6 * ARCMIN,
                                   'soft_zone_width': 50.0 * ARCMIN}) for w in windows[:8]])
    assert stage.soft_zone_shortfall == -0.6 * ARCMIN
    stamp = windows[7].t_end
    play = stage.estimator.lost_motion(stage.estimator.growth_trend())[0]
    assert stage.record(stamp)['lost_motion_rad'] == pytest.approx(play + 0.6 * ARCMIN)
    logs = []
    restarted = EstimatorStage(PARAMS, store=StateFile(path), log=logs.append)
    assert restarted.soft_zone_shortfall == -0.6 * ARCMIN
    assert "the flanks' reading plus 0.60 arcmin" in logs[-1]


@pytest.mark.parametrize('value', [[0.5], 'wide', None, True])
def test_a_state_file_with_a_bad_shortfall_falls_back_to_its_backup(windows, tmp_path, value):
    path = tmp_path / 'joint_1.json'
    stage = EstimatorStage(PARAMS, store=StateFile(path))
    run(stage, _with_shortfall(windows[:4], 0.5 * ARCMIN))
    path.write_bytes(reencode_with(path.read_bytes(), **{SOFT_ZONE_KEY: value}))
    with pytest.raises(StateFileError, match=f'{SOFT_ZONE_KEY} must be a finite number of '
                                             f'radians, got {re.escape(repr(value))}'):
        load_estimator(path, PARAMS)
    restored = EstimatorStage(PARAMS, store=StateFile(path))
    assert restored.restored_from == str(backup_path(path))
    assert restored.soft_zone_shortfall == 0.5 * ARCMIN
