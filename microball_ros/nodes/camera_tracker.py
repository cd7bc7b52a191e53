"""camera_tracker: camera frames (or a video file) -> /tracking/positions.

Subscribes to sensor_msgs/Image on /camera/image_raw (from bench_simulator or any camera
driver such as v4l2_camera or usb_cam), or reads ``video_path``, and tracks the slider and
stator marks in their regions of interest with core.tracking (sub-pixel, blur-robust). Each
TrackedPositions keeps the image's stamp (plus ``stamp_offset``, for drivers that stamp the
start of the exposure); a lost mark is published as invalid (NaN), never invented. With
``publish_debug_image`` the frame is republished with the ROIs and tracked marks drawn.

Images come from real drivers as they are: the subscription is best effort with a queue of 5
(it connects to sensor-data and reliable publishers alike; the qos_overrides parameters make
it reliable, as lock-step replay does), in any encoding io.video reads (mono8/16, bgr8, rgb8,
bayer_*). A frame of another size than the first, an unknown encoding, data shorter than
height x step, a stamp going backwards or a frame from a second camera is dropped, logged once
per kind and counted on /diagnostics; the node keeps tracking the good frames after it.
"""

import sys

from microball_msgs.msg import TrackedPositions
import numpy as np
from rclpy.node import Node
from sensor_msgs.msg import Image

from microball_ros.core.errors import InputError
from microball_ros.core.tracking import (
    Tracker,
    TrackerConfig,
    check_distinct_rois,
    check_roi,
    check_scale,
    draw_tracking,
)
from microball_ros.io import conversions
from microball_ros.io.video import IMAGE_ENCODINGS, FrameSource
from microball_ros.nodes.common import (
    DATA_QOS,
    InputGuard,
    NodeDiagnostics,
    Param,
    create_publisher,
    declare_parameters,
    image_subscription_qos,
    run,
)

PARAMS = {
    'slider_roi': Param([0, 0, 0, 0], 'slider mark region x, y, w, h, px (over its whole '
                                      'travel)', read_only=True),
    'stator_roi': Param([0, 0, 0, 0], 'stator mark region x, y, w, h, px', read_only=True),
    'meters_per_pixel': Param(5e-6, 'image scale along the bearing axis, m/px', 1e-9, 1.0,
                              read_only=True),
    'stamp_offset': Param(0.0, 'added to each image stamp to get mid-exposure time, s',
                          -1.0, 1.0),
    'video_path': Param('', 'track this video file (or image folder) instead of the topic',
                        read_only=True),
    'video_fps': Param(0.0, "frame rate of video_path; 0 takes the file's", 0.0, 10000.0,
                       read_only=True),
    'video_exposure': Param(0.0, 'exposure of video_path frames, s; 0 assumes half the frame '
                                 'period', 0.0, 1.0, read_only=True),
    'video_speed': Param(1.0, 'video playback speed factor', 0.01, 1000.0, read_only=True),
    'polarity': Param('auto', "marks darker or brighter than their plate: 'auto' (learned), "
                              "'dark' or 'bright'", read_only=True),
    'publish_debug_image': Param(False, 'publish tracking/debug_image with the marks drawn'),
    'frame_id': Param('camera', 'frame_id for positions from video_path', read_only=True),
    'wait_for_subscribers': Param(0, 'subscribe to the images only once tracking/positions has '
                                     'this many matched subscribers (so none misses the first '
                                     'positions); 0 subscribes at once', 0, 100,
                                  read_only=True),
    'expected_publishers': Param(1, 'cameras expected on camera/image_raw; frames from more '
                                    'are dropped as foreign (0: accept any)', 0, 100,
                                 read_only=True),
}


# The qos_overrides parameters that make the image subscription reliable, with a queue deep
# enough for lock-step replay and for a run whose tracker falls seconds behind (experiment,
# reprocess): every frame is then tracked, none dropped by the transport.
RELIABLE_IMAGES = {'reliability': 'reliable', 'depth': 300}


def reliable_images(role):
    """Return the qos_overrides value making /camera/image_raw's ``role`` RELIABLE_IMAGES.

    ``role`` is 'publisher' or 'subscription'.
    """
    return {'/camera/image_raw': {role: dict(RELIABLE_IMAGES)}}


def check_parameters(values):
    """Return None if the parameter values are consistent, else a one-line reason."""
    try:
        check_distinct_rois({'slider': check_roi(values['slider_roi'], name='slider'),
                             'stator': check_roi(values['stator_roi'], name='stator')})
        check_scale(values['meters_per_pixel'])
        TrackerConfig(polarity=values['polarity'])
    except ValueError as error:
        return str(error)
    return None


def image_problem(msg, first_size):
    """Return (kind, detail) if an Image cannot be tracked with the others, else None."""
    if msg.encoding not in IMAGE_ENCODINGS:
        return 'unknown encoding', f'{msg.encoding!r}'
    if first_size is not None and (msg.width, msg.height) != first_size:
        return ('image of another size',
                f'{msg.width}x{msg.height}, the first was {first_size[0]}x{first_size[1]}')
    channels, size, _ = IMAGE_ENCODINGS[msg.encoding]
    if msg.step < msg.width * channels * size or len(msg.data) < msg.height * msg.step:
        return ('image data too short',
                f'{len(msg.data)} bytes for {msg.height} rows of step {msg.step}')
    return None


