"""
Header stamps before 1970: one clear error before any work, and nothing left behind.

The derived bag is logged at the JointState header stamps, and a log time cannot be
negative (an MCAP log time is unsigned). A recording stamped before 1970-01-01 (a clock
set to a negative offset) ended in the array writer's ``log_times_ns and
publish_times_ns must be >= 0 ns``, naming neither the bag, the topic nor the stamp.
Bags written here with rosbags from a simulated recording, stamps moved, log times kept.
"""

import hashlib
import json
from pathlib import Path

import pytest
from reducer_twin.analysis.simulate import AGING_KEY
from reducer_twin.cli import main
from reducer_twin.io.outputs import TEMP_TAG
from rosbags.highlevel import AnyReader
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import get_typestore, Stores
from small_bags import small_bag

JOINT_STATE = 'sensor_msgs/msg/JointState'
SEC = 1_000_000_000


@pytest.fixture(scope='module')
def recording(tmp_path_factory):
    """Simulate 10 s of two joints at 500 Hz."""
    return small_bag(tmp_path_factory, 'epoch')


def restamped(recording, root, first_stamp_ns):
    """Write the JointState messages with rosbags, header stamps from ``first_stamp_ns`` on."""
    typestore = get_typestore(Stores.ROS2_JAZZY)
    writer = Writer(root, version=9, storage_plugin=StoragePlugin.MCAP)
    writer.set_custom_data(AGING_KEY, '360000.0')
    shift = None
    with AnyReader([recording], default_typestore=typestore) as reader, writer:
        connection = writer.add_connection('/joint_states', JOINT_STATE, typestore=typestore)
        joint_states = [c for c in reader.connections if c.msgtype == JOINT_STATE]
        for _, log_ns, raw in reader.messages(connections=joint_states):
            msg = reader.deserialize(raw, JOINT_STATE)
            stamp = msg.header.stamp.sec * SEC + msg.header.stamp.nanosec
            shift = first_stamp_ns - stamp if shift is None else shift
            msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp + shift, SEC)
            writer.write(connection, log_ns, typestore.serialize_cdr(msg, JOINT_STATE))
    return root


def digest(root):
    """Return the sha256 of every file under ``root`` (equal: unchanged)."""
    return {str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(Path(root).rglob('*')) if p.is_file()}


def analyze(argv, capsys):
    """Run ``reducer-twin analyze`` in this process; return code, stdout and stderr."""
    code = main(['analyze', *(str(a) for a in argv)])
    out, err = capsys.readouterr()
    return code, out, err


def test_a_bag_stamped_before_1970_is_one_error_naming_bag_topic_stamp_and_range(
        recording, tmp_path, capsys):
    bag = restamped(recording, tmp_path / 'before1970', -100 * SEC)
    before = digest(bag)
    out = tmp_path / 'd'
    code, stdout, err = analyze([bag, '--out', out, '--json'], capsys)
    assert code == 1 and stdout == '' and 'Traceback' not in err
    assert err.splitlines() == [
        f'ERROR: {bag}: the header stamps on /joint_states go back to -100.000 s (1969-12-31 '
        '23:58:20 UTC), before 1970; expected stamps >= 0 s (1970-01-01 00:00:00 UTC or '
        'later): the derived bag is logged at the stamps, and a log time cannot be negative']
    assert not out.exists(), 'no derived bag'
    assert [p.name for p in tmp_path.iterdir() if TEMP_TAG in p.name] == [], 'no temporary'
    assert digest(bag) == before, 'the recording is untouched'


def test_a_bag_stamped_from_the_epoch_on_is_analysed(recording, tmp_path, capsys):
    # The lowest stamp allowed: 0 s, as with a simulated clock started at zero.
    bag = restamped(recording, tmp_path / 'from1970', 0)
    code, stdout, err = analyze([bag, '--out', tmp_path / 'd', '--json'], capsys)
    assert code == 0 and 'ERROR' not in err, err
    joints = json.loads(stdout)['joints']
    assert sorted(joints) == ['joint_1', 'joint_2']
    assert all(j['observed'] and j['windows'] > 0 for j in joints.values()), joints
    assert (tmp_path / 'd' / 'metadata.yaml').exists()
