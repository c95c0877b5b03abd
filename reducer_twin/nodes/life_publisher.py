"""
life_publisher: remaining life of a reducer and its health on ``/diagnostics``.

Subscribes to ``/reducer_twin/<joint>/wear`` (the estimator's state) and
``/reducer_twin/<joint>/te_features`` (the duty, for the catalogue life);
publishes P10/P50/P90 remaining operating life on
``/reducer_twin/<joint>/remaining_life`` and a ``DiagnosticStatus`` per
reducer (``hardware_id`` = the reducer id) whose level is OK / WARN / ERROR
by the configured remaining-life thresholds, with wear, lost motion, TE and
remaining life as key/values: the joint's
:class:`~reducer_twin.core.joint_twin.HealthSummary`, as the bag analysis
writes it. It also hears ``/reducer_twin/<joint>/test_torque_check``
(:mod:`.torque_check`): a warning or an error resting on the loaded flanks' play, the
width at the test torque compared too little or not at all, says so, and a life read from a
lost motion below its bins' width at the test torque says so whatever its level.
"""

from rclpy.node import Node
from reducer_twin.core.errors import InvalidInput
from reducer_twin.core.joint_twin import assess, HealthSummary, joint_topic
from reducer_twin.core.joint_twin import reducer_status_name
from reducer_twin.core.params import ReducerParams
from reducer_twin.core.pipeline import features_from_record, LifeConfig, LifeStage
from reducer_twin.msg_adapters.layouts import (
    record_values, REMAINING_LIFE, TE_FEATURES, WEAR_ESTIMATE)
from reducer_twin.msg_adapters.ros import from_multiarray, to_multiarray
from reducer_twin.nodes.diagnostics import publish_diagnostics
from reducer_twin.nodes.parameters import declare_plain, SpecParameters
from reducer_twin.nodes.qos import latest_qos, stream_qos, WINDOW_DEPTH
from reducer_twin.nodes.rejects import RejectCounter
from reducer_twin.nodes.runtime import run_nodes, WORKER
from reducer_twin.nodes.torque_check import CheckListener
from std_msgs.msg import Float64MultiArray


class LifePublisher(Node):
    """
    Publish remaining life and diagnostics of one reducer.

    Parameters
    ----------
    node_name : str
        ROS node name.
    params : ReducerParams, optional
        The joint's reducer.
    **kwargs
        Passed to :class:`rclpy.node.Node`.

    """

    def __init__(self, node_name='life_publisher', params=None, **kwargs):
        super().__init__(node_name, **kwargs)
        p = declare_plain(self, {
            'joint': ('joint_1', 'joint whose reducer is assessed'),
            'hardware_id': ('', "reducer identifier in /diagnostics ('' = the joint name)")})
        self.joint = p['joint']
        self.hardware_id = p['hardware_id'] or self.joint
        self.params = params or ReducerParams()
        self.life_params = SpecParameters(self, 'life', LifeConfig(), on_change=self._reconfig)
        self.stage = LifeStage(self.params, self.life_params.value)
        self.rejects = RejectCounter(self)
        self.last = None
        self.last_features = None
        self.pub = self.create_publisher(Float64MultiArray,
                                         joint_topic(self.joint, 'remaining_life'), latest_qos())
        self.create_subscription(Float64MultiArray, joint_topic(self.joint, 'wear'),
                                 self._on_wear, latest_qos())
        self.create_subscription(Float64MultiArray, joint_topic(self.joint, 'te_features'),
                                 self._on_features, stream_qos(WINDOW_DEPTH))
        self.check = CheckListener(self, self.joint)
        publish_diagnostics(self, self._statuses)

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
        WORKER.post(self, self._observe_duty, duty)

    def _observe_duty(self, duty):
        self.rejects.guard('life', 'bad_features', self.stage.observe_duty, duty)

    def _on_wear(self, msg):
        try:
            wear = from_multiarray(msg, WEAR_ESTIMATE)
        except InvalidInput as err:
            self.rejects.reject('bad_wear', str(err))
            return
        WORKER.post(self, self._assess, wear)

    def _assess(self, wear):
        """Sample the remaining life of one estimate and publish it (on the worker)."""
        ok, life = self.rejects.guard('life', 'bad_wear', assess, self.stage, wear)
        if ok:
            self.last = (wear, life)
            self.pub.publish(to_multiarray(REMAINING_LIFE,
                                           record_values(REMAINING_LIFE, life.record)))

    def health(self):
        """Return the latest :class:`~reducer_twin.core.joint_twin.HealthSummary`, or None."""
        if self.last is None:
            return None
        te_pp = None if self.last_features is None else self.last_features['te_pp_rad']
        return HealthSummary.of(*self.last, te_pp)

    def summary(self):
        """
        Return the latest assessment in edge units (for the demo and tests).

        Returns
        -------
        dict or None
            Wear, lost motion, remaining life and level
            (:meth:`HealthSummary.as_dict`); None before the first estimate.

        """
        health = self.health()
        return None if health is None else health.as_dict()

    def _statuses(self):
        health = self.health()
        if health is None:
            level, message = 'STALE', 'no wear estimate yet'
            values = {'rejected_messages': self.rejects.total}
        else:
            level, message, values = health.diagnostic(self.rejects.total)
            message, values = self.check.said(level, message, values, self.last[0])
        return [(reducer_status_name(self.joint), self.hardware_id, level, message, values)]


def main(args=None):
    """Run the life_publisher node."""
    return run_nodes(LifePublisher, args)


if __name__ == '__main__':
    raise SystemExit(main())
