"""Robustness: a node waits quietly for its publishers; a killed estimator restarts cleanly."""

import os
import signal
import subprocess
import sys

from microball_msgs.msg import DerivativeEstimate, FrictionModel, TrackedPositions
import pytest
from ros_testing import Harness

from microball_ros.core import bench
from microball_ros.io import conversions
from microball_ros.nodes.common import DATA_QOS
from microball_ros.nodes.friction_identifier import FrictionIdentifier


def _start_estimator():
    return subprocess.Popen([sys.executable, '-m', 'microball_ros.nodes.three_stage_estimator'],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)


def _subscription_ids(node, topic):
    return {bytes(info.endpoint_gid) for info in node.get_subscriptions_info_by_topic(topic)}


def test_killed_estimator_restarts_and_the_pipeline_resumes(ros_context):
    record = bench.simulate(bench.get_scenario('paper'), 40.0)
    identifier = FrictionIdentifier(context=ros_context)
    harness = Harness(ros_context, identifier)
    estimator = _start_estimator()
    try:
        probe = harness.probe
        models, windows = [], []
        probe.create_subscription(FrictionModel, 'friction/model', models.append, DATA_QOS)
        probe.create_subscription(DerivativeEstimate, 'estimation/derivatives', windows.append,
                                  DATA_QOS)
        positions = probe.create_publisher(TrackedPositions, 'tracking/positions', DATA_QOS)
        # Started before anything publishes positions, the estimator waits quietly.
        harness.wait_for_subscribers(positions)
        assert estimator.poll() is None and windows == []

        def publish(frames):
            for k in frames:
                positions.publish(conversions.tracked_positions(
                    record.time[k], k, record.slider_position[k], record.stator_position[k],
                    1.0, 1.0))

        publish(range(0, 450))  # 15 s
        harness.spin_until(lambda: len(models) >= 6, timeout=60, message='6 models')
        old_subscriptions = _subscription_ids(probe, 'tracking/positions')
        os.kill(estimator.pid, signal.SIGKILL)
        estimator.wait(timeout=10)
        before = len(windows)

        estimator = _start_estimator()
        harness.spin_until(
            lambda: _subscription_ids(probe, 'tracking/positions') - old_subscriptions,
            timeout=30, message='the restarted estimator')
        harness.wait_for_subscribers(positions)
        publish(range(600, 1200))  # 20 s more, after a gap of 5 s
        harness.spin_until(lambda: len(windows) >= before + 8, timeout=60,
                           message='windows from the restarted estimator')
        harness.spin_until(lambda: len(models) == len(windows), timeout=60,
                           message='a model for every window')
        resumed = windows[before:]
        assert min(conversions.stamp_to_seconds(w.header.stamp) for w in resumed) >= \
            record.time[600]
        model = models[-1]
        assert model.window_count == len(windows)
        assert model.a * model.alpha / 3 == pytest.approx(1.2 * 110 / 3, rel=0.05)
        assert all(w.memoryless for w in windows)
    finally:
        estimator.kill()
        estimator.wait(timeout=10)
        harness.close()
