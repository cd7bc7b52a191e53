"""microball_ros: friction measurement and modelling for MEMS microball bearings on ROS 2."""

__version__ = '0.1.0'
