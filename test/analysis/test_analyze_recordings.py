"""
reducer-twin analyze on ros2_control's DynamicJointState, ROS 1 bags and rosbag2-compressed bags.

Each recording is the simulator's bag rewritten by an independent writer (rosbags'
rosbag2 and rosbag1 writers, and its ROS 2 to ROS 1 converter): the analysis must agree
with that of the original (wear and lost motion within 2 %).
"""

import json
from pathlib import Path
import re
import sqlite3

from cli_runs import run_cli as _run
import numpy as np
import pytest
from reducer_twin.analysis.pipeline import analyze_bag
from reducer_twin.analysis.settings import AnalysisSettings
from reducer_twin.analysis.simulate import simulate_bag, SimulationSpec
from reducer_twin.core.errors import BagError
from reducer_twin.io.bag import open_bag
from reducer_twin.msg_adapters.dynamic_joint_state import MSGTYPE as DJS
from reducer_twin.msg_adapters.jointstate_cdr import MSGTYPE as JOINT_STATE
from rosbags.convert import convert
from rosbags.highlevel import AnyReader
from rosbags.rosbag1 import Writer as Writer1
from rosbags.rosbag2 import Reader, StoragePlugin, Writer
from rosbags.rosbag2.enums import CompressionFormat, CompressionMode
from rosbags.typesys import get_types_from_msg, get_typestore, Stores

AGING = 180_000.0
SPEC = SimulationSpec(hours=2000.0, aging_factor=AGING, joints=2, rate_hz=250.0, seed=5,
                      wear_rate_scales=(1.0, 2.0), load_torque_nm=1.2 * 784.0)
SETTINGS = AnalysisSettings(aging_factor=AGING)
IV = 'control_msgs/msg/InterfaceValue'
JAZZY = get_typestore(Stores.ROS2_JAZZY)
NOETIC = get_typestore(Stores.ROS1_NOETIC)
STORE = get_typestore(Stores.ROS2_JAZZY)
STORE.register({
    **get_types_from_msg('std_msgs/Header header\nstring[] joint_names\n'
                         'InterfaceValue[] interface_values\n', DJS),
    **get_types_from_msg('string[] interface_names\nfloat64[] values\n', IV)})
TYPES = STORE.types
JOINTS = ('joint_1', 'joint_2')


def _messages(bag):
    """Read the JointState messages of a bag with rosbags."""
    with AnyReader([Path(bag)], default_typestore=JAZZY) as reader:
        conns = [c for c in reader.connections if c.msgtype == JOINT_STATE]
        return [(c.topic, t, reader.deserialize(raw, c.msgtype))
                for c, t, raw in reader.messages(conns)]


def _interfaces(msg, joint, names):
    index = {n: k for k, n in enumerate(msg.name)}
    link, motor = index[joint], index[joint + '_motor']
    return {'position': msg.position[link], 'velocity': msg.velocity[link],
            'effort': msg.effort[link], names['motor']: msg.position[motor],
            'temperature': 41.5}


def _write_djs(dst, messages, storage=StoragePlugin.MCAP, joint_states=False,
               motor_only=False, motor='motor_position', extra=()):
    """
    Rewrite combined JointState messages as ros2_control publishes them.

    ``/dynamic_joint_states`` with each joint's interfaces (in a different order per joint,
    as hardware exports them), and with ``joint_states`` the broadcaster's ``/joint_states``
    that holds the joints only. ``motor_only``: the dynamic topic carries the motor
    interface alone. ``extra``: joints with a position interface only (a gripper).
    """
    with Writer(dst, version=9, storage_plugin=storage) as writer:
        dynamic = writer.add_connection('/dynamic_joint_states', DJS, typestore=STORE)
        states = writer.add_connection('/joint_states', JOINT_STATE, typestore=STORE) \
            if joint_states else None
        for _, stamp, msg in messages:
            ivs = []
            for k, joint in enumerate(JOINTS):
                values = _interfaces(msg, joint, {'motor': motor})
                names = [motor] if motor_only else list(values)[::1 if k == 0 else -1]
                ivs.append(TYPES[IV](names, np.array([values[n] for n in names])))
            ivs += [TYPES[IV](['position'], np.array([0.01])) for _ in extra]
            writer.write(dynamic, stamp, STORE.serialize_cdr(
                TYPES[DJS](msg.header, [*JOINTS, *extra], ivs), DJS))
            if states is not None:
                keep = [msg.name.index(j) for j in JOINTS]
                writer.write(states, stamp, STORE.serialize_cdr(TYPES[JOINT_STATE](
                    msg.header, list(JOINTS), msg.position[keep], msg.velocity[keep],
                    msg.effort[keep]), JOINT_STATE))
    return dst


