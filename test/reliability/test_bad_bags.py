"""
Bad input in bags: the reliability table through ``reducer-twin analyze``, and damaged files.

Every case of ``bad_inputs.py`` (the table the live chain gets over DDS) is written
into a rosbag2 bag with the project's writer, as ``ros2 bag record`` would have stored
the controller's messages (log times in arrival order, header stamps as the case has
them), and analysed by the ``reducer-twin analyze`` CLI, in this process (and twice
as the installed console script). Then damaged files: an MCAP file cut at several
offsets, empty, with a wrong magic, with flipped bits, and bag directories whose
``metadata.yaml`` disagrees with their files.

What the README promises: bad messages in a readable bag are dropped or repaired by
the ingestion rules, counted (``rejected`` in the JSON, the ingest status on the
derived bag's ``/diagnostics``), and the bag exits 0; a damaged bag is analysed as
far as it is readable, says where reading stopped, and exits 1; an unreadable one
prints one ``ERROR:`` line and exits 1. Never a traceback.
"""

import contextlib
import io
import json
import math
import re
import shutil
import subprocess

import bad_inputs as bad
from diagnostic_msgs.msg import DiagnosticArray
import numpy as np
import pytest
from rclpy.serialization import deserialize_message, serialize_message
from reducer_twin.analysis.simulate import AGING_KEY
from reducer_twin.cli import main
from reducer_twin.io.bag import BagDirWriter, open_bag
from reducer_twin.msg_adapters.jointstate_cdr import encode_joint_states
from reducer_twin.msg_adapters.ros import make_joint_state


pytestmark = pytest.mark.timeout(120, method='thread')

JOINT_STATE = 'sensor_msgs/msg/JointState'
T0_NS = 1_700_000_000_000_000_000
"""Stamp of the first sample (November 2023) [ns]."""

TOPICS = {'link': '/joint_states', 'motor': '/motor_states'}
JSON_FIELDS = ('wear_um', 'wear_std_um', 'rul_p10_h', 'rul_p50_h', 'rul_p90_h',
               'lost_motion_arcmin', 'lost_motion_std_arcmin')
REJECTING = ('non_finite', 'duplicate', 'out_of_order')
"""Stream rules whose samples the JSON's ``rejected`` counts (with unpaired and spike)."""


def _regular(m):
    n = len(m.names)
    return len(m.position) == n and len(m.velocity) in (0, n) and len(m.effort) in (0, n)


def write_bag(root, messages, chunk_size=None):
    """
    Write messages into a rosbag2 bag directory as a recorder receives them.

    Log times are the arrival order (1 ms apart), header stamps the messages' own.
    Runs of messages with the same layout go through the vectorised encoder; a
    message whose arrays do not match its names is serialised by rclpy.
    """
    extra = {} if chunk_size is None else {'chunk_size': chunk_size}
    with BagDirWriter(root, compression='none', custom_data={AGING_KEY: repr(bad.AGING)},
                      **extra) as writer:
        channels = {side: writer.add_topic(TOPICS[side], JOINT_STATE)
                    for side in dict.fromkeys(m.topic for m in messages)}
        start = 0
        while start < len(messages):
            first = messages[start]
            key = (first.topic, first.names, len(first.velocity), len(first.effort))
            stop = start + 1
            if _regular(first):
                while stop < len(messages) and _regular(messages[stop]) and (
                        messages[stop].topic, messages[stop].names,
                        len(messages[stop].velocity), len(messages[stop].effort)) == key:
                    stop += 1
                run = messages[start:stop]
                buf, offsets = encode_joint_states(
                    np.array([m.stamp_ns for m in run]), first.names,
                    np.array([m.position for m in run]),
                    np.array([m.velocity for m in run]) if first.velocity else None,
                    np.array([m.effort for m in run]) if first.effort else None)
                writer.write_batch(channels[first.topic],
                                   T0_NS + np.arange(start, stop) * 1_000_000, buf, offsets)
            else:
                msg = make_joint_state(first.stamp_ns, first.names, first.position,
                                       first.velocity or None, first.effort or None)
                writer.write(channels[first.topic], T0_NS + start * 1_000_000,
                             serialize_message(msg))
            start = stop
    return root


def analyze(argv, capsys):
    """Run ``reducer-twin analyze`` in this process; return code, JSON (or None), stderr."""
    try:
        code = main(['analyze', *(str(a) for a in argv)])
    except SystemExit as exit_:
        code = exit_.code
    out, err = capsys.readouterr()
    assert 'Traceback' not in out + err
    assert all(line.startswith(('ERROR: ', 'WARNING: ')) for line in err.splitlines()), err
    return code, (json.loads(out) if out.strip() else None), err


def ingest_status(derived, joint):
    """Return the key/values of the last ingest status of ``joint`` in a derived bag."""
    found = None
    with open_bag(derived) as bag:
        for _, raw in bag.iter_raw(['/diagnostics']):
            for i in range(len(raw)):
                msg = deserialize_message(bytes(raw.payload(i)), DiagnosticArray)
                for status in msg.status:
                    if status.name == f'reducer_twin: {joint} encoder ingest':
                        found = {kv.key: kv.value for kv in status.values}
    assert found is not None, f'no ingest status of {joint} in {derived}'
    return found


