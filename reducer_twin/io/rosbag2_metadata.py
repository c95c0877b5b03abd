"""
The rosbag2 (Jazzy) bag metadata: QoS profiles, ``metadata.yaml`` and ``custom_data``.

What ``ros2 bag record`` stores beside the messages, as data and as the YAML yaml-cpp
writes: the offered QoS profiles of a topic (metadata version 9: policies as strings;
older bags and hand-written files give integers, both are read), the bag metadata
document of ``metadata.yaml`` and of the MCAP file's ``rosbag2`` record, and its
``custom_data`` read back as the strings written.
"""

from dataclasses import dataclass
import functools
import json
import re

import numpy as np
from reducer_twin.core.errors import InvalidInput
import yaml


ROS_DISTRO = 'jazzy'
METADATA_VERSION = 9
MAX_TIME = 2**63 - 1  # rosbag2's starting_time before the first message


# --------------------------------------------------------------------------- QoS


_ENUMS = {
    'history': ('system_default', 'keep_last', 'keep_all', 'unknown'),
    'reliability': ('system_default', 'reliable', 'best_effort', 'unknown', 'best_available'),
    'durability': ('system_default', 'transient_local', 'volatile', 'unknown',
                   'best_available'),
    'liveliness': ('system_default', 'automatic', 'manual_by_node', 'manual_by_topic',
                   'unknown', 'best_available'),
}
INFINITE = (9223372036, 854775807)  # RMW_DURATION_INFINITE as rmw_time_t


@dataclass(frozen=True)
class QosProfile:
    """
    One offered QoS profile, as rosbag2 stores it per topic.

    Policies are the strings of metadata version 9 (``'reliable'``, ``'volatile'``, ...);
    durations are ``(sec, nsec)``. The defaults are what ``ros2 bag record`` on Jazzy
    stores for a publisher with rclpy's default profile (DDS does not report the
    history depth of a remote publisher, so history is ``unknown`` with depth 0).
    """

    history: str = 'unknown'
    depth: int = 0
    reliability: str = 'reliable'
    durability: str = 'volatile'
    deadline: tuple = INFINITE
    lifespan: tuple = INFINITE
    liveliness: str = 'automatic'
    liveliness_lease_duration: tuple = INFINITE
    avoid_ros_namespace_conventions: bool = False

    def as_dict(self):
        """
        Return the profile as rosbag2 serialises it (version 9).

        Returns
        -------
        dict
            Keys in rosbag2's order; durations as ``{'sec': .., 'nsec': ..}``.

        """
        def duration(value):
            return {'sec': int(value[0]), 'nsec': int(value[1])}
        return {
            'history': self.history, 'depth': int(self.depth),
            'reliability': self.reliability, 'durability': self.durability,
            'deadline': duration(self.deadline), 'lifespan': duration(self.lifespan),
            'liveliness': self.liveliness,
            'liveliness_lease_duration': duration(self.liveliness_lease_duration),
            'avoid_ros_namespace_conventions': bool(self.avoid_ros_namespace_conventions),
        }


DEFAULT_QOS = (QosProfile(),)


def _policy(name, value):
    choices = _ENUMS[name]
    if isinstance(value, bool):
        raise InvalidInput(f'QoS {name} must be one of {choices} or 0..{len(choices) - 1}, '
                           f'got {value!r}')
    if isinstance(value, int):
        if 0 <= value < len(choices):
            return choices[value]
        return 'unknown'
    text = str(value).strip().lower()
    if text not in choices:
        raise InvalidInput(f'QoS {name} must be one of {choices}, got {value!r}')
    return text


def _duration(name, value):
    if value is None:
        return INFINITE
    if isinstance(value, dict):
        try:
            return int(value['sec']), int(value['nsec'])
        except (KeyError, TypeError, ValueError) as err:
            raise InvalidInput(f'QoS {name} must be {{sec, nsec}}, got {value!r}') from err
    try:
        sec, nsec = value
        return int(sec), int(nsec)
    except (TypeError, ValueError) as err:
        raise InvalidInput(f'QoS {name} must be (sec, nsec), got {value!r}') from err


