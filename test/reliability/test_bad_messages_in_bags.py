"""
Bad messages in a bag count, never abort: repeated names, stamps that stand, non-files.

A JointState that names a joint twice (a controller configuration error) has its later
entries dropped and counted, and the joint is analysed as from a clean recording; header
stamps that do not advance (a frozen clock, or all zero with no log time either) give a
WARNING naming the topic and the count, and a publisher that never stamps is read on the
recorder's receive times, said; a named pipe, a socket or a device given as a bag is
refused at once instead of blocking the reader.
"""

import json
import os
from pathlib import Path
import socket
import subprocess
import sys

import numpy as np
import pytest
from reducer_twin.analysis.simulate import AGING_KEY, simulate_bag, SimulationSpec
from reducer_twin.cli import main
from reducer_twin.io.bag import BagDirWriter, open_bag, write_bag_dir
from reducer_twin.msg_adapters.jointstate_cdr import JointStateBatch
import yaml

pytestmark = pytest.mark.timeout(120, method='thread')

JOINT_STATE = 'sensor_msgs/msg/JointState'
SPEC = SimulationSpec(hours=1000.0, aging_factor=360_000.0, joints=1, rate_hz=500.0, seed=7)


@pytest.fixture(scope='module')
def clean(tmp_path_factory):
    """Simulate a one-joint bag; return it and its JointState messages."""
    out = tmp_path_factory.mktemp('clean') / 'clean'
    simulate_bag(out, SPEC)
    with open_bag(out) as bag:
        batch = bag.read_joint_states()['/joint_states']
    return out, batch


def rewrite(path, batch):
    """Write ``batch`` as a bag with the simulated bag's aging factor."""
    return write_bag_dir(path, {'/joint_states': batch}, compression='none',
                         custom_data={AGING_KEY: repr(SPEC.aging_factor)})


def analyze(bag, out, capsys):
    """Run ``reducer-twin analyze --json`` in this process; return code, JSON and stderr."""
    code = main(['analyze', str(bag), '--out', str(out), '--json'])
    captured = capsys.readouterr()
    assert 'Traceback' not in captured.err
    return code, (json.loads(captured.out) if captured.out.strip() else None), captured.err


def warnings(err):
    """Return the WARNING lines of stderr."""
    return [line for line in err.splitlines() if line.startswith('WARNING:')]


@pytest.mark.parametrize('every', [1, 3], ids=['every message', 'every third message'])
def test_a_joint_named_twice_in_a_message_is_dropped_counted_and_the_first_entry_counts(
        clean, tmp_path, capsys, every):
    bag, batch = clean
    n = len(batch)
    repeated = JointStateBatch(
        batch.stamps_ns, batch.names + ('joint_1',),
        np.concatenate([batch.position, np.full((n, 1), 1e6)], axis=1),
        np.concatenate([batch.velocity, np.full((n, 1), -1e6)], axis=1),
        np.concatenate([batch.effort, np.full((n, 1), 7e5)], axis=1))
    twice = np.arange(n) % every == 0   # messages that name joint_1 twice
    path = write_runs(tmp_path / 'twice', [repeated if t else batch for t in twice])
    code, got, err = analyze(path, tmp_path / 'd', capsys)
    ref_code, ref, _ = analyze(bag, tmp_path / 'ref', capsys)
    assert code == ref_code == 0, err
    (line,) = [w for w in warnings(err) if 'named a joint' in w]
    assert f'{int(twice.sum()):,} JointState entries on /joint_states' in line, line
    assert list(got['joints']) == ['joint_1']
    for key in ('wear_um', 'lost_motion_arcmin', 'rul_p50_h', 'messages', 'rejected'):
        assert got['joints']['joint_1'][key] == ref['joints']['joint_1'][key], key
    info = yaml.safe_load((tmp_path / 'd' / 'metadata.yaml').read_text())
    info = info['rosbag2_bagfile_information']
    assert info['message_count'] > 0
    assert info['starting_time']['nanoseconds_since_epoch'] < 2**63 - 1


