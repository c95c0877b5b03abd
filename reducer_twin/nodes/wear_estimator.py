"""
wear_estimator: Kalman estimate of a reducer's combined wear, persisted across restarts.

Subscribes to ``/reducer_twin/<joint>/te_features`` and steps the joint's estimator stage
(:class:`~reducer_twin.core.pipeline.EstimatorStage`, the estimate half of a
:class:`~reducer_twin.core.joint_twin.TwinBack`) with each window; publishes the estimate on
``/reducer_twin/<joint>/wear`` (reliable, transient-local). The state is written atomically
after every window and restored on start (falling back to the previous good copy); a state
file that cannot be used stops the node with an error. The service
``/reducer_twin/<joint>/reset`` (``std_srvs/Trigger``) records a maintenance event (reducer
replaced) and restarts the filter; the latest event goes on ``maintenance``
(``std_msgs/String``, transient-local) for ``te_monitor`` to start its windows afresh.

With ``store`` and ``robot`` the node joins the reducer's history in a fleet store
(:mod:`reducer_twin.fleet.live`): it starts from the stored state when that is newer, and
writes every window's records every ``store_period_s`` as one live segment on a thread of its
own; store trouble never holds the stream (``/diagnostics`` says WARN or ERROR until a write
succeeds). The segments carry what ``te_monitor``'s window analysis found at the test torque
(:mod:`~reducer_twin.nodes.torque_check`), as a bag's summary does.
"""

