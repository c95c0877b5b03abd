"""
Spec: ``analyze`` reads every form a controller publishes, or says why it cannot.

One simulated recording is rewritten the way other controllers publish it (effort only on
the motor entry, in motor units; no velocity field; motor angles already divided by the
ratio; link and motor on two topics written seconds apart; frozen stamps; no effort at
all). A form the twin can read must give the original's estimate; a form it cannot must be
declared not observed, with the reason, a WARNING line and exit status 3.
"""

from dataclasses import replace
import json

import numpy as np
import pytest
from reducer_twin.analysis import pipeline
from reducer_twin.analysis.pipeline import analyze_bag
from reducer_twin.analysis.report import write_report
from reducer_twin.analysis.settings import AnalysisSettings
from reducer_twin.analysis.simulate import AGING_KEY, simulate_bag, SimulationSpec
from reducer_twin.cli import main
from reducer_twin.core.kinematics import total_ratio
from reducer_twin.core.params import ReducerParams
from reducer_twin.core.transmission_error import lost_motion
from reducer_twin.core.units import ARCMIN
from reducer_twin.io.bag import BagDirWriter, open_bag, write_bag_dir
from reducer_twin.msg_adapters.jointstate_cdr import encode_joint_states, JointStateBatch
from reducer_twin.msg_adapters.jointstate_cdr import MSGTYPE as JOINT_STATE
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import get_typestore, Stores
from scipy.signal import butter, sosfiltfilt

AGING = 180_000.0
SPEC = SimulationSpec(hours=3000.0, aging_factor=AGING, joints=2, rate_hz=250.0, seed=3,
                      wear_rate_scales=(1.0, 2.0), load_torque_nm=1.2 * 784.0)
RATIO = total_ratio(ReducerParams().geometry)
CUSTOM = {AGING_KEY: repr(AGING)}


@pytest.fixture(scope='module')
def original(tmp_path_factory):
    """Simulate the bag; return its JointState batch and its analysis."""
    root = tmp_path_factory.mktemp('forms')
    simulate_bag(root / 'bag', SPEC)
    with open_bag(root / 'bag') as bag:
        js = bag.read_joint_states()['/joint_states']
    return js, analyze_bag(root / 'bag', root / 'derived')


def _rewrite(js, tmp_path, name, **fields):
    batch = JointStateBatch(fields.get('stamps_ns', js.stamps_ns), js.names,
                            fields.get('position', js.position),
                            fields.get('velocity', js.velocity),
                            fields.get('effort', js.effort))
    return write_bag_dir(tmp_path / name, {'/joint_states': batch}, custom_data=CUSTOM)


def _wear(result):
    return {j: r.summary()['wear_um'] for j, r in result.joints.items()}


def _assert_same_estimate(result, original, rel=0.02):
    for joint, wear in _wear(original[1]).items():
        got = result.joints[joint].summary()
        assert got['observed'] and got['windows'] >= 5
        assert got['wear_um'] == pytest.approx(wear, rel=rel)


def _motor_columns(js):
    return [k for k, n in enumerate(js.names) if n.endswith('_motor')]


def test_effort_only_on_the_motor_entry_in_motor_units_reads_like_the_link_effort(
        original, tmp_path):
    js = original[0]
    effort = np.full_like(js.effort, np.nan)
    for k in _motor_columns(js):
        link = js.names.index(js.names[k][:-len('_motor')])
        effort[:, k] = js.effort[:, link] / RATIO    # the motor's torque
    result = analyze_bag(_rewrite(js, tmp_path, 'motor_effort', effort=effort),
                         tmp_path / 'd')
    _assert_same_estimate(result, original)


def test_a_stream_without_velocity_gets_it_from_the_positions(original, tmp_path):
    js = original[0]
    result = analyze_bag(_rewrite(js, tmp_path, 'no_velocity',
                                  velocity=np.full_like(js.velocity, np.nan)), tmp_path / 'd')
    _assert_same_estimate(result, original, rel=0.03)


def _output_angles(js):
    position = js.position.copy()
    position[:, _motor_columns(js)] /= RATIO
    return position


def test_motor_angles_divided_by_the_ratio_are_recognised_without_a_config(original, tmp_path):
    js = original[0]
    result = analyze_bag(_rewrite(js, tmp_path, 'output', position=_output_angles(js)),
                         tmp_path / 'd')
    _assert_same_estimate(result, original)


def test_a_motor_torque_beside_output_angles_is_read_as_one_and_said(
        original, tmp_path, capsys):
    # A drive that reports the joint's angle (divided by the ratio) and its motor's torque:
    # the effort, read in joint units, never reached the bins the lost motion is read
    # from, and every joint was not observed ("... set motor_effort_units to motor").
    js = original[0]
    effort = np.full_like(js.effort, np.nan)
    for k in _motor_columns(js):
        link = js.names.index(js.names[k][:-len('_motor')])
        effort[:, k] = js.effort[:, link] / RATIO    # the motor's torque
    bag = _rewrite(js, tmp_path, 'drive', position=_output_angles(js), effort=effort)
    code, got, err = _cli_json(bag, tmp_path, capsys)
    assert code == 0, err
    for joint, res in original[1].joints.items():
        (line,) = [x for x in err.splitlines() if f'{joint}: the effort of its motor entry' in x]
        assert line.startswith('WARNING: ') and "read as the motor's torque, times the " \
            'ratio 81' in line and 'twin.motor_effort_units' in line, line
        assert got['joints'][joint]['wear_um'] == pytest.approx(res.summary()['wear_um'],
                                                                rel=0.02)
    config = tmp_path / 'twin.yaml'
    config.write_text('twin:\n  motor_effort_units: motor\n')
    code, told, err = _cli_json(bag, tmp_path, capsys, '--config', config, out='told')
    assert code == 0 and 'the effort of its motor entry' not in err
    got.pop('messages_per_s'), told.pop('messages_per_s')
    assert got == told      # as if the configuration had said it
    config.write_text('twin:\n  motor_effort_units: joint\n')
    code, joint_units, err = _cli_json(bag, tmp_path, capsys, '--config', config, out='joint')
    assert code == 3 and all('motor_effort_units' in res['reason']
                             for res in joint_units['joints'].values())


