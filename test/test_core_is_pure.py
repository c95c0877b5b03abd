"""The numerical core imports no ROS and no bag library, opens no file and starts no thread."""

import ast
import json
import subprocess
import sys

import pytest

FORBIDDEN_PREFIXES = (
    'rclpy', 'rosidl', 'sensor_msgs', 'std_msgs', 'diagnostic_msgs',
    'builtin_interfaces', 'mcap', 'rosbags',
)

# Run in a fresh interpreter: this test process may already hold rclpy.
IMPORT_ALL_OF_CORE = """
import importlib, json, pkgutil, sys
import reducer_twin.core as core
names = [core.__name__]
for info in pkgutil.walk_packages(core.__path__, core.__name__ + '.'):
    importlib.import_module(info.name)
    names.append(info.name)
json.dump({'imported': names, 'loaded': sorted(sys.modules)}, sys.stdout)
"""


def test_importing_every_core_module_loads_no_ros_or_bag_module(repo_root):
    result = subprocess.run(
        [sys.executable, '-c', IMPORT_ALL_OF_CORE], cwd=repo_root,
        capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, f'importing reducer_twin.core failed:\n{result.stderr}'
    report = json.loads(result.stdout)
    offenders = [name for name in report['loaded'] if name.startswith(FORBIDDEN_PREFIXES)]
    assert offenders == [], (
        f'reducer_twin.core pulled in {offenders} '
        f'(core modules imported: {report["imported"]})')


# What touches a disk, starts a thread or keeps a cache between processes belongs to
# reducer_twin.io (or the caller); the core takes and returns arrays and mappings.
FORBIDDEN_IMPORTS = {
    'threading', 'queue', 'concurrent', 'multiprocessing', 'yaml', 'tempfile', 'mmap',
    'shutil', 'sqlite3', 'pathlib', 'io', 'glob', 'fcntl', 'pickle', 'shelve',
}
FORBIDDEN_CALLS = {
    'open',
    # os file calls
    'os.open', 'os.fdopen', 'os.replace', 'os.rename', 'os.remove', 'os.unlink',
    'os.mkdir', 'os.makedirs', 'os.rmdir', 'os.fsync', 'os.statvfs', 'os.listdir',
    'os.scandir', 'os.walk', 'os.stat', 'os.chmod', 'os.write', 'os.read',
    # numpy file calls
    'np.load', 'np.save', 'np.savez', 'np.savez_compressed', 'np.loadtxt', 'np.savetxt',
    'np.fromfile', 'np.memmap', 'np.genfromtxt',
}
FORBIDDEN_METHODS = {
    # pathlib.Path's reading and writing, whatever the object is called
    'write_text', 'write_bytes', 'read_text', 'read_bytes', 'mkdir', 'touch', 'unlink',
    'rmdir', 'symlink_to', 'hardlink_to', 'tofile',
}


def _dotted(node):
    """Return ``a.b.c`` for a Name/Attribute chain, else None."""
    parts = []
    while isinstance(node, ast.Attribute):
        parts.append(node.attr)
        node = node.value
    if isinstance(node, ast.Name):
        parts.append(node.id)
        return '.'.join(reversed(parts))
    return None


def _offences(path):
    tree = ast.parse(path.read_text(encoding='utf-8'), filename=str(path))
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            names = [node.module or ''] if node.level == 0 else []
        else:
            names = []
        for name in names:
            if name.split('.')[0] in FORBIDDEN_IMPORTS:
                found.append(f'{path.name}:{node.lineno} imports {name}')
        if isinstance(node, ast.Call):
            name = _dotted(node.func)
            if name in FORBIDDEN_CALLS:
                found.append(f'{path.name}:{node.lineno} calls {name}()')
            elif isinstance(node.func, ast.Attribute) and node.func.attr in FORBIDDEN_METHODS:
                found.append(f'{path.name}:{node.lineno} calls .{node.func.attr}()')
    return found


def test_the_core_opens_no_file_starts_no_thread_and_reads_no_yaml(repo_root):
    sources = sorted((repo_root / 'reducer_twin' / 'core').rglob('*.py'))
    assert sources, 'no core module found'
    offences = [line for path in sources for line in _offences(path)]
    assert offences == [], 'reducer_twin.core does I/O or threading:\n' + '\n'.join(offences)


@pytest.mark.parametrize('source, offence', [
    ('import threading\n', 'imports threading'),
    ('from pathlib import Path\n', 'imports pathlib'),
    ('import yaml\n', 'imports yaml'),
    ('with open("f") as fh:\n    pass\n', 'calls open()'),
    ('import os\nos.replace("a", "b")\n', 'calls os.replace()'),
    ('import numpy as np\nnp.save("f", 1)\n', 'calls np.save()'),
    ('p.write_bytes(b"")\n', 'calls .write_bytes()'),
    ('p.parent.mkdir(parents=True)\n', 'calls .mkdir()'),
])
def test_the_purity_check_sees_each_kind_of_io(tmp_path, source, offence):
    path = tmp_path / 'module.py'
    path.write_text(source, encoding='utf-8')
    assert [line.split(' ', 1)[1] for line in _offences(path)] == [offence]
