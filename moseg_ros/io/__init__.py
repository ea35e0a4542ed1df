"""Image messages <-> numpy, rosbag2 reading and writing, KITTI layouts. Imports no rclpy."""
