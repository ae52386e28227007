"""ROS-free node cores, the lock-step protocol and the runner that drives them in one loop."""
