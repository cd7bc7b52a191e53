"""camera_source: frames of a camera device, a video file or an image folder -> camera/image_raw.

For labs without a ROS camera driver (v4l2_camera, usb_cam): an OpenCV capture device
(``device`` = /dev/videoN or an index N), or a recorded video or an image sequence (a folder,
sorted by name) opened through io.video.FrameSource. Each sensor_msgs/Image carries the
source's pixels as they come: mono8, mono16 (16-bit PNG/TIFF sequences), or bgr8 (colour
devices; FrameSource gives gray for files). header.stamp is the frame's mid-exposure time:
for files k / fps + exposure / 2 from zero (so a file gives the same stamps every run, as a
recorded experiment); for a device the node's clock when the frame arrived minus half the
exposure (a frame arrives when its exposure ends). Published reliable (common.IMAGE_QOS), so
camera_tracker's best-effort subscription and a reliable recorder both get the frames.
"""

import os
import stat
import sys
import threading

import cv2
import numpy as np
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from sensor_msgs.msg import Image

from microball_ros.core.errors import InputError
from microball_ros.io import conversions
from microball_ros.io.video import FrameSource
from microball_ros.nodes.common import (
    IMAGE_QOS,
    NodeDiagnostics,
    Param,
    create_publisher,
    declare_parameters,
    run,
)

PARAMS = {
    'device': Param('', 'camera device (/dev/videoN or an index N), video file, or folder of '
                        'images (sorted by name)', read_only=True),
    'fps': Param(0.0, "frame rate, Hz; 0 takes the video's or the device's (required for an "
                      'image folder); asked of a device', 0.0, 10000.0, read_only=True),
    'exposure': Param(0.0, 'exposure time, s, for the mid-exposure stamps (0: half the frame '
                           'period); asked of a device (V4L2: manual exposure)', 0.0, 10.0,
                      read_only=True),
    'frame_id': Param('camera', 'frame_id of the images', read_only=True),
    'loop': Param(False, 'start a file again at its end (stamps keep increasing)',
                  read_only=True),
    'wait_for_subscribers': Param(0, 'hold the first frame until the images have this many '
                                     'matched subscribers; 0 starts at once', 0, 100,
                                  read_only=True),
}

ENCODINGS = {(np.dtype(np.uint8), 1): 'mono8', (np.dtype(np.uint16), 1): 'mono16',
             (np.dtype(np.uint8), 3): 'bgr8'}


def check_parameters(values):
    """Return None if the parameter values are consistent, else a one-line reason."""
    if not values['device']:
        return 'device is required (/dev/videoN, an index N, a video file or an image folder)'
    if values['fps'] and values['exposure'] > 1.0 / values['fps']:
        return (f"exposure {values['exposure']:g} s exceeds the frame period "
                f"{1.0 / values['fps']:g} s")
    return None


def is_device(device):
    """Return True if ``device`` names a capture device (an index or a character device)."""
    if device.isdigit():
        return True
    try:
        return stat.S_ISCHR(os.stat(device).st_mode)
    except OSError:
        return device.startswith('/dev/video')


def frame_message(frame, stamp, frame_id):
    """Return a frame (H x W uint8 / uint16, or H x W x 3 uint8 BGR) as a sensor_msgs/Image."""
    frame = np.ascontiguousarray(frame)
    channels = 1 if frame.ndim == 2 else frame.shape[2]
    encoding = ENCODINGS.get((frame.dtype, channels))
    if encoding is None:
        raise InputError(f'frames of {frame.dtype} with {channels} channels have no supported '
                         f'encoding ({", ".join(ENCODINGS.values())})')
    msg = Image()
    msg.header.stamp = conversions.nanoseconds_to_stamp(stamp) if isinstance(stamp, int) \
        else conversions.seconds_to_stamp(stamp)
    msg.header.frame_id = frame_id
    msg.height, msg.width = frame.shape[:2]
    msg.encoding = encoding
    msg.is_bigendian = int(sys.byteorder == 'big')
    msg.step = frame.strides[0]
    msg.data = frame.tobytes()
    return msg


def file_stamp(index, fps, exposure):
    """Return the mid-exposure time (ns) of frame ``index`` of a file: k / fps + exposure / 2."""
    return int(round((index / fps + exposure / 2.0) * 1e9))