def qos_from_dict(item):
    """
    Build a QosProfile from a rosbag2 QoS mapping.

    Parameters
    ----------
    item : dict
        One entry of ``offered_qos_profiles``; policies as strings (version 9) or as
        the integers older bags use.

    Returns
    -------
    QosProfile
        The profile; an unknown integer policy becomes ``'unknown'``.

    Raises
    ------
    InvalidInput
        If the mapping lacks keys or holds values of the wrong kind.

    """
    if not isinstance(item, dict):
        raise InvalidInput(f'a QoS profile must be a mapping, got {item!r}')
    try:
        return QosProfile(
            history=_policy('history', item.get('history', 'unknown')),
            depth=int(item.get('depth', 0)),
            reliability=_policy('reliability', item.get('reliability', 'unknown')),
            durability=_policy('durability', item.get('durability', 'unknown')),
            deadline=_duration('deadline', item.get('deadline')),
            lifespan=_duration('lifespan', item.get('lifespan')),
            liveliness=_policy('liveliness', item.get('liveliness', 'unknown')),
            liveliness_lease_duration=_duration(
                'liveliness_lease_duration', item.get('liveliness_lease_duration')),
            avoid_ros_namespace_conventions=bool(
                item.get('avoid_ros_namespace_conventions', False)))
    except (TypeError, ValueError) as err:
        if isinstance(err, InvalidInput):
            raise
        raise InvalidInput(f'QoS profile {item!r} is not understood: {err}') from err


_SAFE_LOADER = getattr(yaml, 'CSafeLoader', yaml.SafeLoader)
_BASE_LOADER = getattr(yaml, 'CBaseLoader', yaml.BaseLoader)
"""PyYAML's loaders on libyaml where it is built with it (the same constructors, faster)."""


def load_yaml(text):
    """
    Read a YAML document as :func:`yaml.safe_load` does (libyaml's parser when available).

    Raises
    ------
    yaml.YAMLError
        If the text is not YAML.

    """
    return yaml.load(text, Loader=_SAFE_LOADER)


def parse_qos_profiles(value):
    """
    Parse ``offered_qos_profiles`` as found in a bag.

    Parameters
    ----------
    value : str, list, QosProfile or None
        A YAML string (channel metadata, metadata.yaml up to version 8), a list of
        mappings (metadata.yaml version 9), or profiles.

    Returns
    -------
    tuple of QosProfile
        Empty for ``''`` or None.

    Raises
    ------
    InvalidInput
        If the text is not YAML or the entries are not QoS mappings.

    """
    if value is None or value == '':
        return ()
    if isinstance(value, QosProfile):
        return (value,)
    if isinstance(value, str):
        try:
            value = load_yaml(value)
        except yaml.YAMLError as err:
            raise InvalidInput(f'offered_qos_profiles is not YAML: {err}') from err
        if value is None:
            return ()
    if isinstance(value, dict):
        value = [value]
    if not isinstance(value, (list, tuple)):
        raise InvalidInput(f'offered_qos_profiles must be a list of profiles, got {value!r}')
    return tuple(v if isinstance(v, QosProfile) else qos_from_dict(v) for v in value)


# --------------------------------------------------------------------------- YAML


_PLAIN = re.compile(r'[A-Za-z0-9_./][A-Za-z0-9_./\-]*')


@functools.lru_cache(maxsize=4096)
def _reads_back(text):
    """Whether YAML reads the plain scalar ``text`` as that string (cached: 0.3 ms a call)."""
    return load_yaml(text) == text


def _scalar(value):
    if value is None:
        return '~'
    if isinstance(value, bool):
        return 'true' if value else 'false'
    if isinstance(value, (int, np.integer)):
        return str(int(value))
    text = str(value)
    if _PLAIN.fullmatch(text) and _reads_back(text):
        return text
    return json.dumps(text, ensure_ascii=False)


