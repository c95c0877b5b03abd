"""
Message definitions and type hashes of ROS 2 message types, as rosbag2 stores them.

rosbag2's MCAP storage plugin writes, for every topic type, a schema of encoding
``ros2msg`` that holds the type's ``.msg`` text followed by the text of each type it
depends on, every dependency introduced by a line of 80 ``=`` and ``MSG: pkg/Name``.
Dependencies are found by scanning the field lines of each text, visited in sorted
order, depth first, each type once (``rosbag2_storage_mcap/message_definition_cache.cpp``,
Jazzy). The channel metadata carries the type's RIHS01 hash, which rosidl computed at
build time and installed beside the ``.msg`` file as ``share/<pkg>/msg/<Name>.json``.

This module reads both from the installed ROS packages (the Jazzy wheels install them
under ``<venv>/share``); it never imports rclpy.
"""

import functools
import json
import os
from pathlib import Path
import re
import site
import sys

from reducer_twin.core.errors import BagError

SEPARATOR = '=' * 80

_TYPE_NAME = re.compile(r'^([A-Za-z][A-Za-z0-9_]*)/(?:(msg|srv|action)/)?([A-Za-z][A-Za-z0-9_]*)$')
_FIELD_TYPE = re.compile(r'(?:^|\n)\s*([a-zA-Z0-9_/]+)(?:\[[^\]]*\])?\s+')
_PRIMITIVES = frozenset((
    'bool', 'byte', 'char', 'float32', 'float64', 'int8', 'uint8', 'int16', 'uint16',
    'int32', 'uint32', 'int64', 'uint64', 'string', 'wstring'))
_MAX_DEPTH = 50


def split_type_name(msgtype):
    """
    Split a ROS type name into package, interface kind and name.

    Parameters
    ----------
    msgtype : str
        ``'sensor_msgs/msg/JointState'`` or the short form ``'sensor_msgs/JointState'``.

    Returns
    -------
    tuple of str
        ``(package, kind, name)``, e.g. ``('sensor_msgs', 'msg', 'JointState')``.

    Raises
    ------
    BagError
        If the name is not of the form ``pkg/Name`` or ``pkg/msg/Name``.

    """
    match = _TYPE_NAME.match(str(msgtype))
    if match is None:
        raise BagError(
            f'message type name {msgtype!r} is not understood: expected '
            "'package/msg/Name' such as 'sensor_msgs/msg/JointState'")
    package, kind, name = match.groups()
    return package, kind or 'msg', name


def ros_share_prefixes():
    """
    List the install prefixes searched for ``share/<pkg>`` directories.

    The order is: the entries of ``AMENT_PREFIX_PATH``, the running interpreter's
    prefix (a virtualenv holding the ROS wheels), the prefixes above each
    site-packages directory, and ``/opt/ros/jazzy``.

    Returns
    -------
    list of pathlib.Path
        Existing directories, without duplicates, in search order.

    """
    candidates = []
    for entry in os.environ.get('AMENT_PREFIX_PATH', '').split(os.pathsep):
        if entry:
            candidates.append(Path(entry))
    candidates.append(Path(sys.prefix))
    try:
        site_dirs = site.getsitepackages()
    except AttributeError:  # pragma: no cover - virtualenvs without site.getsitepackages
        site_dirs = []
    for site_dir in site_dirs:
        path = Path(site_dir)
        if len(path.parents) > 2:
            candidates.append(path.parents[2])
    candidates.append(Path('/opt/ros/jazzy'))
    seen = []
    for path in candidates:
        if path.is_dir() and path not in seen:
            seen.append(path)
    return seen