from rclpy.node import Node
from reducer_twin.core.errors import InvalidInput
from reducer_twin.core.estimator import EstimatorConfig
from reducer_twin.core.joint_twin import joint_topic, maintenance_event
from reducer_twin.core.params import ReducerParams
from reducer_twin.core.pipeline import EstimatorStage, features_from_record, LifeConfig
from reducer_twin.io.state_file import StateFile
from reducer_twin.msg_adapters.layouts import record_values, TE_FEATURES, WEAR_ESTIMATE
from reducer_twin.msg_adapters.ros import from_multiarray, to_multiarray
from reducer_twin.nodes.diagnostics import estimator_status, publish_diagnostics
from reducer_twin.nodes.parameters import declare_plain, SpecParameters
from reducer_twin.nodes.qos import latest_qos, stream_qos, WINDOW_DEPTH
from reducer_twin.nodes.rejects import RejectCounter
from reducer_twin.nodes.runtime import CLOSE_FLUSH_TIMEOUT_S, run_nodes, state_path
from reducer_twin.nodes.runtime import store_worker, WORKER
from reducer_twin.nodes.settings import StoreSettings
from reducer_twin.nodes.timers import create_spread_timer
from reducer_twin.nodes.torque_check import CheckListener
from std_msgs.msg import Float64MultiArray, String
from std_srvs.srv import Trigger


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
        p = declare_plain(self, {
            'joint': ('joint_1', 'joint whose reducer is estimated'),
            'state_file': ('', "estimator state file; '' = <state_dir>/<joint>.json; 'none' = "
                               'keep no state'),
            'state_dir': ('', "directory of state files; '' = $XDG_STATE_HOME/reducer_twin"),
            'store': ('', 'fleet store (SQLite, as analyze --store writes) the live history '
                          "is written to and continued from; '' = none"),
            'robot': ('', 'robot of this reducer in the fleet store (needed with store)')})
        period = SpecParameters(self, '', StoreSettings()).value.store_period_s
        self.joint = joint = p['joint']
        self.params = params or ReducerParams()
        self.est_params = SpecParameters(self, 'estimator', EstimatorConfig())
        path = state_path(joint, p['state_file'], p['state_dir'])
        self.stage = EstimatorStage(self.params, self.est_params.value,
                                    StateFile(path, background=True) if path else None,
                                    log=self.get_logger().info)
        self.live = None
        if p['store']:
            self._join_store(p['store'], p['robot'])
        self.rejects, self._rejected_seen, self.statuses = RejectCounter(self), 0, {}
        self.pub = self.create_publisher(Float64MultiArray, joint_topic(joint, 'wear'),
                                         latest_qos())
        self.create_subscription(Float64MultiArray, joint_topic(joint, 'te_features'),
                                 self._on_features, stream_qos(WINDOW_DEPTH))
        self.create_service(Trigger, joint_topic(joint, 'reset'), self._on_reset)
        self.events = self.create_publisher(String, joint_topic(joint, 'maintenance'),
                                            latest_qos())
        publish_diagnostics(self, self._statuses)
        self._flush_queued = False
        if self.live is not None:
            create_spread_timer(self, period, self._queue_store_flush)
        self._publish()

    def _join_store(self, store, robot):
        """Continue from the fleet store when it is newer, and keep the live history there."""
        from reducer_twin.fleet.live import join_store
        self.life_params = SpecParameters(self, 'life', LifeConfig(),
                                          on_change=self._life_changed)
        self.live = join_store(self.stage, store, robot, self.joint, self.params,
                               self.est_params.value, self.life_params.value, self.get_name(),
                               log=self.get_logger().info, warn=self.get_logger().warning)
        self.check = CheckListener(self, self.joint, self.live)

    def _life_changed(self, config):
        # The live history's life stage lives on the worker; swap it there, between windows.
        WORKER.submit(self.live.configure_life, config).result()

    def _on_features(self, msg):
        try:
            record = from_multiarray(msg, TE_FEATURES)
            features = features_from_record(record)
        except InvalidInput as err:
            self.rejects.reject('bad_features', str(err))
            return
        WORKER.post(self, self._update, features, record)

    def _update(self, features, record=None):
        """Step the filter with one window and publish the estimate (on the worker)."""
        ok, status = self.rejects.guard('estimator', 'bad_features', self.stage.process,
                                        features)
        if ok:
            self.statuses[status] = self.statuses.get(status, 0) + 1
            wear = self.stage.record(features.t_end)
            if self.live is not None and status != 'replay' and record is not None:
                total = self.rejects.total
                self.live.add(record, wear, self.stage.estimator.state_dict(),
                              self.stage.last_observation, total - self._rejected_seen)
                self._rejected_seen = total
            self._publish(features.t_end, wear)

    def _queue_store_flush(self):
        """Hand a flush to the store thread unless one is waiting there (executor thread)."""
        if self._flush_queued:
            return
        self._flush_queued = True
        store_worker().submit(self._flush_store)

    def _flush_store(self):
        self._flush_queued = False
        try:
            self.live.flush()
        except Exception as err:  # noqa: B902 - a failing flush must be seen, not lost
            self.get_logger().error(f'fleet store flush failed: {err!r}')

    def flush_store(self, timeout=CLOSE_FLUSH_TIMEOUT_S):
        """Write the windows stepped so far to the store now; return the windows waiting."""
        if self.live is None:
            return 0
        WORKER.wait_idle(timeout)
        store_worker().submit(self.live.flush).result(timeout)
        return self.live.pending

    def close(self):
        """Process the queued windows and write the last state before the node goes away."""
        WORKER.wait_idle()
        self.stage.flush()
        if self.live is not None:
            waiting = self.flush_store()
            if waiting:
                self.get_logger().error(
                    f'{waiting} window(s) of {self.live.robot}/{self.joint} were not written '
                    f'to the fleet store {self.live.path} ({self.live.error or self.live.busy}); '
                    'the state file keeps the estimate')

    def _reset(self):
        self.stage.reset('maintenance: reducer replaced (reset service)')
        if self.live is not None:
            self.live.mark_replacement('maintenance: reducer replaced (reset service of '
                                       f'{self.get_name()})')
        self._publish()

    def _on_reset(self, request, response):
        # On the worker, after the windows already queued: they belong to the old reducer.
        WORKER.submit(self._reset).result()
        response.success = True
        response.message = f'{self.joint}: estimator reset to a new reducer'
        return response

    def _publish(self, stamp_s=None, rec=None):
        """Publish the estimate; at start and after a reset, the latest maintenance event."""
        event = maintenance_event(self.stage.estimator.events) if stamp_s is None else None
        if event is not None:
            self.events.publish(String(data=event))
        stamp = self.get_clock().now().nanoseconds * 1e-9 if stamp_s is None else stamp_s
        rec = self.stage.record(stamp) if rec is None else rec
        self.pub.publish(to_multiarray(WEAR_ESTIMATE, record_values(WEAR_ESTIMATE, rec)))

    def _statuses(self):
        level, message, values = estimator_status(self.stage, self.rejects.total, self.live)
        return [(f'reducer_twin: {self.joint} wear estimator', self.joint, level, message,
                 values)]


def main(args=None):
    """Run the wear_estimator node."""
    return run_nodes(WearEstimatorNode, args)


if __name__ == '__main__':
    raise SystemExit(main())