def debug_image(frame, rois, positions_px, labels=None):
    """Return a BGR copy of frame with the ROIs and tracked marks drawn (core draw_tracking)."""
    return draw_tracking(frame, rois, positions_px, labels=labels)


class CameraTracker(Node):
    """Track the two marks in every frame and publish their positions."""

    def __init__(self, **kwargs):
        super().__init__('camera_tracker', **kwargs)
        self._values = declare_parameters(self, PARAMS, check_parameters)
        self.add_post_set_parameters_callback(
            lambda ps: self._values.update({p.name: p.value for p in ps if p.name in PARAMS}))
        values = self._values
        self._rois = {'slider': tuple(values['slider_roi']),
                      'stator': tuple(values['stator_roi'])}
        self._tracker = None
        self._frame_size = None
        self._frames = 0
        self.diagnostics = NodeDiagnostics(self)
        self._publisher = create_publisher(self, TrackedPositions, 'tracking/positions',
                                           DATA_QOS)
        self._debug = self.create_publisher(Image, 'tracking/debug_image', 10)
        if values['video_path']:
            self._open_video(values)
        elif values['wait_for_subscribers']:
            self._waiting = self.create_timer(0.01, self._subscribe_when_matched)
        else:
            self._subscribe()

    @property
    def frames_dropped(self):
        """Return how many frames were dropped (any kind; /diagnostics has them by kind)."""
        return sum(self.diagnostics.drops.values())

    def _subscribe(self):
        guard = InputGuard(self, self.diagnostics, 'camera/image_raw',
                           expected=self._values['expected_publishers'],
                           check=lambda msg: image_problem(msg, self._frame_size))
        guard.subscribe(Image, self._on_image, image_subscription_qos())

    def _subscribe_when_matched(self):
        if self._publisher.get_subscription_count() >= self._values['wait_for_subscribers']:
            self._waiting.cancel()
            self._subscribe()

    @property
    def frames_tracked(self):
        """Return how many frames were tracked."""
        return self._frames

    def _open_video(self, values):
        self._video = FrameSource(values['video_path'])
        fps = values['video_fps'] or self._video.fps
        if not fps:
            raise InputError(f"{values['video_path']}: unknown frame rate; set video_fps")
        self._tracker = Tracker(self._rois, values['meters_per_pixel'], fps,
                                values['video_exposure'] or None,
                                config=TrackerConfig(polarity=values['polarity']),
                                frame_size=self._video.frame_size)
        self._video_frames = iter(self._video)
        self._video_timer = self.create_timer(1.0 / (fps * values['video_speed']),
                                              self._on_video_frame)

    def _on_video_frame(self):
        frame = next(self._video_frames, None)
        if frame is None:
            self._video_timer.cancel()
            self.get_logger().info(f'video finished after {self._frames} frames')
            return
        result = self._tracker.process(frame)
        self._publish(result, frame, conversions.seconds_to_stamp(result.time),
                      self._values['frame_id'])

    def _on_image(self, msg):
        try:
            frame = conversions.image_array(msg)
            if self._tracker is None:
                self._tracker = Tracker(self._rois, self._values['meters_per_pixel'],
                                        config=TrackerConfig(polarity=self._values['polarity']),
                                        frame_size=(msg.width, msg.height))
                self._frame_size = (msg.width, msg.height)
        except InputError as error:  # e.g. ROIs outside the first frame: every frame fails
            self.diagnostics.dropped('untrackable frame', str(error))
            return
        stamp = conversions.stamp_to_seconds(msg.header.stamp) + self._values['stamp_offset']
        try:
            result = self._tracker.process(frame, stamp)
        except Exception as error:  # noqa: B902 - one bad frame must not stop a lab's run
            self.diagnostics.error(f'frame at {stamp:.6f} s not tracked: {error!r}')
            return
        self._publish(result, frame, conversions.seconds_to_stamp(stamp), msg.header.frame_id)

    def _publish(self, result, frame, stamp, frame_id):
        slider, stator = result.marks['slider'], result.marks['stator']
        scale = result.meters_per_pixel
        msg = conversions.tracked_positions(
            stamp, result.index, result.position('slider'), result.position('stator'),
            slider.quality, stator.quality, frame_id,
            slider_sigma=slider.sigma_px * scale, stator_sigma=stator.sigma_px * scale)
        self._publisher.publish(msg)
        self._frames += 1
        lost = (not msg.slider_valid) + (not msg.stator_valid)
        if lost:
            self.diagnostics.count('lost marks', lost)
        if self._values['publish_debug_image']:
            labels = {name: mark.polarity or ''
                      for name, mark in self._tracker.marks.items()}
            drawn = debug_image(np.asarray(frame), self._rois,
                                {name: m.position_px for name, m in result.marks.items()},
                                labels)
            self._debug.publish(conversions.image_message(drawn, stamp, frame_id))


def main(args=None):
    """Run the node (console script camera_tracker)."""
    return run(CameraTracker, args)


if __name__ == '__main__':
    sys.exit(main())