def assert_finite(summary):
    """Assert every estimate of a joint's JSON summary is a finite number."""
    for field in JSON_FIELDS:
        value = summary[field]
        assert value is not None and math.isfinite(value), field
    assert summary['rul_p10_h'] <= summary['rul_p50_h'] <= summary['rul_p90_h']


@pytest.fixture(scope='module')
def stream():
    """Return the clean stream of the table."""
    return bad.simulate(T0_NS)


@pytest.fixture(scope='module')
def clean(stream, tmp_path_factory):
    """
    Return the clean bag and the JSON summary of its joint.

    Small chunks (64 KiB, 15 of them), so that damage leaves most of the file readable.
    """
    root = tmp_path_factory.mktemp('clean') / 'robot'
    write_bag(root, stream.messages(), chunk_size=64 * 1024)
    text = io.StringIO()
    with contextlib.redirect_stdout(text):
        assert main(['analyze', str(root), '--out', str(root.parent / 'derived'),
                     '--json']) == 0
    return root, json.loads(text.getvalue())['joints'][bad.JOINT]


# --------------------------------------------------------------------------- bad messages


@pytest.mark.parametrize('case', bad.CASES, ids=[c.name for c in bad.CASES])
def test_a_bag_with_a_bad_input_is_analysed_counting_what_was_dropped(
        tmp_path, capsys, stream, clean, case):
    messages = case.spoil(stream)
    bag = write_bag(tmp_path / 'robot', messages)
    code, data, err = analyze([bag, '--out', tmp_path / 'derived', '--json'], capsys)
    assert code == 0, err                       # a readable bag: bad samples are not damage
    assert list(data['joints']) == [bad.JOINT]
    got = data['joints'][bad.JOINT]
    assert_finite(got)
    # The ingest counts on the derived bag's /diagnostics, and what `rejected` sums; a
    # message refused whole (as the node refuses it) is malformed, not a message read.
    expected = bad.expected_counts(case, stream, offline=True)
    refused = expected.pop('rejected_messages', 0)
    assert got['messages'] == len(messages) - refused - case.not_naming
    status = ingest_status(tmp_path / 'derived', bad.JOINT)
    assert {k: int(status[k]) for k in expected} == expected
    assert int(status['malformed_messages']) == refused
    assert int(status['published']) == case.published(stream)
    assert got['rejected'] == refused + sum(v for k, v in expected.items()
                                            if k.endswith(REJECTING)
                                            or k in ('unpaired', 'spike'))

    # The estimate holds, with the tolerances of the live table (test_bad_messages.py).
    reference = clean[1]
    tol = 3.0 * math.hypot(got['wear_std_um'], reference['wear_std_um'])
    if case.same_windows:
        tol = 0.02
    assert abs(got['wear_um'] - reference['wear_um']) <= tol
    # The remaining-life intervals agree: calibrated 80 % intervals from a few windows that
    # differ need not hold each other's median, but they must overlap.
    assert got['rul_p10_h'] <= reference['rul_p90_h']
    assert reference['rul_p10_h'] <= got['rul_p90_h']


def test_the_installed_command_analyses_a_bag_with_a_clock_reset_without_a_traceback(
        tmp_path, stream, venv_bin):
    case = next(c for c in bad.CASES if c.spoil.__name__ == '_clock_reset')
    bag = write_bag(tmp_path / 'robot', case.spoil(stream))
    result = subprocess.run([str(venv_bin / 'reducer-twin'), 'analyze', str(bag), '--out',
                             str(tmp_path / 'derived'), '--json'],
                            capture_output=True, text=True, timeout=120)
    assert result.returncode == 0 and 'Traceback' not in result.stderr, result.stderr
    assert_finite(json.loads(result.stdout)['joints'][bad.JOINT])


# --------------------------------------------------------------------------- damaged files


def _mcap(root):
    (path,) = root.glob('*.mcap')
    return path


def _cut(fraction):
    def damage(root):
        path = _mcap(root)
        data = path.read_bytes()
        path.write_bytes(data[:int(len(data) * fraction)])
    return damage


def _flip(seed):
    """Flip three seeded bits in the chunks (the first 80 % of the file, past its header)."""
    def damage(root):
        path = _mcap(root)
        data = bytearray(path.read_bytes())
        rng = np.random.default_rng(seed)
        for at in rng.integers(1000, int(0.8 * len(data)), 3):
            data[at] ^= 1 << int(rng.integers(0, 8))
        path.write_bytes(bytes(data))
    return damage


def _empty_split_file(root):
    """Make a split bag whose second file exists but is empty (0 bytes)."""
    (root / 'robot_1.mcap').write_bytes(b'')
    _edit_metadata(root, '    - robot_0.mcap\n', '    - robot_0.mcap\n    - robot_1.mcap\n')