@functools.lru_cache(maxsize=None)
def interface_file(msgtype, suffix):
    """
    Find the installed interface file of a type.

    Parameters
    ----------
    msgtype : str
        Type name, e.g. ``'std_msgs/msg/Header'``.
    suffix : str
        ``'.msg'`` or ``'.json'``.

    Returns
    -------
    pathlib.Path
        ``<prefix>/share/<pkg>/<kind>/<Name><suffix>``.

    Raises
    ------
    BagError
        If no searched prefix holds the file.

    """
    package, kind, name = split_type_name(msgtype)
    relative = Path('share') / package / kind / f'{name}{suffix}'
    prefixes = ros_share_prefixes()
    for prefix in prefixes:
        path = prefix / relative
        if path.is_file():
            return path
    searched = ', '.join(str(p) for p in prefixes) or '(none)'
    raise BagError(
        f'cannot find the definition of {msgtype}: no {relative} under the searched '
        f'prefixes [{searched}]; install the ROS interface package (e.g. '
        "'pip install ros-jazzy-common-interfaces') or set AMENT_PREFIX_PATH")


def _dependencies(text, package):
    deps = set()
    for match in _FIELD_TYPE.finditer(text):
        field_type = match.group(1)
        if field_type in _PRIMITIVES:
            continue
        deps.add(field_type if '/' in field_type else f'{package}/{field_type}')
    return sorted(deps)


def assemble_definition(msgtype, read_text):
    """
    Assemble a ``ros2msg`` schema text with rosbag2's dependency walk.

    Parameters
    ----------
    msgtype : str
        Root type name, e.g. ``'sensor_msgs/msg/JointState'``.
    read_text : callable
        ``read_text(type_name) -> str`` returns the ``.msg`` text of a type given as
        ``'pkg/msg/Name'`` or ``'pkg/Name'``.

    Returns
    -------
    str
        The root text, then for every dependency (depth first, sorted, each once) a
        newline, a line of 80 ``=``, ``MSG: pkg/Name``, a newline and its text.

    Raises
    ------
    BagError
        If the definitions nest deeper than 50 levels.

    """
    seen = set()

    def append(type_name, depth):
        if depth <= 0:
            raise BagError(
                f'definition of {msgtype} nests deeper than {_MAX_DEPTH} levels; '
                'expected a finite message definition')
        package, _, _ = split_type_name(type_name)
        text = read_text(type_name)
        result = text
        for dep in _dependencies(text, package):
            if dep in seen:
                continue
            seen.add(dep)
            result += f'\n{SEPARATOR}\nMSG: {dep}\n' + append(dep, depth - 1)
        return result

    return append(msgtype, _MAX_DEPTH)


@functools.lru_cache(maxsize=None)
def message_definition(msgtype):
    """
    Return the full ``ros2msg`` schema text of a message type, as rosbag2 writes it.

    Parameters
    ----------
    msgtype : str
        Type name, e.g. ``'sensor_msgs/msg/JointState'``.

    Returns
    -------
    str
        The type's ``.msg`` text, then for every dependency (depth first, sorted, each
        once) a newline, a line of 80 ``=``, ``MSG: pkg/Name`` and the dependency's text.

    Raises
    ------
    BagError
        If the type or one of its dependencies is not installed.

    """
    return assemble_definition(
        msgtype, lambda name: interface_file(name, '.msg').read_bytes().decode('utf-8'))


@functools.lru_cache(maxsize=None)
def type_hash(msgtype):
    """
    Return the RIHS01 type description hash of a message type.

    Parameters
    ----------
    msgtype : str
        Type name, e.g. ``'sensor_msgs/msg/JointState'``.

    Returns
    -------
    str
        ``'RIHS01_'`` followed by 64 hex digits, as ``ros2 bag record`` stores it in the
        channel metadata ``topic_type_hash``.

    Raises
    ------
    BagError
        If the type's ``.json`` description is missing or holds no hash for the type.

    """
    package, kind, name = split_type_name(msgtype)
    full_name = f'{package}/{kind}/{name}'
    path = interface_file(msgtype, '.json')
    try:
        description = json.loads(path.read_text(encoding='utf-8'))
        hashes = {entry['type_name']: entry['hash_string']
                  for entry in description['type_hashes']}
    except (OSError, ValueError, KeyError, TypeError) as err:
        raise BagError(
            f'cannot read the type hash of {full_name} from {path}: {err}; expected '
            "rosidl's JSON type description with a 'type_hashes' list") from err
    if full_name not in hashes:
        raise BagError(
            f'{path} lists no type hash for {full_name}; found {sorted(hashes)}')
    return hashes[full_name]
