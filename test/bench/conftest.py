"""
Fixtures the tests of both truth generators share (bench/*_generator.py).

A test module that uses ``split_bag`` names its generator and recording at module
level: ``gen`` (the script, from ``bench_scripts.load``) and ``SHORT`` (the
``gen.Spec`` keywords of a short split-layout recording).
"""

from pathlib import Path

from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
import numpy as np
import pytest
from rosbags.highlevel import AnyReader
from rosbags.typesys import get_typestore, Stores


def read_rosbags(path):
    """
    Read a bag back with rosbags.

    Parameters
    ----------
    path : Path
        Bag directory.

    Returns
    -------
    dict
        ``{topic: (connection, [(log_ns, message), ...])}``.

    """
    out = {}
    with AnyReader([Path(path)], default_typestore=get_typestore(Stores.ROS2_JAZZY)) as reader:
        for con in reader.connections:
            out[con.topic] = (con, [])
        for con, log_ns, raw in reader.messages():
            out[con.topic][1].append((log_ns, reader.deserialize(raw, con.msgtype)))
    return out


def read_mcap(path, topic):
    """
    Read a bag's MCAP file back with the mcap library.

    Parameters
    ----------
    path : Path
        Bag directory (one ``.mcap`` file).
    topic : str
        Topic whose positions to decode.

    Returns
    -------
    tuple
        ``(counts, channels, positions)``: messages per topic from the summary's
        statistics, ``(channel, schema)`` pairs, and the ``position`` field of every
        message on ``topic`` (messages, entries).

    """
    (mcap_file,) = Path(path).glob('*.mcap')
    with open(mcap_file, 'rb') as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        summary = reader.get_summary()
        channels = {c.id: c for c in summary.channels.values()}
        counts = {channels[i].topic: c
                  for i, c in summary.statistics.channel_message_counts.items()}
        positions = np.array([msg.position for _, _, _, msg in
                              reader.iter_decoded_messages(topics=[topic])])
    return counts, [(c, summary.schemas[c.schema_id]) for c in channels.values()], positions


@pytest.fixture(scope='session')
def mcap_reader():
    """Return :func:`read_mcap` (bag directory, topic -> counts, channels, positions)."""
    return read_mcap


@pytest.fixture(scope='session')
def rosbags_reader():
    """Return :func:`read_rosbags` (bag directory -> messages per topic)."""
    return read_rosbags


@pytest.fixture(scope='module')
def split_bag(request, tmp_path_factory):
    """Write the module's ``SHORT`` recording with its ``gen``; return (path, stream, truth)."""
    gen = request.module.gen
    path = tmp_path_factory.mktemp(gen.__name__) / 'robot'
    stream = gen.generate(gen.Spec(**request.module.SHORT))
    counts = gen.write_bag(stream, path)
    truth = stream.truth_json()
    truth['messages'] = counts
    return path, stream, truth


@pytest.fixture(scope='module')
def split_read(split_bag):
    """Read the split bag back with rosbags."""
    return read_rosbags(split_bag[0])