def dump_yaml(node, indent=0):
    """
    Serialise nested dicts and lists the way yaml-cpp (and so rosbag2) writes them.

    Block style; a sequence under a key is indented by two spaces; empty sequences
    are written as ``[]`` and empty or missing mappings as ``~``; strings that YAML
    would read as something else are double-quoted.

    Parameters
    ----------
    node : dict, list or scalar
        The document.
    indent : int
        Indentation of the top level, in spaces.

    Returns
    -------
    str
        The YAML text, without a trailing newline.

    """
    pad = ' ' * indent
    if isinstance(node, dict):
        if not node:
            return pad + '{}'
        lines = []
        for key, value in node.items():
            head = f'{pad}{_scalar(key)}:'
            if isinstance(value, dict) and value:
                lines.append(head + '\n' + dump_yaml(value, indent + 2))
            elif isinstance(value, (list, tuple)):
                lines.append(head + '\n' + dump_yaml(list(value), indent + 2))
            elif isinstance(value, dict):
                lines.append(head + ' ~')
            else:
                lines.append(f'{head} {_scalar(value)}')
        return '\n'.join(lines)
    if isinstance(node, (list, tuple)):
        if not node:
            return pad + '[]'
        lines = []
        for item in node:
            if isinstance(item, (dict, list, tuple)) and item:
                body = dump_yaml(item, indent + 2)
                lines.append(pad + '- ' + body[indent + 2:])
            else:
                lines.append(f'{pad}- {_scalar(item) if not isinstance(item, dict) else "{}"}')
        return '\n'.join(lines)
    return pad + _scalar(node)


def bag_metadata(topics, files, custom_data=None, storage_identifier='mcap'):
    """
    Build rosbag2's BagMetadata (version 9) as a dict in rosbag2's key order.

    Parameters
    ----------
    topics : list of dict
        Per topic: ``name``, ``type``, ``qos`` (sequence of QosProfile), ``type_hash``
        and ``count``.
    files : list of dict
        Per file: ``path`` (relative), ``start`` and ``end`` (ns, None if empty) and
        ``count``.
    custom_data : dict of str to str, optional
        User key/values (rosbag2's ``custom_data``).
    storage_identifier : str
        ``'mcap'``.

    Returns
    -------
    dict
        The content of ``rosbag2_bagfile_information``.

    """
    starts = [f['start'] for f in files if f['start'] is not None]
    ends = [f['end'] for f in files if f['end'] is not None]
    start = min(starts) if starts else MAX_TIME
    duration = max(ends) - start if ends else 0

    def file_entry(f):
        f_start = MAX_TIME if f['start'] is None else f['start']
        f_duration = 0 if f['start'] is None else f['end'] - f['start']
        return {'path': f['path'], 'starting_time': {'nanoseconds_since_epoch': f_start},
                'duration': {'nanoseconds': f_duration}, 'message_count': f['count']}

    return {
        'version': METADATA_VERSION,
        'storage_identifier': storage_identifier,
        'duration': {'nanoseconds': duration},
        'starting_time': {'nanoseconds_since_epoch': start},
        'message_count': sum(f['count'] for f in files),
        'topics_with_message_count': [
            {'topic_metadata': {
                'name': t['name'], 'type': t['type'], 'serialization_format': 'cdr',
                'offered_qos_profiles': [q.as_dict() for q in t['qos']],
                'type_description_hash': t['type_hash']},
             'message_count': t['count']} for t in topics],
        'compression_format': '',
        'compression_mode': '',
        'relative_file_paths': [f['path'] for f in files],
        'files': [file_entry(f) for f in files],
        'custom_data': dict(custom_data) if custom_data else None,
        'ros_distro': ROS_DISTRO,
    }


def custom_data_strings(text):
    """
    Read rosbag2 ``custom_data`` from metadata YAML, every value as the string written.

    yaml-cpp writes a value such as ``1.5`` unquoted; rosbag2 reads it back as a string,
    and so does this function (a plain YAML load would turn it into a float).

    Parameters
    ----------
    text : str
        A metadata.yaml document or a ``serialized_metadata`` value.

    Returns
    -------
    dict of str to str or None
        None when the text holds no ``custom_data`` mapping.

    """
    try:
        raw = yaml.load(text, Loader=_BASE_LOADER)
    except yaml.YAMLError:
        return None
    if isinstance(raw, dict) and 'rosbag2_bagfile_information' in raw:
        raw = raw['rosbag2_bagfile_information']
    if not isinstance(raw, dict):
        return None
    custom = raw.get('custom_data')
    if not isinstance(custom, dict):
        return None
    return {str(k): str(v) for k, v in custom.items()}
