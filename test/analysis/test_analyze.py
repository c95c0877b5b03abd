"""reducer-twin analyze: the live pipeline offline, derived bags read back by other libraries."""

import json
from pathlib import Path
import shutil

from cli_runs import run_cli as _run
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
import numpy as np
import pytest
from reducer_twin.analysis.pipeline import analyze_bag
from reducer_twin.analysis.settings import AnalysisSettings
from reducer_twin.analysis.simulate import AGING_KEY, simulate_bag, SimulationSpec
from reducer_twin.core.errors import BagError
from reducer_twin.core.ingest import StreamCleaner
from reducer_twin.core.joint_twin import TwinConfig
from reducer_twin.core.kinematics import total_ratio
from reducer_twin.core.pairing import pair_columns
from reducer_twin.core.params import ReducerParams
from reducer_twin.core.pipeline import features_record, TimeOffsetCalibration
from reducer_twin.core.spikes import SpikeFilter
from reducer_twin.core.te_extraction import TEExtractor
from reducer_twin.core.transmission_error import lost_motion
from reducer_twin.core.units import ARCMIN
from reducer_twin.core.window_analysis import WindowAnalyzer
from reducer_twin.io.bag import open_bag, write_bag_dir
from reducer_twin.io.mcap_array_writer import McapBagWriter
from reducer_twin.io.rosbag2_metadata import bag_metadata, dump_yaml
from reducer_twin.msg_adapters.jointstate_cdr import encode_joint_states, JointStateBatch
from reducer_twin.msg_adapters.layouts import (
    LAYOUTS, record_values, REMAINING_LIFE, TE_BATCH, TE_FEATURES)
from reducer_twin.msg_adapters.layouts import WEAR_ESTIMATE
from reducer_twin.msg_adapters.multiarray_cdr import decode_layout_batch
from rosbags.highlevel import AnyReader
from rosbags.typesys import get_typestore, Stores
from sqlite3_bags import humble_qos, write_joint_states_db3
import yaml

REAL_BAGS = Path(__file__).resolve().parents[2].parent / 'shared' / 'data' / 'rosbag2-jazzy'
JOINT_STATE = 'sensor_msgs/msg/JointState'
AGING = 180_000.0
# 3000 operating hours in 60 s of stream at 250 Hz; joint 2 wears twice as fast, both joints
# under 1.2x rated gravity load (as the demo) so the wear is large enough to be seen.
SPEC = SimulationSpec(hours=3000.0, aging_factor=AGING, joints=2, rate_hz=250.0, seed=3,
                      wear_rate_scales=(1.0, 2.0), load_torque_nm=1.2 * 784.0)
JSON_KEYS = {'wear_um', 'wear_std_um', 'rul_p10_h', 'rul_p50_h', 'rul_p90_h',
             'lost_motion_arcmin', 'lost_motion_std_arcmin', 'messages', 'rejected',
             'observed', 'windows', 'reason', 'partial', 'pairing', 'velocity',
             'rate_resolved', 'faster_than_wear', 'growth_law', 'curve_extrapolation',
             'service', 'inputs', 'soft_zone', 'within_zone', 'test_torque_check'}
DERIVED = ('te', 'te_features', 'wear', 'remaining_life', 'ground_truth')
DIAG_KEYS = ['wear_um', 'wear_std_um', 'rate_scale', 'lost_motion_arcmin',
             'lost_motion_std_arcmin', 'lost_motion_obs_arcmin', 'rul_p10_h', 'rul_p50_h',
             'rul_p90_h', 'rul_p90_censored', 'catalogue_life_h', 'exposure_h', 'updates',
             'rejected_updates', 'te_pp_arcmin', 'rejected_messages',
             'lost_motion_limit_arcmin']


@pytest.fixture(scope='module')
def sim(tmp_path_factory):
    """Simulate a bag; return it and the simulator's truth at its end."""
    out = tmp_path_factory.mktemp('sim') / 'robot'
    return out, simulate_bag(out, SPEC).truth


@pytest.fixture(scope='module')
def analysed(sim, tmp_path_factory):
    """Analyse the simulated bag in this process."""
    out = tmp_path_factory.mktemp('derived') / 'derived'
    return analyze_bag(sim[0], out)


def _errors(err):
    return [line for line in err.splitlines() if line.startswith('ERROR:')]


def _same_results(a, b):
    assert list(a.joints) == list(b.joints)
    for name in a.joints:
        x, y = a.joints[name], b.joints[name]
        np.testing.assert_array_equal(x.features, y.features)
        np.testing.assert_array_equal(x.wear, y.wear)
        np.testing.assert_array_equal(x.life, y.life)
        np.testing.assert_array_equal(x.te, y.te)
        assert x.levels == y.levels and x.counts == y.counts
        assert x.summary() == y.summary()


# --------------------------------------------------------------------------- results


