"""Smoke test: every custom message crosses DDS between two processes, field for field."""

import math
import os
import subprocess
import sys

from msg_samples import MESSAGE_TYPES, sample_message, topic_for
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

HERE = os.path.dirname(os.path.abspath(__file__))


def test_samples_set_every_field_to_a_non_default_value():
    for message_type in MESSAGE_TYPES:
        sample = sample_message(message_type)
        for name in message_type.get_fields_and_field_types():
            default = getattr(message_type(), name)
            assert str(getattr(sample, name)) != str(default), (message_type.__name__, name)


def test_friction_model_interval_keeps_infinity():
    from microball_msgs.msg import FrictionModel

    model = FrictionModel(alpha_ci95=[80.0, math.inf])
    assert math.isinf(model.alpha_ci95[1])


def test_every_message_type_round_trips_between_processes(ros_harness):
    publisher = subprocess.Popen([sys.executable, os.path.join(HERE, 'publish_samples.py')],
                                 stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    try:
        assert publisher.stdout.readline().strip() == 'READY'
        qos = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)
        received = {}
        for message_type in MESSAGE_TYPES:
            ros_harness.probe.create_subscription(
                message_type, topic_for(message_type),
                lambda msg, name=message_type.__name__: received.setdefault(name, msg), qos)
        ros_harness.spin_until(lambda: len(received) == len(MESSAGE_TYPES), 30.0,
                               'a sample of every message type')
        assert sorted(received) == sorted(t.__name__ for t in MESSAGE_TYPES)
        for message_type in MESSAGE_TYPES:
            expected = sample_message(message_type)
            got = received[message_type.__name__]
            for name in message_type.get_fields_and_field_types():
                assert str(getattr(got, name)) == str(getattr(expected, name)), name
            assert got == expected
    finally:
        publisher.stdin.close()
        publisher.wait(timeout=30)
    assert publisher.returncode == 0
