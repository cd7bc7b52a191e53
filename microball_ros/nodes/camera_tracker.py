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

Priming, as ``microball track`` does (core.tracking.track): the node keeps the first
``prime_frames`` good frames (60 by default), learns the marks from them (the mark, a static
background, and on a plate whose texture moves with the mark the learned plate:
Tracker.prime), then tracks and publishes every kept frame in order, each with its own stamp,
frame_id and debug image, and then each new frame as it comes. Its positions for a sequence of
frames are therefore those ``track(frames, rois, meters_per_pixel, 30.0, times=stamps)``
returns, value for value (topic mode assumes an exposure of half the frame period, as that
call does without ``exposure``). The price: positions are published late by up to
``prime_frames`` frames, once: a camera at 30 fps gets nothing for the first 2 s, then those
2 s of positions together. /diagnostics says 'priming: n/60 frames' meanwhile, and then each
mark's ``centre_sigma_px`` (how well its centre on a textured plate is known: one error in
every frame, in the published sigmas too; core.tracking.plate_rows). A video
(``video_path``) shorter than ``prime_frames`` is primed on all its frames at its end. The
kept frames are held in memory (60 frames of 720 x 480 mono8: 21 MB); ``prime_frames`` 0
publishes each frame at once, unprimed (as before priming existed).

Only one thing here depends on timing: if the images pause before ``prime_frames`` frames
have come (no frame for ``prime_timeout`` s of wall-clock time: a short stream, a camera
stopped), the node primes on the frames it has, publishes them, warns once in the log and on
/diagnostics ('primed on N of M frames: the images paused') and then streams; otherwise a
stream that stops early would keep its frames forever. Every other output is a function of
the ordered frames and the parameters.
"""

import math
import sys

from diagnostic_msgs.msg import DiagnosticStatus, KeyValue
from microball_msgs.msg import TrackedPositions
import numpy as np
from rclpy.clock import Clock, ClockType
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
    'black_level': Param(0.0, "the camera's dark offset, DN (a pixel that gets no light): a "
                              'shadow passing over a mark is divided out above it (0: '
                              'estimated from the shadow)', 0.0, 1.0e6,
                         read_only=True),
    'gamma': Param(0.0, "the camera's encoding gamma: frames are decoded to linear light "
                        'first (1: a linear camera, as machine-vision cameras are; about 2.2 '
                        'for sRGB video; 0: found from the priming frames, else 1)', 0.0, 5.0,
                   read_only=True),
    'publish_debug_image': Param(False, 'publish tracking/debug_image with the marks drawn'),
    'frame_id': Param('camera', 'frame_id for positions from video_path', read_only=True),
    'wait_for_subscribers': Param(0, 'subscribe to the images only once tracking/positions has '
                                     'this many matched subscribers (so none misses the first '
                                     'positions); 0 subscribes at once', 0, 100,
                                  read_only=True),
    'expected_publishers': Param(1, 'cameras expected on camera/image_raw; frames from more '
                                    'are dropped as foreign (0: accept any)', 0, 100,
                                 read_only=True),
    'prime_frames': Param(TrackerConfig().prime_frames,
                          'learn the marks from this many first frames, then track them and '
                          'every later frame (as microball track does; their positions come '
                          'that many frames late); 0 publishes each frame at once, unprimed',
                          0, 100000, read_only=True),
    'prime_timeout': Param(1.0, 'wall-clock seconds without a frame after which the node '
                                'primes on the frames it has (images paused before '
                                'prime_frames)', 0.01, 3600.0, read_only=True),
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
        TrackerConfig(polarity=values['polarity'], black_level=values['black_level'],
                      gamma=values['gamma'])
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


class TrackerDiagnostics(NodeDiagnostics):
    """NodeDiagnostics plus the priming state: 'priming: n/M frames', then how it ended.

    Once primed, 'centre_sigma_px' too: each mark's centre_sigma_px ('slider 0.0500, ...'),
    and once a passing shadow was divided out of a frame (core.tracking.shade),
    'shaded_frames': how many frames per mark ('slider 41, stator 0'), and once the shadows
    told the camera's black level (not given), 'black_level_dn' ('6.1 +- 0.3'); once primed,
    'gamma': the gamma the frames are decoded with ('1.00 (found)', '2.20').

    While the node learns, the status message says so; a priming cut short by a pause of the
    images is a warning for one period (the 'priming' value keeps saying it).
    """

    def __init__(self, node, **kwargs):
        self.priming = ''
        self.centres = ''  # once primed: each mark's centre_sigma_px
        self.shaded = ''  # the frames per mark a passing shadow was divided out of, if any
        self.black = ''  # the camera's black level estimated from the shadows, if any
        self.gamma = ''  # once primed: the gamma the frames are decoded with
        self._warning = ''
        super().__init__(node, **kwargs)

    def warn(self, text):
        """Log ``text`` and publish it as a warning in the next period's status."""
        self._node.get_logger().warning(text)
        self._warning = text

    def status(self):
        """Return NodeDiagnostics' status with the priming state added."""
        status = super().status()
        if self.priming:
            status.values.append(KeyValue(key='priming', value=self.priming))
            if self.priming.startswith('priming') and status.message == 'ok':
                status.message = f'learning the marks: {self.priming}'
        if self.centres:
            status.values.append(KeyValue(key='centre_sigma_px', value=self.centres))
        if self.shaded:
            status.values.append(KeyValue(key='shaded_frames', value=self.shaded))
        if self.black:
            status.values.append(KeyValue(key='black_level_dn', value=self.black))
        if self.gamma:
            status.values.append(KeyValue(key='gamma', value=self.gamma))
        if self._warning:
            status.level = max(status.level, DiagnosticStatus.WARN)
            status.message = (self._warning if status.message == 'ok'
                              else f'{self._warning}; {status.message}')
            self._warning = ''
        return status


