"""Frames in and out of files: videos, image folders, and sensor_msgs/Image pixel buffers.

Owns every file the tracker reads and the synthetic camera writes, through OpenCV:
``FrameSource`` / ``iter_frames`` open a video (anything this OpenCV build decodes) or a
folder of images (sorted by name), or wrap arrays, and yield gray 2-D frames;
``track_video`` tracks such a source with core.tracking (the container's frame rate unless
one is given); ``image_to_gray`` turns the fields of a sensor_msgs/Image (mono8/16,
bgr/rgb 8/16, Bayer 8/16) into a gray array; ``write_video``, ``write_image_sequence`` and
``codec_available`` write rendered frames (FFV1 lossless or MJPG lossy, like a DV camera).
Problems a user can cause (a
missing or unreadable file, an unsupported encoding) raise InputError with a one-line message.
"""

from collections.abc import Iterator
import math
import os
import tempfile
from typing import Any

import cv2
import numpy as np

from microball_ros.core.errors import InputError
from microball_ros.core.tracking import TrackResult, to_gray, track

IMAGE_EXTENSIONS = ('.png', '.tif', '.tiff', '.bmp', '.pgm', '.ppm', '.jpg', '.jpeg')
# FourCCs of lossy codecs (JPEG, MPEG-1/2/4, H.263/264/265, VP8/9, AV1, WMV, ...), lower case
LOSSY_CODECS = frozenset((
    'mjpg', 'mjpa', 'jpeg', 'avc1', 'h264', 'x264', 'davc', 'hev1', 'hvc1', 'hevc', 'h265',
    'x265', 'mp4v', 'fmp4', 'xvid', 'divx', 'dx50', 'mp42', 'mp43', 'div3', 'vp80', 'vp90',
    'vp08', 'vp09', 'av01', 'theo', 'wmv1', 'wmv2', 'wmv3', 'wvc1', 'mpg1', 'mpg2', 'mpeg',
    'h263', 'flv1', 'cvid'))
LOSSY_IMAGES = ('.jpg', '.jpeg')
LOSSLESS_CODEC = 'FFV1'
LOSSY_CODEC = 'MJPG'

# sensor_msgs/Image encodings we track: encoding -> (channels, bytes per channel, cv2
# conversion to gray). OpenCV names a Bayer pattern by its second row's second and third
# pixels, ROS by the first row's: ROS bayer_rggb is OpenCV's BayerBG, and so on (as cv_bridge).
_BAYER = {'rggb': cv2.COLOR_BayerBG2GRAY, 'bggr': cv2.COLOR_BayerRG2GRAY,
          'gbrg': cv2.COLOR_BayerGR2GRAY, 'grbg': cv2.COLOR_BayerGB2GRAY}
