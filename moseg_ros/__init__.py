"""moseg_ros: object-level motion segmentation from a moving monocular camera, as a ROS 2 node."""

__version__ = "0.1.0"
