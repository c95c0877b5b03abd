"""In-process hand-over of batches between composed nodes, as rclcpp's intra-process does."""

from reducer_twin.msg_adapters.ros import BatchPublisherMessage


class SharedOutput:
    """
    A batch stream handed to in-process consumers, and published while anyone subscribes.

    Parameters
    ----------
    publisher : rclpy.publisher.Publisher
        The topic's publisher (``Float64MultiArray``).
    layout : Layout
        The batch layout of :mod:`reducer_twin.msg_adapters.layouts`.

    """

    def __init__(self, publisher, layout):
        self.publisher = publisher
        self.published = 0
        self.message = BatchPublisherMessage(layout)
        self.sinks = []
        self.listened = True

    def emit(self, rows):
        """Hand ``rows`` to the in-process consumers; publish them if anyone subscribes."""
        self.published += rows.shape[0]
        for sink in self.sinks:
            sink(rows)
        if self.listened:
            self.publisher.publish(self.message.fill(rows))

    def check_listeners(self):
        """Publish only while subscribed, once an in-process consumer takes the batches."""
        self.listened = not self.sinks or self.publisher.get_subscription_count() > 0
