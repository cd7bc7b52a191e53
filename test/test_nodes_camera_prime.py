"""camera_tracker primes like ``microball track``: its positions are track()'s, value for value.

The node keeps the first prime_frames frames, learns the marks from them (Tracker.prime), then
tracks and publishes them and streams. Frames are rendered here (tracking_scenes): a textured
plate under a static texture, where priming changes the positions by more than a pixel, and a
plain plate. Frames go to the node one at a time, each waited for (no sleeps). Only the pause
test depends on wall-clock time (the node's prime_timeout), as the node's docstring says.
"""

import math

import cv2
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from microball_msgs.msg import TrackedPositions
import numpy as np
import pytest
from rclpy.parameter import Parameter
from sensor_msgs.msg import Image
from tracking_scenes import PlateSpec, SceneSpec, plates, render

from microball_ros.app.experiment import flatten_parameters
from microball_ros.core.tracking import Tracker, TrackerConfig, track
from microball_ros.io import conversions
from microball_ros.nodes import camera_tracker as camera_tracker_module
from microball_ros.nodes.camera_tracker import CameraTracker, reliable_images
from microball_ros.nodes.common import DATA_QOS
from microball_ros.testing import Harness

pytestmark = pytest.mark.ros

SCALE = 5e-6
STAMP_OFFSET = 0.002


@pytest.fixture(scope='module')
def textured():
    """Render a plate whose texture moves with the mark, under a static texture."""
    return render(SceneSpec(plates=plates(texture=30.0), static_texture=20.0), 72, seed=5)


@pytest.fixture(scope='module')
def plain():
    """Render the plain plates of the default scene."""
    return render(SceneSpec(), 30, seed=2)


def _node(context, scene, **values):
    parameters = {'slider_roi': list(scene.rois['slider']),
                  'stator_roi': list(scene.rois['stator']), 'meters_per_pixel': SCALE,
                  # Frames are sent one at a time: a reliable subscription loses none.
                  **flatten_parameters({'qos_overrides': reliable_images('subscription')}),
                  **values}
    return CameraTracker(context=context, parameter_overrides=[
        Parameter(name, value=value) for name, value in parameters.items()])


class Camera:
    """The test's camera: publishes frames one at a time, each received before the next."""

    def __init__(self, harness, tracker):
        self.harness, self.tracker = harness, tracker
        self.publisher = harness.probe.create_publisher(Image, 'camera/image_raw', DATA_QOS)
        self.positions = harness.collect(TrackedPositions, 'tracking/positions')
        self.debug = harness.collect(Image, 'tracking/debug_image', 100)
        self.statuses = []
        harness.probe.create_subscription(
            DiagnosticArray, '/diagnostics',
            lambda m: self.statuses.extend(s for s in m.status
                                           if s.name.endswith('camera_tracker')), 10)
        harness.wait_for_subscribers(self.publisher)

    def send(self, frame, stamp, frame_id='camera'):
        """Publish one frame; return once the node has taken it (held, tracked or dropped)."""
        before = self.tracker.diagnostics.received_total + self.tracker.frames_dropped
        self.publisher.publish(conversions.image_message(frame, stamp, frame_id))
        self.harness.spin_until(
            lambda: self.tracker.diagnostics.received_total + self.tracker.frames_dropped
            > before, 30.0, f'the frame at {stamp:.4f} s to arrive')

    def wait_for_positions(self, count, timeout=60.0):
        """Spin until ``count`` positions have arrived."""
        self.harness.spin_until(lambda: len(self.positions) >= count, timeout,
                                f'{count} positions')

    def wait_for_status(self, predicate, what):
        """Spin until a /diagnostics status of the node satisfies predicate; return it."""
        self.harness.spin_until(lambda: any(predicate(s) for s in self.statuses), 30.0, what)
        return next(s for s in self.statuses if predicate(s))


def _values(status):
    return {kv.key: kv.value for kv in status.values}


def _stamps(n, start=1.0):
    """Frame stamps as sent, as the node reads them back (ns), plus stamp_offset."""
    sent = [start + k / 30 for k in range(n)]
    return sent, [conversions.stamp_to_seconds(conversions.seconds_to_stamp(t)) + STAMP_OFFSET
                  for t in sent]


