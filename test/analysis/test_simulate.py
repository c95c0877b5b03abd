"""reducer-twin simulate: a rosbag2 bag of simulated joints, as ros2 bag record writes it."""

import json
import math
from pathlib import Path

from mcap.reader import make_reader
import numpy as np
import pytest
from reducer_twin.analysis.pipeline import analyze_bag
from reducer_twin.analysis.simulate import AGING_KEY, ROBOT_KEY, SIMULATION_KEY, SimulationSpec
from reducer_twin.analysis.simulate import simulate_bag, START_HOURS_KEY, START_NS
from reducer_twin.cli import main
from reducer_twin.core.params import ReducerParams
from reducer_twin.core.simulator import JointSimulator, SimConfig
from reducer_twin.core.units import HOUR
from reducer_twin.io.bag import open_bag
from reducer_twin.msg_adapters.layouts import GROUND_TRUTH
from reducer_twin.msg_adapters.multiarray_cdr import decode_layout_batch
from rosbags.highlevel import AnyReader
from rosbags.typesys import get_typestore, Stores
import yaml

# 400 h in 8 s of stream at 250 Hz: 2000 ticks per joint.
SMALL = SimulationSpec(hours=400.0, aging_factor=180_000.0, joints=2, rate_hz=250.0, seed=7,
                       wear_rate_scales=(1.0, 2.0))


@pytest.fixture(scope='module')
def small_bag(tmp_path_factory):
    out = tmp_path_factory.mktemp('sim') / 'small'
    return out, simulate_bag(out, SMALL)