IMAGE_ENCODINGS = {'mono8': (1, 1, None), '8UC1': (1, 1, None),
                   'mono16': (1, 2, None), '16UC1': (1, 2, None),
                   'bgr8': (3, 1, cv2.COLOR_BGR2GRAY), 'rgb8': (3, 1, cv2.COLOR_RGB2GRAY),
                   'bgra8': (4, 1, cv2.COLOR_BGRA2GRAY), 'rgba8': (4, 1, cv2.COLOR_RGBA2GRAY),
                   'bgr16': (3, 2, cv2.COLOR_BGR2GRAY), 'rgb16': (3, 2, cv2.COLOR_RGB2GRAY),
                   **{f'bayer_{p}{b}': (1, b // 8, code) for p, code in _BAYER.items()
                      for b in (8, 16)}}


def image_to_gray(encoding: str, height: int, width: int, step: int,
                  data: Any, is_bigendian: int = 0) -> np.ndarray:
    """Return the pixels of a sensor_msgs/Image (its fields) as a gray H x W array.

    8-bit encodings give uint8, 16-bit ones (mono16, bgr16, bayer_*16, ...) uint16; Bayer
    mosaics are demosaiced by OpenCV. Works on the fields of any Image object (rclpy's or
    rosbags'); InputError (one line) for an unsupported encoding or data shorter than
    height x step.
    """
    if encoding not in IMAGE_ENCODINGS:
        raise InputError(f'unsupported image encoding {encoding!r} '
                         f'(supported: {", ".join(IMAGE_ENCODINGS)})')
    channels, size, code = IMAGE_ENCODINGS[encoding]
    buffer = np.frombuffer(data, dtype=np.uint8)
    if step < width * channels * size or buffer.size < height * step:
        raise InputError(f'{encoding} image {width} x {height}, step {step}: '
                         f'{buffer.size} bytes of data is too short')
    rows = buffer[:height * step].reshape(height, step)[:, :width * channels * size]
    if size == 2:
        rows = np.ascontiguousarray(rows).view('>u2' if is_bigendian else '<u2').astype(
            np.uint16)
    pixels = rows.reshape(height, width, channels)
    if code is None:
        return np.ascontiguousarray(pixels[:, :, 0])
    if channels == 1:
        return cv2.cvtColor(np.ascontiguousarray(pixels[:, :, 0]), code)
    return cv2.cvtColor(pixels, code)


class FrameSource:
    """Frames from an array, a list of arrays, a video file or a folder of images.

    ``fps`` is the container's frame rate for a video (None if unknown, and for arrays and
    folders), ``frame_size`` is (width, height), ``n_frames`` the count (a video's count is
    the container's estimate). ``codec``: a video's FourCC ('' otherwise); ``lossy``: True
    for a lossy codec (``LOSSY_CODECS``) or JPEG images, whose block artefacts the trackers'
    standard errors do not model. Iterating yields 2-D arrays (colour is converted to gray).
    Unreadable or missing input raises InputError with a one-line message.
    """

    def __init__(self, source: Any):
        """Open ``source`` and read its first frame to learn the frame size."""
        self.source = source
        self.fps: float | None = None
        self.kind = ''
        self.codec = ''
        self.lossy = False
        self._paths: list[str] = []
        if isinstance(source, (str, os.PathLike)):
            path = os.fspath(source)
            if os.path.isdir(path):
                self._open_folder(path)
            elif os.path.isfile(path):
                self._open_video(path)
            else:
                raise InputError(f'{path}: no such file or directory')
        else:
            self._open_arrays(source)

    def _open_arrays(self, source):
        if isinstance(source, np.ndarray):
            if source.ndim == 2:
                source = source[None]
            if source.ndim not in (3, 4) or source.shape[0] == 0:
                raise InputError(f'frames must be an N x H x W (x 3) array, got shape '
                                 f'{source.shape}')
        else:
            try:
                source = list(source)
            except TypeError:
                raise InputError('frames must be an array, a list of arrays, a video file or '
                                 'a folder of images') from None
            if not source:
                raise InputError('no frames')
        self.kind = 'arrays'
        self._frames = source
        self._learn(to_gray(source[0]), len(source))

    def _learn(self, first, count):
        self.frame_size = (first.shape[1], first.shape[0])
        self.n_frames = count
        self.dtype = first.dtype

    def _open_folder(self, path):
        names = sorted(n for n in os.listdir(path)
                       if os.path.splitext(n)[1].lower() in IMAGE_EXTENSIONS)
        if not names:
            raise InputError(f'{path}: no image files ({", ".join(IMAGE_EXTENSIONS)})')
        self.kind = 'folder'
        self._paths = [os.path.join(path, n) for n in names]
        self.lossy = any(n.lower().endswith(LOSSY_IMAGES) for n in names)
        self._learn(self._read_image(self._paths[0]), len(self._paths))

    @staticmethod
    def _read_image(path):
        image = cv2.imread(path, cv2.IMREAD_UNCHANGED)
        if image is None:
            raise InputError(f'{path}: cannot read image')
        return to_gray(image)

    def _open_video(self, path):
        capture = cv2.VideoCapture(path)
        try:
            ok, frame = capture.read() if capture.isOpened() else (False, None)
            if not ok or frame is None:
                raise InputError(f'{path}: cannot read video (not a video this OpenCV build '
                                 f'decodes, or empty)')
            fps = capture.get(cv2.CAP_PROP_FPS)
            count = int(capture.get(cv2.CAP_PROP_FRAME_COUNT))
            fourcc = int(capture.get(cv2.CAP_PROP_FOURCC))
        finally:
            capture.release()
        self.kind = 'video'
        self.codec = ''.join(chr((fourcc >> 8 * i) & 0xFF) for i in range(4)).strip('\0 ')
        self.lossy = self.codec.lower() in LOSSY_CODECS
        self._path = path
        self.fps = float(fps) if fps and math.isfinite(fps) and fps > 0 else None
        self._learn(to_gray(frame), count if count > 0 else None)

    def __iter__(self) -> Iterator[np.ndarray]:
        """Yield the frames as 2-D arrays, in order."""
        if self.kind == 'arrays':
            for frame in self._frames:
                yield self._checked(to_gray(frame))
        elif self.kind == 'folder':
            for path in self._paths:
                yield self._checked(self._read_image(path))
        else:
            capture = cv2.VideoCapture(self._path)
            try:
                while True:
                    ok, frame = capture.read()
                    if not ok:
                        break
                    yield self._checked(to_gray(frame))
            finally:
                capture.release()

    def _checked(self, frame):
        if (frame.shape[1], frame.shape[0]) != self.frame_size:
            raise InputError(f'frame size {frame.shape[1]}x{frame.shape[0]} differs from the '
                             f'first frame {self.frame_size[0]}x{self.frame_size[1]}')
        return frame


def iter_frames(source: Any) -> Iterator[np.ndarray]:
    """Yield 2-D frames from an array, a list of arrays, a video file or a folder of images."""
    return iter(FrameSource(source))


def track_video(source: Any, rois: dict, meters_per_pixel: Any, fps: float | None = None,
                **options: Any) -> TrackResult:
    """Track the marks through anything FrameSource opens; return a core TrackResult.

    ``fps``: None takes the video's own rate (InputError if it is unknown) unless ``times``
    (in ``options``) gives it. ``options`` are those of core.tracking.track (exposure,
    start_time, config, progress, max_frames, times); progress gets the container's frame
    count as the total.
    """
    frames = source if isinstance(source, FrameSource) else FrameSource(source)
    times = options.get('times')
    if fps is None and (times is None or np.size(times) < 2):
        fps = frames.fps
    return track(frames, rois, meters_per_pixel, fps, n_frames=frames.n_frames, **options)


def write_video(path: str | os.PathLike, frames: Any, fps: float = 30.0,
                codec: str = LOSSLESS_CODEC) -> str | os.PathLike:
    """Write mono8 frames to a video file with OpenCV (FFmpeg backend) and return the path.

    ``codec`` is a FourCC: 'FFV1' (lossless; .mkv or .avi) or 'MJPG' (lossy, like a DV camera;
    .avi), or any FourCC this OpenCV build writes (see ``codec_available``). The FFmpeg
    backend ignores a quality setting, so the lossy codecs use FFmpeg's defaults. Raises
    InputError if the writer cannot be opened or the frames are not 2-D uint8 of one size.
    """
    frames = [np.asarray(f) for f in frames]
    if not frames:
        raise InputError('no frames to write')
    height, width = frames[0].shape[:2]
    if len(codec) != 4:
        raise InputError(f'codec must be a 4-character FourCC, got {codec!r}')
    for frame in frames:
        if frame.shape != (height, width) or frame.dtype != np.uint8:
            raise InputError('frames must all be 2-D uint8 arrays of the same size')
    directory = os.path.dirname(os.path.abspath(path))
    os.makedirs(directory, exist_ok=True)
    writer = cv2.VideoWriter(os.fspath(path), cv2.VideoWriter.fourcc(*codec), float(fps),
                             (width, height), isColor=False)
    if not writer.isOpened():
        raise InputError(f'{path}: this OpenCV build cannot write {codec!r} video')
    try:
        for frame in frames:
            writer.write(frame)
    finally:
        writer.release()
    return path


def write_image_sequence(directory: str | os.PathLike, frames: Any,
                         pattern: str = 'frame_{:06d}.png') -> list[str]:
    """Write frames as numbered lossless images into ``directory``; return the file paths."""
    os.makedirs(directory, exist_ok=True)
    paths = []
    for index, frame in enumerate(frames):
        path = os.path.join(directory, pattern.format(index))
        if not cv2.imwrite(path, np.asarray(frame)):
            raise InputError(f'{path}: cannot write image')
        paths.append(path)
    return paths


def codec_available(codec: str, suffix: str = '.avi', directory: str | None = None) -> bool:
    """Return True if this OpenCV build writes and reads back ``codec`` video in ``suffix``.

    Writes two tiny frames into a temporary file (in ``directory`` if given) and removes it.
    """
    with tempfile.TemporaryDirectory(dir=directory) as tmp:
        path = os.path.join(tmp, f'probe{suffix}')
        writer = cv2.VideoWriter(path, cv2.VideoWriter.fourcc(*codec), 30.0, (32, 24),
                                 isColor=False)
        if not writer.isOpened():
            return False
        for value in (60, 180):
            writer.write(np.full((24, 32), value, dtype=np.uint8))
        writer.release()
        capture = cv2.VideoCapture(path)
        try:
            ok, frame = capture.read()
        finally:
            capture.release()
        return bool(ok) and frame is not None and frame.shape[:2] == (24, 32)
