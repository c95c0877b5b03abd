"""The fleet store: a versioned SQLite file that survives crashes and concurrent writers."""

import multiprocessing
import sqlite3

import numpy as np
import pytest
from reducer_twin.core.errors import InvalidParameter
from reducer_twin.fleet.store import FleetStore, iso_from_ns, MIGRATIONS, parse_time
from reducer_twin.fleet.store import SCHEMA_VERSION, Segment, StoreConflict, StoreError
from reducer_twin.msg_adapters.layouts import REMAINING_LIFE, TE_FEATURES, WEAR_ESTIMATE

T0 = 1_767_225_600 * 1_000_000_000


def _segment(joint, revision, first_ns, windows=3, wear_m=1e-6):
    rng = np.random.default_rng(windows)
    wear = rng.random((windows + 1, len(WEAR_ESTIMATE.fields)))
    wear[:, WEAR_ESTIMATE.fields.index('stamp_s')] = (first_ns + np.arange(windows + 1)) * 1e-9
    return Segment(
        joint=joint, expected_revision=revision,
        state={'estimator': {'x': [wear_m, 0.0], 'P': [[1e-14, 0.0], [0.0, 0.1]]}},
        first_ns=first_ns, last_ns=first_ns + windows, windows=windows, exposure_s=3600.0,
        messages=100, rejected=0, summary={'wear_um': wear_m * 1e6}, levels=['OK'] * windows,
        features=rng.random((windows, len(TE_FEATURES.fields))), wear=wear,
        life=rng.random((windows + 1, len(REMAINING_LIFE.fields))), limit_rad=8.7e-4,
        warn_s=3.6e6, error_s=7.2e5)


def test_a_new_store_has_the_current_schema_in_wal_mode(tmp_path):
    with FleetStore(tmp_path / 'fleet.db', create=True) as store:
        assert store.schema_version == SCHEMA_VERSION
        assert store.conn.execute('PRAGMA journal_mode').fetchone()[0] == 'wal'
        assert store.reducers() == []


def test_a_missing_store_is_an_error_unless_it_may_be_created(tmp_path):
    with pytest.raises(StoreError, match='no fleet store at'):
        FleetStore(tmp_path / 'none.db')
    assert not (tmp_path / 'none.db').exists()


def test_an_older_store_is_migrated_and_keeps_its_history(tmp_path):
    path = tmp_path / 'old.db'
    with FleetStore(path, create=True) as store:
        store.write_bag('r1', 'f' * 64, '/bags/a', T0, T0 + 3, 3600.0, 100,
                        [_segment('joint_1', None, T0)])
    # Take it back to version 1, as an older reducer-twin wrote it.
    conn = sqlite3.connect(path)
    conn.execute('ALTER TABLE segments DROP COLUMN worker')
    conn.execute('ALTER TABLE bags DROP COLUMN source')
    conn.execute('ALTER TABLE bags DROP COLUMN session')
    conn.execute('PRAGMA user_version = 1')
    conn.commit()
    conn.close()
    with FleetStore(path) as store:
        assert store.schema_version == SCHEMA_VERSION == len(MIGRATIONS)
        [reducer] = store.reducers()
        assert (reducer.robot, reducer.joint, reducer.bags, reducer.windows) == (
            'r1', 'joint_1', 1, 3)
        columns = [r[1] for r in store.conn.execute('PRAGMA table_info(segments)')]
        assert 'worker' in columns
        assert store.bag('f' * 64).source == 'bag', 'a bag stored before live segments existed'


@pytest.mark.parametrize('make, fragment', [
    (lambda c: c.execute('PRAGMA user_version = 99'), 'newer than'),
    (lambda c: c.execute('CREATE TABLE other (x)'), 'not a fleet store'),
], ids=['a newer schema', 'another SQLite file'])
def test_a_newer_or_foreign_sqlite_file_is_refused_and_left_alone(tmp_path, make, fragment):
    path = tmp_path / 'x.db'
    conn = sqlite3.connect(path)
    make(conn)
    conn.commit()
    conn.close()
    before = path.read_bytes()
    with pytest.raises(StoreError, match=fragment):
        FleetStore(path, create=True)
    assert path.read_bytes() == before


