"""
wear_estimator: Kalman estimate of a reducer's combined wear, persisted across restarts.

Subscribes to ``/reducer_twin/<joint>/te_features`` and steps the core's
filter (:class:`~reducer_twin.core.pipeline.EstimatorStage`) with each
window; publishes the estimate on ``/reducer_twin/<joint>/wear``
(reliable, transient-local: a late subscriber gets the latest). The state
is written atomically with a checksum after every window and restored on
start (falling back to the previous good copy); a state file that cannot be
used stops the node with an error rather than starting from zero. The
service ``/reducer_twin/<joint>/reset`` (``std_srvs/Trigger``) records a
maintenance event (reducer replaced) and restarts the filter.
"""

import os
from pathlib import Path

from diagnostic_msgs.msg import DiagnosticArray
from msg_adapters.layouts import record_values, TE_FEATURES, WEAR_ESTIMATE
from msg_adapters.ros import diagnostic_array, diagnostic_status, from_multiarray
from msg_adapters.ros import to_multiarray
from rcl_interfaces.msg import ParameterDescriptor
from reducer_twin.core.errors import InvalidInput
from reducer_twin.core.estimator import EstimatorConfig
from reducer_twin.core.params import ReducerParams
from reducer_twin.core.pipeline import EstimatorStage, features_from_record
from reducer_twin.core.units import m_to_um
from reducer_twin.nodes.base import create_background_timer, diagnostics_qos, joint_topic
from reducer_twin.nodes.base import latest_qos, Node
from reducer_twin.nodes.base import RejectCounter, run_nodes, SpecParameters, stream_qos
from reducer_twin.nodes.base import WINDOW_DEPTH, WORKER
from std_msgs.msg import Float64MultiArray
from std_srvs.srv import Trigger


def default_state_dir():
    """Return ``$XDG_STATE_HOME/reducer_twin`` (``~/.local/state/reducer_twin``)."""
    base = os.environ.get('XDG_STATE_HOME') or Path.home() / '.local' / 'state'
    return Path(base) / 'reducer_twin'


class WearEstimatorNode(Node):
    """
    Estimate the wear of one reducer from its window features.

    Parameters
    ----------
    node_name : str
        ROS node name.
    params : ReducerParams, optional
        Reducer parameters.
    **kwargs
        Passed to :class:`rclpy.node.Node`.

    """

    def __init__(self, node_name='wear_estimator', params=None, **kwargs):
        super().__init__(node_name, **kwargs)
        joint = self.declare_parameter('joint', 'joint_1', ParameterDescriptor(
            description='joint whose reducer is estimated', read_only=True)).value
        state_file = self.declare_parameter('state_file', '', ParameterDescriptor(
            description="estimator state file; '' = <state_dir>/<joint>.json; 'none' = keep no "
                        'state', read_only=True)).value
        state_dir = self.declare_parameter('state_dir', '', ParameterDescriptor(
            description="directory of state files; '' = $XDG_STATE_HOME/reducer_twin",
            read_only=True)).value
        period = self.declare_parameter('diagnostics_period_s', 1.0, ParameterDescriptor(
            description='period of /diagnostics [s]', read_only=True)).value
        self.joint = joint
        self.params = params or ReducerParams()
        self.est_params = SpecParameters(self, 'estimator', EstimatorConfig())
        if state_file == 'none':
            path = None
        else:
            path = Path(state_file) if state_file else (
                Path(state_dir) if state_dir else default_state_dir()) / f'{joint}.json'
        self.stage = EstimatorStage(self.params, self.est_params.value, path,
                                    log=self.get_logger().info, background_save=True)
        self.rejects = RejectCounter(self)
        self.statuses = {}
        self.pub = self.create_publisher(Float64MultiArray, joint_topic(joint, 'wear'),
                                         latest_qos())
        self.diag_pub = self.create_publisher(DiagnosticArray, '/diagnostics', diagnostics_qos())
        self.create_subscription(Float64MultiArray, joint_topic(joint, 'te_features'),
                                 self._on_features, stream_qos(WINDOW_DEPTH))
        self.create_service(Trigger, joint_topic(joint, 'reset'), self._on_reset)
        create_background_timer(self, period, self._publish_diagnostics)
        self._publish()

    def _on_features(self, msg):
        try:
            features = features_from_record(from_multiarray(msg, TE_FEATURES))
        except InvalidInput as err:
            self.rejects.reject('bad_features', str(err))
            return
        WORKER.submit(self._update, features)

    def _update(self, features):
        """Step the filter with one window and publish the estimate (on the worker)."""
        ok, status = self.rejects.guard('estimator', 'bad_features', self.stage.process,
                                        features)
        if ok:
            self.statuses[status] = self.statuses.get(status, 0) + 1
            self._publish(features.t_end)

    def close(self):
        """Process the queued windows and write the last state before the node goes away."""
        WORKER.wait_idle()
        self.stage.flush()

    def _reset(self):
        self.stage.reset('maintenance: reducer replaced (reset service)')
        self._publish()

    def _on_reset(self, request, response):
        # On the worker, after the windows already queued: they belong to the old reducer.
        WORKER.submit(self._reset).result()
        response.success = True
        response.message = f'{self.joint}: estimator reset to a new reducer'
        return response

    def _publish(self, stamp_s=None):
        stamp = self.get_clock().now().nanoseconds * 1e-9 if stamp_s is None else stamp_s
        rec = self.stage.record(stamp)
        self.pub.publish(to_multiarray(WEAR_ESTIMATE, record_values(WEAR_ESTIMATE, rec)))

    def _publish_diagnostics(self):
        est = self.stage.estimator
        values = {'wear_um': m_to_um(est.wear), 'wear_std_um': m_to_um(est.wear_std),
                  'rate_scale': est.rate_scale, 'updates': est.updates,
                  'rejected_updates': est.rejected, 'replayed_windows': self.stage.skipped_replays,
                  'rejected_messages': self.rejects.total,
                  'state_writes_failed': (self.stage.writer.failures
                                          if self.stage.writer else 0),
                  'state_writes_recovered': (self.stage.writer.recoveries
                                             if self.stage.writer else 0),
                  'state_file': str(self.stage.state_path or 'none'),
                  'restored_from': self.stage.restored_from or 'new reducer'}
        level = 'OK' if self.rejects.total == 0 else 'WARN'
        writer = self.stage.writer
        error = writer.error if writer is not None else None
        if error is not None:   # the file on disk is the last good state
            level = 'ERROR'
            values['state_write_error'] = str(error)
        message = f'wear {values["wear_um"]:.2f} +/- {values["wear_std_um"]:.2f} um'
        if error is not None:
            message = f'{error}; {message}'
        self.diag_pub.publish(diagnostic_array(
            self.get_clock().now().nanoseconds,
            [diagnostic_status(f'reducer_twin: {self.joint} wear estimator', self.joint, level,
                               message, values)]))


def main(args=None):
    """Run the wear_estimator node."""
    return run_nodes(WearEstimatorNode, args)


if __name__ == '__main__':
    raise SystemExit(main())