def _edit_metadata(root, old, new):
    path = root / 'metadata.yaml'
    text = path.read_text()
    assert old in text
    path.write_text(text.replace(old, new, 1))


# (id, damage, exit code, what stderr must say, messages analysed: 'some', 'all' or 'none')
DAMAGED = [
    ('a file cut in its header', _cut(0.0005), 1, r'ERROR: .*robot_0\.mcap: reading stopped '
     r'at byte \d+ of \d+', 'none'),
    ('a file cut at 30 %', _cut(0.3), 1, r'WARNING: .*robot_0\.mcap: reading stopped at '
     r'byte \d+ of \d+', 'some'),
    ('a file cut at 60 %', _cut(0.6), 1, r'WARNING: .*robot_0\.mcap: reading stopped at '
     r'byte \d+ of \d+', 'some'),
    ('a file cut at 97 %', _cut(0.97), 1, r'WARNING: .*robot_0\.mcap: reading stopped at '
     r'byte \d+ of \d+', 'some'),
    pytest.param(
        'a file cut in its summary', _cut(0.9999), 1, r'WARNING: .*robot_0\.mcap: ', 'all',
        id='a file cut in its summary'),
    ('an empty file', lambda root: _mcap(root).write_bytes(b''), 1,
     r'^ERROR: .*robot_0\.mcap is empty \(0 bytes\)', 'none'),
    ('a file with a wrong magic',
     lambda root: _mcap(root).write_bytes(b'PK\x03\x04' + _mcap(root).read_bytes()[4:]), 1,
     r'^ERROR: .*robot_0\.mcap is neither MCAP nor sqlite3: byte 0 holds 50 4b 03 04',
     'none'),
    ('bits flipped in the chunks (seed 1)', _flip(1), 1,
     r'WARNING: .*robot_0\.mcap: chunk at byte \d+ fails its CRC check', 'some'),
    ('bits flipped in the chunks (seed 2)', _flip(2), 1,
     r'WARNING: .*robot_0\.mcap: chunk at byte \d+ fails its CRC check', 'some'),
    ('an empty second file of a split bag', _empty_split_file, 1,
     r'WARNING: .*robot_1\.mcap is empty \(0 bytes\).*skipping that file', 'all'),
    pytest.param(
        'metadata listing a file that is missing',
        lambda root: _edit_metadata(root, '    - robot_0.mcap\n',
                                    '    - robot_0.mcap\n    - robot_1.mcap\n'),
        1, r"WARNING: .*metadata\.yaml lists 1 file\(s\) that do not exist: \['robot_1\.mcap'\]",
        'all',
        id='metadata listing a file that is missing'),
    pytest.param(
        'metadata counting more messages than the files hold',
        lambda root: _edit_metadata(root, '      message_count: 6000\n',
                                    '      message_count: 7000\n'),
        1, r'WARNING: .*metadata lists 7000 messages on /joint_states, but the storage files '
        r'hold 6000', 'all',
        id='metadata counting more messages than the files hold'),
]


def _row(row):
    return row if hasattr(row, 'values') else pytest.param(*row, id=row[0])


@pytest.mark.parametrize('label, damage, code, says, analysed', [_row(r) for r in DAMAGED])
def test_a_damaged_bag_says_where_and_what_is_still_analysed(
        tmp_path, capsys, clean, stream, label, damage, code, says, analysed):
    root = tmp_path / 'robot'
    shutil.copytree(clean[0], root)
    damage(root)
    got, data, err = analyze([root, '--out', tmp_path / 'derived', '--json'], capsys)
    assert got == code, err
    assert re.search(says, err, re.MULTILINE), err
    if analysed == 'none':
        assert data is None and len([x for x in err.splitlines() if x.startswith('ERROR:')]) == 1
        return
    summary = data['joints'][bad.JOINT]
    assert_finite(summary)
    if analysed == 'all':
        assert summary['messages'] == bad.SAMPLES
    else:
        assert 0 < summary['messages'] < bad.SAMPLES
    # What was read is in the derived bag, and its windows reached the estimate.
    with open_bag(tmp_path / 'derived') as derived:
        assert derived.topics[f'/reducer_twin/{bad.JOINT}/wear'].count >= 2


def test_the_installed_command_reports_a_cut_bag_without_a_traceback(
        tmp_path, clean, venv_bin):
    root = tmp_path / 'robot'
    shutil.copytree(clean[0], root)
    _cut(0.5)(root)
    result = subprocess.run([str(venv_bin / 'reducer-twin'), 'analyze', str(root), '--out',
                             str(tmp_path / 'derived'), '--json'],
                            capture_output=True, text=True, timeout=120)
    assert result.returncode == 1 and 'Traceback' not in result.stderr
    assert f'WARNING: {_mcap(root)}: reading stopped at byte' in result.stderr
    assert 0 < json.loads(result.stdout)['joints'][bad.JOINT]['messages'] < bad.SAMPLES