def test_a_file_that_is_not_sqlite_is_refused(tmp_path):
    path = tmp_path / 'notes.db'
    path.write_text('not a database, just notes\n' * 100)
    with pytest.raises(StoreError, match='not a usable fleet store'):
        FleetStore(path)


def test_windows_and_states_read_back_exactly_and_trends_span_bags(tmp_path):
    with FleetStore(tmp_path / 'f.db', create=True) as store:
        a, b = _segment('joint_1', None, T0, 3), _segment('joint_1', 1, T0 + 10, 4, 2e-6)
        store.write_bag('r1', 'a' * 64, '/bags/a', T0, T0 + 3, 1.0, 100, [a])
        store.write_bag('r1', 'b' * 64, '/bags/b', T0 + 10, T0 + 14, 1.0, 100, [b])
        [reducer] = store.reducers()
        assert reducer.bags == 2 and reducer.windows == 7 and reducer.revision == 2
        assert reducer.state == b.state and reducer.last_ns == T0 + 14
        trend = store.trend(reducer.row_id)
    np.testing.assert_array_equal(trend.features, np.concatenate([a.features, b.features]))
    np.testing.assert_array_equal(trend.wear, np.concatenate([a.wear, b.wear]))
    assert trend.levels == ['OK'] * 7 and len(trend.bag_starts_h) == 2


def test_a_write_planned_on_an_older_revision_is_refused_and_changes_nothing(tmp_path):
    with FleetStore(tmp_path / 'f.db', create=True) as store:
        store.write_bag('r1', 'a' * 64, '/bags/a', T0, T0 + 3, 1.0, 100,
                        [_segment('joint_1', None, T0)])
        # Another run planned before that write: it expected no reducer yet.
        with pytest.raises(StoreConflict, match='changed in the store'):
            store.write_bag('r1', 'b' * 64, '/bags/b', T0 + 10, T0 + 13, 1.0, 100,
                            [_segment('joint_1', None, T0 + 10)])
        assert store.bag('b' * 64) is None and store.reducers()[0].bags == 1


def test_overlapping_bags_of_one_reducer_are_refused(tmp_path):
    with FleetStore(tmp_path / 'f.db', create=True) as store:
        store.write_bag('r1', 'a' * 64, '/bags/a', T0, T0 + 3, 1.0, 100,
                        [_segment('joint_1', None, T0)])
        with pytest.raises(StoreError, match='overlap'):
            store.write_bag('r1', 'b' * 64, '/bags/b', T0 + 2, T0 + 5, 1.0, 100,
                            [_segment('joint_1', 1, T0 + 2)])


def test_a_second_writer_fails_clearly_or_waits_for_the_first(tmp_path):
    first = FleetStore(tmp_path / 'f.db', create=True)
    first.lock_for_writing()
    second = FleetStore(tmp_path / 'f.db')
    with pytest.raises(StoreError, match='another process is writing'):
        second.lock_for_writing(wait=False)
    first.close()
    second.lock_for_writing(wait=False)
    second.close()


def _open_at_once(path, barrier, said):
    barrier.wait()      # every process opens the new store at the same moment
    try:
        with FleetStore(path, create=True) as store:
            said.put(('ok', store.schema_version))
    except StoreError as err:
        said.put(('error', str(err)))


def test_processes_that_create_a_store_at_once_all_open_one_fleet_store(tmp_path):
    # Two analyses started together on a new --store: one of them read the version
    # before the other's schema was committed and the tables after it, and refused the
    # store as "an SQLite file but not a fleet store" (3 of 100 rounds of 8 processes).
    ctx = multiprocessing.get_context('fork')
    for k in range(60):
        barrier, said = ctx.Barrier(8), ctx.Queue()
        procs = [ctx.Process(target=_open_at_once, args=(tmp_path / f'f{k}.db', barrier, said))
                 for _ in range(8)]
        for proc in procs:
            proc.start()
        got = [said.get(timeout=60) for _ in procs]
        for proc in procs:
            proc.join()
        assert got == [('ok', SCHEMA_VERSION)] * 8, got