@pytest.mark.parametrize('divided', [False, True], ids=['raw', 'output'])
def test_a_motor_encoder_that_counts_against_the_link_is_read_reversed_and_said(
        original, tmp_path, capsys, divided):
    js = original[0]
    position = _output_angles(js) if divided else js.position.copy()
    effort = np.full_like(js.effort, np.nan)
    for k in _motor_columns(js):
        link = js.names.index(js.names[k][:-len('_motor')])
        position[:, k] *= -1.0      # a negative reduction: the motor turns the other way
        # Its torque in its own sense (motor units with raw angles, joint units with output
        # angles: the 'auto' units).
        effort[:, k] = -js.effort[:, link] / (1.0 if divided else RATIO)
    bag = _rewrite(js, tmp_path, 'reversed', position=position, effort=effort)
    code, out, err = _cli_json(bag, tmp_path, capsys)
    assert code == 0
    for joint, wear in _wear(original[1]).items():
        assert out['joints'][joint]['observed'] is True
        assert out['joints'][joint]['wear_um'] == pytest.approx(wear, rel=0.02)
        assert any(line.startswith('WARNING:') and f'motor encoder of {joint} counts against '
                   'the link' in line for line in err.splitlines())
    # Configured, it is read without a warning; configured the other way, it is an error.
    config = tmp_path / 'twin.yaml'
    for direction, want in ((-1, 0), (1, 1)):
        config.write_text(f'twin:\n  motor_direction: {direction}\n')
        code = main(['analyze', str(bag), '--out', str(tmp_path / f'c{direction}'),
                     '--config', str(config)])
        err = capsys.readouterr().err
        assert code == want and 'counts against the link' not in err
        if want:
            (line,) = [x for x in err.splitlines() if x.startswith('ERROR:')]
            assert 'twin.motor_direction is 1' in line and 'motor_direction -1' in line, line


@pytest.mark.parametrize('side', ['motor', 'link'])
def test_a_frozen_encoder_is_declared_not_observed_never_read_as_wear(
        original, tmp_path, capsys, side):
    js = original[0]
    position = js.position.copy()
    k = js.names.index('joint_1_motor' if side == 'motor' else 'joint_1')
    position[:, k] = position[0, k]     # the encoder stopped counting
    bag = _rewrite(js, tmp_path, f'frozen_{side}', position=position)
    code, out, err = _cli_json(bag, tmp_path, capsys)
    assert code == 3
    got = out['joints']['joint_1']
    assert got['observed'] is False and got['wear_um'] is None and got['rul_p50_h'] is None
    assert 'do not measure the same motion' in got['reason'] and 'frozen encoder' in got['reason']
    assert any(x.startswith('WARNING: joint_1: not observed') for x in err.splitlines())
    assert out['joints']['joint_2']['observed'] is True


@pytest.mark.parametrize('scale, said', [(1.01, 'turns 81.'), (101.0 / 81.0, 'turns 100.')],
                         ids=['1 % off', 'another ratio of the frame'])
def test_a_motor_that_turns_another_number_of_times_than_the_ratio_is_said_with_it(
        original, tmp_path, capsys, scale, said):
    # Read against 81, a motor 1 % off was refused as "the effort has the opposite sign",
    # one of ratio 101 as encoders that "do not measure the same motion": neither named it.
    js = original[0]
    position = js.position.copy()
    position[:, _motor_columns(js)] *= scale
    code, out, err = _cli_json(_rewrite(js, tmp_path, 'ratio', position=position), tmp_path,
                               capsys)
    assert code == 3
    for joint, got in out['joints'].items():
        # Refused for what the TE then shows, the reason names the ratio too.
        assert got['observed'] is False and 'the motor encoder turns' in got['reason']
        (line,) = [x for x in err.splitlines() if f'{joint}: the motor encoder turns' in x]
        assert line.startswith('WARNING: ') and said in line
        assert 'where the configured reduction ratio is 81' in line, line


def test_a_config_that_contradicts_the_motor_angles_is_an_error_naming_both(
        original, tmp_path, capsys):
    js = original[0]
    bag = _rewrite(js, tmp_path, 'output', position=_output_angles(js))
    config = tmp_path / 'twin.yaml'
    config.write_text('twin:\n  motor_angles: raw\n')
    code = main(['analyze', str(bag), '--out', str(tmp_path / 'd'), '--config', str(config)])
    err = capsys.readouterr().err
    assert code == 1
    line = [x for x in err.splitlines() if x.startswith('ERROR:')][0]
    assert "twin.motor_angles is 'raw'" in line and "'output'" in line
    assert 'Traceback' not in err


def test_link_and_motor_topics_far_apart_in_the_file_lose_no_pair_at_chunk_boundaries(
        original, tmp_path, monkeypatch):
    js = original[0]
    links = [k for k in range(len(js.names)) if k not in _motor_columns(js)]
    motors = _motor_columns(js)

    def side(cols, names):
        return JointStateBatch(js.stamps_ns, tuple(names), js.position[:, cols],
                               js.velocity[:, cols], js.effort[:, cols])

    link = side(links, [js.names[k] for k in links])
    motor = side(motors, [js.names[k] for k in links])    # the same joint names
    root = tmp_path / 'apart'
    with BagDirWriter(root, compression='none', custom_data=CUSTOM) as writer:
        a = writer.add_topic('/joint_states', JOINT_STATE)
        b = writer.add_topic('/motor_states', JOINT_STATE)
        # Each motor message is logged 3 s after its link message (a slow recorder queue).
        writer.write_joint_states(a, link)
        writer.write_joint_states(b, motor, log_times_ns=motor.stamps_ns + 3_000_000_000)
    monkeypatch.setattr(pipeline, 'CHUNK_MESSAGES', 4096)
    result = analyze_bag(root, tmp_path / 'd')
    for joint, res in result.joints.items():
        assert res.counts['unpaired'] == 0
        assert res.summary()['rejected'] == 0
    _assert_same_estimate(result, original, rel=0.03)


@pytest.mark.parametrize('offset_ns, second_first', [(0, False), (300_000, True)],
                         ids=['same stamp', 'stamped 0.3 ms apart, logged out of order'])
def test_two_publishers_of_one_topic_each_with_its_joints_lose_no_sample(
        original, tmp_path, offset_ns, second_first):
    # Two joint_state_broadcasters on /joint_states, each sending its own joints of a
    # tick: the second message of a tick was taken for a frozen clock (joint_2 "not
    # observed"), or, stamped a little earlier, for a sample out of order.
    js = original[0]
    parts = []
    for joint in ('joint_1', 'joint_2'):
        cols = [js.names.index(joint), js.names.index(joint + '_motor')]
        stamps = js.stamps_ns + (offset_ns if joint == 'joint_1' else 0)
        buffer, offsets = encode_joint_states(stamps, (joint, joint + '_motor'),
                                              js.position[:, cols], js.velocity[:, cols],
                                              js.effort[:, cols])
        parts.append([buffer[offsets[i]:offsets[i + 1]].tobytes() for i in range(len(js))])
    if second_first:
        parts.reverse()
    root = tmp_path / 'two_publishers'
    with BagDirWriter(root, compression='none', custom_data=CUSTOM) as writer:
        channel = writer.add_topic('/joint_states', JOINT_STATE)
        for i, log_ns in enumerate(js.stamps_ns):
            for k, part in enumerate(parts):
                writer.write(channel, int(log_ns) + k, part[i])
    result = analyze_bag(root, tmp_path / 'd')
    for res in result.joints.values():
        assert res.summary()['rejected'] == 0 and res.messages == len(js)
    _assert_same_estimate(result, original, rel=0.005)