def write_runs(path, sources):
    """Write message i of ``sources[i]`` (a batch per message), runs of one batch at once."""
    n = len(sources)
    with BagDirWriter(path, compression='none',
                      custom_data={AGING_KEY: repr(SPEC.aging_factor)}) as writer:
        channel = writer.add_topic('/joint_states', JOINT_STATE)
        start = 0
        while start < n:
            stop = start + 1
            while stop < n and sources[stop] is sources[start]:
                stop += 1
            part = sources[start].take(np.arange(start, stop))
            writer.write_joint_states(channel, part, log_times_ns=part.stamps_ns)
            start = stop
    return path


def test_a_publisher_that_never_stamps_is_read_on_the_recorders_receive_times_and_said(
        clean, tmp_path, capsys):
    # Every header stamp zero (a driver that leaves header.stamp unset) made every joint
    # "not observed: stamps do not advance", although the recorder's log times were there.
    bag, batch = clean
    n = len(batch)
    code, expected, _ = analyze(bag, tmp_path / 'd', capsys)
    # Received 0.2-0.6 ms after the encoders were read, in order.
    delay = np.random.default_rng(4).uniform(2e5, 6e5, n).astype(np.int64)
    zero = JointStateBatch(np.zeros(n, np.int64), batch.names, batch.position, batch.velocity,
                           batch.effort, log_time_ns=batch.stamps_ns + delay)
    code, got, err = analyze(rewrite(tmp_path / 'zero', zero), tmp_path / 'd0', capsys)
    assert code == 0, err
    (line,) = [w for w in warnings(err) if 'header stamp' in w]
    assert 'every header stamp on /joint_states is zero' in line
    assert 'the times the recorder received them (log times) are taken instead' in line
    for joint, res in got['joints'].items():
        want = expected['joints'][joint]
        assert res['observed'] and res['windows'] >= want['windows'] - 1
        assert res['wear_um'] == pytest.approx(want['wear_um'], rel=0.05)
        assert res['lost_motion_arcmin'] == pytest.approx(want['lost_motion_arcmin'], rel=0.02)


