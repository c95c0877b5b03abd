"""
Fixtures of the reliability tests: the node-test harness, shared, not copied.

``test/nodes/conftest.py`` holds the harness (an rclpy context per module, a
:class:`RosHarness` per test, the installed node programs); its fixtures are
re-exported here so that these tests spin real nodes over real DDS the same way.
The test tree has no packages (``--import-mode=importlib``), so the file is loaded
by path.
"""

import importlib.util
from pathlib import Path

import pytest


def _load_node_fixtures():
    path = Path(__file__).resolve().parents[1] / 'nodes' / 'conftest.py'
    spec = importlib.util.spec_from_file_location('reliability_node_fixtures', path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


nodes = _load_node_fixtures()
RosHarness = nodes.RosHarness
ros_context = nodes.ros_context
ros = nodes.ros
default_ros_context = nodes.default_ros_context
default_ros = nodes.default_ros
run_for = nodes.run_for
node_program = nodes.node_program


@pytest.fixture(scope='module')
def module_ros(ros_context):
    """Return a :class:`RosHarness` for module fixtures; its nodes end with the module."""
    harness = RosHarness(ros_context)
    yield harness
    harness.close()