class CameraTracker(Node):
    """Track the two marks in every frame and publish their positions (primed first)."""

    def __init__(self, **kwargs):
        super().__init__('camera_tracker', **kwargs)
        self._values = declare_parameters(self, PARAMS, check_parameters)
        self.add_post_set_parameters_callback(
            lambda ps: self._values.update({p.name: p.value for p in ps if p.name in PARAMS}))
        values = self._values
        self._rois = {'slider': tuple(values['slider_roi']),
                      'stator': tuple(values['stator_roi'])}
        self._config = TrackerConfig(polarity=values['polarity'],
                                     prime_frames=values['prime_frames'],
                                     black_level=values['black_level'],
                                     gamma=values['gamma'])
        self._tracker = None
        self._frame_size = None
        self._frames = 0
        # Frames kept until the tracker is primed: (frame, stamp s or None, frame_id).
        self._held = []
        self._primed = values['prime_frames'] == 0
        self.diagnostics = TrackerDiagnostics(self)
        self._publisher = self.diagnostics.watch_output(create_publisher(
            self, TrackedPositions, 'tracking/positions', DATA_QOS))
        self._debug = self.create_publisher(Image, 'tracking/debug_image', 10)
        if not self._primed:
            self.diagnostics.priming = f'priming: 0/{values["prime_frames"]} frames'
        if values['video_path']:
            self._open_video(values)
            return
        if not self._primed:
            # The one wall-clock dependence: images that pause before prime_frames.
            self._pause_timer = self.create_timer(
                values['prime_timeout'], self._on_pause, clock=Clock(
                    clock_type=ClockType.STEADY_TIME), autostart=False)
        if values['wait_for_subscribers']:
            self._waiting = self.create_timer(0.01, self._subscribe_when_matched)
        else:
            self._subscribe()

    @property
    def frames_dropped(self):
        """Return how many frames were dropped (any kind; /diagnostics has them by kind)."""
        return sum(self.diagnostics.drops.values())

    @property
    def frames_held(self):
        """Return how many frames wait for the tracker to be primed."""
        return len(self._held)

    @property
    def primed(self):
        """Return True once the tracker has learned the marks (always with prime_frames 0)."""
        return self._primed

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
                                values['video_exposure'] or None, config=self._config,
                                frame_size=self._video.frame_size)
        self._video_frames = iter(self._video)
        self._video_timer = self.create_timer(1.0 / (fps * values['video_speed']),
                                              self._on_video_frame)

    def _on_video_frame(self):
        frame = next(self._video_frames, None)
        if frame is None:
            self._video_timer.cancel()
            if not self._primed:  # a video shorter than prime_frames: prime on all of it
                self._prime()
            self.get_logger().info(f'video finished after {self._frames} frames')
            return
        self._take(frame, None, self._values['frame_id'])

    def _on_image(self, msg):
        try:
            frame = conversions.image_array(msg)
            if self._tracker is None:
                self._tracker = Tracker(self._rois, self._values['meters_per_pixel'],
                                        config=self._config,
                                        frame_size=(msg.width, msg.height))
                self._frame_size = (msg.width, msg.height)
        except InputError as error:  # e.g. ROIs outside the first frame: every frame fails
            self.diagnostics.dropped('untrackable frame', str(error))
            return
        stamp = conversions.stamp_to_seconds(msg.header.stamp) + self._values['stamp_offset']
        if not self._primed:
            self._pause_timer.reset()
        self._take(frame, stamp, msg.header.frame_id)

    def _take(self, frame, stamp, frame_id):
        """Track and publish a frame, or hold it until prime_frames frames are held."""
        if self._primed:
            self._track(frame, stamp, frame_id)
            return
        self._held.append((frame, stamp, frame_id))
        wanted = self._values['prime_frames']
        self.diagnostics.priming = f'priming: {len(self._held)}/{wanted} frames'
        if len(self._held) >= wanted:
            self._prime()

    def _on_pause(self):
        """No image for prime_timeout s: prime on the held frames rather than keep them."""
        self._pause_timer.cancel()
        if self._primed or not self._held:
            return
        wanted = self._values['prime_frames']
        self.diagnostics.warn(f'primed on {len(self._held)} of {wanted} frames: the images '
                              f'paused (no frame for {self._values["prime_timeout"]:g} s)')
        self._prime()

    def _prime(self):
        """Learn the marks from the held frames, then track and publish each of them."""
        held, self._held = self._held, []
        self._primed = True
        if not self._values['video_path']:
            self._pause_timer.cancel()
        wanted = self._values['prime_frames']
        try:
            self._tracker.prime([frame for frame, _, _ in held])
        except Exception as error:  # noqa: B902 - track unprimed rather than stop a lab's run
            self.diagnostics.error(f'priming on {len(held)} frames failed, tracking without '
                                   f'it: {error!r}')
        self.diagnostics.priming = (f'primed on {len(held)} frames' if len(held) >= wanted
                                    else f'primed on {len(held)} of {wanted} frames')
        # How well each mark's centre is known: one error in every frame (in the sigmas too)
        self.diagnostics.centres = ', '.join(f'{name} {mark.centre_sigma_px:.4f}'
                                             for name, mark in self._tracker.marks.items())
        # The gamma the frames are decoded with, and whether priming found it (gamma 0)
        found = ' (found)' if math.isfinite(self._tracker.gamma_found) else ''
        self.diagnostics.gamma = f'{self._tracker.decoder.gamma:.2f}{found}'
        for frame, stamp, frame_id in held:
            self._track(frame, stamp, frame_id)

    def _track(self, frame, stamp, frame_id):
        """Track one frame and publish its positions (a frame that fails is counted)."""
        try:
            result = self._tracker.process(frame, stamp)
        except Exception as error:  # noqa: B902 - one bad frame must not stop a lab's run
            when = f'{stamp:.6f} s' if stamp is not None else f'index {self._tracker.index}'
            self.diagnostics.error(f'frame at {when} not tracked: {error!r}')
            return
        if any(self._tracker.shaded.values()):
            self.diagnostics.shaded = ', '.join(f'{name} {count}'
                                                for name, count in self._tracker.shaded.items())
        black = self._tracker.black
        if black.value is not None:
            self.diagnostics.black = f'{black.value:.1f} +- {black.sigma:.1f}'
        self._publish(result, frame, conversions.seconds_to_stamp(result.time), frame_id)

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