def open_device(device, fps, exposure):
    """Open an OpenCV capture device; ask for fps and a manual exposure; return the capture."""
    capture = cv2.VideoCapture(int(device) if device.isdigit() else device)
    if not capture.isOpened():
        raise InputError(f'{device}: cannot open the camera device')
    if fps:
        capture.set(cv2.CAP_PROP_FPS, fps)
    if exposure:
        capture.set(cv2.CAP_PROP_AUTO_EXPOSURE, 1)           # V4L2: manual
        capture.set(cv2.CAP_PROP_EXPOSURE, exposure / 100e-6)  # V4L2: units of 100 us
    return capture


class CameraSource(Node):
    """Publish the frames of a device, a video file or an image folder."""

    def __init__(self, **kwargs):
        super().__init__('camera_source', **kwargs)
        self._values = declare_parameters(self, PARAMS, check_parameters)
        values = self._values
        self.frames_published = 0
        self._publisher = create_publisher(self, Image, 'camera/image_raw', IMAGE_QOS)
        self.diagnostics = NodeDiagnostics(self, hardware_id=values['device'])
        self._stop = threading.Event()
        self._thread = None
        if is_device(values['device']):
            self._open_device(values)
        else:
            self._open_file(values)

    def _open_file(self, values):
        self._source = FrameSource(values['device'])
        fps = values['fps'] or self._source.fps
        if not fps:
            raise InputError(f"{values['device']}: unknown frame rate; set the fps parameter")
        self._fps = fps
        self._exposure = values['exposure'] or 0.5 / fps
        if self._exposure > 1.0 / fps:
            raise InputError(f'exposure {self._exposure:g} s exceeds the frame period '
                             f'{1.0 / fps:g} s')
        self._frames = iter(self._source)
        self._index = 0
        self.get_logger().info(f"{values['device']}: {self._source.kind}, "
                               f'{self._source.frame_size[0]}x{self._source.frame_size[1]} '
                               f'{self._source.dtype}, {fps:g} fps')
        self._timer = self.create_timer(1.0 / fps, self._on_file_frame,
                                        clock=Clock(clock_type=ClockType.STEADY_TIME))

    def _ready(self):
        wanted = self._values['wait_for_subscribers']
        return not wanted or self._publisher.get_subscription_count() >= wanted

    def _on_file_frame(self):
        if self._index == 0 and not self._ready():
            return
        frame = next(self._frames, None)
        if frame is None and self._values['loop'] and self._index:
            self._frames = iter(self._source)
            frame = next(self._frames, None)
        if frame is None:
            self._timer.cancel()
            self.get_logger().info(f'{self._values["device"]}: done after {self._index} frames')
            return
        self._publish(frame, file_stamp(self._index, self._fps, self._exposure))
        self._index += 1

    def _publish(self, frame, stamp):
        self._publisher.publish(frame_message(frame, stamp, self._values['frame_id']))
        self.frames_published += 1
        self.diagnostics.count('frames published')

    def _open_device(self, values):
        self._capture = open_device(values['device'], values['fps'], values['exposure'])
        fps = values['fps'] or self._capture.get(cv2.CAP_PROP_FPS) or 30.0
        self._exposure = values['exposure'] or 0.5 / fps
        self._thread = threading.Thread(target=self._read_device, name='camera', daemon=True)
        self._thread.start()

    def _read_device(self):
        """Read frames as the device delivers them (a blocking read, off the executor)."""
        while not self._stop.is_set():
            ok, frame = self._capture.read()
            arrived = self.get_clock().now().nanoseconds
            if not ok:
                self.diagnostics.error(f"{self._values['device']}: no frame from the device")
                self._stop.wait(0.5)
                continue
            if self._ready():
                self._publish(frame, arrived - int(round(self._exposure / 2 * 1e9)))

    def destroy_node(self):
        """Stop reading the device, release it, then destroy the node."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(5.0)
            self._capture.release()
        super().destroy_node()


def main(args=None):
    """Run the node (console script camera_source)."""
    return run(CameraSource, args)


if __name__ == '__main__':
    sys.exit(main())
