"""sofia_ros: SOFIA pointing-control emulation and calibration analysis on ROS 2."""

__version__ = '0.1.0'
