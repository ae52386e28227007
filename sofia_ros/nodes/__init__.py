"""rclpy shells: each node is a thin Node around a ROS-free core (see sofia_ros.sim)."""
