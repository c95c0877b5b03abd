"""A rosbag2 ``.db3`` file as Humble's sqlite3 storage writes it (integer QoS enums)."""

import sqlite3

from reducer_twin.msg_adapters.jointstate_cdr import MSGTYPE as JOINT_STATE


def humble_qos(reliability):
    """
    Return an ``offered_qos_profiles`` string with Humble's integer enums.

    Parameters
    ----------
    reliability : int
        1 reliable, 2 best effort.

    """
    return (f'- history: 3\n  depth: 0\n  reliability: {reliability}\n  durability: 2\n'
            '  deadline:\n    sec: 9223372036\n    nsec: 854775807\n  lifespan:\n'
            '    sec: 9223372036\n    nsec: 854775807\n  liveliness: 1\n'
            '  liveliness_lease_duration:\n    sec: 9223372036\n    nsec: 854775807\n'
            '  avoid_ros_namespace_conventions: false')


def write_joint_states_db3(path, stamps_ns, buffer, offsets, qos, order=None):
    """
    Write serialised JointState messages on ``/joint_states`` to a new ``.db3`` file.

    Parameters
    ----------
    path : Path
        The file to create.
    stamps_ns : ndarray
        Receive times [ns], one per message.
    buffer, offsets : ndarray
        The CDR payloads, message ``i`` at ``buffer[offsets[i]:offsets[i + 1]]``.
    qos : str
        The topic's ``offered_qos_profiles``.
    order : iterable of int, optional
        Order in which the rows are inserted (default: as given).

    """
    rows = range(len(stamps_ns)) if order is None else order
    with sqlite3.connect(path) as db:
        db.execute('CREATE TABLE topics(id INTEGER PRIMARY KEY, name TEXT NOT NULL, type TEXT '
                   'NOT NULL, serialization_format TEXT NOT NULL, offered_qos_profiles TEXT '
                   'NOT NULL)')
        db.execute('CREATE TABLE messages(id INTEGER PRIMARY KEY, topic_id INTEGER NOT NULL, '
                   'timestamp INTEGER NOT NULL, data BLOB NOT NULL)')
        db.execute('INSERT INTO topics VALUES (1, ?, ?, ?, ?)',
                   ('/joint_states', JOINT_STATE, 'cdr', qos))
        db.executemany('INSERT INTO messages(topic_id, timestamp, data) VALUES (1, ?, ?)',
                       [(int(stamps_ns[i]), buffer[offsets[i]:offsets[i + 1]].tobytes())
                        for i in rows])
