"""The numerical core imports no ROS and no bag library (style.md, layout)."""

import json
import subprocess
import sys

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
