"""QoS profiles of the twin's topics: encoder and derived streams, estimates, diagnostics."""

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

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