def _run(argv, capsys):
    try:
        code = main(argv)
    except SystemExit as exit_:
        code = exit_.code
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def test_the_bag_is_a_rosbag2_directory_with_metadata_version_9_and_mcap_profile_ros2(small_bag):
    out, _ = small_bag
    assert sorted(p.name for p in out.iterdir()) == ['metadata.yaml', 'small_0.mcap']
    info = yaml.safe_load((out / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    assert info['version'] == 9 and info['storage_identifier'] == 'mcap'
    assert info['relative_file_paths'] == ['small_0.mcap']
    topics = {t['topic_metadata']['name']: t for t in info['topics_with_message_count']}
    assert topics['/joint_states']['message_count'] == 2000
    assert topics['/joint_states']['topic_metadata']['type'] == 'sensor_msgs/msg/JointState'
    assert info['custom_data'][AGING_KEY] == '180000.0'
    settings = json.loads(info['custom_data'][SIMULATION_KEY])
    assert settings['seed'] == 7 and settings['wear_rate_scales'] == [1.0, 2.0]
    with open(out / 'small_0.mcap', 'rb') as stream:
        reader = make_reader(stream)
        assert reader.get_header().profile == 'ros2'
        summary = reader.get_summary()
        assert {s.encoding for s in summary.schemas.values()} == {'ros2msg'}
        for channel in summary.channels.values():
            assert channel.message_encoding == 'cdr'
            assert channel.metadata['topic_type_hash'].startswith('RIHS01_')
            assert 'reliability: reliable' in channel.metadata['offered_qos_profiles']
        records = {m.name: m.metadata for m in reader.iter_metadata()}
    assert AGING_KEY in records['rosbag2']['serialized_metadata']


def test_joint_states_are_what_the_simulator_node_publishes(small_bag):
    out, _ = small_bag
    with open_bag(out) as bag:
        js = bag.read_joint_states()['/joint_states']
    assert js.names == ('joint_1', 'joint_1_motor', 'joint_2', 'joint_2_motor')
    params = ReducerParams()
    for k in range(2):
        cfg = SimConfig(name=f'joint_{k + 1}', exact_mesh=False, rate_hz=250.0,
                        aging_factor=180_000.0, wear_rate_scale=SMALL.wear_rate_scales[k],
                        seed=7 + k)
        expected = JointSimulator(params, cfg).step(2000)
        np.testing.assert_array_equal(js.position[:, 2 * k], expected.link_angle)
        np.testing.assert_array_equal(js.position[:, 2 * k + 1], expected.motor_angle)
        np.testing.assert_array_equal(js.velocity[:, 2 * k], expected.link_velocity)
        np.testing.assert_array_equal(js.effort[:, 2 * k], expected.effort)
        assert np.isnan(js.velocity[:, 2 * k + 1]).all()
        assert np.isnan(js.effort[:, 2 * k + 1]).all()
    np.testing.assert_array_equal(js.stamps_ns, START_NS + np.arange(2000) * 4_000_000)
    np.testing.assert_array_equal(js.log_time_ns, js.stamps_ns)


def test_the_summary_truth_is_the_simulators_truth_at_the_end_of_the_bag(small_bag):
    _, result = small_bag
    params = ReducerParams()
    for k, name in enumerate(('joint_1', 'joint_2')):
        cfg = SimConfig(name=name, exact_mesh=False, rate_hz=250.0, aging_factor=180_000.0,
                        wear_rate_scale=SMALL.wear_rate_scales[k], seed=7 + k)
        sim = JointSimulator(params, cfg)
        sim.step(2000)
        truth = result.truth[name]
        assert truth['true_wear_um'] == pytest.approx(sim.truth().wear * 1e6, rel=1e-12)
        assert truth['true_rul_h'] == pytest.approx(sim.true_rul_s() / HOUR, rel=1e-12)
        assert truth['wear_rate_scale'] == SMALL.wear_rate_scales[k]
    assert result.as_json() == {'joints': result.truth, 'messages': 2000}
    # The faster-wearing joint has less life left.
    assert result.truth['joint_2']['true_rul_h'] < result.truth['joint_1']['true_rul_h']


def test_ground_truth_is_recorded_every_second_and_at_the_end(small_bag):
    out, result = small_bag
    with open_bag(out) as bag:
        topic = '/reducer_twin/joint_2/ground_truth'
        payloads = [raw.payload(i) for _, raw in bag.iter_raw([topic]) for i in range(len(raw))]
    rows = decode_layout_batch(GROUND_TRUTH, payloads)
    field = GROUND_TRUTH.fields.index
    np.testing.assert_allclose(rows[:, field('stamp_s')], START_NS * 1e-9 + np.arange(1, 9),
                               rtol=0, atol=1e-6)
    np.testing.assert_allclose(rows[:, field('exposure_s')], np.arange(1, 9) * 180_000.0)
    assert np.all(np.diff(rows[:, field('wear_m')]) > 0)
    last = rows[-1]
    assert last[field('wear_m')] * 1e6 == pytest.approx(result.truth['joint_2']['true_wear_um'])
    assert last[field('true_rul_s')] / HOUR == pytest.approx(
        result.truth['joint_2']['true_rul_h'])
    assert last[field('aging_factor')] == 180_000.0 and last[field('wear_rate_scale')] == 2.0


def test_the_bag_reads_with_rosbags_anyreader(small_bag):
    out, _ = small_bag
    store = get_typestore(Stores.ROS2_JAZZY)
    with AnyReader([out], default_typestore=store) as reader:
        counts = {}
        for connection, _, raw in reader.messages():
            msg = reader.deserialize(raw, connection.msgtype)
            counts[connection.topic] = counts.get(connection.topic, 0) + 1
            if connection.topic == '/joint_states':
                assert list(msg.name) == ['joint_1', 'joint_1_motor', 'joint_2', 'joint_2_motor']
    assert counts['/joint_states'] == 2000 and counts['/reducer_twin/joint_1/ground_truth'] == 8


def test_the_split_layout_puts_the_motor_side_on_motor_states(tmp_path):
    spec = SimulationSpec(hours=20.0, aging_factor=36_000.0, joints=2, rate_hz=200.0,
                          layout='split', compression='zstd')
    result = simulate_bag(tmp_path / 'split', spec)
    assert result.messages == 2 * 400
    with open_bag(tmp_path / 'split') as bag:
        got = bag.read_joint_states()
    link, motor = got['/joint_states'], got['/motor_states']
    assert link.names == motor.names == ('joint_1', 'joint_2')
    np.testing.assert_array_equal(link.stamps_ns, motor.stamps_ns)
    assert np.isnan(motor.velocity).all()
    ratio = np.median(motor.position[1:, 0] - motor.position[0, 0]) / np.median(
        link.position[1:, 0] - link.position[0, 0])
    assert ratio == pytest.approx(81.0, rel=0.01)


def test_a_split_layout_bag_whose_topics_fill_separate_chunks_analyses_to_the_truth(tmp_path):
    # A minute at 500 Hz: the writer fills /joint_states' chunks, then /motor_states', so
    # the two topics lie in chunks that overlap in log time, tens of seconds apart in the
    # file (B3 of the red-team report: both joints "not observed" when read in file order).
    spec = SimulationSpec(hours=6000.0, aging_factor=360_000.0, joints=2, rate_hz=500.0,
                          seed=7, wear_rate_scales=(0.6, 1.8), layout='split')
    truth = simulate_bag(tmp_path / 'split', spec).truth
    with open(next((tmp_path / 'split').glob('*.mcap')), 'rb') as stream:
        summary = make_reader(stream).get_summary()
    topic = {cid: channel.topic for cid, channel in summary.channels.items()}
    spans = {name: [(c.message_start_time, c.message_end_time) for c in summary.chunk_indexes
                    if {topic[cid] for cid in c.message_index_offsets} == {name}]
             for name in ('/joint_states', '/motor_states')}
    assert spans['/motor_states'][0][0] < spans['/joint_states'][-1][1], 'chunks overlap'
    result = analyze_bag(tmp_path / 'split', tmp_path / 'derived')
    for name in ('joint_1', 'joint_2'):
        got = result.joints[name].summary()
        # Read in log-time order, link and motor samples pair as in the one-topic bag.
        assert got['observed'] and got['rejected'] == 0, got['reason']
        assert got['wear_um'] == pytest.approx(truth[name]['true_wear_um'], rel=0.10)


def test_the_cli_prints_the_issue_json_and_writes_the_bag(tmp_path, capsys):
    out = tmp_path / 'bag'
    code, stdout, err = _run(['simulate', '--out', str(out), '--hours', '50', '--aging-factor',
                              '90000', '--joints', '1', '--rate-hz', '100', '--seed', '2',
                              '--wear-rate-scale', '1.5', '--json'], capsys)
    assert code == 0, err
    data = json.loads(stdout)
    assert set(data) == {'joints', 'messages'} and data['messages'] == 200
    assert set(data['joints']['joint_1']) == {'true_wear_um', 'true_rul_h', 'wear_rate_scale'}
    assert data['joints']['joint_1']['wear_rate_scale'] == 1.5
    assert (out / 'metadata.yaml').is_file()
    code, stdout, _ = _run(['simulate', '--out', str(out), '--hours', '50', '--aging-factor',
                            '90000', '--rate-hz', '100', '--overwrite'], capsys)
    assert code == 0 and 'true wear' in stdout


def _file(tmp_path):
    path = tmp_path / 'a_file'
    path.write_text('x')
    return str(path)


def _full_dir(tmp_path):
    path = tmp_path / 'full'
    path.mkdir()
    (path / 'notes.txt').write_text('mine')
    return str(path)


BAD_INPUTS = [
    ('non-numeric --hours', ['--hours', 'abc'], 2, 'abc'),
    ('non-numeric --wear-rate-scale', ['--wear-rate-scale', 'fast'], 2, 'fast'),
    ('--joints 0', ['--joints', '0'], 1, '--joints'),
    ('--joints 13', ['--joints', '13'], 1, '1 .. 12'),
    ('negative --hours', ['--hours', '-5'], 1, '--hours'),
    ('NaN --aging-factor', ['--aging-factor', 'nan'], 1, '--aging-factor'),
    ('zero --rate-hz', ['--rate-hz', '0'], 1, '--rate-hz'),
    ('negative --seed', ['--seed', '-1'], 1, '--seed'),
    ('scales for the wrong joint count', ['--joints', '3', '--wear-rate-scale', '1,2'], 1,
     '3 values'),
    ('less than one sample', ['--hours', '1e-6'], 1, 'less than one sample'),
    ('too many messages', ['--hours', '1e6', '--aging-factor', '1', '--rate-hz', '1e5'], 1,
     'at most'),
]


@pytest.mark.parametrize('extra, code, fragment', [row[1:] for row in BAD_INPUTS],
                         ids=[row[0] for row in BAD_INPUTS])
def test_bad_inputs_print_one_error_line_and_write_nothing(tmp_path, capsys, extra, code,
                                                           fragment):
    out = tmp_path / 'never'
    got, stdout, err = _run(['simulate', '--out', str(out), *extra], capsys)
    assert got == code
    errors = [line for line in err.splitlines() if line.startswith('ERROR:')]
    assert len(errors) == 1 and fragment in errors[0], err
    assert 'Traceback' not in err and not out.exists()


@pytest.mark.parametrize('make, fragment', [(_file, 'not a directory'),
                                            (_full_dir, 'not empty')],
                         ids=['--out is a file', '--out is not empty'])
def test_an_existing_out_that_is_not_an_empty_directory_is_refused(tmp_path, capsys, make,
                                                                   fragment):
    path = make(tmp_path)
    code, _, err = _run(['simulate', '--out', path, '--hours', '1'], capsys)
    assert code == 1 and fragment in err and 'Traceback' not in err
    if Path(path).is_dir():
        assert sorted(p.name for p in Path(path).iterdir()) == ['notes.txt']


def test_the_stream_length_follows_hours_and_aging_factor():
    spec = SimulationSpec(hours=1000.0, aging_factor=3600.0, rate_hz=1000.0)
    assert spec.messages == 1_000_000 and math.isclose(spec.stream_s, 1000.0)


def _contents(bag_dir):
    """Return the JointState rows, ground-truth records and custom_data of a bag."""
    with open_bag(bag_dir) as bag:
        js = bag.read_joint_states()['/joint_states']
        custom = dict(bag.metadata)
        truth = {}
        for topic, raw in bag.iter_raw([t for t in bag.topics if t.endswith('ground_truth')]):
            payloads = [raw.payload(i) for i in range(len(raw))]
            truth.setdefault(topic, []).append(decode_layout_batch(GROUND_TRUTH, payloads))
    return js, {t: np.concatenate(v) for t, v in truth.items()}, custom


@pytest.mark.parametrize('rate_hz, aging', [(500.0, 360_000.0), (250.0, 9_000.0)],
                         ids=['whole blocks', 'partial blocks'])
def test_two_segments_of_a_life_join_exactly_into_one_bag_of_the_whole_span(
        tmp_path, rate_hz, aging):
    common = {'aging_factor': aging, 'joints': 2, 'rate_hz': rate_hz, 'seed': 11, 'robot': 'r1'}
    first = simulate_bag(tmp_path / 'a', SimulationSpec(hours=2000.0, **common))
    second = simulate_bag(tmp_path / 'b', SimulationSpec(hours=2000.0, start_hours=2000.0,
                                                         **common))
    whole = simulate_bag(tmp_path / 'ab', SimulationSpec(hours=4000.0, **common))
    js_a, truth_a, custom_a = _contents(tmp_path / 'a')
    js_b, truth_b, custom_b = _contents(tmp_path / 'b')
    js_ab, truth_ab, _ = _contents(tmp_path / 'ab')
    # The samples and stamps of the two segments are those of the whole life, in order.
    np.testing.assert_array_equal(np.concatenate([js_a.stamps_ns, js_b.stamps_ns]),
                                  js_ab.stamps_ns)
    np.testing.assert_array_equal(np.concatenate([js_a.position, js_b.position]),
                                  js_ab.position)
    assert js_b.stamps_ns[0] > js_a.stamps_ns[-1]
    for name in first.truth:
        topic = f'/reducer_twin/{name}/ground_truth'
        wear, hours = (GROUND_TRUTH.fields.index(k) for k in ('wear_m', 'exposure_s'))
        # The truth at the second segment's start is the first segment's end, exactly.
        assert truth_b[topic][0, wear] == truth_a[topic][-1, wear]
        assert truth_b[topic][0, hours] == pytest.approx(2000.0 * HOUR)
        assert truth_b[topic][-1, wear] == truth_ab[topic][-1, wear]
        assert second.truth[name] == whole.truth[name]
        assert 0.0 < first.truth[name]['true_wear_um'] < second.truth[name]['true_wear_um']
    assert (custom_a[ROBOT_KEY], custom_a[START_HOURS_KEY]) == ('r1', '0.0')
    assert (custom_b[ROBOT_KEY], custom_b[START_HOURS_KEY]) == ('r1', '2000.0')


def test_the_cli_records_robot_and_start_hours_and_refuses_bad_ones(tmp_path, capsys):
    out = tmp_path / 'later'
    code, _, err = _run(['simulate', '--out', str(out), '--hours', '50', '--aging-factor',
                         '180000', '--rate-hz', '100', '--robot', 'cell-7/r2',
                         '--start-hours', '300'], capsys)
    assert code == 0, err
    _, truth, custom = _contents(out)
    assert custom[ROBOT_KEY] == 'cell-7/r2' and float(custom[START_HOURS_KEY]) == 300.0
    hours = truth['/reducer_twin/joint_1/ground_truth'][:, GROUND_TRUTH.fields.index(
        'exposure_s')] / HOUR
    assert hours[0] >= 300.0 and hours[-1] == pytest.approx(350.0)
    for extra, fragment in ((['--start-hours', '-5'], '--start-hours'),
                            (['--robot', 'two words'], '--robot')):
        code, _, err = _run(['simulate', '--out', str(tmp_path / 'bad'), '--hours', '1',
                             *extra], capsys)
        errors = [line for line in err.splitlines() if line.startswith('ERROR:')]
        assert code == 1 and len(errors) == 1 and fragment in errors[0], err
        assert not (tmp_path / 'bad').exists()


def test_a_start_that_would_replay_a_life_for_hours_is_refused_naming_start_wear(
        tmp_path, capsys):
    # An 8 000-h unit at aging factor 1 continues its seed's life from the first sample:
    # 2.9e10 samples a joint, over an hour of work with nothing said.
    code, _, err = _run(['simulate', '--out', str(tmp_path / 'rt'), '--hours', '0.1',
                         '--aging-factor', '1', '--start-hours', '8000'], capsys)
    (line,) = [x for x in err.splitlines() if x.startswith('ERROR:')]
    assert code == 1 and not (tmp_path / 'rt').exists()
    assert '--start-hours 8000 at --aging-factor 1' in line and '2.88e+10 samples' in line
    assert 'expected at most 3e+09' in line and '--start-wear-um' in line
    # A used unit met at its wear instead: the life before is not simulated.
    code, _, err = _run(['simulate', '--out', str(tmp_path / 'rt'), '--hours', '0.01',
                         '--aging-factor', '1', '--start-wear-um', '6.8', '--json'], capsys)
    assert code == 0, err
    _, truth, _ = _contents(tmp_path / 'rt')
    wear = truth['/reducer_twin/joint_1/ground_truth'][:, GROUND_TRUTH.fields.index('wear_m')]
    assert wear[0] == pytest.approx(6.8e-6, rel=1e-6) and wear[-1] < 6.801e-6
    code, _, err = _run(['simulate', '--out', str(tmp_path / 'both'), '--hours', '1',
                         '--start-wear-um', '6.8', '--start-hours', '10'], capsys)
    assert code == 1 and 'expected one of them' in err
    # One wear per joint, as --wear-rate-scale takes one scale per joint.
    code, out, err = _run(['simulate', '--out', str(tmp_path / 'two'), '--hours', '0.01',
                           '--aging-factor', '1', '--joints', '2', '--start-wear-um', '3,9',
                           '--json'], capsys)
    assert code == 0, err
    assert [round(j['true_wear_um'], 3) for j in json.loads(out)['joints'].values()] == [3.0, 9.0]
    code, _, err = _run(['simulate', '--out', str(tmp_path / 'three'), '--hours', '1',
                         '--joints', '2', '--start-wear-um', '3,9,4'], capsys)
    assert code == 1 and '--start-wear-um' in err and 'one value or 2 values' in err
