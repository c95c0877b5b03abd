"""
Arrival times for a topic whose publisher does not stamp its messages.

A driver that leaves ``header.stamp`` unset publishes every stamp as zero. The topic's
first message decides: from a zero stamp on, the topic's messages are taken at the times
they arrive here (the node's clock), said once in the log; ``/diagnostics`` names such
topics (:func:`.diagnostics.ingest_statuses`). Zeros among real stamps stay what they are
(a clock that stands, which the ingestion drops and counts).
"""

from reducer_twin.core.stamp_clock import unstamped_message


class ArrivalStamps:
    """
    Per topic, the header stamp or, for a publisher that does not stamp, the arrival time.

    Parameters
    ----------
    node : rclpy.node.Node
        The node whose clock and logger are used.
    topics : dict
        Topic name of each side (``'link'``, ``'motor'``).

    """

    def __init__(self, node, topics):
        self._node = node
        self._topics = topics
        self._arrival = {}    # side -> its topic's first message had no stamp

    def stamp(self, side, t_ns):
        """Return the stamp [ns] to take for a message of ``side`` stamped ``t_ns``."""
        arrival = self._arrival.get(side)
        if arrival is None:     # decided by the topic's first message
            arrival = self._arrival[side] = t_ns == 0
            if arrival:
                self._node.get_logger().warning(unstamped_message(
                    self._topics[side], 'they arrived here (arrival times)'))
        return self._node.get_clock().now().nanoseconds if arrival else t_ns

    def unstamped_topics(self):
        """Return the topics whose messages are taken at their arrival times."""
        return [self._topics[side] for side, arrival in self._arrival.items() if arrival]