def test_stamps_that_never_advance_give_a_warning_naming_the_topic_and_the_count(
        clean, tmp_path, capsys):
    _, batch = clean
    n = len(batch)
    # Zero stamps, and no log time to read instead (a bag whose log times are zero too).
    zero = JointStateBatch(np.zeros(n, np.int64), batch.names, batch.position, batch.velocity,
                           batch.effort, log_time_ns=np.zeros(n, np.int64))
    code, got, err = analyze(rewrite(tmp_path / 'zero', zero), tmp_path / 'd0', capsys)
    # Nothing can be observed with one stamp: the joints are declared, exit 3.
    assert code == 3 and got is not None
    assert all(not joint['observed'] for joint in got['joints'].values())
    (line,) = [w for w in warnings(err) if 'header stamp' in w and 'JointState messages' in w]
    assert f'{n - 1:,} of {n:,} JointState messages on /joint_states' in line
    assert 'all zero' in line, line
    frozen_stamps = batch.stamps_ns.copy()
    frozen_stamps[n // 2:] = frozen_stamps[n // 2]
    frozen = JointStateBatch(frozen_stamps, batch.names, batch.position, batch.velocity,
                             batch.effort, log_time_ns=batch.stamps_ns)
    code, got, err = analyze(rewrite(tmp_path / 'frozen', frozen), tmp_path / 'd1', capsys)
    (line,) = [w for w in warnings(err) if 'header stamp' in w and 'JointState messages' in w]
    assert f'{n - n // 2 - 1:,} of {n:,}' in line and 'a frozen clock' in line, line


def test_a_clock_set_back_while_recording_is_named_not_taken_for_a_frozen_one(
        clean, tmp_path, capsys):
    # Stamps and log times a quarter of the recording back from the middle on (an NTP
    # step): the two passes over that quarter interleave by log time, each stamp twice
    # with other positions. It was called 'a frozen clock, or each message logged twice'.
    _, batch = clean
    n = len(batch)
    stamps = batch.stamps_ns.copy()
    stamps[n // 2:] -= stamps[n // 4] - stamps[0]
    stepped = JointStateBatch(stamps, batch.names, batch.position, batch.velocity,
                              batch.effort, log_time_ns=stamps)
    # As a recorder writes it: chunks of a few hundred messages, in the order they came.
    with BagDirWriter(tmp_path / 'stepped', compression='none', chunk_size=16_384,
                      custom_data={AGING_KEY: repr(SPEC.aging_factor)}) as writer:
        writer.write_joint_states(writer.add_topic('/joint_states', JOINT_STATE), stepped)
    code, got, err = analyze(tmp_path / 'stepped', tmp_path / 'd', capsys)
    (line,) = [w for w in warnings(err) if 'header stamp' in w and 'JointState messages' in w]
    repeats = int(line.split(' of ')[0].split()[-1].replace(',', ''))
    assert repeats >= 0.9 * (n // 4), line
    assert 'two streams under one clock' in line and 'set back' in line, line
    assert 'frozen clock' not in line


def test_stamps_that_scatter_about_their_period_are_said(clean, tmp_path, capsys):
    # Stamped on arrival: +-0.9 ms about a 2 ms period, order kept.
    _, batch = clean
    rng = np.random.default_rng(3)
    stamps = batch.stamps_ns + rng.integers(-900_000, 900_000, len(batch))
    jittered = JointStateBatch(stamps, batch.names, batch.position, batch.velocity,
                               batch.effort, log_time_ns=stamps)
    code, got, err = analyze(rewrite(tmp_path / 'jittered', jittered), tmp_path / 'd', capsys)
    (line,) = [w for w in warnings(err) if 'scatter by' in w]
    assert 'about their 2 ms period' in line and 'stamped when a message arrived' in line
    share = int(line.split('period (')[1].split(' %')[0])
    assert 30 <= share <= 45, line


def test_stream_time_lost_in_holes_is_said_as_not_counted_operation(clean, tmp_path, capsys):
    # Bursts of lost messages, a tenth of the stream: the remaining life came out short
    # (its operating time not counted) without a word.
    _, batch = clean
    n = len(batch)
    keep = np.ones(n, bool)
    for start in range(n // 20, n, n // 10):
        keep[start:start + n // 100] = False            # ten holes of 1 % each
    holes = JointStateBatch(batch.stamps_ns[keep], batch.names, batch.position[keep],
                            batch.velocity[keep], batch.effort[keep],
                            log_time_ns=batch.stamps_ns[keep])
    code, got, err = analyze(rewrite(tmp_path / 'holes', holes), tmp_path / 'd', capsys)
    (line,) = [w for w in warnings(err) if 'holes longer than' in w]
    assert 'joint_1: ' in line and '(10 %) fall in 10 holes' in line, line
    assert 'not counted as operation' in line


def test_a_clean_bag_gives_no_stamp_or_name_warning(clean, tmp_path, capsys):
    code, _, err = analyze(clean[0], tmp_path / 'd', capsys)
    # A bag this short does not resolve its unit's own wear rate, which is said; nothing
    # about its stamps or names is.
    assert code == 0
    assert [w for w in warnings(err) if 'wear rate is not yet resolved' not in w] == []


def _fifo(tmp_path):
    path = tmp_path / 'pipe.mcap'
    os.mkfifo(path)
    return path


def _socket(tmp_path):
    path = tmp_path / 'sock.mcap'
    server = socket.socket(socket.AF_UNIX)
    server.bind(str(path))
    return path


def _fifo_in_a_bag_directory(tmp_path):
    root = tmp_path / 'bagdir'
    root.mkdir()
    os.mkfifo(root / 'bagdir_0.mcap')
    return root


@pytest.mark.parametrize('make, kind', [
    (_fifo, 'named pipe'), (_socket, 'socket'), (lambda t: Path('/dev/zero'), 'device'),
    (_fifo_in_a_bag_directory, 'named pipe')],
    ids=['fifo', 'socket', 'device', 'fifo in a bag directory'])
def test_a_named_pipe_socket_or_device_as_a_bag_is_refused_at_once(tmp_path, make, kind):
    given = make(tmp_path)
    done = subprocess.run([str(Path(sys.executable).parent / 'reducer-twin'), 'analyze',
                           str(given), '--out', str(tmp_path / 'd')],
                          capture_output=True, text=True, timeout=60)
    errors = [line for line in done.stderr.splitlines() if line.startswith('ERROR:')]
    assert done.returncode == 1 and 'Traceback' not in done.stderr
    assert len(errors) == 1 and kind in errors[0], done.stderr
    assert not (tmp_path / 'd').exists()
