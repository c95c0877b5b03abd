"""
life_publisher: remaining life of a reducer and its health on ``/diagnostics``.

Subscribes to ``/reducer_twin/<joint>/wear`` (the estimator's state) and
``/reducer_twin/<joint>/te_features`` (the duty, for the catalogue life);
publishes P10/P50/P90 remaining operating life on
``/reducer_twin/<joint>/remaining_life`` and a ``DiagnosticStatus`` per
reducer (``hardware_id`` = the reducer id) whose level is OK / WARN / ERROR
by the configured remaining-life thresholds, with wear, lost motion, TE and
remaining life as key/values.
"""

import math

from diagnostic_msgs.msg import DiagnosticArray
from msg_adapters.layouts import record_values, REMAINING_LIFE, TE_FEATURES, WEAR_ESTIMATE
from msg_adapters.ros import diagnostic_array, diagnostic_status, from_multiarray
from msg_adapters.ros import to_multiarray
from rcl_interfaces.msg import ParameterDescriptor
from rclpy.node import Node
from reducer_twin.core.errors import InvalidInput
from reducer_twin.core.joint_twin import joint_topic
from reducer_twin.core.params import ReducerParams
from reducer_twin.core.pipeline import features_from_record, LifeConfig, LifeStage
from reducer_twin.core.units import HOUR, m_to_um, rad_to_arcmin
from reducer_twin.nodes.parameters import SpecParameters
from reducer_twin.nodes.qos import diagnostics_qos, latest_qos, stream_qos, WINDOW_DEPTH
from reducer_twin.nodes.rejects import RejectCounter
from reducer_twin.nodes.runtime import run_nodes, WORKER
from reducer_twin.nodes.timers import create_background_timer
from std_msgs.msg import Float64MultiArray


class LifePublisher(Node):
    """
    Publish remaining life and diagnostics of one reducer.

    Parameters
    ----------
    node_name : str
        ROS node name.
    params : ReducerParams, optional
        Reducer parameters.
    **kwargs
        Passed to :class:`rclpy.node.Node`.

    """

    def __init__(self, node_name='life_publisher', params=None, **kwargs):
        super().__init__(node_name, **kwargs)
        self.joint = self.declare_parameter('joint', 'joint_1', ParameterDescriptor(
            description='joint whose reducer is assessed', read_only=True)).value
        self.hardware_id = self.declare_parameter('hardware_id', '', ParameterDescriptor(
            description="reducer identifier in /diagnostics ('' = the joint name)",
            read_only=True)).value or self.joint
        period = self.declare_parameter('diagnostics_period_s', 1.0, ParameterDescriptor(
            description='period of /diagnostics [s]', read_only=True)).value
        self.params = params or ReducerParams()
        self.life_params = SpecParameters(self, 'life', LifeConfig(), on_change=self._reconfig)
        self.stage = LifeStage(self.params, self.life_params.value)
        self.rejects = RejectCounter(self)
        self.last = None
        self.last_features = None
        self.pub = self.create_publisher(Float64MultiArray,
                                         joint_topic(self.joint, 'remaining_life'), latest_qos())
        self.diag_pub = self.create_publisher(DiagnosticArray, '/diagnostics', diagnostics_qos())
        self.create_subscription(Float64MultiArray, joint_topic(self.joint, 'wear'),
                                 self._on_wear, latest_qos())
        self.create_subscription(Float64MultiArray, joint_topic(self.joint, 'te_features'),
                                 self._on_features, stream_qos(WINDOW_DEPTH))
        create_background_timer(self, period, self._publish_diagnostics)

    def _reconfig(self, config):
        def apply():
            duty = self.stage.duty
            self.stage = LifeStage(self.params, config)
            self.stage.observe_duty(duty)
        # The stage lives on the worker; swap it there, between two assessments.
        WORKER.submit(apply).result()

    def _on_features(self, msg):
        try:
            rec = from_multiarray(msg, TE_FEATURES)
            duty = features_from_record(rec).duty
        except InvalidInput as err:
            self.rejects.reject('bad_features', str(err))
            return
        self.last_features = rec
        WORKER.submit(self._observe_duty, duty)

    def _observe_duty(self, duty):
        self.rejects.guard('life', 'bad_features', self.stage.observe_duty, duty)

    def _on_wear(self, msg):
        try:
            wear = from_multiarray(msg, WEAR_ESTIMATE)
        except InvalidInput as err:
            self.rejects.reject('bad_wear', str(err))
            return
        WORKER.submit(self._assess, wear)

    def _assess(self, wear):
        """Sample the remaining life of one estimate and publish it (on the worker)."""
        ok, result = self.rejects.guard('life', 'bad_wear', self.stage.process, wear)
        if ok:
            self.last = (wear, *result)
            self.pub.publish(to_multiarray(REMAINING_LIFE,
                                           record_values(REMAINING_LIFE, result[0])))

    def summary(self):
        """
        Return the latest assessment in edge units (for the demo and tests).

        Returns
        -------
        dict or None
            Wear, lost motion, remaining life and level; None before the
            first estimate.

        """
        if self.last is None:
            return None
        wear, rec, level, message = self.last
        out = {'wear_um': m_to_um(wear['wear_m']), 'wear_std_um': m_to_um(wear['wear_std_m']),
               'rate_scale': wear['rate_scale'],
               'lost_motion_arcmin': rad_to_arcmin(wear['lost_motion_rad']),
               'lost_motion_obs_arcmin': rad_to_arcmin(wear['lost_motion_obs_rad']),
               'rul_p10_h': rec['p10_s'] / HOUR, 'rul_p50_h': rec['p50_s'] / HOUR,
               'rul_p90_h': rec['p90_s'] / HOUR, 'rul_p90_censored': bool(rec['p90_censored']),
               'catalogue_life_h': rec['catalogue_life_s'] / HOUR,
               'exposure_h': wear['exposure_s'] / HOUR, 'level': level, 'message': message,
               'updates': int(wear['updates']), 'rejected_updates': int(wear['rejected'])}
        if self.last_features is not None:
            out['te_pp_arcmin'] = rad_to_arcmin(self.last_features['te_pp_rad'])
        return out

    def _publish_diagnostics(self):
        summary = self.summary()
        if summary is None:
            status = diagnostic_status(f'reducer_twin: {self.joint} reducer', self.hardware_id,
                                       'STALE', 'no wear estimate yet',
                                       {'rejected_messages': self.rejects.total})
        else:
            values = {k: v for k, v in summary.items() if k not in ('level', 'message')}
            values['rejected_messages'] = self.rejects.total
            values['lost_motion_limit_arcmin'] = rad_to_arcmin(self.stage.limit)
            level = summary['level']
            if level == 'OK' and self.rejects.total and math.isfinite(summary['rul_p10_h']):
                level = 'WARN'
            status = diagnostic_status(f'reducer_twin: {self.joint} reducer', self.hardware_id,
                                       level, summary['message'], values)
        self.diag_pub.publish(diagnostic_array(self.get_clock().now().nanoseconds, [status]))


def main(args=None):
    """Run the life_publisher node."""
    return run_nodes(LifePublisher, args)


if __name__ == '__main__':
    raise SystemExit(main())