def _assert_published_equals(positions, expected, times):
    """Assert the messages carry exactly the numbers of ``expected`` (TrackResult or list)."""
    assert len(positions) == len(times)
    for k, msg in enumerate(positions):
        assert msg.header.stamp == conversions.seconds_to_stamp(times[k])
        assert msg.frame_index == k
    for name in ('slider', 'stator'):
        if isinstance(expected, list):
            position = np.array([r.position(name) for r in expected])
            quality = np.array([r.marks[name].quality for r in expected])
            sigma = np.array([r.marks[name].sigma_px for r in expected]) * SCALE
        else:
            position = expected.position[name]
            quality = expected.quality[name]
            sigma = expected.sigma_px[name] * expected.meters_per_pixel
        published = np.array([getattr(m, f'{name}_position') for m in positions])
        np.testing.assert_array_equal(published, position, err_msg=name)
        np.testing.assert_array_equal(
            np.array([getattr(m, f'{name}_quality') for m in positions], np.float32),
            quality.astype(np.float32), err_msg=name)
        valid = np.isfinite(position)
        np.testing.assert_array_equal([getattr(m, f'{name}_valid') for m in positions], valid)
        np.testing.assert_array_equal(
            np.array([getattr(m, f'{name}_sigma') for m in positions])[valid], sigma[valid],
            err_msg=name)


def test_a_shadow_is_divided_out_as_track_does_and_counted(ros_context):
    """A shadow sweeping over both marks: the node publishes what track gives.

    Value for value (the shaded frames' sigmas widened), and /diagnostics counts the shaded
    frames and says the camera's black level (8 DN, not given) the shadow told.
    """
    from dataclasses import replace

    mark = PlateSpec(band=(30.0, 150.0), width=16.0, height=30.0, contrast=-120.0,
                     level=150.0, amplitude=90.0, frequency=0.9, origin=240.0)
    spec = SceneSpec(plates={'slider': mark, 'stator': replace(mark, band=(200.0, 320.0),
                                                                phase=1.0)},
                     width=480, height=350, fps=30.0, exposure=0.02, black=8.0,
                     shadow=(60, 100, 60.0, 420.0, 40.0, 8.0, 0.45, 20.0))
    scene = replace(render(spec, 100, seed=9), rois={'slider': (100, 55, 280, 70),
                                                     'stator': (100, 225, 280, 70)})
    n = len(scene.frames)
    sent, times = _stamps(n)
    expected = track(scene.frames, scene.rois, SCALE, 30.0, times=times)
    assert all(20 <= count <= 45 for count in expected.shaded.values()), expected.shaded
    black, sigma = expected.black_level
    assert abs(black - 8.0) < max(3.0 * sigma, 1.0), expected.black_level
    tracker = _node(ros_context, scene, stamp_offset=STAMP_OFFSET, prime_timeout=600.0)
    harness = Harness(ros_context, tracker)
    try:
        camera = Camera(harness, tracker)
        for k in range(n):
            camera.send(scene.frames[k], sent[k])
            if k >= 59:  # primed on the first 60, then each frame's position at once
                camera.wait_for_positions(k + 1)
        _assert_published_equals(camera.positions, expected, times)
        # /diagnostics is periodic: one after the last frame has the final counts
        counted = ', '.join(f'{name} {expected.shaded[name]}' for name in ('slider', 'stator'))
        camera.wait_for_status(lambda s: _values(s).get('shaded_frames') == counted, counted)
        said = f'{black:.1f} +- {sigma:.1f}'
        camera.wait_for_status(lambda s: _values(s).get('black_level_dn') == said, said)
    finally:
        harness.close()


