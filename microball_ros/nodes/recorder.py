"""recorder: subscribe to topics as serialized messages and write a rosbag2 MCAP bag.

Topics are discovered while recording (all of them, or the ones named in ``topics``); each is
subscribed once it has a publisher, with ``raw=True`` so messages are written as received
(no decode/encode round trip), and with a QoS that matches its publishers (reliable if they
all are, transient local if they all are), as rosbag2 does. Log time is the receipt time
(system clock, when the recorder takes the message); publish time is the middleware's source
timestamp (the publisher's system clock when it wrote the message), as rosbag2_transport's
recorder stores them, or the receipt time where the middleware gives none. Never a header
stamp: both times are on the same clock, so ``--message-order sent`` and any tool trusting
publish time see the recording's clock. The bag's custom_data (with the platform
fingerprint) is written when the bag opens, and the bag is flushed about once a second, so a
killed recorder loses at most that much and keeps its custom_data and topics
(``microball reindex`` repairs it).
Lost messages are counted from the middleware's message-lost events.
"""

import sys
import time

from rclpy.event_handler import SubscriptionEventCallbacks
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, ReliabilityPolicy
import yaml

from microball_ros.io.bags.schema import qos_profiles_yaml
from microball_ros.io.bags.writer import BagWriter
from microball_ros.io.conversions import message_class
from microball_ros.nodes.common import Param, declare_parameters, matching_qos, run

IGNORED_TOPICS = ('/rosout', '/parameter_events')

PARAMS = {
    'output': Param('', 'bag directory to create', read_only=True),
    'topics': Param([''], "topics to record; [''] records every topic", read_only=True),
    'compression': Param('zstd', 'MCAP chunk compression: zstd, lz4 or none',
                         read_only=True),
    'discovery_period': Param(0.5, 'how often to look for new topics, s', 0.05, 60.0),
    'flush_period': Param(1.0, 'how often to make the bag durable on disk, s', 0.05, 60.0),
    'custom_data': Param('', 'YAML mapping of strings kept in metadata.yaml custom_data',
                         read_only=True),
}


def check_parameters(values):
    """Return None if the parameter values are consistent, else a one-line reason."""
    if not values['output']:
        return 'output (the bag directory) is required'
    if values['compression'] not in ('zstd', 'lz4', 'none'):
        return f"compression must be zstd, lz4 or none, got {values['compression']!r}"
    try:
        custom = yaml.safe_load(values['custom_data']) if values['custom_data'] else {}
    except yaml.YAMLError:
        return 'custom_data is not YAML'
    if not isinstance(custom, dict) or not all(
            isinstance(k, str) and isinstance(v, str) for k, v in custom.items()):
        return 'custom_data must be a YAML mapping of strings to strings'
    return None


# Messages one callback takes beyond its own before it yields to the timers (flush, discovery).
DRAIN_LIMIT = 1000


def publish_time(info, received):
    """Return a message's publish time: the middleware's source timestamp, else ``received``.

    ``info`` is the MessageInfo rclpy hands a callback (or take_message returns); a middleware
    that does not stamp sources gives 0 there.
    """
    source = info.get('source_timestamp') if info else None
    return source if source and source > 0 else received


def subscription_qos(publisher_profiles):
    """Return the QoS that receives everything the publishers offer (rosbag2's adaptation)."""
    reliable = all(q.reliability == ReliabilityPolicy.RELIABLE for q in publisher_profiles)
    latched = all(q.durability == DurabilityPolicy.TRANSIENT_LOCAL for q in publisher_profiles)
    return matching_qos(reliable, latched)


class Recorder(Node):
    """Record topics to a rosbag2 MCAP bag."""

    def __init__(self, **kwargs):
        super().__init__('recorder', **kwargs)
        self._values = declare_parameters(self, PARAMS, check_parameters)
        values = self._values
        compression = None if values['compression'] == 'none' else values['compression']
        custom_data = yaml.safe_load(values['custom_data']) if values['custom_data'] else {}
        self._writer = BagWriter(values['output'], compression=compression,
                                 custom_data=custom_data)
        self._wanted = {t for t in values['topics'] if t}
        self._recorded = {}
        self._closed = None
        self.lost = {}
        self.matched = {}
        self.create_timer(values['discovery_period'], self._discover)
        self.create_timer(values['flush_period'], self._writer.flush)
        self._discover()

    @property
    def counts(self):
        """Return messages written per topic."""
        return dict(self._writer.counts)

    def _discover(self):
        for topic, types in self.get_topic_names_and_types():
            if topic in self._recorded or topic in IGNORED_TOPICS:
                continue
            if self._wanted and topic not in self._wanted:
                continue
            self._subscribe(topic, types[0])

    def _subscribe(self, topic, type_name):
        try:
            message_type = message_class(type_name)
        except ValueError as error:
            self.get_logger().warning(f'not recording {topic}: {error}', once=True)
            self._recorded[topic] = None
            return
        offered = [info.qos_profile for info in self.get_publishers_info_by_topic(topic)]
        if not offered:
            return  # subscribe once a publisher shows its QoS (next discovery round)
        self._writer.add_topic(topic, type_name, qos_profiles_yaml(offered))
        self.lost[topic] = 0

        def record(data, info, topic=topic):
            received = time.time_ns()  # system time, as rosbag2 stamps receipt
            self._writer.write(topic, data, received, publish_time(info, received))

        def on_message(data, info, topic=topic, record=record):
            record(data, info)
            # Take what else has arrived on this topic here, in order: a round of the executor
            # costs several times the write (measured in bench/bench_bags.py).
            subscription = self._recorded[topic]
            for _ in range(DRAIN_LIMIT):
                with subscription.handle:
                    taken = subscription.handle.take_message(subscription.msg_type, True)
                if taken is None:
                    break
                record(taken[0], taken[1])

        def on_lost(info, topic=topic):
            self.lost[topic] += info.total_count_change

        def on_matched(info, topic=topic):
            self.matched[topic] = info.current_count

        self._recorded[topic] = self.create_subscription(
            message_type, topic, on_message, subscription_qos(offered), raw=True,
            event_callbacks=SubscriptionEventCallbacks(message_lost=on_lost,
                                                       matched=on_matched))
        self.get_logger().info(f'recording {topic} ({type_name})')

    def close(self):
        """Finish the bag (summary, metadata.yaml) once; return per-topic counts."""
        if self._closed is None:
            self._closed = self._writer.close()
        return self._closed

    def destroy_node(self):
        """Finish the bag, report counts and losses, then destroy the node."""
        counts = self.close()
        for topic in sorted(counts):
            print(f'{topic}: {counts[topic]} messages, {self.lost.get(topic, 0)} lost',
                  flush=True)
        super().destroy_node()


def main(args=None):
    """Run the node (console script recorder)."""
    return run(Recorder, args)


if __name__ == '__main__':
    sys.exit(main())