def test_the_json_has_the_issue_shape_and_the_estimate_approaches_the_truth(
        sim, tmp_path, capsys):
    code, out, err = _run(['analyze', sim[0], '--out', tmp_path / 'd', '--json'], capsys)
    assert code == 0, err
    data = json.loads(out)
    assert set(data) == {'joints', 'messages_per_s'} and data['messages_per_s'] > 0
    truth = sim[1]
    for name in ('joint_1', 'joint_2'):
        got = data['joints'][name]
        assert set(got) == JSON_KEYS
        assert got['messages'] == 15_000 and got['rejected'] == 0
        assert got['pairing'].startswith('shared stamps')    # one message per tick
        # Wear within 10 % of the truth after 3000 h (the README's accuracy floor).
        assert got['wear_um'] == pytest.approx(truth[name]['true_wear_um'], rel=0.10)
        assert 0.0 < got['wear_std_um'] < 0.1 * got['wear_um']
        # The lost motion with its standard deviation, which holds the truth.
        true_lm = lost_motion(truth[name]['true_wear_um'] * 1e-6, ReducerParams()) / ARCMIN
        assert 0.0 < got['lost_motion_std_arcmin'] < 0.2 * got['lost_motion_arcmin']
        assert abs(got['lost_motion_arcmin'] - true_lm) < 3.0 * got['lost_motion_std_arcmin']
        assert got['rul_p10_h'] <= got['rul_p50_h'] <= got['rul_p90_h']
        assert got['rul_p50_h'] == pytest.approx(truth[name]['true_rul_h'], rel=0.3)
        # A few dozen windows of a third of a life: the wear model's curve carries the
        # rest further than the span its shape was compared over, and the JSON says so.
        assert got['growth_law'] is None and got['curve_extrapolation'] > 1.0
        # No window of this duty held the load at the test torque long enough to compare
        # the width there with the loaded flanks: --json says so; with a clean answer (OK)
        # no line does (an alarm would carry one, test_joint_words.py).
        assert got['soft_zone'] is None and got['test_torque_check'] == 'not compared'
        assert got['within_zone'] is None
        assert not any('test torque' in line for line in got['inputs'])
    # The joint that wears twice as fast is estimated more worn, with less life left.
    assert data['joints']['joint_2']['wear_um'] > 1.5 * data['joints']['joint_1']['wear_um']
    assert data['joints']['joint_2']['rul_p50_h'] < data['joints']['joint_1']['rul_p50_h']


def test_the_derived_bag_reads_back_with_mcap_ros2_and_every_message_decodes(analysed):
    root = analysed.out
    assert (root / 'metadata.yaml').is_file()
    files = sorted(root.glob('*.mcap'))
    counts, labels = {}, {}
    with open(files[0], 'rb') as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        assert reader.get_header().profile == 'ros2'
        for schema, channel, _, msg in reader.iter_decoded_messages():
            counts[channel.topic] = counts.get(channel.topic, 0) + 1
            if schema.name == 'std_msgs/msg/Float64MultiArray':
                labels.setdefault(channel.topic, set()).add(msg.layout.dim[-1].label)
    expected = {f'/reducer_twin/{j}/{s}' for j in ('joint_1', 'joint_2') for s in DERIVED}
    assert set(counts) == expected | {'/diagnostics'}
    for joint, res in analysed.joints.items():
        windows = len(res.features)
        # 60 s at 250 Hz; a window holds at least 1000 samples (4 s) at this rate.
        assert windows >= 12
        assert counts[f'/reducer_twin/{joint}/te_features'] == windows
        assert counts[f'/reducer_twin/{joint}/wear'] == windows + 1    # + the start record
        assert counts[f'/reducer_twin/{joint}/remaining_life'] == windows + 1
        # Every second of the 60 s stream, the last one at its end.
        assert counts[f'/reducer_twin/{joint}/ground_truth'] == 60
        for suffix in ('te', 'te_features', 'wear', 'remaining_life', 'ground_truth'):
            assert labels[f'/reducer_twin/{joint}/{suffix}'] == {LAYOUTS[suffix].label}
    # Per window and joint one life status, and the ingest counts once at the end.
    assert counts['/diagnostics'] == sum(len(r.wear) for r in analysed.joints.values()) + 1


def test_the_derived_bag_reads_back_with_rosbags_and_carries_the_nodes_messages(analysed):
    store = get_typestore(Stores.ROS2_JAZZY)
    te_rows, statuses = 0, []
    with AnyReader([analysed.out], default_typestore=store) as reader:
        for connection, stamp, raw in reader.messages():
            msg = reader.deserialize(raw, connection.msgtype)
            if connection.topic == '/reducer_twin/joint_1/te':
                te_rows += msg.layout.dim[0].size
                assert msg.layout.dim[0].stride == msg.layout.dim[0].size * 4
                assert abs(stamp - msg.data[-4] * 1e9) < 1e3   # logged at its last sample
            elif connection.topic == '/diagnostics':
                statuses += msg.status
    # TE needs the motor angle where the link encoder sampled (50 us after its stamp); it is
    # extrapolated over the offset at chunk ends, so every sample has its TE.
    assert te_rows == 15_000
    life = [s for s in statuses if s.name == 'reducer_twin: joint_2 reducer']
    assert len(life) == len(analysed.joints['joint_2'].wear)
    assert [v.key for v in life[-1].values] == DIAG_KEYS
    assert life[-1].hardware_id == 'joint_2'
    levels = {'OK': 0, 'WARN': 1, 'ERROR': 2}
    assert life[-1].level == levels[analysed.joints['joint_2'].levels[-1]]
    assert 'remaining life P10' in life[-1].message
    ingest = [s for s in statuses if s.name.endswith('encoder ingest')]
    assert [s.hardware_id for s in ingest] == ['joint_1', 'joint_2']


