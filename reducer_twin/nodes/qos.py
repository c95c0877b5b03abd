"""QoS profiles of the twin's topics: encoder and derived streams, estimates, diagnostics."""

from functools import partial

from rclpy.event_handler import SubscriptionEventCallbacks
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.qos import qos_policy_name_from_kind

ENCODER_DEPTH = 200
"""History depth of 1 kHz encoder streams (>= 100: a stalled reader loses old samples)."""


def encoder_qos(reliable=True):
    """
    Return the QoS of encoder streams (controller topics and paired samples).

    Parameters
    ----------
    reliable : bool
        RELIABLE (default, matches ros2_control's broadcaster) or BEST_EFFORT.

    Returns
    -------
    rclpy.qos.QoSProfile
        KEEP_LAST with depth :data:`ENCODER_DEPTH`, volatile.

    """
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST, depth=ENCODER_DEPTH,
        reliability=ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT,
        durability=DurabilityPolicy.VOLATILE)


WINDOW_DEPTH = 20
"""History depth of per-window topics (``te_features``): 40 s of windows for a stalled reader."""


def stream_qos(depth=100):
    """
    Return the QoS of derived streams: reliable, volatile.

    Parameters
    ----------
    depth : int
        KEEP_LAST depth: 100 for TE batches (2 s at 50 Hz), :data:`WINDOW_DEPTH`
        for per-window features.

    Returns
    -------
    rclpy.qos.QoSProfile
        The profile.

    """
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth,
                      reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.VOLATILE)


def latest_qos():
    """Return the QoS of estimates: reliable, transient-local, the latest sample kept."""
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1,
                      reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL)


def diagnostics_qos():
    """Return the QoS of ``/diagnostics``: reliable, depth 10, volatile."""
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10,
                      reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.VOLATILE)


class UnheardPublishers:
    """
    Publishers a node's subscriptions cannot hear, by topic: their QoS or their type.

    Such a publisher's messages never arrive, and the stream looks merely quiet: a
    controller that publishes its joint states BEST_EFFORT (sensor-data QoS) to a RELIABLE
    subscription, or a topic of another type (``/dynamic_joint_states`` given as the
    link topic). Each topic is said once in the node's log (an error) and kept for
    ``/diagnostics``.

    Parameters
    ----------
    node : rclpy.node.Node
        The subscribing node (its logger and the ROS graph).
    reliable : bool
        Whether the subscriptions are RELIABLE (the remedy then named).

    """

    def __init__(self, node, reliable):
        self._node = node
        self._reliable = reliable
        self.topics = {}
        self._typed = set()     # topics said for their type (judged again at every check)

    def callbacks(self, topic):
        """Return the event callbacks of a subscription to ``topic``."""
        return SubscriptionEventCallbacks(incompatible_qos=partial(self._on_event, topic))

    def _on_event(self, topic, event):
        policy = qos_policy_name_from_kind(event.last_policy_kind)
        hint = ('; it publishes BEST_EFFORT: set reliable to false (twin.reliable in the '
                'bringup YAML)' if policy == 'RELIABILITY' and self._reliable else '')
        self._say(topic, f'a publisher of {topic} offers a QoS this subscription cannot '
                         f'match ({policy}): none of its messages are received{hint}')

    def check_types(self, topics, type_name):
        """
        Say a topic whose publishers are all of another type than ``type_name``.

        DDS matches no such publisher and raises no event for it (Fast DDS): it is read
        from the ROS graph, as ``ros2 topic info`` reads it. Unlike a QoS event, which
        DDS reports once, the graph is read again at every check: a topic said for its
        type is no longer said once a publisher of ``type_name`` appears.
        """
        for topic in topics:
            if topic in self.topics and topic not in self._typed:
                continue
            types = {i.topic_type for i in self._node.get_publishers_info_by_topic(topic)}
            if types and type_name not in types:
                self._typed.add(topic)
                self._say(topic, f'the publishers of {topic} publish {", ".join(sorted(types))}'
                                 f', not {type_name}: none of their messages are received')
            elif topic in self._typed:
                self._typed.discard(topic)
                del self.topics[topic]

    def _say(self, topic, reason):
        if topic not in self.topics:
            self._node.get_logger().error(reason)
        self.topics[topic] = reason

    def reason(self, topic):
        """Say why ``topic``'s publisher is not heard, and what to set."""
        return self.topics[topic]
