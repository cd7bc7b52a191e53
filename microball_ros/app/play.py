"""Replay a bag: publish its messages in recorded order with their original bytes.

``Player`` is an rclpy node driven by ``microball play`` (and by ``microball reprocess``):
one publisher per topic with the recorded QoS (reliable / transient local as offered), the
recorded serialized bytes published as they are, paced by the recorded log times divided by
``rate``, optionally with /clock from bag time. In lock-step mode each message is published
only after every matched reliable subscriber has acknowledged the previous one on its topic,
so no subscriber can fall behind and drop.
"""

import os
import time

from rclpy.node import Node
from rosgraph_msgs.msg import Clock as ClockMsg

from microball_ros.io import conversions
from microball_ros.io.bags.schema import parse_qos_profiles
from microball_ros.io.conversions import message_class
from microball_ros.nodes.common import matching_qos

LOCKSTEP_PROFILE = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))),
                                'config', 'fastdds_lockstep.xml')


def use_lockstep_profile():
    """Make this process's (and its children's) Fast DDS writers heartbeat every 1 ms.

    Must run before rclpy.init. With Fast DDS's default 3 s heartbeat period,
    wait_for_all_acked waits up to 3 s per message; lock-step replay needs the
    acknowledgement as soon as the readers have the message (the profile also makes readers
    answer a heartbeat within 0.1 ms). A profile file the user set already is left alone.
    """
    if not os.path.isfile(LOCKSTEP_PROFILE):  # a packaging mistake, not bad input
        raise FileNotFoundError(f'lock-step Fast DDS profile missing: {LOCKSTEP_PROFILE}')
    os.environ.setdefault('FASTDDS_DEFAULT_PROFILES_FILE', LOCKSTEP_PROFILE)


def replay_qos(qos_profiles_yaml):
    """Return the QoS to replay a topic with: what its recorded publishers offered.

    Reliable unless a publisher was best effort; transient local if every publisher was
    (policies by name, or by rosbag2's older integer codes: best effort 2, transient local 1).
    """
    profiles = parse_qos_profiles(qos_profiles_yaml)
    best_effort = any(p.get('reliability') in ('best_effort', 2) for p in profiles)
    latched = bool(profiles) and all(
        p.get('durability') in ('transient_local', 1) for p in profiles)
    return matching_qos(not best_effort, latched)


class Player(Node):
    """Publish a bag's messages; call ``play()`` after creating it."""

    def __init__(self, bag, topics=None, clock=False, **kwargs):
        super().__init__('player', **kwargs)
        self.bag = bag
        self.publishers_by_topic = {}
        self.skipped_types = {}
        chosen = set(topics) if topics else set(bag.topics)
        missing = chosen - set(bag.topics)
        if missing:
            raise ValueError(f'bag has no topic {", ".join(sorted(missing))}; it has: '
                             f'{", ".join(sorted(bag.topics))}')
        for name in sorted(chosen):
            info = bag.topics[name]
            try:
                message_type = message_class(info.type)
            except ValueError as error:
                self.skipped_types[name] = str(error)
                self.get_logger().warning(f'skipping {name}: {error}')
                continue
            self.publishers_by_topic[name] = self.create_publisher(
                message_type, name, replay_qos(info.qos_profiles_yaml))
        self._clock = self.create_publisher(ClockMsg, '/clock', 10) if clock else None
        self.published = 0

    def wait_for_subscribers(self, executor, topics, timeout=30.0):
        """Spin until each named topic's publisher has a matched subscriber."""
        deadline = time.monotonic() + timeout
        for topic in topics:
            publisher = self.publishers_by_topic[topic]
            while publisher.get_subscription_count() < 1:
                if time.monotonic() > deadline:
                    raise TimeoutError(f'no subscriber for {topic} after {timeout:g} s')
                executor.spin_once(timeout_sec=0.05)

    def play(self, executor, rate=1.0, start_offset=0.0, lockstep=False, progress=None,
             paused=None, ack_timeout=30.0, ready=None):
        """Publish every message once; return how many were published.

        ``executor`` is spun between messages so the process keeps serving its own nodes;
        ``paused()`` (optional) holds playback while it returns True; ``ready()`` (optional)
        is called before each message and returns when it may be published (it spins).
        """
        start = self.bag.start_ns + int(start_offset * 1e9)
        wall_start, bag_start = None, None
        next_report = time.monotonic() + 2.0
        count = 0
        for message in self.bag.messages(list(self.publishers_by_topic)):
            if message.log_time_ns < start:
                continue
            if bag_start is None:
                wall_start, bag_start = time.monotonic(), message.log_time_ns
            if not lockstep and rate > 0:
                due = wall_start + (message.log_time_ns - bag_start) * 1e-9 / rate
                while time.monotonic() < due or (paused and paused()):
                    executor.spin_once(timeout_sec=min(0.05, max(0.0, due - time.monotonic())))
                    if paused and paused():
                        due += 0.05
            if ready is not None:
                ready()
            publisher = self.publishers_by_topic[message.topic]
            if self._clock is not None:
                self._clock.publish(ClockMsg(clock=conversions.nanoseconds_to_stamp(
                    message.log_time_ns)))
            publisher.publish(message.data)
            count += 1
            self.published += 1
            if lockstep and publisher.get_subscription_count() > 0:
                if not publisher.wait_for_all_acked(_duration(ack_timeout)):
                    raise TimeoutError(f'{message.topic}: a subscriber did not acknowledge '
                                       f'within {ack_timeout:g} s')
            executor.spin_once(timeout_sec=0)
            if progress and time.monotonic() >= next_report:
                progress(count, (message.log_time_ns - self.bag.start_ns) * 1e-9)
                next_report = time.monotonic() + 2.0
        return count


def _duration(seconds):
    from rclpy.duration import Duration

    return Duration(nanoseconds=int(seconds * 1e9))
