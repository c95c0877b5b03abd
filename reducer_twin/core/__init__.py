"""
Pure numerical core of the reducer twin.

Nothing below this package imports rclpy, ROS message packages or mcap: the
live nodes and the offline bag analysis both call into it. Quantities are SI
(metres, radians, newton-metres, seconds) throughout.
"""