def test_the_derived_topics_hold_the_stage_outputs(analysed):
    with open_bag(analysed.out) as bag:
        def records(topic, layout):
            return decode_layout_batch(layout, [raw.payload(i) for _, raw in bag.iter_raw([topic])
                                                for i in range(len(raw))])
        for joint, res in analysed.joints.items():
            np.testing.assert_array_equal(
                records(f'/reducer_twin/{joint}/te_features', TE_FEATURES), res.features)
            np.testing.assert_array_equal(records(f'/reducer_twin/{joint}/wear', WEAR_ESTIMATE),
                                          res.wear)
            np.testing.assert_array_equal(
                records(f'/reducer_twin/{joint}/remaining_life', REMAINING_LIFE), res.life)
            te = records(f'/reducer_twin/{joint}/te', TE_BATCH)
            # Every sample has its TE (the motor angle is extrapolated over the time offset).
            assert te.shape[0] == 15_000 and np.all(np.diff(te[:, 0]) > 0)
        assert bag.metadata[AGING_KEY] == repr(AGING)
    summary = analysed.joints['joint_1'].summary()
    assert summary['wear_um'] == pytest.approx(analysed.joints['joint_1'].wear[-1][1] * 1e6)


def test_windows_before_the_time_offset_is_learnt_equal_a_te_monitor_run(sim, analysed):
    """The core stages fed as the live nodes feed them give the same windows."""
    params = ReducerParams()
    ratio = total_ratio(params.geometry)
    with open_bag(sim[0]) as bag:
        js = bag.read_joint_states()['/joint_states']
    cols = [js.names.index(n) for n in ('joint_2', 'joint_2_motor')]
    cleaner, spikes = StreamCleaner(), SpikeFilter(ratio)
    extractor = TEExtractor(ratio, max_gap_s=TwinConfig().max_gap_s)
    calibration = TimeOffsetCalibration(extractor)
    analyzer = WindowAnalyzer(params, window_s=2.0, aging_factor=AGING)
    live = []
    for k in range(0, len(js), 25):     # pieces of 0.1 s (25 samples) until calibrated
        part = slice(k, k + 25)
        clean = cleaner.process(js.stamps_ns[part], js.position[part][:, cols],
                                js.velocity[part][:, cols], js.effort[part][:, cols])
        t_ns, motor, link, effort, velocity = pair_columns(clean, 0, 1)[0]
        keep = spikes.keep(motor, link)
        t = t_ns[keep] * 1e-9
        stream = extractor.update(t, motor[keep], t, link[keep])
        for f in analyzer.update(stream, effort[keep], velocity[keep]):
            calibration.observe(f)
            live.append(record_values(TE_FEATURES, features_record(f, params)))
        if calibration.applied is not None:
            break
    offline = analysed.joints['joint_2'].features
    assert calibration.applied is not None and len(live) >= 5
    np.testing.assert_array_equal(np.array(live), offline[:len(live)])


def test_a_motor_step_of_more_than_half_a_turn_is_fed_in_the_nodes_pieces_until_calibrated(
        sim, tmp_path):
    """
    While the offset is learnt, the TE of a chunk is computed once only when that is exact.

    Ten dropped messages at 250 Hz leave a 44 ms hole (inside the TE's 50 ms gap rule) in
    which the motor turns ~0.9 of a turn: TE extraction over the whole chunk would count a
    motor turn less there, extraction piece by piece does not. The analysis must give the
    windows of the node's 0.1 s pieces.
    """
    with open_bag(sim[0]) as bag:
        js = bag.read_joint_states()['/joint_states']
    stamps = js.stamps_ns.copy()
    stamps[200:211] = stamps[199]       # dropped as duplicates: a hole at a piece boundary
    root = write_bag_dir(tmp_path / 'holes', {'/joint_states': JointStateBatch(
        stamps, js.names, js.position, js.velocity, js.effort)},
        custom_data={AGING_KEY: repr(AGING)})
    params = ReducerParams()
    ratio = total_ratio(params.geometry)
    cols = [js.names.index(n) for n in ('joint_1', 'joint_1_motor')]
    clean = StreamCleaner().process(stamps, js.position[:, cols], js.velocity[:, cols],
                                    js.effort[:, cols])
    t_ns, motor, link, effort, velocity = pair_columns(clean, 0, 1)[0]
    assert np.abs(np.diff(motor)).max() > np.pi
    extractor = TEExtractor(ratio, max_gap_s=TwinConfig().max_gap_s)
    calibration = TimeOffsetCalibration(extractor)
    analyzer = WindowAnalyzer(params, window_s=2.0, aging_factor=AGING)
    live = []
    t = t_ns * 1e-9
    for k in range(0, t.size, 25):      # the node's 0.1 s at 250 Hz
        part = slice(k, k + 25)
        stream = extractor.update(t[part], motor[part], t[part], link[part])
        for f in analyzer.update(stream, effort[part], velocity[part]):
            calibration.observe(f)
            live.append(record_values(TE_FEATURES, features_record(f, params)))
        if calibration.applied is not None:
            break
    offline = analyze_bag(root, tmp_path / 'd').joints['joint_1'].features
    assert calibration.applied is not None and len(live) >= 5
    np.testing.assert_array_equal(np.array(live), offline[:len(live)])