def test_textured_plate_positions_equal_track_value_for_value(ros_context, textured):
    scene = textured
    n = len(scene.frames)
    sent, times = _stamps(n)
    expected = track(scene.frames, scene.rois, SCALE, 30.0, times=times)
    # The scene makes priming matter: primed, every mark within 0.4 px of the truth; the same
    # tracker unprimed is off by more than a pixel (so a node that skips priming fails).
    unprimed = Tracker(scene.rois, SCALE, frame_size=(scene.spec.width, scene.spec.height))
    unprimed = [unprimed.process(frame, t) for frame, t in zip(scene.frames, times, strict=True)]
    for name in ('slider', 'stator'):
        assert np.max(np.abs(expected.position_px[name] - scene.truth[name])) < 0.4, name
    assert max(np.nanmax(np.abs(np.array([r.marks[name].position_px for r in unprimed])
                                - scene.truth[name])) for name in ('slider', 'stator')) > 1.0

    tracker = _node(ros_context, scene, stamp_offset=STAMP_OFFSET, publish_debug_image=True,
                    prime_timeout=600.0)  # no pause here: no dependence on timing
    harness = Harness(ros_context, tracker)
    try:
        camera = Camera(harness, tracker)
        for k in range(59):
            camera.send(scene.frames[k], sent[k], frame_id=f'cam{k % 3}')
        assert tracker.frames_held == 59 and not tracker.primed
        assert camera.positions == []
        # While learning, /diagnostics says so.
        status = camera.wait_for_status(
            lambda s: _values(s).get('priming') == 'priming: 59/60 frames', 'priming 59/60')
        assert status.message == 'learning the marks: priming: 59/60 frames'
        assert status.level == DiagnosticStatus.OK
        camera.send(scene.frames[59], sent[59], frame_id='cam2')
        camera.wait_for_positions(60)  # the held frames, all at once
        assert tracker.primed and tracker.frames_held == 0
        for k in range(60, n):
            camera.send(scene.frames[k], sent[k], frame_id=f'cam{k % 3}')
            camera.wait_for_positions(k + 1)  # streaming: each frame's position at once
        _assert_published_equals(camera.positions, expected, times)
        assert [m.header.frame_id for m in camera.positions] == [f'cam{k % 3}'
                                                                 for k in range(n)]
        status = camera.wait_for_status(
            lambda s: _values(s).get('priming') == 'primed on 60 frames', 'primed on 60 frames')
        # How well each textured mark's centre is known, as track says (one error in every
        # frame, in the sigmas published)
        centres = dict(part.split() for part in _values(status)['centre_sigma_px'].split(', '))
        for name in ('slider', 'stator'):
            assert float(centres[name]) == pytest.approx(expected.centre_sigma_px[name],
                                                         abs=1e-4)
            assert expected.centre_sigma_px[name] > 0
        # The frames are linear: priming (gamma 0, the default) found so (core.tracking.gamma)
        assert _values(status)['gamma'] == '1.00 (found)' and expected.gamma == 1.0
        harness.spin_until(lambda: len(camera.debug) == n, 30.0, f'{n} debug images')
        assert [d.header for d in camera.debug] == [p.header for p in camera.positions]
        assert tracker.diagnostics.counts['errors'] == 0
    finally:
        harness.close()


def test_plain_plate_positions_equal_track_with_fewer_priming_frames(ros_context, plain):
    scene = plain
    sent, times = _stamps(len(scene.frames), start=5.0)
    expected = track(scene.frames, scene.rois, SCALE, 30.0, times=times,
                     config=TrackerConfig(prime_frames=20))
    for name in ('slider', 'stator'):
        assert np.max(np.abs(expected.position_px[name] - scene.truth[name])) < 0.3, name
    tracker = _node(ros_context, scene, stamp_offset=STAMP_OFFSET, prime_frames=20,
                    prime_timeout=600.0)
    harness = Harness(ros_context, tracker)
    try:
        camera = Camera(harness, tracker)
        for k in range(len(scene.frames)):
            camera.send(scene.frames[k], sent[k])
            if k < 19:
                assert camera.positions == [] and tracker.frames_held == k + 1
        camera.wait_for_positions(len(scene.frames))
        _assert_published_equals(camera.positions, expected, times)
    finally:
        harness.close()


def test_prime_frames_zero_publishes_each_frame_at_once_unprimed(ros_context, plain):
    scene = plain
    sent, times = _stamps(5)
    unprimed = Tracker(scene.rois, SCALE, frame_size=(scene.spec.width, scene.spec.height))
    expected = [unprimed.process(frame, t)
                for frame, t in zip(scene.frames[:5], times, strict=True)]
    tracker = _node(ros_context, scene, stamp_offset=STAMP_OFFSET, prime_frames=0)
    harness = Harness(ros_context, tracker)
    try:
        camera = Camera(harness, tracker)
        for k in range(5):
            camera.send(scene.frames[k], sent[k])
            camera.wait_for_positions(k + 1)
        _assert_published_equals(camera.positions, expected, times)
        assert tracker.primed and tracker.frames_held == 0
    finally:
        harness.close()