def _write_ros1(dst, messages):
    """Rewrite JointState messages (any topics) with rosbags' ROS 1 writer, lz4 chunks."""
    writer = Writer1(dst)
    writer.set_compression(Writer1.CompressionFormat.LZ4)
    with writer:
        conns = {}
        for seq, (topic, stamp, msg) in enumerate(messages):
            if topic not in conns:
                conns[topic] = writer.add_connection(topic, JOINT_STATE, typestore=NOETIC)
            header = NOETIC.types['std_msgs/msg/Header'](
                seq, NOETIC.types['builtin_interfaces/msg/Time'](msg.header.stamp.sec,
                                                                 msg.header.stamp.nanosec),
                msg.header.frame_id)
            writer.write(conns[topic], stamp, NOETIC.serialize_ros1(NOETIC.types[JOINT_STATE](
                header, msg.name, msg.position, msg.velocity, msg.effort), JOINT_STATE))
    return dst


def _convert_to_ros1(src, dst):
    """Convert with rosbags' converter, called as the ros1-bag acceptance check calls it."""
    convert([Path(src)], Path(dst), dst_storage='sqlite3', dst_version=8, compress=None,
            compress_mode='file', default_typestore=JAZZY, typestore=NOETIC,
            exclude_topics=[], include_topics=[], exclude_msgtypes=[], include_msgtypes=[])
    return dst


@pytest.fixture(scope='module')
def combined(tmp_path_factory):
    """Simulate the one-topic bag; return it, its JointState messages and its analysis."""
    root = tmp_path_factory.mktemp('combined')
    simulate_bag(root / 'robot', SPEC)
    return root / 'robot', _messages(root / 'robot'), analyze_bag(root / 'robot',
                                                                  root / 'derived', SETTINGS)


@pytest.fixture(scope='module')
def split(tmp_path_factory):
    """Simulate the two-topic bag (``/joint_states``, ``/motor_states``) and analyse it."""
    root = tmp_path_factory.mktemp('split')
    simulate_bag(root / 'robot', SimulationSpec(**{**SPEC.__dict__, 'layout': 'split'}))
    return root / 'robot', _messages(root / 'robot'), analyze_bag(root / 'robot',
                                                                  root / 'derived', SETTINGS)


def _agree(result, original):
    """Wear and lost motion of every joint within 2 % of the original analysis."""
    assert list(result.joints) == list(original.joints) == list(JOINTS)
    for joint, want in original.joints.items():
        a, b = result.joints[joint].summary(), want.summary()
        assert b['wear_um'] > 0 and b['lost_motion_arcmin'] > 0
        for key in ('wear_um', 'lost_motion_arcmin'):
            assert a[key] == pytest.approx(b[key], rel=0.02), (joint, key)
        assert len(result.joints[joint].features) == len(want.features)


# --------------------------------------------------------------------------- DynamicJointState


def test_a_dynamic_joint_states_bag_alone_analyses_like_the_joint_states_it_came_from(
        combined, tmp_path):
    bag = _write_djs(tmp_path / 'djs', combined[1])
    result = analyze_bag(bag, tmp_path / 'out', SETTINGS)
    assert (result.plan.link_topic, result.plan.motor_topic) == ('/dynamic_joint_states', None)
    assert result.plan.motor_names == ('joint_1_motor', 'joint_2_motor')
    assert result.messages == len(combined[1]) and result.warnings == []
    _agree(result, combined[2])


