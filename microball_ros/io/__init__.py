"""Files and messages: rosbag2 MCAP bags, position CSVs, camera frames, msg <-> numpy.

Everything that touches a file or a ROS message type lives here; the numerics stay in core.
"""
