"""
What the comparison at the lost-motion test torque found: ``te_monitor`` to ``life_publisher``.

``te_monitor`` reads it (:class:`.soft_zone.SoftZoneCheck`); the remaining life is assessed
by ``life_publisher``, which sees only the wear estimate. Where the windows compared the
width at the test torque too little to say a soft zone (``'unconfirmed'``), or not at all
(``'not compared'``), the lost motion is the loaded flanks' play, more than the catalogue's
lost motion where such a zone exists: an alarm resting on it says so
(:func:`.life_basis.play_clause`, the bag analysis' rule too).

``/reducer_twin/<joint>/test_torque_check`` carries a ``diagnostic_msgs/KeyValue``: the
outcome as ``key`` (``'soft zone'``, ``'unconfirmed'``, ``'none found'``, ``'not
compared'``) and its line as ``value`` (empty where there is none), published when either
changes, transient local (a life publisher started later hears the latest).
"""

from diagnostic_msgs.msg import KeyValue
from reducer_twin.core.joint_twin import joint_topic
from reducer_twin.core.life_basis import play_clause
from reducer_twin.nodes.qos import latest_qos

TOPIC = 'test_torque_check'
"""The topic's last name under ``/reducer_twin/<joint>/``."""


class CheckPublisher:
    """
    Publish what a joint's window analysis found at the test torque, when it changes.

    Parameters
    ----------
    node : rclpy.node.Node
        The ``te_monitor``.
    joint : str
        The joint's name.

    """

    def __init__(self, node, joint):
        self.pub = node.create_publisher(KeyValue, joint_topic(joint, TOPIC), latest_qos())
        self.last = None

    def update(self, analyzer):
        """Publish ``analyzer``'s outcome and line if they changed (:class:`.WindowAnalyzer`)."""
        check = analyzer.test_torque_check
        if check is None:
            return
        line = (analyzer.test_torque_caveat if check == 'unconfirmed'
                else analyzer.test_torque_not_compared) or ''
        if (check, line) != self.last:
            self.last = (check, line)
            self.pub.publish(KeyValue(key=check, value=line))


class CheckListener:
    """
    The latest outcome at the test torque of a joint, and the clause it gives an alarm.

    Heard by ``life_publisher`` (its status) and by a ``wear_estimator`` that writes the
    reducer's live history to a fleet store (the segments' summaries).

    Parameters
    ----------
    node : rclpy.node.Node
        The ``life_publisher``.
    joint : str
        The joint's name.
    live : LiveHistory, optional
        A ``wear_estimator``'s live history in the fleet store, told each outcome heard
        (:attr:`.fleet.live.LiveHistory.test_torque_check`): its segments' summaries carry
        it as a bag's do.

    """

    def __init__(self, node, joint, live=None):
        self.latest = (None, None)
        self.live = live
        node.create_subscription(KeyValue, joint_topic(joint, TOPIC), self._on_check,
                                 latest_qos())

    def _on_check(self, msg):
        self.latest = (msg.key, msg.value or None)
        if self.live is not None:
            self.live.test_torque_check = self.latest

    def said(self, level, message, values, wear_record):
        """
        Return the status' message and key/values with what the comparison found.

        ``values`` gets ``test_torque_check`` once an outcome was heard; the message gets
        its line where :func:`.life_basis.play_clause` says it.
        """
        check, line = self.latest
        if check is None:
            return message, values
        values = {**values, 'test_torque_check': check}
        clause = play_clause(level, check, line, wear_record)
        return (message if clause is None else f'{message}; {clause}'), values