def test_a_dynamic_joint_without_the_motor_interface_is_named_with_the_setting(
        combined, tmp_path):
    bag = _write_djs(tmp_path / 'gripper', combined[1], extra=('gripper',))
    result = analyze_bag(bag, tmp_path / 'out', SETTINGS)
    _agree(result, combined[2])
    (warning,) = result.warnings
    assert ('/dynamic_joint_states also carries gripper without a motor entry '
            '(<joint>_motor): not analysed; a reducer among them needs both its encoders '
            "published under the twin's names (its interface 'motor_position': "
            'twin.interfaces.motor_position; twin.joints chooses the joints)') in str(warning)


def test_dynamic_joint_states_beside_the_broadcasters_joint_states_give_the_motor_angles(
        combined, tmp_path):
    # /joint_states holds the joints only (as joint_state_broadcaster publishes it): the
    # pairs are on /dynamic_joint_states.
    bag = _write_djs(tmp_path / 'both', combined[1], joint_states=True)
    result = analyze_bag(bag, tmp_path / 'out', SETTINGS)
    assert result.plan.link_topic == '/dynamic_joint_states'
    _agree(result, combined[2])


def test_a_motor_interface_alone_on_dynamic_joint_states_pairs_with_joint_states(
        combined, tmp_path):
    bag = _write_djs(tmp_path / 'motor', combined[1], joint_states=True, motor_only=True)
    result = analyze_bag(bag, tmp_path / 'out', SETTINGS)
    plan = result.plan
    assert (plan.link_topic, plan.motor_topic) == ('/joint_states', '/dynamic_joint_states')
    assert result.plan.motor_names == ('joint_1_motor', 'joint_2_motor')
    _agree(result, combined[2])


def test_a_sqlite3_bag_is_read_by_its_stored_definition_and_without_one_by_the_builtin(
        combined, tmp_path):
    bag = _write_djs(tmp_path / 'db3', combined[1], storage=StoragePlugin.SQLITE3)
    _agree(analyze_bag(bag, tmp_path / 'out', SETTINGS), combined[2])
    # rosbag2 before Iron stored no definitions: the reader says it uses control_msgs'.
    with sqlite3.connect(next(bag.glob('*.db3'))) as db:
        db.execute('DELETE FROM message_definitions')
    result = analyze_bag(bag, tmp_path / 'out2', SETTINGS)
    _agree(result, combined[2])
    (warning,) = result.warnings
    assert 'stores no message definition of control_msgs/msg/DynamicJointState' in str(warning)


def test_config_names_the_motor_interface_a_robot_exports(combined, tmp_path, capsys):
    bag = _write_djs(tmp_path / 'custom', combined[1], motor='encoder2/position')
    code, _, err = _run(['analyze', bag, '--out', tmp_path / 'a'], capsys)
    assert code == 1
    assert "from its interface 'motor_position' (twin.interfaces.motor_position)" in err
    config = tmp_path / 'twin.yaml'
    config.write_text(f'twin:\n  aging_factor: {AGING}\n  interfaces:\n'
                      '    motor_position: encoder2/position\n', encoding='utf-8')
    code, out, err = _run(['analyze', bag, '--out', tmp_path / 'b', '--json', '--config',
                           config], capsys)
    assert code == 0, err
    got = json.loads(out)['joints']
    for joint, want in combined[2].joints.items():
        for key in ('wear_um', 'lost_motion_arcmin'):
            assert got[joint][key] == pytest.approx(want.summary()[key], rel=0.02)


@pytest.mark.parametrize('interfaces, reason', [
    ('{motor_angle: x}', r"twin.interfaces: unknown keys \['motor_angle'\]"),
    ('{motor_position: position}', 'six distinct'),
], ids=['an unknown key', 'the joint position named as the motor position'])
def test_a_bad_interfaces_config_is_one_error_line(combined, tmp_path, capsys, interfaces,
                                                   reason):
    config = tmp_path / 'twin.yaml'
    config.write_text(f'twin:\n  interfaces: {interfaces}\n', encoding='utf-8')
    code, out, err = _run(['analyze', combined[0], '--out', tmp_path / 'o', '--config', config],
                          capsys)
    assert code != 0 and out == ''
    (line,) = err.strip().splitlines()
    assert line.startswith('ERROR: ') and re.search(reason, line), line