def test_the_worker_and_reader_processes_give_identical_results(sim, analysed, tmp_path):
    # With a worker, joint_2's front runs there too (every sixth joint's does).
    _same_results(analyze_bag(sim[0], tmp_path / 'w', stage_worker=True), analysed)
    _same_results(analyze_bag(sim[0], tmp_path / 'r', stage_worker=True, reader_process=True),
                  analysed)


def test_a_front_in_the_worker_pairs_split_topics_like_one_here(tmp_path):
    spec = SimulationSpec(**{**SPEC.__dict__, 'layout': 'split', 'hours': 1000.0})
    simulate_bag(tmp_path / 'split', spec)
    here = analyze_bag(tmp_path / 'split', tmp_path / 'here')
    _same_results(analyze_bag(tmp_path / 'split', tmp_path / 'worker', stage_worker=True), here)


@pytest.mark.parametrize('reader_process', [False, True], ids=['one process', 'reader process'])
def test_malformed_joint_states_are_skipped_counted_and_reported(sim, tmp_path, reader_process):
    js = _joint_states(sim[0])
    buffer, offsets = encode_joint_states(js.stamps_ns, js.names, js.position, js.velocity,
                                          js.effort)
    payloads = [buffer[a:b].tobytes() for a, b in zip(offsets[:-1], offsets[1:])]
    for k in (100, 5000, 9000):
        payloads[k] = payloads[k][:30]          # cut inside the joint names
    bounds = np.concatenate([[0], np.cumsum([len(x) for x in payloads])])
    root = tmp_path / 'bad'
    root.mkdir()
    with McapBagWriter(root / 'bad_0.mcap') as writer:
        channel = writer.add_topic('/joint_states', JOINT_STATE)
        writer.write_batch(channel, js.stamps_ns, b''.join(payloads), bounds)
    info = bag_metadata(writer.topic_summaries(), [writer.file_summary()],
                        {AGING_KEY: repr(AGING)})
    (root / 'metadata.yaml').write_text(dump_yaml({'rosbag2_bagfile_information': info}))
    result = analyze_bag(root, tmp_path / 'd', stage_worker=reader_process,
                         reader_process=reader_process)
    summary = result.joints['joint_1'].summary()
    assert summary['messages'] == 15_000 - 3 and summary['rejected'] >= 3
    assert result.joints['joint_1'].counts['malformed_messages'] == 3
    assert not result.damaged
    (warning,) = [str(w) for w in result.warnings if 'malformed' in str(w)]
    assert '3 malformed JointState message(s) on /joint_states skipped' in warning


ANALYZE_IN_A_FRESH_PROCESS = """
import json, sys
from reducer_twin.cli import main
code = main(sys.argv[1:])
json.dump({'code': code, 'filterpy': [m for m in sys.modules if m.startswith('filterpy')],
           'scipy.special': [m for m in sys.modules if m.startswith('scipy.special')]},
          sys.stdout)
"""


@pytest.mark.parametrize('stage_process', ['yes', 'no'])
def test_the_analysis_imports_neither_filterpy_nor_scipy_special(sim, tmp_path, stage_process):
    # Importing filterpy's package costs half a second of scipy imports; the estimator
    # computes the scaled sigma points' weights itself (test_sigma_points: the same), and
    # the growth law the log of the normal distribution function (test_normal_cdf), which
    # spares the 0.1 s of importing scipy.special.
    import subprocess
    import sys
    done = subprocess.run([sys.executable, '-c', ANALYZE_IN_A_FRESH_PROCESS, 'analyze',
                           str(sim[0]), '--out', str(tmp_path / 'd'), '--stage-process',
                           stage_process, '--json'], capture_output=True, text=True,
                          timeout=300, check=True)
    # The command's --json comes first, then what the process had imported.
    report = json.loads(done.stdout[done.stdout.rindex('{"code"'):])
    assert report == {'code': 0, 'filterpy': [], 'scipy.special': []}


# --------------------------------------------------------------------------- inputs


def test_compressed_chunks_and_a_bare_mcap_file_analyse_alike(analysed, tmp_path):
    for compression in ('zstd', 'lz4'):
        spec = SimulationSpec(**{**SPEC.__dict__, 'compression': compression})
        simulate_bag(tmp_path / compression, spec)
        _same_results(analyze_bag(tmp_path / compression, tmp_path / f'd_{compression}'),
                      analysed)
    bare = tmp_path / 'zstd' / 'zstd_0.mcap'
    # The aging factor also travels in the MCAP file's own rosbag2 metadata record.
    _same_results(analyze_bag(bare, tmp_path / 'd_bare'), analysed)


def _joint_states(bag_dir):
    with open_bag(bag_dir) as bag:
        return bag.read_joint_states()['/joint_states']


