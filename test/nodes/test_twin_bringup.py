"""
The bringup builds every joint's nodes from ``config/twin.yaml`` (``nodes.twin_bringup``).

A robot's axes carry different reducers: each joint's simulator, TE monitor, wear
estimator and life publisher take that joint's reducer from ``reducers.<joint>`` (a file
or overrides), the other joints the common ``reducer``; the joint processing's settings
reach the TE monitors as parameters derived from the core's ``TwinConfig``, and a
joint's reducer's service time (``service_time_s.<joint>``) its wear estimator.
"""

from pathlib import Path

import pytest
from reducer_twin.core.errors import InvalidParameter
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
        '  friction_in_effort: 0\n  effort_lag_s: 0.02\n  reliable: false\n'
        f'  state_dir: {tmp_path}\n'
        'reducer: {rating: {rated_life: 3.6e7}}\n'
        f'reducers:\n  base: {{file: {RV80E}, rating: {{rated_torque: 1568.0}}}}\n'
        '  wrist: {rating: {rated_torque: 392.0}}\n'
        'service_time_s: {elbow: 4.32e7}\n')
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
        assert te.config == TwinConfig(window_s=3.0, friction_in_effort=0, effort_lag_s=0.02)
        assert te.get_parameter('window_s').value == 3.0
        assert te.twin.analyzer.friction is False
        assert te.twin.analyzer.effort_lag_s == 0.02
        assert te.get_parameter('max_gap_s').value == TwinConfig().max_gap_s
    # A controller that publishes BEST_EFFORT is subscribed to so.
    assert nodes['ingest'].get_parameter('reliable').value is False
    # The elbow's reducer ran 12 000 h before the twin started; the others' time is unknown.
    service = {joint: node.stage.estimator.config.service_time_s
               for joint, node in nodes['estimator'].items()}
    assert service == {'base': 0.0, 'elbow': 4.32e7, 'wrist': 0.0}
    assert nodes['estimator']['elbow'].get_parameter('estimator.service_time_s').value == 4.32e7


def test_joints_whose_names_are_no_topic_names_run_on_valid_topics(default_ros, tmp_path):
    # A joint named 'joint-1' or '2nd axis' (a URDF takes any name) made the bringup fail
    # on its first publisher: a ROS 2 topic or node name takes letters, digits and '_'.
    config_file = tmp_path / 'twin.yaml'
    config_file.write_text('twin:\n  joints: [joint-1, 2nd axis]\n  simulate: true\n'
                           f'  state_dir: {tmp_path}\n')
    nodes = build_nodes(load_config(config_file))
    for node in [nodes['simulator'], nodes['ingest'], *nodes['te'].values(),
                 *nodes['estimator'].values(), *nodes['life'].values()]:
        default_ros.add(node)
    for joint, token in (('joint-1', 'joint_1'), ('2nd axis', '_2nd_axis')):
        te = nodes['te'][joint]
        assert te.get_name() == f'te_monitor_{token}'
        assert te.te_pub.topic_name == f'/reducer_twin/{token}/te'
        assert nodes['estimator'][joint].pub.topic_name == f'/reducer_twin/{token}/wear'
        # The simulator's JointState carries the names as they are; they reach the monitor.
        default_ros.spin_until(lambda: te.samples > 0, what=f'samples of {joint}')


def test_joints_that_would_share_their_topics_are_refused_naming_both(tmp_path):
    config_file = tmp_path / 'twin.yaml'
    config_file.write_text('twin:\n  joints: [joint-1, joint_1]\n  simulate: true\n')
    with pytest.raises(InvalidParameter, match="'joint-1' and 'joint_1' would publish on the "
                                               'same topics'):
        build_nodes(load_config(config_file))