# --------------------------------------------------------------------------- ROS 1


def test_a_ros1_bag_from_rosbags_converter_analyses_like_the_original(combined, tmp_path,
                                                                      capsys):
    bag = _convert_to_ros1(combined[0], tmp_path / 'robot.bag')
    config = tmp_path / 'twin.yaml'   # a ROS 1 bag has no custom_data: the config says
    config.write_text(f'twin:\n  aging_factor: {AGING}\n', encoding='utf-8')
    code, out, err = _run(['analyze', bag, '--out', tmp_path / 'derived', '--json',
                           '--config', config], capsys)
    assert code == 0, err
    got = json.loads(out)['joints']
    for joint, want in combined[2].joints.items():
        for key in ('wear_um', 'lost_motion_arcmin'):
            assert got[joint][key] == pytest.approx(want.summary()[key], rel=0.02)
        assert got[joint]['messages'] == len(combined[1])
    # The derived bag is rosbag2 MCAP, as for any input; the ground truth came along as CDR.
    assert len(list((tmp_path / 'derived').glob('*.mcap'))) == 1
    assert 'storage_identifier: mcap' in (tmp_path / 'derived' / 'metadata.yaml').read_text()
    with AnyReader([tmp_path / 'derived'], default_typestore=JAZZY) as reader:
        truth = [c for c in reader.connections if c.topic.endswith('ground_truth')]
        assert len(truth) == 2
        for conn, _, raw in reader.messages(truth):
            assert len(reader.deserialize(raw, conn.msgtype).data) > 0


def test_a_ros1_bag_of_two_topics_from_rosbags_writer_analyses_like_the_original(
        split, tmp_path):
    topics = {t for t, _, _ in split[1]}
    assert topics == {'/joint_states', '/motor_states'}
    bag = _write_ros1(tmp_path / 'split.bag', split[1])
    result = analyze_bag(bag, tmp_path / 'out', SETTINGS)
    plan = result.plan
    assert (plan.link_topic, plan.motor_topic) == ('/joint_states', '/motor_states')
    assert result.messages == len(split[1]) and result.warnings == []
    _agree(result, split[2])


def test_without_a_config_a_ros1_bag_is_analysed_at_aging_factor_one(combined, tmp_path):
    bag = _write_ros1(tmp_path / 'robot.bag', combined[1][:2000])
    result = analyze_bag(bag, tmp_path / 'out')
    assert result.aging_factor == 1.0


def test_a_ros1_bag_without_joint_states_is_refused_naming_its_topics(tmp_path):
    path = tmp_path / 'talk.bag'
    with Writer1(path) as writer:
        conn = writer.add_connection('/chatter', 'std_msgs/msg/String', typestore=NOETIC)
        writer.write(conn, 1, NOETIC.serialize_ros1(NOETIC.types['std_msgs/msg/String']('hi'),
                                                    'std_msgs/msg/String'))
    with pytest.raises(BagError, match=r'no sensor_msgs/msg/JointState topic; found: '
                                       r'/chatter \(std_msgs/msg/String\)'):
        analyze_bag(path, tmp_path / 'out')