def test_a_split_bag_over_two_files_analyses_like_one_file(sim, analysed, tmp_path):
    js = _joint_states(sim[0])
    root = tmp_path / 'split'
    root.mkdir()
    summaries, topics = [], {}
    for index, part in enumerate((slice(0, 7000), slice(7000, None))):
        with McapBagWriter(root / f'split_{index}.mcap') as writer:
            channel = writer.add_topic('/joint_states', JOINT_STATE)
            buffer, offsets = encode_joint_states(js.stamps_ns[part], js.names,
                                                  js.position[part], js.velocity[part],
                                                  js.effort[part])
            writer.write_batch(channel, js.stamps_ns[part], buffer, offsets)
        summaries.append(writer.file_summary())
        for topic in writer.topic_summaries():
            topics.setdefault(topic['name'], dict(topic, count=0))['count'] += topic['count']
    info = bag_metadata(list(topics.values()), summaries, {AGING_KEY: repr(AGING)})
    (root / 'metadata.yaml').write_text(dump_yaml({'rosbag2_bagfile_information': info}))
    result = analyze_bag(root, tmp_path / 'd')
    assert not result.warnings
    for name in analysed.joints:
        np.testing.assert_array_equal(result.joints[name].features,
                                      analysed.joints[name].features)
        assert result.joints[name].summary() == analysed.joints[name].summary()


def test_a_sqlite3_bag_with_integer_qos_becomes_an_mcap_bag(sim, analysed, tmp_path):
    js = _joint_states(sim[0])
    buffer, offsets = encode_joint_states(js.stamps_ns, js.names, js.position, js.velocity,
                                          js.effort)
    root = tmp_path / 'humble'
    root.mkdir()
    write_joint_states_db3(root / 'humble_0.db3', js.stamps_ns, buffer, offsets,
                           humble_qos(reliability=1))
    # A bag of an older distribution has no aging factor: a real robot's, 1 (the default).
    config = tmp_path / 'twin.yaml'
    config.write_text(f'twin:\n  aging_factor: {AGING}\n')
    result = analyze_bag(root / 'humble_0.db3', tmp_path / 'out',
                         AnalysisSettings.from_config(config))
    assert sorted(p.suffix for p in (tmp_path / 'out').iterdir()) == ['.mcap', '.yaml']
    for name in analysed.joints:
        np.testing.assert_array_equal(result.joints[name].features,
                                      analysed.joints[name].features)
    # A robot's recording without an aging factor is aged in real time, without a word.
    plain = analyze_bag(root, tmp_path / 'out1')
    assert plain.aging_factor == 1.0
    assert not [w for w in plain.warnings if 'aging' in w.message]


def test_a_simulated_recording_that_lost_its_aging_factor_says_1_is_assumed(sim, tmp_path):
    root = tmp_path / 'stripped'
    shutil.copytree(sim[0], root)
    meta = root / 'metadata.yaml'
    info = yaml.safe_load(meta.read_text())
    info['rosbag2_bagfile_information'].pop('custom_data')
    meta.write_text(yaml.safe_dump(info))
    result = analyze_bag(root, tmp_path / 'out')
    assert result.aging_factor == 1.0
    said = [w.message for w in result.warnings if AGING_KEY in w.message]
    assert len(said) == 1 and 'aging factor 1 assumed' in said[0]
    assert 'twin.aging_factor' in said[0] and '/ground_truth' in said[0]


def test_split_link_and_motor_topics_are_paired_by_the_ingestion_rules(tmp_path):
    spec = SimulationSpec(**{**SPEC.__dict__, 'layout': 'split', 'joints': 1,
                             'wear_rate_scales': (1.0,)})
    truth = simulate_bag(tmp_path / 'split', spec).truth['joint_1']
    result = analyze_bag(tmp_path / 'split', tmp_path / 'd')
    assert result.plan.motor_topic == '/motor_states'
    summary = result.joints['joint_1'].summary()
    assert summary['messages'] == 2 * 15_000 and summary['rejected'] == 0
    assert summary['wear_um'] == pytest.approx(truth['true_wear_um'], rel=0.10)


def test_a_250_hz_recording_reads_its_wear_and_life_as_at_1_khz(tmp_path):
    # The bins near the test torque, which the load passes quickly at each reversal, were
    # dropped from 200 Hz up: the lost motion came from the bins beyond 200 N*m, and the
    # wear read 11 % low on both joints.
    spec = SimulationSpec(hours=200.0, aging_factor=3600.0, joints=2, rate_hz=250.0, seed=7,
                          wear_rate_scales=(10.0, 5.0))
    truth = simulate_bag(tmp_path / 'bag', spec).truth
    result = analyze_bag(tmp_path / 'bag', tmp_path / 'd')
    for joint, got in result.joints.items():
        summary = got.summary()
        assert summary['wear_um'] == pytest.approx(truth[joint]['true_wear_um'], rel=0.05)
        assert summary['rul_p10_h'] <= truth[joint]['true_rul_h'] <= summary['rul_p90_h']


