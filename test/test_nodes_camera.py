"""bench_simulator and camera_tracker in process: frames over DDS, tracked against the truth."""

import math

from microball_msgs.msg import BenchState, ServoCommand, TrackedPositions
import numpy as np
import pytest
from rclpy.parameter import Parameter
from sensor_msgs.msg import Image

from microball_ros.core import bench, rig
from microball_ros.io import conversions
from microball_ros.nodes.bench_simulator import BenchSimulator
from microball_ros.nodes.camera_tracker import CameraTracker
from microball_ros.nodes.common import DATA_QOS, LATCHED_QOS
from microball_ros.testing import Harness


def _tracker_parameters(scenario):
    rois = rig.suggested_rois(scenario)
    scale = rig.camera_for(scenario).meters_per_pixel
    return [Parameter('slider_roi', value=list(rois['slider'])),
            Parameter('stator_roi', value=list(rois['stator'])),
            Parameter('meters_per_pixel', value=scale)], scale


def test_tracked_bench_frames_follow_the_ground_truth(ros_context):
    scenario = bench.get_scenario('paper')
    parameters, scale = _tracker_parameters(scenario)
    simulator = BenchSimulator(context=ros_context, parameter_overrides=[
        Parameter('speed', value=4.0), Parameter('duration', value=6.0)])
    tracker = CameraTracker(context=ros_context, parameter_overrides=parameters + [
        Parameter('publish_debug_image', value=True)])
    harness = Harness(ros_context, simulator, tracker)
    try:
        truth, positions, debug = {}, {}, []
        probe = harness.probe
        probe.create_subscription(BenchState, 'bench/ground_truth',
                                  lambda m: truth.setdefault(m.frame_index, m), DATA_QOS)
        probe.create_subscription(TrackedPositions, 'tracking/positions',
                                  lambda m: positions.setdefault(
                                      conversions.stamp_to_seconds(m.header.stamp), m),
                                  DATA_QOS)
        probe.create_subscription(Image, 'tracking/debug_image', debug.append, 10)
        command = probe.create_publisher(ServoCommand, 'servo/command', LATCHED_QOS)
        command.publish(ServoCommand(enabled=True, frequency=2.95,
                                     angular_velocity=2 * math.pi * 2.95, amplitude=1.2e-3,
                                     ramp_time=0.5))
        harness.spin_until(lambda: len(positions) >= 180 and len(truth) >= 180,
                           timeout=120, message='180 tracked frames')
        assert simulator.frames_published == 180  # the duration parameter stops the bench
        states = [truth[k] for k in sorted(truth)]
        stamps = np.array([conversions.stamp_to_seconds(s.header.stamp) for s in states])
        np.testing.assert_allclose(np.diff(stamps), 1 / 30, atol=1e-9)
        assert stamps[0] == pytest.approx(1 / 120)  # mid-exposure of a 1/60 s exposure
        tracked = [positions[t] for t in stamps]
        assert all(p.slider_valid and p.stator_valid for p in tracked)
        for mark in ('slider', 'stator'):
            measured = np.array([getattr(p, f'{mark}_position') for p in tracked]) / scale
            true = np.array([getattr(s, f'{mark}_position_exposure_mean')
                             for s in states]) / scale
            # The tracker reports the exposure average of the blurred mark (in image columns:
            # the constant offset is the image origin of the plate coordinates).
            error = (measured - true) - np.median(measured - true)
            assert np.sqrt(np.mean(error ** 2)) < 0.15, mark
            # Mid-exposure and exposure mean differ by sinc(w T / 2) - 1 = -0.4 %.
            middle = np.array([getattr(s, f'{mark}_position') for s in states]) / scale
            assert np.max(np.abs(true - middle)) < 1.0
        # The motor ramped up: the crank reaches 2.95 Hz.
        assert states[-1].crank_angular_velocity == pytest.approx(2 * math.pi * 2.95, rel=1e-3)
        assert states[-1].friction_law == 'langevin'
        assert debug and debug[-1].encoding == 'bgr8'
    finally:
        harness.close()


def test_tracker_rejects_an_roi_outside_the_frame_and_publishes_nothing(ros_context):
    scenario = bench.get_scenario('paper')
    parameters, _ = _tracker_parameters(scenario)
    parameters[0] = Parameter('slider_roi', value=[700, 10, 300, 40])
    tracker = CameraTracker(context=ros_context, parameter_overrides=parameters)
    harness = Harness(ros_context, tracker)
    try:
        positions = []
        harness.probe.create_subscription(TrackedPositions, 'tracking/positions',
                                          positions.append, DATA_QOS)
        images = harness.probe.create_publisher(Image, 'camera/image_raw', DATA_QOS)
        harness.wait_for_subscribers(images)
        frame = np.full((480, 720), 128, np.uint8)
        images.publish(conversions.image_message(frame, 1.0))
        harness.spin_until(lambda: tracker.frames_dropped == 1, message='the dropped frame')
        assert tracker.frames_tracked == 0
        assert positions == []
    finally:
        harness.close()


def test_bad_roi_parameter_is_refused_at_start(ros_context):
    with pytest.raises(ValueError, match='slider ROI'):
        CameraTracker(context=ros_context, parameter_overrides=[
            Parameter('slider_roi', value=[1, 2, 3])])


def test_tracker_listens_to_images_only_once_its_positions_have_subscribers(ros_context):
    parameters, _ = _tracker_parameters(bench.get_scenario('paper'))
    tracker = CameraTracker(context=ros_context, parameter_overrides=parameters + [
        Parameter('wait_for_subscribers', value=1)])
    harness = Harness(ros_context, tracker)
    try:
        images = harness.probe.create_publisher(Image, 'camera/image_raw', DATA_QOS)

        def listening():
            return any(s.topic_name == '/camera/image_raw' for s in tracker.subscriptions)
        for _ in range(20):  # its timer checks every 10 ms; nobody takes its positions yet
            harness.executor.spin_once(timeout_sec=0.05)
        assert not listening()
        positions = []
        harness.probe.create_subscription(TrackedPositions, 'tracking/positions',
                                          positions.append, DATA_QOS)
        harness.spin_until(listening, message='the tracker to subscribe to images')
        harness.wait_for_subscribers(images)
        frame = np.zeros((480, 720), dtype=np.uint8)
        images.publish(conversions.image_message(frame, 1.0))
        harness.spin_until(lambda: len(positions) == 1, message='the first position')
        assert positions[0].header.stamp.sec == 1
    finally:
        harness.close()
