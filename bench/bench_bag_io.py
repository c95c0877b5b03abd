#!/usr/bin/env python3
"""
Benchmark of the rosbag2 storage layer on a JointState bag (a script, not a test).

Writes a bag of N ``sensor_msgs/msg/JointState`` messages (one output-link joint and one
motor entry per message, position/velocity/effort, 1 kHz stamps) with our writer, reads
and decodes it with our reader, and on the same bag measures rosbags (AnyReader plus
``deserialize_cdr``, typestore ROS2_JAZZY) and the mcap library (raw messages, and decoded
with mcap-ros2-support on a slice). Prints messages per second for each.

Usage (with the package installed, e.g. ``pip install -e .``)::

    .venv/bin/python bench/bench_bag_io.py [--messages 1000000] [--repeat 3]
"""

import argparse
import os
from pathlib import Path
import sys
import tempfile
import time

import numpy as np
from reducer_twin.io.bag import BagDirWriter, open_bag
from reducer_twin.msg_adapters.jointstate_cdr import JointStateBatch

JOINT_STATE = 'sensor_msgs/msg/JointState'
T0 = 1_700_000_000_000_000_000
RATIO = 81.0  # reduction ratio of the simulated RV reducer


def make_batch(n, seed=0):
    """
    Build N messages of a slowly swinging joint and its motor, sampled at 1 kHz.

    Parameters
    ----------
    n : int
        Number of messages.
    seed : int
        Seed of the measurement noise.

    Returns
    -------
    JointStateBatch
        Link and motor position (rad), velocity (rad/s) and effort (N m).

    """
    rng = np.random.default_rng(seed)
    t = np.arange(n) * 1e-3
    link = 0.8 * np.sin(2 * np.pi * 0.25 * t)
    link_velocity = 0.8 * 2 * np.pi * 0.25 * np.cos(2 * np.pi * 0.25 * t)
    motor = RATIO * link + 2e-4 * np.sin(2 * np.pi * 39 * t) + rng.normal(0, 1e-5, n)
    position = np.stack([link, motor], axis=1)
    velocity = np.stack([link_velocity, RATIO * link_velocity], axis=1)
    effort = np.stack([120 + 30 * np.sin(2 * np.pi * 0.25 * t), 1.6 + rng.normal(0, 0.01, n)],
                      axis=1)
    stamps = T0 + np.arange(n, dtype=np.int64) * 1_000_000
    return JointStateBatch(stamps, ('joint_link', 'motor'), position, velocity, effort)


def time_write(out_dir, batch, framing='fast'):
    """Write the batch into a bag directory; return (wall, CPU) seconds."""
    start, cpu = time.perf_counter(), time.process_time()
    with BagDirWriter(out_dir, overwrite=True, framing=framing,
                      custom_data={'reducer_twin.bench': 'bag_io'}) as writer:
        channel = writer.add_topic('/joint_states', JOINT_STATE)
        writer.write_joint_states(channel, batch)
    return time.perf_counter() - start, time.process_time() - cpu


def time_read(out_dir, batch):
    """Read and decode the JointState topic; return (wall, CPU) seconds; checks values."""
    start, cpu = time.perf_counter(), time.process_time()
    with open_bag(out_dir) as bag:
        got = bag.read_joint_states(['/joint_states'])['/joint_states']
    seconds, cpu = time.perf_counter() - start, time.process_time() - cpu
    assert len(got) == len(batch) and np.array_equal(got.position, batch.position)
    return seconds, cpu


def time_rosbags(out_dir):
    """Read and fully deserialize every message with rosbags; return (seconds, count)."""
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import get_typestore, Stores
    typestore = get_typestore(Stores.ROS2_JAZZY)
    start = time.perf_counter()
    count = 0
    with AnyReader([Path(out_dir)], default_typestore=typestore) as reader:
        for connection, _, raw in reader.messages():
            typestore.deserialize_cdr(raw, connection.msgtype)
            count += 1
    return time.perf_counter() - start, count


def time_mcap(path, decode_limit):
    """Read raw messages with the mcap library, and decode a slice with mcap_ros2."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory
    start = time.perf_counter()
    with open(path, 'rb') as stream:
        count = sum(1 for _ in make_reader(stream).iter_messages())
    raw_seconds = time.perf_counter() - start
    start = time.perf_counter()
    decoded = 0
    with open(path, 'rb') as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        for _ in reader.iter_decoded_messages():
            decoded += 1
            if decoded >= decode_limit:
                break
    return count, raw_seconds, decoded, time.perf_counter() - start


def main(argv=None):
    """Run the benchmark and print messages per second."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--messages', type=int, default=1_000_000)
    parser.add_argument('--repeat', type=int, default=3)
    parser.add_argument('--no-baselines', action='store_true')
    args = parser.parse_args(argv)
    n = args.messages
    batch = make_batch(n)
    rows = []
    load = os.getloadavg()[0]
    with tempfile.TemporaryDirectory(prefix='bench_bag_io_') as tmp:
        out_dir = Path(tmp) / 'bench'
        writes = [time_write(out_dir, batch) for _ in range(args.repeat)]
        size = (out_dir / 'bench_0.mcap').stat().st_size
        os.sync()  # the bag is read as a recording written earlier, not while it flushes
        reads = [time_read(out_dir, batch) for _ in range(args.repeat)]
        for label, runs in (('reducer_twin write (encode + zstd MCAP + metadata.yaml)', writes),
                            ('reducer_twin read + decode to arrays', reads)):
            walls = [wall for wall, _ in runs]
            rows.append((label, n / walls[0], n / min(walls)))
            rows.append(('  same, per CPU second (all threads)', n / runs[0][1],
                         n / min(cpu for _, cpu in runs)))
        # The framing analyze uses for its derived bags (the mcap library's Writer).
        library = [time_write(Path(tmp) / 'library', batch, 'library')
                   for _ in range(args.repeat)]
        walls = [wall for wall, _ in library]
        rows.append(('mcap library Writer, same messages (derived-bag framing)', n / walls[0],
                     n / min(walls)))
        if not args.no_baselines:
            seconds, count = time_rosbags(out_dir)
            assert count == n
            rows.append(('rosbags AnyReader + deserialize_cdr', n / seconds, None))
            count, raw_seconds, decoded, decode_seconds = time_mcap(
                out_dir / 'bench_0.mcap', min(n, 100_000))
            assert count == n
            rows.append(('mcap reader, raw messages', n / raw_seconds, None))
            rows.append((f'mcap + mcap_ros2 decode ({decoded} msgs)', decoded / decode_seconds,
                         None))
    print(f'{n} JointState messages (2 joints: link + motor), bag file {size / 1e6:.1f} MB')
    print(f'{"path":58s} {"first run":>12s} {"best of " + str(args.repeat):>12s}')
    for label, first, best in rows:
        best_text = f'{best:>12,.0f}' if best is not None else f'{"":>12s}'
        print(f'{label:58s} {first:>12,.0f} {best_text}   msg/s')
    if not args.no_baselines:
        by_label = {label: first for label, first, _ in rows}
        ours = by_label['reducer_twin read + decode to arrays']
        base = by_label['rosbags AnyReader + deserialize_cdr']
        print(f'read + decode vs rosbags deserialize: {ours / base:.1f}x (first run)')
    print(f'1-minute load average {load:.2f} before, {os.getloadavg()[0]:.2f} after '
          f'({os.cpu_count()} cores; other work on the machine slows the wall-clock figures)')
    return 0


if __name__ == '__main__':
    sys.exit(main())
