"""Publish one sample of every microball_msgs type (latched), until standard input closes.

Run by test_messages.py as a separate process, so the messages really cross DDS.
"""

import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

from msg_samples import MESSAGE_TYPES, sample_message, topic_for  # noqa: E402
import rclpy  # noqa: E402
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy  # noqa: E402


def main():
    """Publish the samples, print READY, then wait for stdin to close."""
    rclpy.init()
    node = rclpy.create_node('microball_sample_publisher')
    qos = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)
    publishers = []
    for message_type in MESSAGE_TYPES:
        publisher = node.create_publisher(message_type, topic_for(message_type), qos)
        publisher.publish(sample_message(message_type))
        publishers.append(publisher)
    print('READY', flush=True)
    sys.stdin.read()
    node.destroy_node()
    rclpy.shutdown()


if __name__ == '__main__':
    main()