def test_a_stream_too_slow_for_the_transmission_error_is_said_to_be(
        original, tmp_path, capsys):
    # Every 25th message of the 250 Hz recording: 10 Hz, 0.1 s between samples, where the
    # twin bridges 0.05 s. It was said to be "positions in degrees or counts".
    js = original[0]
    keep = np.arange(0, len(js.stamps_ns), 25)
    thin = JointStateBatch(js.stamps_ns[keep], js.names, js.position[keep],
                           js.velocity[keep], js.effort[keep])
    bag = write_bag_dir(tmp_path / 'ten_hz', {'/joint_states': thin}, custom_data=CUSTOM)
    code, out, err = _cli_json(bag, tmp_path, capsys)
    assert code == 3
    for joint in ('joint_1', 'joint_2'):
        got = out['joints'][joint]
        assert got['observed'] is False and got['rul_p50_h'] is None
        assert got['reason'].startswith('its samples on /joint_states are 0.100 s apart on '
                                        'average (10 Hz), further than the 0.05 s the twin '
                                        'bridges (twin.max_gap_s)')
        assert 'degrees' not in got['reason']


def _cli_json(bag, tmp_path, capsys, *extra, out='d'):
    code = main(['analyze', str(bag), '--out', str(tmp_path / out), '--json',
                 *(str(x) for x in extra)])
    captured = capsys.readouterr()
    return code, json.loads(captured.out), captured.err


@pytest.mark.parametrize('form, said', [
    ('zero-filled', 'the velocity field is zero where the link angle turns'),
    ('degrees per second', 'degrees per second'),
    ("the motor's speed", "the motor's speed: the ratio is 81"),
    ('the other sense', 'the other sense'),
    ('20 ms late', 'lags the rate of the link angle by 19.'),
    ('noisy', 'is noisier than the rate of the link angle: 0.05'),
])
def test_a_velocity_field_in_another_form_reads_as_no_field_and_is_said(
        form, said, original, tmp_path, capsys):
    # Read as it is, a negated field on an independent-generator wrist read its wear 68 %
    # low, and a zero-filled one "too few samples per torque reversal", not observed.
    js = original[0]
    velocity = {'zero-filled': np.zeros_like(js.velocity),
                'degrees per second': np.degrees(js.velocity),
                "the motor's speed": js.velocity * RATIO,
                'the other sense': -js.velocity,
                '20 ms late': np.concatenate([js.velocity[:5], js.velocity[:-5]]),
                'noisy': js.velocity + np.random.default_rng(9).normal(0.0, 0.05,
                                                                       js.velocity.shape)}[form]
    none = _rewrite(js, tmp_path, 'none', velocity=np.full_like(js.velocity, np.nan))
    code, expected, err = _cli_json(none, tmp_path, capsys, out='d0')
    assert code == 0 and 'velocity field' not in err
    code, got, err = _cli_json(_rewrite(js, tmp_path, 'other', velocity=velocity), tmp_path,
                               capsys, out='d1')
    assert code == 0
    expected.pop('messages_per_s'), got.pop('messages_per_s')
    inputs = {joint: res.pop('inputs') for joint, res in got['joints'].items()}
    assert all(res.pop('inputs') == [] for res in expected['joints'].values())
    assert got == expected      # every number, as if the field were not there
    for joint, res in got['joints'].items():
        assert res['observed'] and res['velocity'] == 'link_angle'
        (line,) = [x for x in err.splitlines() if f'{joint}: the velocity field' in x]
        assert line.startswith('WARNING: ') and said in line, line
        assert line.endswith('the rate of the link angle is used instead')
        assert line.split(f'{joint}: ', 1)[1] in inputs[joint]     # and in --json


