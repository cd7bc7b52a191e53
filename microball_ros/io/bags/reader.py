"""Read rosbag2 MCAP bags without a ROS runtime: the one import point for readers of bags.

The reading side lives in four modules, and this one re-exports their public names so that
``from microball_ros.io.bags.reader import ...`` keeps working: bag (``open_bag`` and the
``Bag`` it returns: topics, times, custom_data and platform fingerprint, messages in log-time
order), mcap_file (one MCAP file through its summary or a full scan; damage), metadata
(metadata.yaml and the MCAP 'rosbag2' record; ros_distro), repair (``reindex``: a killed
recorder's bag made whole, originals kept beside the bag directory) and decode
(``read_positions``, ``read_frames``, ``recorded_parameters``).
"""

from microball_ros.core.errors import BagError
from microball_ros.io.bags.bag import Bag, BagMessage, TopicInfo, open_bag
from microball_ros.io.bags.decode import (
    IMAGE_TYPE,
    IMAGES_TOPIC,
    POSITIONS_TOPIC,
    POSITIONS_TYPE,
    read_frames,
    read_positions,
    recorded_parameters,
)
from microball_ros.io.bags.mcap_file import MAGIC
from microball_ros.io.bags.metadata import METADATA_FILE, ros_distro
from microball_ros.io.bags.repair import reindex

__all__ = ['IMAGES_TOPIC', 'IMAGE_TYPE', 'MAGIC', 'METADATA_FILE', 'POSITIONS_TOPIC',
           'POSITIONS_TYPE', 'Bag', 'BagError', 'BagMessage', 'TopicInfo', 'open_bag',
           'read_frames', 'read_positions', 'recorded_parameters', 'reindex', 'ros_distro']
