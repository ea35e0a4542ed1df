"""Launch the segmenter with the shipped parameters (ROS installs; launch is not on PyPI).

ros2 launch moseg_ros segmenter.launch.py image:=/camera/image_raw camera_info:=/camera/camera_info
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node


def generate_launch_description() -> LaunchDescription:
    params = os.path.join(get_package_share_directory("moseg_ros"), "config", "segmenter.yaml")
    return LaunchDescription([
        DeclareLaunchArgument("image", default_value="/camera/image_raw"),
        DeclareLaunchArgument("camera_info", default_value="/camera/camera_info"),
        DeclareLaunchArgument("params_file", default_value=params),
        Node(
            package="moseg_ros",
            executable="segmenter",
            name="segmenter",
            parameters=[LaunchConfiguration("params_file")],
            remappings=[("image", LaunchConfiguration("image")),
                        ("camera_info", LaunchConfiguration("camera_info"))],
            output="screen",
        ),
    ])
