"""The nodes are thin: modules of at most 200 lines on rclpy's public API."""

import re

import pytest

NODES = ('encoder_ingest', 'te_monitor', 'wear_estimator', 'life_publisher', 'joint_simulator',
         'twin_bringup')
MAX_LINES = 200
PRIVATE_RCLPY = ('implementation_singleton', '_parameter_overrides', '_rclpy')


def test_the_nodes_checked_are_the_nodes_the_package_runs(repo_root):
    scripts = (repo_root / 'setup.py').read_text()
    run = set(re.findall(r'reducer_twin\.nodes\.(\w+):main', scripts))
    assert run == set(NODES)


@pytest.mark.parametrize('node', NODES)
def test_a_node_module_stays_within_two_hundred_lines(repo_root, node):
    # What a node needs beyond subscribing, publishing and its parameters lives in the core
    # or in a helper module beside it (buffers, diagnostics, arrival times, runtime).
    source = (repo_root / 'reducer_twin' / 'nodes' / f'{node}.py').read_text()
    lines = source.count('\n')
    assert lines <= MAX_LINES, f'reducer_twin/nodes/{node}.py has {lines} lines'


def test_no_node_module_reaches_into_rclpy_internals(repo_root):
    found = {path.name: name for path in (repo_root / 'reducer_twin' / 'nodes').glob('*.py')
             for name in PRIVATE_RCLPY if name in path.read_text()}
    assert found == {}
