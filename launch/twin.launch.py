"""
Launch the reducer twin bringup: every node for every joint of a twin.yaml in one process.

Usage (in a ROS 2 Jazzy installation with this package built by colcon)::

    ros2 launch reducer_twin twin.launch.py
    ros2 launch reducer_twin twin.launch.py config:=/path/to/my_robot_twin.yaml

``config`` defaults to the installed ``share/reducer_twin/config/twin.yaml``; the file
names the joints, the controller topics (``/joint_states`` with ``<joint>_motor``
entries, or a motor topic), the torque source, the aging factor and the life
thresholds (see the README).
"""

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration, PathJoinSubstitution
from launch_ros.actions import Node
from launch_ros.substitutions import FindPackageShare


def generate_launch_description():
    """Return the bringup with its ``config`` argument."""
    config = DeclareLaunchArgument(
        'config',
        default_value=PathJoinSubstitution([FindPackageShare('reducer_twin'), 'config',
                                            'twin.yaml']),
        description='bringup configuration (joints, topics, aging factor, life thresholds)')
    bringup = Node(package='reducer_twin', executable='twin_bringup', name='twin_bringup',
                   output='screen', parameters=[{'config': LaunchConfiguration('config')}])
    return LaunchDescription([config, bringup])
