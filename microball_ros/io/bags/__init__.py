"""rosbag2-compatible MCAP bags: schemas, a writer, a reader (no rclpy needed)."""

from microball_ros.io.bags.reader import (
                                       Bag,
                                       BagError,
                                       BagMessage,
                                       TopicInfo,
                                       open_bag,
                                       read_positions,
                                       reindex,
)
from microball_ros.io.bags.schema import message_definition, qos_profiles_yaml
from microball_ros.io.bags.writer import BagWriter

__all__ = ['Bag', 'BagError', 'BagMessage', 'BagWriter', 'TopicInfo', 'message_definition',
           'open_bag', 'qos_profiles_yaml', 'read_positions', 'reindex']