def test_motor_angles_already_divided_by_the_ratio_are_read_with_the_config(sim, analysed,
                                                                            tmp_path):
    js = _joint_states(sim[0])
    position = js.position.copy()
    ratio = total_ratio(ReducerParams().geometry)
    position[:, 1::2] /= ratio
    batch = JointStateBatch(js.stamps_ns, js.names, position, js.velocity, js.effort)
    write_bag_dir(tmp_path / 'output_side', {'/joint_states': batch},
                  custom_data={AGING_KEY: repr(AGING)})
    config = tmp_path / 'twin.yaml'
    config.write_text('twin:\n  motor_angles: output\n')
    result = analyze_bag(tmp_path / 'output_side', tmp_path / 'd',
                         AnalysisSettings.from_config(config))
    for name, res in result.joints.items():
        assert res.summary()['wear_um'] == pytest.approx(
            analysed.joints[name].summary()['wear_um'], rel=0.02)


def test_dropped_samples_count_for_the_joint_that_had_them(sim, tmp_path):
    js = _joint_states(sim[0])
    position = js.position.copy()
    position[1000:1010, js.names.index('joint_2')] = np.nan
    batch = JointStateBatch(js.stamps_ns, js.names, position, js.velocity, js.effort)
    write_bag_dir(tmp_path / 'nan', {'/joint_states': batch},
                  custom_data={AGING_KEY: repr(AGING)})
    result = analyze_bag(tmp_path / 'nan', tmp_path / 'd')
    assert result.joints['joint_1'].summary()['rejected'] == 0
    assert result.joints['joint_2'].counts['stream_non_finite'] == 10
    assert result.joints['joint_2'].summary()['rejected'] >= 10


def test_the_config_chooses_joints_and_overrides_the_bags_aging_factor(sim, tmp_path, capsys):
    config = tmp_path / 'twin.yaml'
    config.write_text('twin:\n  joints: [joint_2]\n  aging_factor: 1.0\n'
                      'life:\n  warn_s: 1.0e9\n  error_s: 1.0e8\n')
    code, out, err = _run(['analyze', sim[0], '--out', tmp_path / 'd', '--config', config,
                           '--json'], capsys)
    assert code == 0, err
    joints = json.loads(out)['joints']
    assert list(joints) == ['joint_2']
    # The configured aging factor replaces the bag's own in the derived bag.
    meta = yaml.safe_load((tmp_path / 'd' / 'metadata.yaml').read_text())
    custom = meta['rosbag2_bagfile_information']['custom_data']
    assert float(custom['reducer_twin.aging_factor']) == 1.0


def _records(bag_dir, topic, layout):
    """Read a derived topic back with the mcap library; return its records."""
    out = []
    for path in sorted(Path(bag_dir).glob('*.mcap')):
        with open(path, 'rb') as f:
            reader = make_reader(f, decoder_factories=[DecoderFactory()])
            for _, _, _, msg in reader.iter_decoded_messages(topics=[topic]):
                out.append(dict(zip(layout.fields, msg.data)))
    return out


def test_the_config_gives_one_joint_its_own_reducer_and_leaves_the_other_alone(
        sim, analysed, tmp_path, capsys):
    # joint_2 carries a reducer rated for twice the life (a file beside the configuration):
    # its catalogue life doubles, nothing else of either joint changes.
    (tmp_path / 'long-life.yaml').write_text('reducer:\n  rating:\n    rated_life: 4.32e7\n')
    config = tmp_path / 'twin.yaml'
    config.write_text('reducers:\n  joint_2: long-life.yaml\n')
    code, out, err = _run(['analyze', sim[0], '--out', tmp_path / 'd', '--config', config,
                           '--json'], capsys)
    assert code == 0, err
    for joint in ('joint_1', 'joint_2'):
        own = _records(tmp_path / 'd', f'/reducer_twin/{joint}/remaining_life', REMAINING_LIFE)
        common = [dict(zip(REMAINING_LIFE.fields, row))
                  for row in analysed.joints[joint].life.tolist()]
        assert len(own) == len(common) > 5
        cat = [(a['catalogue_life_s'], b['catalogue_life_s']) for a, b in zip(common, own)
               if np.isfinite(a['catalogue_life_s'])]
        assert len(cat) > 5
        factor = 2.0 if joint == 'joint_2' else 1.0
        np.testing.assert_allclose([b for _, b in cat], [factor * a for a, _ in cat],
                                   rtol=1e-12)
        rest = [k for k in REMAINING_LIFE.fields if k != 'catalogue_life_s']
        np.testing.assert_array_equal([[b[k] for k in rest] for b in own],
                                      [[a[k] for k in rest] for a in common])
        wear = _records(tmp_path / 'd', f'/reducer_twin/{joint}/wear', WEAR_ESTIMATE)
        np.testing.assert_array_equal([list(w.values()) for w in wear],
                                      analysed.joints[joint].wear)


@pytest.mark.parametrize('how', [['--jobs', '2'], ['--stage-process', 'yes']],
                         ids=['two processes', 'one after the other, one estimator worker'])