def _json_mcap(path, messages, cdr_from=None):
    """
    Write JointState as a Foxglove bridge records it: JSON, in an MCAP of its own making.

    ``cdr_from``: a bag whose CDR messages (and schemas) are copied in beside.
    """
    from mcap.reader import make_reader
    from mcap.writer import Writer as McapWriter
    with open(path, 'wb') as stream:
        writer = McapWriter(stream)
        writer.start(profile='', library='a bridge')
        schema = writer.register_schema(name=JOINT_STATE, encoding='jsonschema', data=b'{}')
        channel = writer.register_channel('/bridge/joint_states', 'json', schema)
        for _, stamp, msg in messages:
            body = {'header': {'stamp': {'sec': msg.header.stamp.sec,
                                         'nanosec': msg.header.stamp.nanosec}},
                    'name': list(msg.name), 'position': msg.position.tolist(),
                    'velocity': msg.velocity.tolist(), 'effort': msg.effort.tolist()}
            writer.add_message(channel, stamp, json.dumps(body).encode(), stamp)
        if cdr_from is not None:
            schemas, channels = {}, {}
            with open(next(Path(cdr_from).glob('*.mcap')), 'rb') as source:
                for sch, ch, m in make_reader(source).iter_messages():
                    if sch.id not in schemas:
                        schemas[sch.id] = writer.register_schema(sch.name, sch.encoding,
                                                                 sch.data)
                    if ch.id not in channels:
                        channels[ch.id] = writer.register_channel(
                            ch.topic, ch.message_encoding, schemas[sch.id], ch.metadata)
                    writer.add_message(channels[ch.id], m.log_time, m.data, m.publish_time)
        writer.finish()
    return path


def test_joint_states_in_json_are_refused_naming_the_encoding(combined, tmp_path):
    # Read as CDR, every message was "malformed JointState CDR ... encapsulation header
    # 7b 22 68 65 is not plain CDR": true, but it did not say the messages were JSON.
    bag = _json_mcap(tmp_path / 'bridge.mcap', combined[1][:200])
    with pytest.raises(BagError, match=r'/bridge/joint_states carries its messages encoded as '
                                       r'.json.; reducer-twin reads JointState as rosbag2 '
                                       r'records it \(CDR\)'):
        analyze_bag(bag, tmp_path / 'out')
    assert not (tmp_path / 'out').exists()


def test_joint_states_in_json_beside_cdr_ones_are_left_out_and_said(combined, tmp_path):
    bag = _json_mcap(tmp_path / 'both.mcap', combined[1][:200], cdr_from=combined[0])
    result = analyze_bag(bag, tmp_path / 'out', SETTINGS)
    said = [w.message for w in result.warnings if "encoded as 'json'" in w.message]
    assert said == ["/bridge/joint_states carries its messages encoded as 'json': left out "
                    '(reducer-twin reads CDR, as rosbag2 records it)']
    for joint, res in combined[2].joints.items():
        assert result.joints[joint].summary() == res.summary()


# --------------------------------------------------------------------------- rosbag2 compression


def _digests(root):
    return {p.name: p.read_bytes() for p in sorted(root.iterdir())}


@pytest.mark.parametrize('mode', ['file', 'message'])
def test_a_recording_rosbag2_compressed_analyses_as_the_original_and_is_left_as_it_was(
        combined, tmp_path, capsys, mode):
    with open_bag(combined[0]) as bag:
        custom = bag.metadata
    writer = Writer(tmp_path / 'packed', version=9, storage_plugin=StoragePlugin.MCAP)
    writer.set_compression(CompressionMode[mode.upper()], CompressionFormat.ZSTD)
    for key, value in custom.items():   # the aging factor, as the recorder was given it
        writer.set_custom_data(key, value)
    with Reader(combined[0]) as reader, writer:
        out = {c.id: writer.add_connection(c.topic, c.msgtype, msgdef=c.msgdef.data,
                                           rihs01=c.digest) for c in reader.connections}
        for connection, stamp, raw in reader.messages():
            writer.write(out[connection.id], stamp, raw)
    before = _digests(tmp_path / 'packed')
    code, text, err = _run(['analyze', tmp_path / 'packed', '--out', tmp_path / 'derived',
                            '--json'], capsys)
    assert code == 0, err
    assert 'WARNING' not in err
    got = json.loads(text)['joints']
    for joint, want in combined[2].joints.items():
        for key in ('wear_um', 'lost_motion_arcmin', 'rul_p50_h'):
            assert got[joint][key] == pytest.approx(want.summary()[key], rel=1e-9), key
        assert got[joint]['messages'] == len(combined[1])
    assert _digests(tmp_path / 'packed') == before
