"""NodeDiagnostics: a node's health on /diagnostics, as rqt_robot_monitor and Foxglove read it."""

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
import pytest
import rclpy

from microball_ros.nodes.common import NodeDiagnostics
from microball_ros.testing import Harness

pytestmark = pytest.mark.ros


def test_drops_are_counted_per_kind_logged_once_and_published(ros_context):
    node = rclpy.create_node('diagnosed', context=ros_context)
    diagnostics = NodeDiagnostics(node, period=0.1, hardware_id='rig-1')
    harness = Harness(ros_context, node)
    seen = []
    harness.probe.create_subscription(DiagnosticArray, '/diagnostics', seen.append, 10)
    try:
        for _ in range(5):
            diagnostics.received()
        diagnostics.dropped('image of another size', '640x480, expected 720x480')
        diagnostics.dropped('image of another size')
        diagnostics.dropped('unknown encoding', 'yuv422')
        diagnostics.count('lost marks', 3)
        harness.spin_until(lambda: any(s.level == DiagnosticStatus.WARN
                                       for m in seen for s in m.status), 10.0, 'a WARN status')
        status = next(s for m in seen for s in m.status if s.level == DiagnosticStatus.WARN)
        values = {kv.key: kv.value for kv in status.values}
        assert status.name == 'diagnosed' and status.hardware_id == 'rig-1'
        assert values['received'] == '5' and values['dropped'] == '3'
        assert values['dropped: image of another size'] == '2'
        assert values['dropped: unknown encoding'] == '1'
        assert values['lost marks'] == '3'
        count = len(seen)
        harness.spin_until(lambda: len(seen) > count, 10.0, 'the next status')
        assert seen[-1].status[0].level == DiagnosticStatus.OK  # nothing new: back to OK
    finally:
        harness.close()


def test_an_output_reports_the_subscriptions_its_writer_matched(ros_context):
    from std_msgs.msg import String

    node = rclpy.create_node('talker', namespace='rig2', context=ros_context)
    output = node.create_publisher(String, 'chatter', 10)
    diagnostics = NodeDiagnostics(node, period=0.1)
    assert diagnostics.watch_output(output) is output
    harness = Harness(ros_context, node)
    statuses = harness.diagnostics()
    try:
        harness.spin_until(lambda: 'rig2/talker' in statuses, 10.0, 'a status')
        assert statuses['rig2/talker']['subscribers: /rig2/chatter'] == '0'
        harness.probe.create_subscription(String, '/rig2/chatter', lambda msg: None, 10)
        harness.probe.create_subscription(String, '/rig2/chatter', lambda msg: None, 10)
        harness.wait_for_output_subscribers('rig2/talker', '/rig2/chatter', 2, timeout=10.0)
        assert statuses['rig2/talker']['subscribers: /rig2/chatter'] == '2'
    finally:
        harness.close()
