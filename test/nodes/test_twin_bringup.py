"""
The bringup builds every joint's nodes from ``config/twin.yaml`` (``nodes.twin_bringup``).

A robot's axes carry different reducers: each joint's simulator, TE monitor, wear
estimator and life publisher take that joint's reducer from ``reducers.<joint>`` (a file
or overrides), the other joints the common ``reducer``; the joint processing's settings
reach the TE monitors as parameters derived from the core's ``TwinConfig``.
"""

from pathlib import Path

import pytest
from reducer_twin.core.joint_twin import TwinConfig
from reducer_twin.core.params import ReducerParams
from reducer_twin.nodes.twin_bringup import build_nodes, load_config

pytestmark = pytest.mark.timeout(60, method='thread')

RV80E = Path(__file__).resolve().parents[2] / 'config' / 'rv80e.yaml'


def test_each_joint_runs_on_its_own_reducer_and_the_others_on_the_common_one(
        default_ros, tmp_path):
    config_file = tmp_path / 'twin.yaml'
    config_file.write_text(
        'twin:\n  joints: [base, elbow, wrist]\n  simulate: true\n  window_s: 3.0\n'
        '  friction_in_effort: 0\n'
        f'  state_dir: {tmp_path}\n'
        'reducer: {rating: {rated_life: 3.6e7}}\n'
        f'reducers:\n  base: {{file: {RV80E}, rating: {{rated_torque: 1568.0}}}}\n'
        '  wrist: {rating: {rated_torque: 392.0}}\n')
    nodes = build_nodes(load_config(config_file))
    for node in [nodes['simulator'], nodes['ingest'], *nodes['te'].values(),
                 *nodes['estimator'].values(), *nodes['life'].values()]:
        default_ros.add(node)
    common = ReducerParams().with_overrides({'rating': {'rated_life': 3.6e7}})
    expected = {'base': ReducerParams().with_overrides({'rating': {'rated_torque': 1568.0}}),
                'elbow': common,
                'wrist': common.with_overrides({'rating': {'rated_torque': 392.0}})}
    sims = {sim.config.name: sim for sim in nodes['simulator'].sims}
    for joint, params in expected.items():
        assert sims[joint].params == params, joint
        for kind in ('te', 'estimator', 'life'):
            assert nodes[kind][joint].params == params, (kind, joint)
        te = nodes['te'][joint]
        assert te.config == TwinConfig(window_s=3.0, friction_in_effort=0)
        assert te.get_parameter('window_s').value == 3.0
        assert te.twin.analyzer.friction is False
        assert te.get_parameter('max_gap_s').value == TwinConfig().max_gap_s