@pytest.mark.parametrize('prime_frames', [60, 5])
def test_a_video_shorter_than_prime_frames_primes_on_all_of_it(ros_context, textured, tmp_path,
                                                             prime_frames):
    frames = textured.frames[:12]
    for k, frame in enumerate(frames):
        assert cv2.imwrite(str(tmp_path / f'frame_{k:03d}.png'), frame)
    config = TrackerConfig(prime_frames=prime_frames)
    expected = track(frames, textured.rois, SCALE, 30.0, config=config)
    assert expected.time[0] == pytest.approx(1 / 120)
    tracker = _node(ros_context, textured, video_path=str(tmp_path), video_fps=30.0,
                    video_speed=100.0, prime_frames=prime_frames, frame_id='video')
    harness = Harness(ros_context, tracker)
    try:
        positions = harness.collect(TrackedPositions, 'tracking/positions')
        harness.spin_until(lambda: len(positions) == 12, 60.0, '12 positions')
        # The video timer has stopped: nothing more comes.
        for _ in range(10):
            harness.spin_once(0.01)
        assert len(positions) == 12
        _assert_published_equals(positions, expected, expected.time)
        assert {m.header.frame_id for m in positions} == {'video'}
        held = min(prime_frames, 12)
        ending = (f'primed on {held} frames' if held == prime_frames
                  else f'primed on 12 of {prime_frames} frames')
        assert _values(tracker.diagnostics.status())['priming'] == ending
    finally:
        harness.close()


def test_paused_images_prime_on_what_came_then_stream(ros_context, textured):
    # The one test that depends on time: the node's prime_timeout (1 s, wall clock) must
    # pass after frame 12, and never between two of the first 12 frames (sent back to back,
    # each waited for).
    scene = textured
    sent, times = _stamps(15)
    primed = Tracker(scene.rois, SCALE, frame_size=(scene.spec.width, scene.spec.height))
    primed.prime(scene.frames[:12])
    expected = [primed.process(frame, t)
                for frame, t in zip(scene.frames[:15], times, strict=True)]
    # Priming on the 12 frames there are is what track() does with them, and it matters here.
    head = track(scene.frames[:12], scene.rois, SCALE, 30.0, times=times[:12])
    unprimed = Tracker(scene.rois, SCALE, frame_size=(scene.spec.width, scene.spec.height))
    unprimed = [unprimed.process(frame, t)
                for frame, t in zip(scene.frames[:12], times[:12], strict=True)]
    for name in ('slider', 'stator'):
        np.testing.assert_array_equal([r.position(name) for r in expected[:12]],
                                      head.position[name])
    assert max(abs(a.marks[name].position_px - b.marks[name].position_px)
               for a, b in zip(expected, unprimed, strict=False)
               for name in ('slider', 'stator')) > 1.0
    tracker = _node(ros_context, scene, stamp_offset=STAMP_OFFSET)
    harness = Harness(ros_context, tracker)
    try:
        camera = Camera(harness, tracker)
        for k in range(12):
            camera.send(scene.frames[k], sent[k])
        camera.wait_for_positions(12, timeout=30.0)  # after prime_timeout of silence
        assert tracker.primed and tracker.frames_held == 0
        text = 'primed on 12 of 60 frames: the images paused'
        warning = camera.wait_for_status(lambda s: text in s.message, 'the warning')
        assert warning.level == DiagnosticStatus.WARN
        assert _values(warning)['priming'] == 'primed on 12 of 60 frames'
        for k in range(12, 15):
            camera.send(scene.frames[k], sent[k])
            camera.wait_for_positions(k + 1)
        _assert_published_equals(camera.positions, expected, times)
        # Warned once: the next periods' statuses are OK again.
        seen = len(camera.statuses)
        harness.spin_until(lambda: len(camera.statuses) >= seen + 2, 30.0, '2 more statuses')
        later = camera.statuses[camera.statuses.index(warning) + 1:]
        assert later and all(text not in s.message for s in later)
        assert all(s.level == DiagnosticStatus.OK for s in camera.statuses[seen:])
    finally:
        harness.close()


