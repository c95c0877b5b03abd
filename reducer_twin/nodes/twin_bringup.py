"""
twin_bringup: every reducer_twin node for every configured joint, in one process.

Reads one YAML (``config/twin.yaml`` by default, parameter ``config``) and
builds one ``encoder_ingest`` for the robot and, per joint, a
``te_monitor``, a ``wear_estimator`` and a ``life_publisher`` (and the
``joint_simulator`` when ``twin.simulate`` is true), all spun by one
EventsExecutor (single-threaded executor as fallback). Nodes are named
``<kind>_<joint>`` so several joints coexist. With ``twin.intra_process``
(default) the ingest hands its clean pairs to the TE monitors directly, as
rclcpp does for composed nodes; the pairs and TE topics are then published
only while something subscribes to them. Motor encoders that ros2_control
exports only on ``/dynamic_joint_states`` are fed through a second
``joint_state_broadcaster`` as ``twin.motor_topic`` (see ``encoder_ingest``).
With ``twin.store`` (and ``twin.robot``) the estimators write the live history into
that fleet store and continue from it (see ``wear_estimator``). Each joint's nodes
take that joint's reducer (``reducers.<joint>`` in the YAML: a reducer file or
overrides of ``reducer``; an RV-160E at the base, an RV-40E at the wrist), and
its reducer's service time where ``service_time_s.<joint>`` gives it (parameter
``estimator.service_time_s`` of its ``wear_estimator``).
"""

from rclpy.node import Node
from rclpy.parameter import Parameter
# The configuration lives in a ROS-free module (the bag analysis reads it too); its
# names stay importable from here.
from reducer_twin.config import default_config, DEFAULTS, load_config  # noqa: F401
from reducer_twin.config import joint_reducers, twin_config
from reducer_twin.core.joint_twin import check_topic_tokens, node_token
from reducer_twin.nodes.runtime import run_nodes


def build_nodes(config, sim_overrides=None):
    """
    Create the nodes of a bringup configuration (rclpy must be initialised).

    Parameters
    ----------
    config : dict
        Output of :func:`load_config`.
    sim_overrides : list of rclpy.parameter.Parameter, optional
        Extra parameters of the simulator node (the demo sets the aging
        factor and the rate scales this way).

    Returns
    -------
    dict
        ``{'simulator': node or None, 'ingest': node, 'te': {joint: node},
        'estimator': {joint: node}, 'life': {joint: node}}``.

    """
    from reducer_twin.nodes.encoder_ingest import EncoderIngest
    from reducer_twin.nodes.joint_simulator import JointSimulatorNode
    from reducer_twin.nodes.life_publisher import LifePublisher
    from reducer_twin.nodes.te_monitor import TEMonitor
    from reducer_twin.nodes.wear_estimator import WearEstimatorNode
    twin, life = config['twin'], config['life']
    params, own = joint_reducers(config)
    joints = list(twin['joints'])
    check_topic_tokens(joints)
    nodes = {'simulator': None, 'te': {}, 'estimator': {}, 'life': {}}
    if twin['simulate']:
        sim = [Parameter('joints', value=joints),
               Parameter('profile', value=config['simulator']['profile']),
               Parameter('sim.aging_factor', value=float(twin['aging_factor']))]
        scales = [float(s) for s in config['simulator'].get('wear_rate_scales') or []]
        if scales:
            sim.append(Parameter('wear_rate_scales', value=scales))
        sim += list(sim_overrides or [])
        nodes['simulator'] = JointSimulatorNode(params=params, joint_params=own,
                                                parameter_overrides=sim)
    local = bool(twin['intra_process'])
    nodes['ingest'] = EncoderIngest(parameter_overrides=[
        Parameter('joints', value=joints),
        # Handed over in process, a batch costs nothing: every message goes on at once.
        Parameter('batch_period_s', value=0.0 if local else 0.002),
        Parameter('link_topic', value=twin['link_topic']),
        Parameter('motor_topic', value=twin['motor_topic']),
        Parameter('motor_suffix', value=twin['motor_suffix']),
        Parameter('motor_angles', value=twin['motor_angles']),
        Parameter('motor_direction', value=twin['motor_direction']),
        Parameter('effort_scale', value=float(twin['effort_scale'])),
        Parameter('effort_source', value=twin['effort_source']),
        Parameter('motor_effort_units', value=twin['motor_effort_units']),
        Parameter('reliable', value=twin['reliable'])])
    life_params = [Parameter(f'life.{k}', value=float(v)) for k, v in life.items()]
    spec = twin_config(config)
    for joint in joints:
        reducer, name = own.get(joint, params), node_token(joint)
        nodes['te'][joint] = TEMonitor(
            f'te_monitor_{name}', params=reducer, subscribe=not local, parameter_overrides=[
                Parameter('joint', value=joint), Parameter('state_dir', value=twin['state_dir']),
                *(Parameter(name, value=float(getattr(spec, name)))
                  for name in ('aging_factor', 'window_s', 'max_gap_s', 'effort_lag_s')),
                Parameter('friction_in_effort', value=int(spec.friction_in_effort))])
        if local:
            nodes['ingest'].attach(joint, nodes['te'][joint].take_pairs)
        store = [Parameter('store', value=str(twin['store'])),
                 Parameter('robot', value=str(twin['robot'] or '')),
                 Parameter('store_period_s', value=float(twin['store_period_s'])),
                 *life_params] if twin['store'] else []
        service = config.get('service_time_s') or {}
        service = [Parameter('estimator.service_time_s', value=float(service[joint]))] \
            if joint in service else []
        nodes['estimator'][joint] = WearEstimatorNode(
            f'wear_estimator_{name}', params=reducer, parameter_overrides=[
                Parameter('joint', value=joint), Parameter('state_dir', value=twin['state_dir']),
                *store, *service])
        nodes['life'][joint] = LifePublisher(f'life_publisher_{name}', params=reducer,
                                             parameter_overrides=[Parameter('joint', value=joint),
                                                                  *life_params])
    return nodes


def all_nodes(nodes):
    """Return the nodes of :func:`build_nodes` as a flat list."""
    out = [nodes['simulator']] if nodes['simulator'] is not None else []
    out.append(nodes['ingest'])
    for kind in ('te', 'estimator', 'life'):
        out.extend(nodes[kind].values())
    return out


class _ConfigReader(Node):
    """A short-lived node that reads the ``config`` parameter from the command line."""

    def __init__(self):
        super().__init__('twin_bringup')
        self.path = self.declare_parameter('config', '').value


def main(args=None):
    """Run every node of the bringup configuration in this process."""
    def factory():
        reader = _ConfigReader()
        path = reader.path or default_config()
        reader.destroy_node()
        return all_nodes(build_nodes(load_config(path)))
    return run_nodes(factory, args)


if __name__ == '__main__':
    raise SystemExit(main())
