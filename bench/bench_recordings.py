#!/usr/bin/env python3
"""
Benchmark of reading the recording forms a robot leaves (a script, not a test).

Simulates a 6-joint robot (one combined ``/joint_states``), rewrites it as
``/dynamic_joint_states`` (each joint: position, velocity, effort, motor_position and a
temperature, written by rosbags' rosbag2 writer), as a ROS 1 ``.bag`` (rosbags'
converter) and with rosbag2's zstd file and message compression (rosbags' writer), then
measures for each form: read and decode with ``Bag.iter_joint_states``
(best of ``--repeat``), rosbags' own reader and deserializer on a slice, and ``analyze``
end to end in this process.

Usage (from the checkout, ``PYTHONPATH=$PWD``)::

    .venv/bin/python bench/bench_recordings.py [--messages 200000] [--repeat 3]
"""

import argparse
from pathlib import Path
import tempfile
import time

import numpy as np
from reducer_twin.analysis.pipeline import analyze_bag
from reducer_twin.analysis.settings import AnalysisSettings
from reducer_twin.analysis.simulate import simulate_bag, SimulationSpec
from reducer_twin.io.bag import open_bag
from reducer_twin.msg_adapters.dynamic_joint_state import MSGTYPE as DJS

JOINT_STATE = 'sensor_msgs/msg/JointState'
IV = 'control_msgs/msg/InterfaceValue'
RATE_HZ = 500.0
AGING = 3600.0


def _stores():
    from rosbags.typesys import get_types_from_msg, get_typestore, Stores
    store = get_typestore(Stores.ROS2_JAZZY)
    store.register({
        **get_types_from_msg('std_msgs/Header header\nstring[] joint_names\n'
                             'InterfaceValue[] interface_values\n', DJS),
        **get_types_from_msg('string[] interface_names\nfloat64[] values\n', IV)})
    return store, get_typestore(Stores.ROS1_NOETIC)


def write_djs(src, dst, store):
    """Rewrite the combined JointState bag as /dynamic_joint_states with rosbags."""
    from rosbags.highlevel import AnyReader
    from rosbags.rosbag2 import StoragePlugin, Writer
    types = store.types
    with AnyReader([src], default_typestore=store) as reader, \
            Writer(dst, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        conn = writer.add_connection('/dynamic_joint_states', DJS, typestore=store)
        states = [c for c in reader.connections if c.topic == '/joint_states']
        for c, stamp, raw in reader.messages(states):
            msg = reader.deserialize(raw, c.msgtype)
            index = {n: k for k, n in enumerate(msg.name)}
            joints = [n for n in msg.name if n + '_motor' in index]
            ivs = []
            for joint in joints:
                k, m = index[joint], index[joint + '_motor']
                ivs.append(types[IV](
                    ['position', 'velocity', 'effort', 'motor_position', 'temperature'],
                    np.array([msg.position[k], msg.velocity[k], msg.effort[k],
                              msg.position[m], 40.0])))
            writer.write(conn, stamp, store.serialize_cdr(types[DJS](msg.header, joints, ivs),
                                                          DJS))


def write_ros1(src, dst, store, noetic):
    """Convert the bag to ROS 1 with rosbags' converter."""
    from rosbags.convert import convert
    convert([src], dst, dst_storage='sqlite3', dst_version=8, compress=None,
            compress_mode='file', default_typestore=store, typestore=noetic,
            exclude_topics=[], include_topics=[], exclude_msgtypes=[], include_msgtypes=[])


def write_compressed(src, dst, mode):
    """Rewrite the bag with rosbag2's zstd compression of ``mode`` (rosbags' writer)."""
    from rosbags.rosbag2 import Reader, StoragePlugin, Writer
    from rosbags.rosbag2.enums import CompressionFormat, CompressionMode
    writer = Writer(dst, version=9, storage_plugin=StoragePlugin.MCAP)
    writer.set_compression(CompressionMode[mode.upper()], CompressionFormat.ZSTD)
    with Reader(src) as reader, writer:
        out = {c.id: writer.add_connection(c.topic, c.msgtype, msgdef=c.msgdef.data,
                                           rihs01=c.digest) for c in reader.connections}
        for connection, stamp, raw in reader.messages():
            writer.write(out[connection.id], stamp, raw)


def ours(path, topic, repeat):
    """Best read+decode rate of Bag.iter_joint_states [msg/s] and the message count."""
    best, count = 0.0, 0
    for _ in range(repeat):
        start = time.perf_counter()
        with open_bag(path) as bag:
            count = sum(len(b) for _, b in bag.iter_joint_states([topic]))
        best = max(best, count / (time.perf_counter() - start))
    return best, count


def rosbags_rate(path, topic, store, limit):
    """Rate of rosbags' AnyReader plus deserialize on the first ``limit`` messages [msg/s]."""
    from rosbags.highlevel import AnyReader
    start = time.perf_counter()
    n = 0
    with AnyReader([path], default_typestore=store) as reader:
        conns = [c for c in reader.connections if c.topic == topic]
        for c, _, raw in reader.messages(conns):
            reader.deserialize(raw, c.msgtype)
            n += 1
            if n == limit:
                break
    return n / (time.perf_counter() - start)


def main():
    """Run the benchmark and print the figures."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--messages', type=int, default=200_000)
    parser.add_argument('--repeat', type=int, default=3)
    args = parser.parse_args()
    store, noetic = _stores()
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        seconds = args.messages / RATE_HZ
        spec = SimulationSpec(hours=seconds * AGING / 3600.0, aging_factor=AGING, joints=6,
                              rate_hz=RATE_HZ, seed=1, wear_rate_scales=(1.0,) * 6)
        simulate_bag(tmp / 'robot', spec)
        write_djs(tmp / 'robot', tmp / 'djs', store)
        write_ros1(tmp / 'robot', tmp / 'robot.bag', store, noetic)
        for mode in ('file', 'message'):
            write_compressed(tmp / 'robot', tmp / mode, mode)
        settings = AnalysisSettings(aging_factor=AGING)
        print(f'6 joints, {args.messages:,} messages at {RATE_HZ:g} Hz')
        for label, path, topic in (('rosbag2 MCAP JointState', tmp / 'robot', '/joint_states'),
                                   ('DynamicJointState (MCAP)', tmp / 'djs',
                                    '/dynamic_joint_states'),
                                   ('ROS 1 .bag JointState', tmp / 'robot.bag',
                                    '/joint_states'),
                                   ('rosbag2 file zstd', tmp / 'file', '/joint_states'),
                                   ('rosbag2 message zstd', tmp / 'message', '/joint_states')):
            rate, count = ours(path, topic, args.repeat)
            base = rosbags_rate(path, topic, store, 20_000)
            start = time.perf_counter()
            result = analyze_bag(path, tmp / f'out-{label[:4]}', settings, overwrite=True)
            total = time.perf_counter() - start
            print(f'{label:26s} read+decode {rate / 1e6:5.2f} M msg/s ({count:,} msgs); '
                  f'rosbags {base / 1e3:5.1f} k msg/s; analyze end to end '
                  f'{result.messages / total / 1e3:5.0f} k msg/s')


if __name__ == '__main__':
    main()