class _FailingTracker(Tracker):
    """A Tracker whose process() raises for one stamp (a frame the core cannot track)."""

    fail_at = None

    def process(self, frame, time=None):
        """Raise for the stamp ``fail_at``, else track."""
        if time is not None and math.isclose(time, self.fail_at, abs_tol=1e-6):
            raise RuntimeError('cannot track this frame')
        return super().process(frame, time)


def test_dropped_frames_are_not_held_and_a_failing_frame_is_counted(ros_context, plain,
                                                                    monkeypatch):
    scene = plain
    sent, times = _stamps(10)
    monkeypatch.setattr(_FailingTracker, 'fail_at', times[3])
    monkeypatch.setattr(camera_tracker_module, 'Tracker', _FailingTracker)
    tracker = _node(ros_context, scene, stamp_offset=STAMP_OFFSET, prime_frames=8,
                    prime_timeout=600.0)
    harness = Harness(ros_context, tracker)
    try:
        camera = Camera(harness, tracker)
        for k in range(4):
            camera.send(scene.frames[k], sent[k])
        camera.send(scene.frames[4][:200, :300].copy(), sent[4])  # another size: dropped
        assert tracker.frames_dropped == 1 and tracker.frames_held == 4
        for k in range(5, 10):
            camera.send(scene.frames[k], sent[k])
        camera.wait_for_positions(8)
        harness.spin_until(lambda: tracker.frames_tracked == 8, 10.0, '8 tracked')
    finally:
        harness.close()
    good = [k for k in range(10) if k not in (3, 4)]
    # Primed on the 8 frames held (the failing one among them), then each tracked but frame 3.
    reference = Tracker(scene.rois, SCALE, frame_size=(scene.spec.width, scene.spec.height),
                        config=TrackerConfig(prime_frames=8))
    reference.prime([scene.frames[k] for k in range(10) if k != 4][:8])
    expected = [reference.process(scene.frames[k], times[k]) for k in good]
    _assert_published_equals(camera.positions, expected, [times[k] for k in good])
    assert tracker.diagnostics.counts['errors'] == 1
    assert 'not tracked' in tracker.diagnostics.last_error
    assert tracker.diagnostics.drops == {'image of another size': 1}


def test_a_bag_of_frames_is_tracked_offline_as_the_node_tracks_it(textured, tmp_path):
    """``microball analyze`` of a frames-only bag (io.frames) primes like the node and track()."""
    from rclpy.serialization import serialize_message
    import yaml

    from microball_ros.io.bags.reader import open_bag
    from microball_ros.io.bags.schema import qos_profiles_yaml
    from microball_ros.io.bags.writer import BagWriter
    from microball_ros.io.frames import tracked_frames, tracker_parameters

    scene = textured
    sent, times = _stamps(len(scene.frames))
    recorded = {'slider_roi': list(scene.rois['slider']),
                'stator_roi': list(scene.rois['stator']), 'meters_per_pixel': SCALE,
                'stamp_offset': STAMP_OFFSET}
    path = str(tmp_path / 'frames')
    with BagWriter(path, custom_data={
            'microball.camera_tracker': yaml.safe_dump(recorded)}) as writer:
        writer.add_topic('/camera/image_raw', 'sensor_msgs/msg/Image',
                         qos_profiles_yaml([DATA_QOS]))
        for frame, t in zip(scene.frames, sent, strict=True):
            stamp_ns = round(t * 1e9)
            writer.write('/camera/image_raw',
                         serialize_message(conversions.image_message(frame, t)), stamp_ns,
                         stamp_ns)
    bag = open_bag(path)
    parameters = tracker_parameters(bag)
    assert parameters['prime_frames'] == 60 and parameters['polarity'] == 'auto'
    assert parameters['black_level'] == 0.0 and parameters['gamma'] == 0.0
    rows = list(tracked_frames(bag, parameters))
    expected = track(scene.frames, scene.rois, SCALE, 30.0, times=times)
    assert [row[1] for row in rows] == list(range(len(scene.frames)))
    for column, name in ((2, 'stator'), (3, 'slider')):
        assert np.array_equal([row[column] for row in rows], expected.position[name],
                              equal_nan=True), name
    assert np.max(np.abs(expected.position_px['slider'] - scene.truth['slider'])) < 0.4