def test_several_bags_get_their_own_outputs_and_a_nested_json(sim, analysed, tmp_path, capsys,
                                                              how):
    second = tmp_path / 'copy'
    shutil.copytree(sim[0], second)
    code, out, err = _run(['analyze', sim[0], second, '--out', tmp_path / 'all', *how,
                           '--json', '--report', tmp_path / 'report'], capsys)
    assert code == 0, err
    data = json.loads(out)
    assert set(data) == {'bags', 'messages_per_s'} and set(data['bags']) == {'robot', 'copy'}
    for name in ('robot', 'copy'):
        assert data['bags'][name]['out'] == str(tmp_path / 'all' / name)
        assert (tmp_path / 'all' / name / 'metadata.yaml').is_file()
        assert (tmp_path / 'report' / name / 'index.html').is_file()
        for joint, res in analysed.joints.items():
            assert data['bags'][name]['joints'][joint] == res.summary()


def test_one_bad_bag_among_several_fails_alone(sim, tmp_path, capsys):
    code, out, err = _run(['analyze', sim[0], REAL_BAGS / 'talker', '--out', tmp_path / 'all',
                           '--json'], capsys)
    assert code == 1
    (line,) = _errors(err)
    assert 'talker: no sensor_msgs/msg/JointState topic' in line
    bags = json.loads(out)['bags']
    assert list(bags) == ['robot', 'talker'] and 'found: ' in bags['talker']['error']
    assert set(bags['robot']['joints']) == {'joint_1', 'joint_2'}
    assert (tmp_path / 'all' / 'robot' / 'metadata.yaml').is_file()
    assert not (tmp_path / 'all' / 'talker').exists()


# --------------------------------------------------------------------------- failures


REAL = ['talker', 'wbag-split', 'cdr_test', 'topics_and_service_events', 'sqlite3-talker',
        'talker/talker.mcap']
FIRST_TOPIC = {'talker': '/topic (std_msgs/msg/String)', 'wbag-split': 'AAA (std_msgs/msg/String)',
               'cdr_test': '/test_topic (test_msgs/msg/BasicTypes)',
               'topics_and_service_events': '/test_service1/_service_event',
               'sqlite3-talker': '/topic (std_msgs/msg/String)',
               'talker/talker.mcap': '/rosout (rcl_interfaces/msg/Log)'}


@pytest.mark.parametrize('name', REAL)
def test_real_rosbag2_bags_without_joint_states_are_rejected_naming_their_topics(
        name, tmp_path, capsys):
    code, out, err = _run(['analyze', REAL_BAGS / name, '--out', tmp_path / 'o'], capsys)
    assert code == 1
    (line,) = _errors(err)
    assert f'{REAL_BAGS / name}: no sensor_msgs/msg/JointState topic; found: ' in line
    assert FIRST_TOPIC[name] in line
    assert 'Traceback' not in err + out and not (tmp_path / 'o').exists()


def test_a_bag_whose_joint_states_have_no_motor_entries_says_which_names_it_found(tmp_path):
    batch = JointStateBatch(np.arange(50, dtype=np.int64) * 1_000_000, ('shoulder', 'elbow'),
                            np.zeros((50, 2)), np.zeros((50, 2)), np.zeros((50, 2)))
    write_bag_dir(tmp_path / 'arm', {'/arm/joint_states': batch})
    with pytest.raises(BagError, match=r"no motor/link encoder pairs.*'shoulder', 'elbow'"):
        analyze_bag(tmp_path / 'arm', tmp_path / 'd')


def test_motor_entries_under_another_suffix_are_named_with_the_setting_that_reads_them(
        tmp_path):
    names = ('shoulder', 'elbow', 'shoulder_enc', 'elbow_enc', 'elbow_10')
    batch = JointStateBatch(np.arange(50, dtype=np.int64) * 1_000_000, names,
                            np.zeros((50, 5)), np.zeros((50, 5)), np.zeros((50, 5)))
    write_bag_dir(tmp_path / 'arm', {'/arm/joint_states': batch})
    with pytest.raises(BagError) as refused:
        analyze_bag(tmp_path / 'arm', tmp_path / 'd')
    assert ('its entries pair as <joint> and <joint>_enc (elbow with elbow_enc, '
            'shoulder with shoulder_enc): if those are the motor encoders, set '
            "twin.motor_suffix: '_enc' in --config") in str(refused.value)
    # Said, not used: with the setting the pairs are found (and judged by their data:
    # encoders that never move are not observed).
    res = analyze_bag(tmp_path / 'arm', tmp_path / 'e', AnalysisSettings(motor_suffix='_enc'))
    assert sorted(res.joints) == ['elbow', 'shoulder']
    assert not any(j.summary()['observed'] for j in res.joints.values())


def test_entries_that_pair_with_nothing_are_said_not_analysed(tmp_path):
    # A joint whose motor encoder is not published vanished from the results without a word.
    names = ('shoulder', 'shoulder_motor', 'elbow', 'gripper', 'wrist_motor')
    batch = JointStateBatch(np.arange(50, dtype=np.int64) * 1_000_000, names,
                            np.zeros((50, 5)), np.zeros((50, 5)), np.zeros((50, 5)))
    write_bag_dir(tmp_path / 'arm', {'/joint_states': batch})
    res = analyze_bag(tmp_path / 'arm', tmp_path / 'd')
    assert list(res.joints) == ['shoulder']
    said = [w.message for w in res.warnings if 'not analysed' in w.message]
    assert said == ['/joint_states also carries elbow, gripper without a motor entry '
                    '(<joint>_motor) and wrist_motor without a link entry: not analysed; a '
                    "reducer among them needs both its encoders published under the twin's "
                    'names (twin.motor_suffix, twin.motor_topic; twin.joints chooses the '
                    'joints)']
    # Joints chosen in the configuration: the others are not said.
    res = analyze_bag(tmp_path / 'arm', tmp_path / 'e', AnalysisSettings(joints=('shoulder',)))
    assert not [w for w in res.warnings if 'not analysed' in w.message]