def test_replace_retires_the_reducer_and_installs_a_new_one_after_its_data(tmp_path):
    with FleetStore(tmp_path / 'f.db', create=True) as store:
        store.write_bag('r1', 'a' * 64, '/bags/a', T0, T0 + 3, 1.0, 100,
                        [_segment('joint_1', None, T0)])
        with pytest.raises(StoreError, match='not after the newest data'):
            store.replace('r1', 'joint_1', T0 + 1)
        with pytest.raises(StoreError, match='no reducer r1/joint_9.*joint_1'):
            store.replace('r1', 'joint_9')
        old, new = store.replace('r1', 'joint_1', note='worn, swapped on the line')
        assert old.retired_ns == new.installed_ns == T0 + 4
        assert (new.bags, new.state, new.in_service) == (0, None, True)
        [event] = store.events()
        assert event['note'] == 'worn, swapped on the line' and event['kind'] == 'replaced'


MS = 1_000_000


def _live(revision, first_ns, windows=3):
    """Return a live segment: windows of 1 ms from ``first_ns``, stamps in the records."""
    seg = _segment('joint_1', revision, first_ns, windows)
    seg.wear, seg.life = seg.wear[1:], seg.life[1:]     # no estimate at start, as live
    start, end = (TE_FEATURES.fields.index(k) for k in ('window_start_s', 'window_end_s'))
    seg.features[:, start] = (first_ns + MS * np.arange(windows)) * 1e-9
    seg.features[:, end] = (first_ns + MS * np.arange(1, windows + 1)) * 1e-9
    seg.last_ns = first_ns + MS * windows
    return seg


def test_live_segments_join_a_bags_history_counted_apart_and_in_time_order(tmp_path):
    with FleetStore(tmp_path / 'f.db', create=True) as store:
        store.write_bag('r1', 'a' * 64, '/bags/a', T0, T0 + 3, 1.0, 100,
                        [_segment('joint_1', None, T0)])
        assert store.write_live_segment('r1', 's1', 0, _live(1, T0 + MS), 360000.0,
                                        'live wear_estimator_joint_1') == 2
        assert store.write_live_segment('r1', 's1', 1, _live(2, T0 + 4 * MS), 360000.0,
                                        'live wear_estimator_joint_1') == 3
        [reducer] = store.reducers()
        assert (reducer.bags, reducer.live_segments, reducer.windows) == (1, 2, 9)
        assert reducer.live_exposure_s == 7200.0 and reducer.exposure_s == 10800.0
        assert reducer.last_ns == T0 + 7 * MS
        assert [b.fingerprint for b in store.bags_of('r1')] == ['a' * 64]
        live = store.bag('live:s1:1')
        assert (live.source, live.session, live.path) == (
            'live', 's1', 'live wear_estimator_joint_1')
        trend = store.trend(reducer.row_id)
        assert len(trend.bag_starts_h) == 2, 'the bag, then the live session'
        # A window that does not end after the history, and a bag over the live hours.
        with pytest.raises(StoreError, match='does not end after the stored history'):
            store.write_live_segment('r1', 's2', 0, _live(3, T0 + 5 * MS), 1.0, 'live x')
        with pytest.raises(StoreError, match='overlap'):
            store.write_bag('r1', 'b' * 64, '/bags/b', T0 + 6 * MS, T0 + 9 * MS, 1.0, 100,
                            [_segment('joint_1', 3, T0 + 6 * MS)])
        with pytest.raises(StoreConflict, match='restart the node'):
            store.write_live_segment('r1', 's2', 0, _live(1, T0 + 20 * MS), 1.0, 'live x')
        assert store.reducers()[0].revision == 3 and store.bag('live:s2:0') is None


@pytest.mark.parametrize('text, expected', [
    ('2026-01-01T00:00:00Z', T0), ('2026-01-01T01:00:00+01:00', T0),
    ('2026-01-01 00:00:01', T0 + 1_000_000_000), (str(T0 + 5), T0 + 5)])
def test_times_are_iso_8601_or_bag_clock_nanoseconds(text, expected):
    assert parse_time(text) == expected
    assert iso_from_ns(T0) == '2026-01-01T00:00:00Z'


@pytest.mark.parametrize('text', ['yesterday', '-5', '2026-13-01'])
def test_a_bad_time_names_the_flag_and_the_forms_allowed(text):
    with pytest.raises(InvalidParameter, match='--at must be'):
        parse_time(text)