def test_an_effort_held_between_slower_updates_is_read_like_a_fresh_one_and_said(
        original_1khz, tmp_path, capsys):
    # The effort of a 100 Hz drive loop on a 1 kHz stream hid its noise from the window
    # analysis: a base joint's wear read 32 % low, a shoulder's effort was refused as "about
    # 4 times the torque", and nothing said why.
    js = original_1khz
    held = js.effort[(np.arange(len(js)) // 10) * 10]
    code, out, err = _cli_json(_rewrite(js, tmp_path, 'held', effort=held), tmp_path, capsys)
    _, fresh, clean = _cli_json(_rewrite(js, tmp_path, 'fresh'), tmp_path, capsys, out='d2')
    assert code == 0 and 'repeats itself' not in clean
    for joint, got in out['joints'].items():
        (line,) = [x for x in err.splitlines() if f'{joint}: the effort repeats itself' in x]
        assert line.startswith('WARNING: ') and 'on a 1000 Hz stream' in line, line
        assert got['observed']
        assert got['wear_um'] == pytest.approx(fresh['joints'][joint]['wear_um'], rel=0.05)


def test_an_effort_whose_noise_is_a_ripple_below_the_sample_rate_is_read_and_said(
        original_1khz, tmp_path, capsys):
    # 2 % of rated torque in 5-50 Hz: neighbouring samples hardly see it (it read 2.0 N*m of
    # 15.7), so the 30 ms average kept most of it beside a 1 N*m band and new units' wear read
    # 67-80 % low, nothing said.
    js = original_1khz
    sos = butter(4, [5.0, 50.0], btype='band', fs=1000.0, output='sos')
    ripple = sosfiltfilt(sos, np.random.default_rng(6).normal(size=js.effort.shape), axis=0)
    ripple *= 0.02 * 784.0 / ripple.std(axis=0)
    effort = js.effort.copy()
    effort[:, _link_columns(js)] += ripple[:, _link_columns(js)]
    code, out, err = _cli_json(_rewrite(js, tmp_path, 'ripple', effort=effort), tmp_path, capsys)
    _, fresh, clean = _cli_json(_rewrite(js, tmp_path, 'fresh'), tmp_path, capsys, out='d2')
    assert code == 0 and 'correlated over successive samples' not in clean
    for joint, got in out['joints'].items():
        (line,) = [x for x in err.splitlines()
                   if f"{joint}: the effort's noise is correlated over successive samples" in x]
        assert line.startswith('WARNING: ') and 'times as noisy' in line, line
        assert got['observed']
        assert got['wear_um'] == pytest.approx(fresh['joints'][joint]['wear_um'], rel=0.05)


@pytest.mark.parametrize('encoder', ['link', 'motor', 'link and motor'])
def test_an_encoder_held_between_slower_updates_is_read_at_its_updates_and_said(
        original_1khz, tmp_path, capsys, encoder):
    # A secondary encoder polled at 250 Hz on a 1 kHz bus: each reading repeated for 4
    # samples is up to 3 ms old, and its TE carried the motion since. Taken as fresh, a
    # used unit at 2.27 arcmin read 1.16, its remaining life 9-10 times the truth, unsaid.
    js = original_1khz
    columns = {'motor': _motor_columns(js), 'link': _link_columns(js)}.get(
        encoder, _motor_columns(js) + _link_columns(js))
    position = js.position.copy()
    stale = (np.arange(len(js)) // 4) * 4
    position[:, columns] = js.position[stale][:, columns]
    code, out, err = _cli_json(_rewrite(js, tmp_path, 'held', position=position), tmp_path,
                               capsys)
    _, fresh, clean = _cli_json(_rewrite(js, tmp_path, 'fresh'), tmp_path, capsys, out='d2')
    assert code == 0 and 'repeats its reading' not in clean
    said = (f'the {encoder} encoder repeats its reading' if ' ' not in encoder
            else 'the link and motor encoders repeat their readings together')
    for joint, got in out['joints'].items():
        (line,) = [x for x in err.splitlines() if f'{joint}: {said}' in x]
        assert line.startswith('WARNING: ') and 'about 250 Hz on a 1000 Hz stream' in line
        assert got['observed']
        assert got['lost_motion_arcmin'] == pytest.approx(
            fresh['joints'][joint]['lost_motion_arcmin'], rel=0.02)


def test_a_true_velocity_field_is_used_and_said_to_be(original):
    for res in original[1].joints.values():
        assert res.summary()['velocity'] == 'field'


def test_joints_whose_names_are_no_topic_names_get_valid_derived_topics_and_it_is_said(
        original, tmp_path, capsys):
    # 'ros2 bag play' of the derived bag refused '/reducer_twin/joint-1/wear'.
    from rclpy.validate_topic_name import validate_topic_name
    js = original[0]
    rename = {'joint_1': 'joint-1', 'joint_2': '2nd axis'}
    names = [rename[n[:-6]] + '_motor' if n.endswith('_motor') else rename[n]
             for n in js.names]
    bag = write_bag_dir(tmp_path / 'named', {'/joint_states': JointStateBatch(
        js.stamps_ns, names, js.position, js.velocity, js.effort)}, custom_data=CUSTOM)
    code, got, err = _cli_json(bag, tmp_path, capsys)
    assert code == 0
    for old, new in rename.items():     # the same joints, by their own names
        assert got['joints'][new]['wear_um'] == pytest.approx(
            original[1].joints[old].summary()['wear_um'], rel=1e-3)
    for said in ('joint-1: its derived topics are /reducer_twin/joint_1/...',
                 '2nd axis: its derived topics are /reducer_twin/_2nd_axis/...'):
        (line,) = [x for x in err.splitlines() if said in x]
        assert line.startswith('WARNING: '), line
    with open_bag(tmp_path / 'd') as derived:
        topics = sorted(derived.topics)
    assert '/reducer_twin/joint_1/wear' in topics and '/reducer_twin/_2nd_axis/te' in topics
    for topic in topics:
        validate_topic_name(topic)      # raises on a name ROS 2 refuses


def test_every_robot_of_a_recording_is_analysed_its_joints_named_by_namespace(
        original, tmp_path, capsys):
    # A second robot's /robot_b/joint_states was left out without a word.
    js = original[0]
    root = tmp_path / 'two_robots'
    with BagDirWriter(root, compression='none', custom_data=CUSTOM) as writer:
        for robot in ('robot_a', 'robot_b'):
            writer.write_joint_states(writer.add_topic(f'/{robot}/joint_states', JOINT_STATE),
                                      js)
    code, out, err = _cli_json(root, tmp_path, capsys)
    assert code == 0, err
    assert sorted(out['joints']) == ['robot_a/joint_1', 'robot_a/joint_2', 'robot_b/joint_1',
                                     'robot_b/joint_2']
    for joint, wear in _wear(original[1]).items():
        for robot in ('robot_a', 'robot_b'):
            got = out['joints'][f'{robot}/{joint}']
            assert got['observed'] is True and got['messages'] == len(js)
            assert got['wear_um'] == pytest.approx(wear, rel=1e-9)
    with open_bag(tmp_path / 'd') as derived:
        assert '/reducer_twin/robot_b/joint_1/wear' in derived.topics
    # Into a fleet store: four reducers, their names whole in the fleet view.
    store = tmp_path / 'fleet.db'
    assert main(['analyze', str(root), '--out', str(tmp_path / 's'), '--store', str(store),
                 '--robot', 'cell1']) == 0
    capsys.readouterr()
    assert main(['fleet', '--store', str(store)]) == 0
    view = capsys.readouterr().out
    for robot in ('robot_a', 'robot_b'):
        for joint in ('joint_1', 'joint_2'):
            assert f'cell1/{robot}/{joint}\n' in view
    # With twin.joints configured, the other robot is declared, never left out.
    config = tmp_path / 'twin.yaml'
    config.write_text('twin:\n  joints: [joint_1, joint_2]\n')
    code = main(['analyze', str(root), '--out', str(tmp_path / 'c'), '--json', '--config',
                 str(config), '--report', str(tmp_path / 'report')])
    captured = capsys.readouterr()
    out = json.loads(captured.out)
    assert code == 3 and out['joints']['joint_1']['observed'] is True
    for joint in ('robot_b/joint_1', 'robot_b/joint_2'):
        got = out['joints'][joint]
        assert got['observed'] is False and got['wear_um'] is None
        assert 'twin.link_topic: /robot_b/joint_states' in got['reason']
        assert any(x.startswith(f'WARNING: {joint}: not observed') for x in
                   captured.err.splitlines())
    text = (tmp_path / 'report' / 'index.html').read_text(encoding='utf-8')
    assert text.count('twin.link_topic: /robot_b/joint_states') == 2


def test_an_estimate_that_stops_before_the_recording_says_as_of_when_and_why(
        original, tmp_path, capsys):
    # Effort only in the first half: the wear read at the half was reported as the end's
    # (41-47 % low) without a word.
    js = original[0]
    effort = js.effort.copy()
    effort[len(effort) // 2:] = np.nan
    code, out, err = _cli_json(_rewrite(js, tmp_path, 'half', effort=effort), tmp_path, capsys)
    assert code == 0
    for joint, got in out['joints'].items():
        assert got['observed'] is True
        assert got['partial'].startswith('no lost motion in the last 5')
        assert 'no effort on /joint_states' in got['partial']
        assert any(x.startswith(f'WARNING: {joint}: observed in part of') for x in
                   err.splitlines())
    # Effort on every other message: read, and the uncounted operating time said.
    effort = js.effort.copy()
    effort[1::2] = np.nan
    _, out, _ = _cli_json(_rewrite(js, tmp_path, 'every_other', effort=effort),
                          tmp_path / 'e', capsys)
    for got in out['joints'].values():
        assert got['observed'] is True and 'operating time is not counted' in got['partial']
    for res in original[1].joints.values():
        assert res.summary()['partial'] is None
    # The report says it too.
    result = analyze_bag(_rewrite(js, tmp_path, 'half_report', effort=effort), tmp_path / 'r')
    page = write_report(result, tmp_path / 'report').read_text(encoding='utf-8')
    assert page.count('observed in part: no effort on /joint_states') == 2


def test_a_joint_whose_entries_go_missing_midway_is_said_to_stand_as_of_then(
        original, tmp_path, capsys):
    # joint_1 renamed halfway (its entries missing from the later messages): its wear at
    # the half was reported as the end's (-54 %) without a word.
    js = original[0]
    position = js.position.copy()
    for name in ('joint_1', 'joint_1_motor'):
        position[len(js) // 2:, js.names.index(name)] = np.nan
    code, out, err = _cli_json(_rewrite(js, tmp_path, 'renamed', position=position), tmp_path,
                               capsys)
    assert code == 0
    got = out['joints']['joint_1']
    assert got['observed'] is True and got['partial'].startswith('its samples stop 3')
    assert 'do not carry joint_1 with its motor entry' in got['partial']
    assert any(x.startswith('WARNING: joint_1: observed in part of') for x in err.splitlines())
    assert out['joints']['joint_2']['partial'] is None


def test_a_recording_without_effort_is_declared_not_observed_with_exit_3(
        original, tmp_path, capsys):
    js = original[0]
    bag = _rewrite(js, tmp_path, 'no_effort', effort=np.full_like(js.effort, np.nan))
    code, out, err = _cli_json(bag, tmp_path, capsys)
    assert code == 3
    for joint, got in out['joints'].items():
        assert got['observed'] is False and got['windows'] == 0
        assert 'no effort on /joint_states' in got['reason']
        assert got['wear_um'] is None and got['rul_p50_h'] is None
        assert any(x.startswith(f'WARNING: {joint}: not observed') for x in err.splitlines())


@pytest.mark.parametrize('rounding_deg', [0.0, 0.001], ids=['exact', 'to 0.001 deg'])
def test_a_link_angle_computed_from_the_motor_is_said_to_need_an_output_encoder(
        original, tmp_path, capsys, rounding_deg):
    # Most robots publish the joint angle as the motor's over the ratio: no TE to read.
    js = original[0]
    position = js.position.copy()
    for k in _motor_columns(js):
        link = position[:, k] / RATIO
        if rounding_deg:
            link = np.round(link / np.radians(rounding_deg)) * np.radians(rounding_deg)
        position[:, js.names.index(js.names[k][:-len('_motor')])] = link
    code, out, err = _cli_json(_rewrite(js, tmp_path, 'derived', position=position),
                               tmp_path, capsys)
    assert code == 3
    for joint, got in out['joints'].items():
        assert got['observed'] is False and got['wear_um'] is None
        assert got['reason'].startswith('the link angle follows the motor angle divided by '
                                        'the reduction ratio to within ')
        assert "not read by an encoder at the reducer's output" in got['reason']
        assert any(x.startswith(f'WARNING: {joint}: not observed') for x in err.splitlines())


def test_link_and_motor_entries_swapped_are_said_to_be(original, tmp_path, capsys):
    # Before: "dropped as spikes ... the motor encoder turns 80.3 times the link where the
    # configured reduction ratio is 81", sending the engineer to the reducer's geometry.
    js = original[0]
    position = js.position.copy()
    motor = _motor_columns(js)
    link = [js.names.index(js.names[k][:-len('_motor')]) for k in motor]
    position[:, motor], position[:, link] = js.position[:, link], js.position[:, motor]
    code, out, err = _cli_json(_rewrite(js, tmp_path, 'swapped', position=position),
                               tmp_path, capsys)
    assert code == 3
    for joint, got in out['joints'].items():
        assert got['observed'] is False and got['wear_um'] is None
        assert got['reason'].startswith(f'its link entry {joint} moves 8')
        assert f'times its motor entry {joint}_motor, where a motor moves about 81 times its ' \
            'link: the two are swapped' in got['reason']
    # Configured raw motor angles are not contradicted by a swap (it is not 'output').
    config = tmp_path / 'twin.yaml'
    config.write_text('twin:\n  motor_angles: raw\n')
    code, out, err = _cli_json(tmp_path / 'swapped', tmp_path, capsys, '--config', config,
                               out='d_raw')
    assert code == 3 and 'ERROR' not in err
    assert all('the two are swapped' in got['reason'] for got in out['joints'].values())


@pytest.mark.parametrize('side, said', [
    ('link', ('moves 1.41', 'times its link entry {j}, where a motor in radians moves 81 times '
              'its link (raw angles) or once (divided by the ratio): 81 x 0.01745, which a '
              'link angle in degrees beside a motor angle in radians gives')),
    ('motor', ('moves 46', 'times its link entry {j}', '81 x 57.3, which a motor angle in '
               'degrees beside a link angle in radians gives')),
], ids=['link in degrees', 'motor in degrees'])
def test_encoders_in_mixed_units_are_named_not_taken_for_spikes(
        original, tmp_path, capsys, side, said):
    # A link in degrees beside a raw motor in radians travels 1.41 times the link: it was
    # read as an output motor, every pair a spike, and the reason listed "positions in
    # degrees or counts, a wrong reduction ratio or motor_angles, link and motor entries
    # swapped, or faulty encoders"; a motor in degrees was said so, and at 250 Hz also to
    # be "stamped 35.9 ms apart".
    js = original[0]
    position, velocity = js.position.copy(), js.velocity.copy()
    columns = _link_columns(js) if side == 'link' else _motor_columns(js)
    position[:, columns] = np.degrees(position[:, columns])
    velocity[:, columns] = np.degrees(velocity[:, columns])
    code, out, err = _cli_json(_rewrite(js, tmp_path, side, position=position,
                                        velocity=velocity), tmp_path, capsys)
    assert code == 3
    for joint, got in out['joints'].items():
        assert got['observed'] is False and got['wear_um'] is None
        assert got['reason'].startswith(f'its motor entry {joint}_motor moves ')
        assert all(part.format(j=joint) in got['reason'] for part in said)
        assert f'a {side} angle in degrees beside a ' in got['reason']
        assert got['reason'].endswith('publish both angles in radians (REP 103)')
        assert 'spikes' not in got['reason'] and 'stamped' not in got['reason']
        assert any(x.startswith(f'WARNING: {joint}: not observed') for x in err.splitlines())


def _link_columns(js):
    return [k for k, n in enumerate(js.names) if not n.endswith('_motor')]


@pytest.mark.parametrize('factor, said, scale', [
    (-1.0, 'the effort has the opposite sign of the torque', -1.0),
    # Beyond the torque bins, ten times the torque is named by its size.
    (10.0, 'times the rated torque', 0.1),
    (0.1, 'the effort reads about', 10.0),        # a motor current in A
    # The motor's torque on the joint entry: below every torque bin.
    (1.0 / RATIO, 'on the joint entry, set effort_scale (twin.effort_scale in --config) to '
     'the ratio, 81', RATIO),
], ids=['sign reversed', 'ten times the torque', 'a tenth of the torque',
        "the motor's torque"])
def test_an_effort_that_is_not_the_output_torque_is_refused_and_the_config_reads_it(
        original, tmp_path, capsys, factor, said, scale):
    js = original[0]
    effort = js.effort.copy()
    effort[:, _link_columns(js)] *= factor
    bag = _rewrite(js, tmp_path, 'effort', effort=effort)
    code, out, err = _cli_json(bag, tmp_path, capsys)
    # Read as the torque, such an effort gave 30 um instead of 0.9 and 0 h left, or -60 %.
    assert code == 3
    for joint, got in out['joints'].items():
        assert got['observed'] is False and got['wear_um'] is None and got['rul_p50_h'] is None
        assert said in got['reason'] and 'twin.effort_scale' in got['reason']
        if factor == 0.1:
            shown = float(got['reason'].split('the effort reads about ')[1].split()[0])
            assert shown == pytest.approx(factor, rel=0.25)
        assert any(x.startswith(f'WARNING: {joint}: not observed') and said in x
                   for x in err.splitlines())
    config = tmp_path / 'twin.yaml'
    config.write_text(f'twin:\n  effort_scale: {scale}\n')
    result = analyze_bag(bag, tmp_path / 'd_scaled', AnalysisSettings.from_config(config))
    _assert_same_estimate(result, original, rel=1e-6)


@pytest.fixture(scope='module')
def original_1khz(tmp_path_factory):
    """Simulate the same joints at 1 kHz (their loads fill the bins near zero torque)."""
    root = tmp_path_factory.mktemp('forms_1khz')
    simulate_bag(root / 'bag', replace(SPEC, rate_hz=1000.0))
    with open_bag(root / 'bag') as bag:
        return bag.read_joint_states()['/joint_states']


def _not_observed_with_offset(js, tmp_path, capsys, offset_nm):
    """Analyse the recording with ``offset_nm`` added to its efforts; check it is refused."""
    effort = js.effort.copy()
    effort[:, _link_columns(js)] += offset_nm
    code, out, err = _cli_json(_rewrite(js, tmp_path, 'offset', effort=effort), tmp_path,
                               capsys)
    assert code == 3
    for joint, got in out['joints'].items():
        assert got['observed'] is False and got['wear_um'] is None
        assert any(x.startswith(f'WARNING: {joint}: not observed') for x in err.splitlines())
    return [got['reason'] for got in out['joints'].values()]


def test_an_effort_offset_from_the_torque_is_refused_naming_the_offset(
        original_1khz, tmp_path, capsys):
    # A drive's uncalibrated torque estimate. Read as the torque, such an effort gave the
    # wear 59-71 % low, or 2-3 times high, with exit 0 and nothing said.
    for reason in _not_observed_with_offset(original_1khz, tmp_path, capsys, 150.0):
        assert 'the effort is offset from the torque' in reason
        named = float(reason.split('zero lies about ')[1].split()[0])
        assert named == pytest.approx(150.0, rel=0.2)
    # The recording as the drive should have published it is read.
    code, out, _ = _cli_json(_rewrite(original_1khz, tmp_path, 'zeroed'), tmp_path / 'z',
                             capsys)
    assert code == 0 and all(got['observed'] for got in out['joints'].values())


def test_an_effort_offset_beyond_the_loads_is_not_taken_for_an_estimate(
        original_1khz, tmp_path, capsys):
    # Beyond every load no flank ever changes: every window's fit lay on the table's lower
    # bound and none was used; the prior's wear (3.2 +- 17 um) and 0 .. 100 000 h were
    # reported as observed, with exit 0.
    for reason in _not_observed_with_offset(original_1khz, tmp_path, capsys, 1000.0):
        assert "read a play beyond a new nominal unit's" in reason


def test_an_effort_with_the_gravity_load_taken_out_is_not_taken_for_an_estimate(
        original, tmp_path, capsys):
    # An external-torque estimate (the drive's torque less its gravity model) changes sign
    # where the reducer's load does not; it is refused, the estimate never made of it.
    js = original[0]
    effort = js.effort.copy()
    for k in _link_columns(js):
        angle = js.position[:, k]
        gravity = np.c_[np.cos(angle), np.sin(angle), np.ones_like(angle)]
        coef = np.linalg.lstsq(gravity, effort[:, k], rcond=None)[0]
        effort[:, k] -= gravity @ coef
    code, out, err = _cli_json(_rewrite(js, tmp_path, 'external', effort=effort), tmp_path,
                               capsys)
    assert code == 3
    for joint, got in out['joints'].items():
        assert got['observed'] is False and got['wear_um'] is None
        assert 'an external-torque estimate' in got['reason']


def test_positions_in_degrees_are_refused_naming_the_units(
        original, tmp_path):
    js = original[0]
    bag = _rewrite(js, tmp_path, 'degrees', position=np.degrees(js.position),
                   velocity=np.degrees(js.velocity))
    result = analyze_bag(bag, tmp_path / 'd')
    for got in result.joints.values():
        summary = got.summary()
        assert not got.observed and summary['wear_um'] is None
        # At 250 Hz a motor in degrees jumps by more than half a "turn" per sample: most
        # pairs are spikes (at 1 kHz the hysteresis is 57 times too wide: "do not read
        # radians"); before, no reason named the units.
        assert 'dropped as spikes' in summary['reason'] and 'degrees' in summary['reason']


def test_an_effort_far_beyond_the_reducers_rating_is_named_as_other_units(original, tmp_path):
    js = original[0]
    effort = np.full_like(js.effort, np.nan)
    for k in _motor_columns(js):       # the joint's torque on the motor entry, in joint units
        effort[:, k] = js.effort[:, js.names.index(js.names[k][:-len('_motor')])]
    result = analyze_bag(_rewrite(js, tmp_path, 'joint_units', effort=effort), tmp_path / 'd')
    for got in result.joints.values():
        reason = got.summary()['reason']
        assert not got.observed and 'times the rated torque' in reason
        assert 'motor_effort_units joint' in reason
    config = tmp_path / 'twin.yaml'
    config.write_text('twin:\n  motor_effort_units: joint\n')
    _assert_same_estimate(analyze_bag(_rewrite(js, tmp_path, 'joint_units2', effort=effort),
                                      tmp_path / 'd2', AnalysisSettings.from_config(config)),
                          original)


def test_messages_logged_out_of_stamp_order_are_dropped_and_said(original, tmp_path, capsys):
    js = original[0]
    stamps = js.stamps_ns.copy()
    swap = np.arange(0, len(stamps) - 1, 20)        # every 20th message logged after the next
    stamps[swap], stamps[swap + 1] = stamps[swap + 1], stamps[swap].copy()
    code, out, err = _cli_json(_rewrite(js, tmp_path, 'late', stamps_ns=stamps), tmp_path,
                               capsys)
    assert code == 0
    (line,) = [x for x in err.splitlines() if 'out of stamp order' in x]
    assert line.startswith('WARNING:') and f'{swap.size:,} of {len(js):,}' in line


def test_a_link_encoder_too_coarse_for_the_lost_motion_is_said(original, tmp_path, capsys):
    js = original[0]
    position = js.position.copy()
    k = js.names.index('joint_1')
    quantum = 2.0 * np.pi / 4096        # a 12-bit link encoder: 5.3 arcmin steps
    position[:, k] = np.round(position[:, k] / quantum) * quantum
    _, _, err = _cli_json(_rewrite(js, tmp_path, 'coarse', position=position), tmp_path,
                          capsys)
    (line,) = [x for x in err.splitlines() if 'moves in steps' in x]
    assert line.startswith('WARNING:') and 'joint_1: the link encoder moves' in line
    assert 'steps of 5.3 arcmin' in line
    assert not any('moves in steps' in x for x in _cli_json(
        _rewrite(js, tmp_path, 'fine'), tmp_path / 'f', capsys)[2].splitlines())


@pytest.mark.parametrize('bits, said', [(17, True), (19, False)])
def test_a_link_encoder_coarse_for_an_early_growth_is_said(
        original, tmp_path, capsys, bits, said):
    # A 17-bit link encoder (0.165 arcmin steps) read a new unit's lost motion within 4 %
    # but its growth as wear 29-43 % high, the remaining life short with the truth above
    # P90, silently; 18 and 19 bits read as unquantised.
    js = original[0]
    position = js.position.copy()
    k = js.names.index('joint_1')
    quantum = 2.0 * np.pi / 2 ** bits
    position[:, k] = np.round(position[:, k] / quantum) * quantum
    _, _, err = _cli_json(_rewrite(js, tmp_path, f'q{bits}', position=position), tmp_path,
                          capsys)
    lines = [x for x in err.splitlines() if 'moves in steps' in x]
    assert len(lines) == int(said)
    if said:
        assert lines[0].startswith('WARNING:') and 'joint_1: the link encoder moves' in lines[0]
        assert 'steps of 0.16 arcmin' in lines[0] and 'early in its life' in lines[0]


@pytest.mark.parametrize('rewrite, said', [
    (lambda js: {'stamps_ns': np.zeros_like(js.stamps_ns)},
     'stamps do not advance on /joint_states'),
    # Positions in degrees (the velocity in rad/s): the TE spans degrees. At 250 Hz the
    # samples jump against each other as spikes, whose reason names degrees among their
    # causes; at 1 kHz the velocity field names them (test_joint_twin.py).
    (lambda js: {'position': np.degrees(js.position)}, 'positions in degrees'),
], ids=['all-zero header stamps', 'positions in degrees'])
def test_a_form_that_cannot_be_read_is_declared_not_observed_naming_it(
        original, tmp_path, capsys, rewrite, said):
    js = original[0]
    bag = _rewrite(js, tmp_path, 'form', **rewrite(js))
    code, out, err = _cli_json(bag, tmp_path, capsys)
    assert code == 3
    for got in out['joints'].values():
        assert got['observed'] is False and got['wear_um'] is None
        assert said in got['reason']


def test_an_observed_joint_reports_its_windows_and_no_reason(original):
    for res in original[1].joints.values():
        got = res.summary()
        assert got['observed'] is True and got['reason'] is None
        assert got['windows'] == int(np.isfinite(
            res.features[:, pipeline.TE_FEATURES.fields.index('lost_motion_rad')]).sum())


def test_a_torque_sensors_effort_is_read_before_the_joint_has_moved_both_ways(tmp_path, capsys):
    # A torque sensor at the output carries no motor friction. Read as a motor current, the
    # first windows of a joint that has moved one way only are withheld (the friction could
    # not yet be told from the load), and the reason names the setting that reads them.
    spec = SimulationSpec(hours=2.5, aging_factor=3600.0, joints=1, rate_hz=1000.0, seed=5,
                          start_hours=6000.0)
    wear = simulate_bag(tmp_path / 'bag', spec).truth['joint_1']['true_wear_um'] * 1e-6
    code, out, err = _cli_json(tmp_path / 'bag', tmp_path, capsys)
    got = out['joints']['joint_1']
    assert code == 3 and got['observed'] is False and got['lost_motion_arcmin'] is None
    assert got['reason'].startswith('the friction in the effort could not yet be told')
    assert 'set twin.friction_in_effort to 0' in got['reason']
    assert any('twin.friction_in_effort' in x for x in err.splitlines())
    config = tmp_path / 'twin.yaml'
    config.write_text('twin:\n  friction_in_effort: 0\n')
    code, out, err = _cli_json(tmp_path / 'bag', tmp_path, capsys, '--config', config,
                               out='d_sensor')
    got = out['joints']['joint_1']
    assert code == 0 and got['observed'] is True and got['reason'] is None
    truth = lost_motion(wear, ReducerParams()) / ARCMIN
    assert got['lost_motion_arcmin'] == pytest.approx(truth, rel=0.15)


def test_effort_source_and_units_come_from_the_config(tmp_path):
    config = tmp_path / 'twin.yaml'
    config.write_text('twin:\n  effort_source: motor\n  motor_effort_units: joint\n')
    settings = AnalysisSettings.from_config(config)
    assert (settings.effort_source, settings.motor_effort_units) == ('motor', 'joint')
    config.write_text('twin:\n  effort_source: elbow\n')
    with pytest.raises(Exception, match="twin.effort_source must be one of 'auto', 'link'"):
        AnalysisSettings.from_config(config)


def test_motor_angles_that_cannot_be_classified_are_said_to_be_taken_as_raw(
        original, tmp_path, capsys):
    js = original[0]
    still = js.position.copy()
    still[:] = still[0]         # a robot that never moved: nothing tells raw from output
    bag = _rewrite(js, tmp_path, 'still', position=still)
    _, _, err = _cli_json(bag, tmp_path, capsys)
    assert any(line.startswith('WARNING:') and 'could not be told raw from output' in line
               and 'twin.motor_angles' in line for line in err.splitlines())


def test_stamps_taken_on_arrival_are_re_timed_and_read_like_the_controllers(
        original_1khz, tmp_path, capsys):
    # A driver that stamps a message when it arrives: 0.3 ms sd about the 1 kHz clock. Read
    # on those stamps the wear came out 6 % high (another recording: 21-35 % low), a tenth
    # of the messages dropped as out of stamp order.
    js = original_1khz
    rng = np.random.default_rng(5)
    stamps = js.stamps_ns + np.round(rng.normal(0.0, 0.3e6, len(js))).astype(np.int64)
    _, clean, _ = _cli_json(_rewrite(js, tmp_path, 'clean'), tmp_path / 'c', capsys)
    code, out, err = _cli_json(_rewrite(js, tmp_path, 'arrival', stamps_ns=stamps),
                               tmp_path / 'a', capsys)
    assert code == 0
    (line,) = [x for x in err.splitlines() if 'scatter by' in x]
    assert line.startswith('WARNING:') and 'stamped when a message arrived' in line
    assert 're-timed' in line and 'out of stamp order' not in err
    for joint, got in out['joints'].items():
        assert got['observed'] and got['rejected'] <= 5
        assert got['wear_um'] == pytest.approx(clean['joints'][joint]['wear_um'], rel=0.02)


JAZZY = get_typestore(Stores.ROS2_JAZZY)


def _write_with_rosbags(path, js, names_of=None, effort_of=None):
    """
    Write the recording's JointState messages with rosbags' MCAP writer, one by one.

    ``names_of(i)`` gives the entries message ``i`` names (default: all of them), as a
    broadcaster that starts late or stops publishes them; ``effort_of(i, effort)`` its
    ``effort[]``. rosbags closes an MCAP chunk at 1 MiB (about 7000 of these messages).
    """
    msg, header, time = (JAZZY.types[t] for t in (JOINT_STATE, 'std_msgs/msg/Header',
                                                  'builtin_interfaces/msg/Time'))
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        writer.set_custom_data(AGING_KEY, repr(AGING))
        channel = writer.add_connection('/joint_states', JOINT_STATE, typestore=JAZZY)
        for i, stamp in enumerate(js.stamps_ns.tolist()):
            names = names_of(i) if names_of else js.names
            cols = [js.names.index(n) for n in names]
            effort = js.effort[i, cols]
            sec, nanosec = divmod(stamp, 1_000_000_000)
            writer.write(channel, stamp, JAZZY.serialize_cdr(msg(
                header=header(stamp=time(sec=sec, nanosec=nanosec), frame_id=''),
                name=list(names), position=js.position[i, cols],
                velocity=js.velocity[i, cols],
                effort=effort_of(i, effort) if effort_of else effort), JOINT_STATE))
    return path


LATE = 8_000
"""Message from which joint_2 is published: after rosbags' first MCAP chunk (about 7000)."""


def test_a_joint_whose_broadcaster_starts_late_is_analysed_as_if_planned_from_the_start(
        original, tmp_path, capsys):
    # joint_2 and joint_2_motor first appear 32 s into the recording, as when a second
    # joint_state_broadcaster starts late: joint_2 was planned from the first messages
    # only and left out without a word (exit 0, joint_1 alone in --json).
    js = original[0]
    first = ('joint_1', 'joint_1_motor')
    late = _write_with_rosbags(tmp_path / 'late', js,
                               lambda i: js.names if i >= LATE else first)
    # The same samples with joint_2 named from the first message (NaN until LATE).
    position = js.position.copy()
    position[:LATE, [js.names.index('joint_2'), js.names.index('joint_2_motor')]] = np.nan
    planned = analyze_bag(_rewrite(js, tmp_path, 'planned', position=position),
                          tmp_path / 'planned_d')
    code, out, err = _cli_json(late, tmp_path, capsys)
    assert code == 0 and 'joint_2' in out['joints']
    got, want = out['joints']['joint_2'], planned.joints['joint_2'].summary()
    assert got['observed'] is True and got['windows'] == want['windows'] >= 3
    assert got['wear_um'] == pytest.approx(want['wear_um'], rel=1e-9)
    assert got['rul_p50_h'] == pytest.approx(want['rul_p50_h'], rel=1e-9)
    assert got['messages'] == len(js) - LATE and got['rejected'] == 0
    assert out['joints']['joint_1']['messages'] == len(js)
    with open_bag(tmp_path / 'd') as derived:
        assert '/reducer_twin/joint_2/wear' in derived.topics
        assert derived.metadata['reducer_twin.joints'] == 'joint_1,joint_2'


def test_a_motor_entry_that_appears_late_is_not_said_to_be_missing(original, tmp_path, capsys):
    # joint_2's link entry is there from the start, its motor entry from message LATE on:
    # unpaired in the first messages, analysed in the end, so not said to be left out.
    js = original[0]
    late = _write_with_rosbags(tmp_path / 'late', js, lambda i: js.names if i >= LATE
                               else ('joint_1', 'joint_1_motor', 'joint_2'))
    code, out, err = _cli_json(late, tmp_path, capsys)
    assert code == 0 and out['joints']['joint_2']['observed'] is True
    assert 'also carries' not in err


def test_a_late_joint_the_fleet_store_cannot_take_is_said_not_dropped(
        original, tmp_path, capsys):
    # The store plans each reducer's chain from the bag's first messages: the late joint
    # is analysed into the derived bag, and stderr says it is not in the history and how.
    js = original[0]
    late = _write_with_rosbags(tmp_path / 'late', js, lambda i: js.names if i >= LATE
                               else ('joint_1', 'joint_1_motor'))
    code, out, err = _cli_json(late, tmp_path, capsys, '--store', tmp_path / 'fleet.db',
                               '--robot', 'r1')
    assert code == 0 and out['joints']['joint_2']['observed'] is True
    assert ('joint_2 first appears partway through the recording: analysed into the derived '
            'bag, not stored in the fleet history of robot r1') in err
    code = main(['fleet', '--store', str(tmp_path / 'fleet.db'), '--json'])
    reducers = json.loads(capsys.readouterr().out)['reducers']
    assert code == 0 and [r['joint'] for r in reducers] == ['joint_1']


def test_a_joint_configured_in_twin_joints_that_appears_late_is_analysed(
        original, tmp_path, capsys):
    # With twin.joints naming it, the bag was refused: "configured joints ['joint_2']
    # have no motor/link pair".
    js = original[0]
    late = _write_with_rosbags(tmp_path / 'late', js, lambda i: js.names if i >= LATE
                               else ('joint_1', 'joint_1_motor'))
    config = tmp_path / 'twin.yaml'
    config.write_text(f'twin:\n  joints: [joint_2]\n  aging_factor: {AGING}\n')
    code, out, _ = _cli_json(late, tmp_path, capsys, '--config', config)
    assert code == 0 and list(out['joints']) == ['joint_2']
    assert out['joints']['joint_2']['observed'] is True


def test_messages_and_rejected_leave_out_the_messages_that_do_not_name_the_joint(
        original, tmp_path, capsys):
    # joint_2 named by the messages 1000 .. 9999 only (late, then no longer published):
    # it was reported with every message of the recording, and its absent entries as
    # rejected non-finite samples (2 per message).
    js = original[0]
    bag = _write_with_rosbags(tmp_path / 'some', js, lambda i: js.names if 1000 <= i < 10_000
                              else ('joint_1', 'joint_1_motor'))
    code, out, _ = _cli_json(bag, tmp_path, capsys)
    assert code == 0
    assert out['joints']['joint_2']['messages'] == 9000
    assert out['joints']['joint_2']['rejected'] == 0
    assert out['joints']['joint_1']['messages'] == len(js)
    assert out['joints']['joint_1']['rejected'] == 0


def test_an_effort_array_not_one_per_name_is_named_malformed_and_counted_as_rejected(
        original, tmp_path, capsys):
    # effort[] of 2 entries for 4 names in every message read as "no effort on
    # /joint_states" with rejected 0, where a short position[] is named malformed.
    js = original[0]
    bag = _write_with_rosbags(tmp_path / 'short_effort', js,
                              effort_of=lambda i, effort: effort[[0, 2]])
    code, out, err = _cli_json(bag, tmp_path, capsys)
    assert code == 3
    for joint, got in out['joints'].items():
        assert got['observed'] is False and got['wear_um'] is None
        assert 'effort[] has 2 entries for 4 names' in got['reason']
        assert got['messages'] == len(js) and got['rejected'] == len(js)
        assert any(x.startswith(f'WARNING: {joint}: not observed') and 'effort[] has 2'
                   in x for x in err.splitlines())
    assert f'{len(js)} malformed JointState message(s) on /joint_states: effort[] has 2 ' \
        'entries for 4 names' in err
