"""
What the window analysis found at the lost-motion test torque: ``te_monitor`` to the life.

``te_monitor`` reads it (:class:`.soft_zone.SoftZoneCheck`,
:class:`.within_zone.WithinZoneCheck`); the remaining life is assessed by
``life_publisher``, which sees only the wear estimate. Where the windows compared the
width at the test torque too little to say a soft zone (``'unconfirmed'``), or not at all
(``'not compared'``), the lost motion is the loaded flanks' play, more than the catalogue's
lost motion where such a zone exists: an alarm resting on it says so. Where the lost motion
read lies below its own bins' width at the test torque (loads that never leave a soft
zone), it is given at that width, itself short where the friction loop of such loads has
not opened, so the remaining life may still be too long: said beside the life whatever its
level.
One rule, :func:`.life_basis.torque_check_lines`, the bag analysis' too.

``/reducer_twin/<joint>/test_torque_check`` carries a ``diagnostic_msgs/DiagnosticStatus``
(``name``: the joint; ``level``: WARN where a line is said, else OK; ``message``: the lines)
whose ``values`` hold ``test_torque_check`` (``'soft zone'``, ``'unconfirmed'``, ``'none
found'``, ``'not compared'``), ``line`` (its caveat, empty where there is none) and
``within_zone`` (empty where there is none). Published when any changes, transient local (a
life publisher started later hears the latest).
"""

from diagnostic_msgs.msg import DiagnosticStatus, KeyValue
from reducer_twin.core.joint_twin import joint_topic
from reducer_twin.core.life_basis import torque_check_lines, TorqueCheckFinding
from reducer_twin.nodes.qos import latest_qos

TOPIC = 'test_torque_check'
"""The topic's last name under ``/reducer_twin/<joint>/``."""


def finding_of(analyzer):
    """
    Return what ``analyzer`` found at the test torque, or None before it compared.

    Parameters
    ----------
    analyzer : WindowAnalyzer
        The joint's window analysis.

    Returns
    -------
    TorqueCheckFinding or None

    """
    check = analyzer.test_torque_check
    if check is None:
        return None
    line = (analyzer.test_torque_caveat if check == 'unconfirmed'
            else analyzer.test_torque_not_compared)
    return TorqueCheckFinding(check, line or None, analyzer.within_zone or None)


def to_status(joint, finding):
    """Return the ``DiagnosticStatus`` that carries ``finding`` (:data:`TOPIC`)."""
    said = [x for x in (finding.within_zone, finding.line) if x]
    return DiagnosticStatus(
        level=DiagnosticStatus.WARN if said else DiagnosticStatus.OK, name=joint,
        message='; '.join(said),
        values=[KeyValue(key='test_torque_check', value=finding.check),
                KeyValue(key='line', value=finding.line or ''),
                KeyValue(key='within_zone', value=finding.within_zone or '')])


def from_status(msg):
    """Return the :class:`.life_basis.TorqueCheckFinding` a ``DiagnosticStatus`` carries."""
    values = {kv.key: kv.value for kv in msg.values}
    return TorqueCheckFinding(values.get('test_torque_check') or None,
                              values.get('line') or None, values.get('within_zone') or None)


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
        self.pub = node.create_publisher(DiagnosticStatus, joint_topic(joint, TOPIC),
                                         latest_qos())
        self.joint = joint
        self.last = None

    def update(self, analyzer):
        """Publish ``analyzer``'s finding if it changed (:class:`.WindowAnalyzer`)."""
        finding = finding_of(analyzer)
        if finding is not None and finding != self.last:
            self.last = finding
            self.pub.publish(to_status(self.joint, finding))


class CheckListener:
    """
    The latest finding at the test torque of a joint, and the lines it gives the life.

    Heard by ``life_publisher`` (its status) and by a ``wear_estimator`` that writes the
    reducer's live history to a fleet store (the segments' summaries).

    Parameters
    ----------
    node : rclpy.node.Node
        The ``life_publisher``.
    joint : str
        The joint's name.
    live : LiveHistory, optional
        A ``wear_estimator``'s live history in the fleet store, told each finding heard
        (:attr:`.fleet.live.LiveHistory.test_torque_check`): its segments' summaries carry
        it as a bag's do.

    """

    def __init__(self, node, joint, live=None):
        self.latest = None
        self.live = live
        node.create_subscription(DiagnosticStatus, joint_topic(joint, TOPIC), self._on_check,
                                 latest_qos())

    def _on_check(self, msg):
        self.latest = from_status(msg)
        if self.live is not None:
            self.live.test_torque_check = self.latest

    def said(self, level, message, values, wear_record):
        """
        Return the status' message and key/values with what was found at the test torque.

        ``values`` gets ``test_torque_check`` once a finding was heard (and
        ``lost_motion_within_zone: true`` where that line is said); the message gets the
        lines :func:`.life_basis.torque_check_lines` says.
        """
        if self.latest is None or self.latest.check is None:
            return message, values
        values = {**values, 'test_torque_check': self.latest.check}
        if self.latest.within_zone:
            values['lost_motion_within_zone'] = 'true'
        lines = torque_check_lines(level, self.latest, wear_record)
        return '; '.join([message, *lines]), values
