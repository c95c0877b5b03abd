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

With ``store`` (a fleet store, as ``reducer-twin analyze --store`` writes) and
``robot``, the node joins the reducer's history across bags
(:mod:`reducer_twin.fleet.live`): it starts from the stored state when that is newer
than its state file, keeps every window's ``te_features``, ``wear`` and
``remaining_life`` records (remaining life with the ``life.*`` parameters, as the
``life_publisher`` computes it) and writes them every ``store_period_s`` as one live
segment on a thread of its own; a reset is recorded as a replacement. Store trouble
(another writer, a full disk) never holds the stream: the windows wait and
``/diagnostics`` says WARN or ERROR until a write succeeds.
"""

import os
from pathlib import Path

from diagnostic_msgs.msg import DiagnosticArray
from msg_adapters.layouts import record_values, TE_FEATURES, WEAR_ESTIMATE
from msg_adapters.ros import diagnostic_array, diagnostic_status, from_multiarray
from msg_adapters.ros import to_multiarray
from rcl_interfaces.msg import ParameterDescriptor
from rclpy.node import Node
from reducer_twin.core.errors import InvalidInput, InvalidParameter, out_of_range
from reducer_twin.core.errors import StateFileError
from reducer_twin.core.estimator import EstimatorConfig
from reducer_twin.core.joint_twin import joint_topic
from reducer_twin.core.params import ReducerParams
from reducer_twin.core.pipeline import EstimatorStage, features_from_record, LifeConfig
from reducer_twin.core.units import m_to_um
from reducer_twin.nodes.parameters import SpecParameters
from reducer_twin.nodes.qos import diagnostics_qos, latest_qos, stream_qos, WINDOW_DEPTH
from reducer_twin.nodes.rejects import RejectCounter
from reducer_twin.nodes.runtime import BackgroundWorker, run_nodes, WORKER
from reducer_twin.nodes.timers import create_background_timer, create_spread_timer
from std_msgs.msg import Float64MultiArray
from std_srvs.srv import Trigger


STORE_PERIOD_RANGE_S = (0.01, 86400.0)
"""Allowed ``store_period_s`` [s]."""

CLOSE_FLUSH_TIMEOUT_S = 30.0
"""Longest wait for the last live segment when the node stops [s]."""

_STORE_WORKER = []


def store_worker():
    """
    Return the process's fleet-store thread (made on first use).

    Every live estimator of the process writes its segments there, one after the other:
    SQLite and ``fsync`` never run on the executor thread nor hold the background
    worker that steps the windows, and the joints of a bringup never compete for the
    store's writer lock among themselves.
    """
    if not _STORE_WORKER:
        _STORE_WORKER.append(BackgroundWorker())
    return _STORE_WORKER[0]


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
        store = self.declare_parameter('store', '', ParameterDescriptor(
            description='fleet store (SQLite, as analyze --store writes) the live history is '
                        "written to and continued from; '' = none", read_only=True)).value
        robot = self.declare_parameter('robot', '', ParameterDescriptor(
            description='robot of this reducer in the fleet store (needed with store)',
            read_only=True)).value
        store_period = self.declare_parameter('store_period_s', 60.0, ParameterDescriptor(
            description='period of live segments written to the fleet store [s] '
                        f'({STORE_PERIOD_RANGE_S[0]:g} .. {STORE_PERIOD_RANGE_S[1]:g})',
            read_only=True)).value
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
        self.live = None
        if store:
            self._join_store(store, robot, store_period)
        self.rejects = RejectCounter(self)
        self._rejected_seen = 0
        self.statuses = {}
        self.pub = self.create_publisher(Float64MultiArray, joint_topic(joint, 'wear'),
                                         latest_qos())
        self.diag_pub = self.create_publisher(DiagnosticArray, '/diagnostics', diagnostics_qos())
        self.create_subscription(Float64MultiArray, joint_topic(joint, 'te_features'),
                                 self._on_features, stream_qos(WINDOW_DEPTH))
        self.create_service(Trigger, joint_topic(joint, 'reset'), self._on_reset)
        create_background_timer(self, period, self._publish_diagnostics)
        self._flush_queued = False
        if self.live is not None:
            create_spread_timer(self, store_period, self._queue_store_flush)
        self._publish()

    def _join_store(self, store, robot, period):
        """Continue from the fleet store when it is newer, and keep the live history there."""
        from reducer_twin.core.estimator import WearEstimator
        from reducer_twin.fleet.live import check_robot, LiveHistory, read_start
        from reducer_twin.fleet.store import StoreError
        check_robot(robot)
        if not STORE_PERIOD_RANGE_S[0] <= float(period) <= STORE_PERIOD_RANGE_S[1]:
            raise InvalidParameter(out_of_range(
                'store_period_s', period, 's',
                f'{STORE_PERIOD_RANGE_S[0]:g} .. {STORE_PERIOD_RANGE_S[1]:g}'))
        self.life_params = SpecParameters(self, 'life', LifeConfig(),
                                          on_change=self._life_changed)
        life = self.life_params.value
        est = self.stage.estimator
        file_t_end = est.t_end if self.stage.restored_from else None
        try:
            start = read_start(store, robot, self.joint, file_t_end)
        except StoreError as err:
            raise StoreError(f'parameter store: {err}') from None
        log = self.get_logger().info
        config = self.est_params.value
        if start.state is not None:
            try:
                self.stage.estimator = WearEstimator.from_state(
                    self.params, start.state['estimator'], config)
            except StateFileError as err:
                raise StateFileError(f'parameter store: the state of {robot}/{self.joint} '
                                     f'in the fleet store {store} cannot be used: {err}') from None
            obs = start.state.get('lost_motion_obs_rad')
            self.stage.last_observation = float('nan') if obs is None else float(obs)
            self.stage.restored_from = f'fleet store {store} ({robot}/{self.joint})'
        elif start.new_reducer:
            self.stage.estimator = WearEstimator(self.params, config)
            self.stage.restored_from = None
        log(start.note)
        if start.state is not None or start.new_reducer:
            self.stage.save()          # the state file follows the store from now on
        self.live = LiveHistory(store, robot, self.joint, self.params, life, start,
                                self.get_name(), log=self.get_logger().warning)

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
        WORKER.submit(self._update, features, record)

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
        """
        Write the windows stepped so far to the fleet store now, and wait for it.

        Returns
        -------
        int
            Windows still waiting (0 unless the store is busy or cannot be written).

        """
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
        stamp = self.get_clock().now().nanoseconds * 1e-9 if stamp_s is None else stamp_s
        rec = self.stage.record(stamp) if rec is None else rec
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
        if self.live is not None:
            store_level, store_values = self.live.status()
            values.update(store_values)
            if store_level == 'ERROR' or (store_level == 'WARN' and level == 'OK'):
                level = store_level
            if store_level != 'OK':
                message += '; fleet store: ' + (store_values.get('store_error')
                                                or store_values['store_busy'])
        self.diag_pub.publish(diagnostic_array(
            self.get_clock().now().nanoseconds,
            [diagnostic_status(f'reducer_twin: {self.joint} wear estimator', self.joint, level,
                               message, values)]))


def main(args=None):
    """Run the wear_estimator node."""
    return run_nodes(WearEstimatorNode, args)


if __name__ == '__main__':
    raise SystemExit(main())