def test_a_truncated_bag_is_analysed_up_to_the_damage_and_exits_1(sim, tmp_path, capsys):
    damaged = tmp_path / 'cut'
    shutil.copytree(sim[0], damaged)
    mcap = damaged / 'robot_0.mcap'
    data = mcap.read_bytes()
    mcap.write_bytes(data[:int(len(data) * 0.6)])
    code, out, err = _run(['analyze', damaged, '--out', tmp_path / 'd', '--json'], capsys)
    assert code == 1 and 'Traceback' not in err
    warnings = [line for line in err.splitlines() if line.startswith('WARNING:')]
    assert any(f'{mcap}: reading stopped at byte' in line for line in warnings), err
    joints = json.loads(out)['joints']
    assert 0 < joints['joint_1']['messages'] < 15_000
    with open_bag(tmp_path / 'd') as bag:
        assert bag.topics['/reducer_twin/joint_1/te_features'].count > 0


def _full(tmp_path):
    path = tmp_path / 'full'
    path.mkdir()
    (path / 'keep.txt').write_text('x')
    return path


BAD_INPUTS = [
    ('no bag', lambda t, b: ['analyze', '--out', t / 'o'], 2, 'BAG'),
    ('missing bag', lambda t, b: ['analyze', t / 'nope', '--out', t / 'o'], 1, 'nope'),
    ('--jobs 0', lambda t, b: ['analyze', b, '--out', t / 'o', '--jobs', '0'], 1, '--jobs'),
    ('non-numeric --jobs', lambda t, b: ['analyze', b, '--out', t / 'o', '--jobs', 'x'], 2,
     "'x'"),
    ('non-empty --out', lambda t, b: ['analyze', b, '--out', _full(t)], 1, 'not empty'),
    ('missing --config', lambda t, b: ['analyze', b, '--out', t / 'o', '--config',
                                       t / 'none.yaml'], 1, 'none.yaml'),
    ('unknown config key', lambda t, b: ['analyze', b, '--out', t / 'o', '--config',
                                         _yaml(t, 'twin:\n  speed: 3\n')], 1, 'speed'),
    ('bad aging factor', lambda t, b: ['analyze', b, '--out', t / 'o', '--config',
                                       _yaml(t, 'twin:\n  aging_factor: -2\n')], 1,
     'twin.aging_factor'),
    ('aging factor 0', lambda t, b: ['analyze', b, '--out', t / 'o', '--config',
                                     _yaml(t, 'twin:\n  aging_factor: 0\n')], 1,
     'twin.aging_factor must be a number in (0, 1e9]'),
    ('missing configured joint', lambda t, b: ['analyze', b, '--out', t / 'o', '--config',
                                               _yaml(t, 'twin:\n  joints: [wrist]\n')], 1,
     "['wrist']"),
]


def _yaml(tmp_path, text):
    path = tmp_path / 'bad.yaml'
    path.write_text(text)
    return path


@pytest.mark.parametrize('make, code, fragment', [row[1:] for row in BAD_INPUTS],
                         ids=[row[0] for row in BAD_INPUTS])
def test_bad_inputs_print_one_error_line_without_a_traceback(sim, tmp_path, capsys, make, code,
                                                             fragment):
    got, out, err = _run(make(tmp_path, sim[0]), capsys)
    assert got == code
    (line,) = _errors(err)
    assert fragment in line, line
    assert 'Traceback' not in err + out and out == ''


def test_a_used_unit_seen_briefly_is_said_to_have_the_models_remaining_life(tmp_path, capsys):
    # A twin without state on a unit 6000 h into its life, for 20 h: the wear is read, the
    # unit's own rate cannot be, and the remaining life is the model's at this duty. It was
    # given as the unit's, without a word.
    spec = SimulationSpec(hours=20.0, aging_factor=1800.0, joints=1, rate_hz=250.0, seed=3,
                          load_torque_nm=1.2 * 784.0, start_hours=6000.0)
    simulate_bag(tmp_path / 'bag', spec)
    code, out, err = _run(['analyze', tmp_path / 'bag', '--out', tmp_path / 'd', '--json'],
                          capsys)
    assert code == 0
    joint = json.loads(out)['joints']['joint_1']
    assert joint['observed'] and joint['rate_resolved'] is False
    (line,) = [x for x in err.splitlines() if "joint_1: this unit's own wear rate" in x]
    assert line.startswith('WARNING: ')
    assert 'is not yet resolved (ln-rate sd' in line and 'cannot tell apart' in line
    assert line.endswith('analyse its recordings in time order with --store, or give its '
                         'operating time before the recording (service_time_s in --config: the '
                         'hour meter)')


def test_a_unit_followed_from_new_has_its_own_rate(analysed):
    for res in analysed.joints.values():
        assert res.summary()['rate_resolved'] is True
