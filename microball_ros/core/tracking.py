"""Sub-pixel, blur-robust tracking of the slider and stator marks along the bearing axis (x).

What a blurred frame encodes: a mark that moves during the exposure is imaged as the still mark
convolved with the distribution of its positions during the exposure (the motion kernel). The
centroid of a convolution is the sum of the centroids, so the centroid of the mark's intensity
deficit is the position *averaged over the exposure*, for any motion and any mark shape, and
that is what the tracker reports, stamped at mid-exposure. (For a sinusoid the exposure average
is the mid-exposure value scaled by sinc(w T / 2), in phase: 0.4 % at 2.95 Hz and 1/60 s.) A
template cut from a still frame does not match a smeared mark, and a symmetric matcher finds the
centre of symmetry of the smeared mark, which differs from the exposure average by up to a few
tenths of a pixel when the speed changes during the exposure (seen with the paper's motion).

Per mark and frame (all 1-D after one pass over the ROI):

1. profile: the ROI's rows averaged with weights proportional to the mark's depth in each row
   (a matched filter across rows, estimated from the frame itself);
2. relative deficit ``d = 1 - profile / baseline``, the baseline a polynomial (cubic) fitted to
   the ROI outside the mark, which removes uneven illumination;
3. detection: the strongest dip of the smoothed deficit, its extent where it exceeds a fraction
   of its peak, plus a pad; checks: signal-to-noise, the mark clear of the ROI edges, no
   saturation, an integrated deficit (blur-invariant "area") consistent with recent frames;
4. position: the deficit centroid over the extent (exact for any blur), or, when the mark has
   barely moved since the previous frame (so the blur is negligible and symmetric), the centre
   of mirror symmetry, found by Gauss-Newton on the antisymmetric energy with band-limited
   (Fourier) interpolation, which reaches the Cramer-Rao bound for still symmetric marks; if
   the two disagree by more than 3 sigma the blur is asymmetric and the centroid is kept.

A failed check gives NaN and a quality below ``min_quality``: positions are never invented, and
each frame is searched over the whole ROI, so a mark is re-acquired as soon as it returns.

Frames come from ``iter_frames`` / ``FrameSource``: an array (N x H x W, or N x H x W x 3),
a list of 2-D arrays, a video file (anything this OpenCV build reads) or a folder of images
(sorted by name). Positions are image columns times ``meters_per_pixel`` (column k is the centre
of pixel k); time of frame n is ``start_time + n / fps + exposure / 2``.

Entry points: ``track`` (a whole sequence -> TrackResult, ``to_columns()`` gives the position
CSV columns), ``Tracker`` (frame by frame, for a node), ``MarkTracker`` (one mark),
``detect_rois`` (ROIs found automatically), ``parse_roi`` / ``check_roi`` / ``check_scale``
(input validation with one-line ValueErrors).
"""

from collections import deque
from dataclasses import dataclass, field
import math
import os

import cv2
import numpy as np

IMAGE_EXTENSIONS = ('.png', '.tif', '.tiff', '.bmp', '.pgm', '.ppm', '.jpg', '.jpeg')
METHODS = ('auto', 'centroid', 'symmetric')
POLARITIES = ('dark', 'bright')
_MAD_TO_SIGMA = 1.4826


@dataclass(frozen=True)
class TrackerConfig:
    """Tracker tuning; the defaults suit dark etched marks on a brighter plate.

    ``method``: 'auto' (centroid, or symmetry when the mark is nearly still), 'centroid' (exact
    for any mark shape, noisier) or 'symmetric' (marks symmetric along x, still or uniformly
    moving only). Lengths in px; ``threshold`` is the fraction of the peak deficit that
    delimits the mark; ``still_motion_px`` is the frame-to-frame motion below which 'auto' uses
    symmetry (blending to the centroid at three times that).
    """

    method: str = 'auto'
    polarity: str = 'dark'
    baseline_degree: int = 3
    smoothing_px: int = 5
    threshold: float = 0.05
    pad_px: int = 4
    weight_rows: bool = True
    min_snr: float = 8.0
    snr_scale: float = 12.0
    min_depth: float = 0.02
    min_baseline: float = 4.0
    saturation_level: float = None
    max_saturated_fraction: float = 0.002
    area_tolerance: float = 0.12
    area_history: int = 9
    still_motion_px: float = 1.0
    min_quality: float = 0.5

    def __post_init__(self):
        """Reject inconsistent settings with a one-line message."""
        if self.method not in METHODS:
            raise ValueError(f'tracker method must be one of {", ".join(METHODS)}, '
                             f'got {self.method!r}')
        if self.polarity not in POLARITIES:
            raise ValueError(f'tracker polarity must be one of {", ".join(POLARITIES)}, '
                             f'got {self.polarity!r}')
        if not 0 <= int(self.baseline_degree) <= 5:
            raise ValueError('tracker baseline_degree must be in 0..5')
        if int(self.smoothing_px) < 1 or int(self.pad_px) < 0 or int(self.area_history) < 1:
            raise ValueError('tracker smoothing_px, area_history must be >= 1, pad_px >= 0')
        if not 0 < self.threshold < 1 or not 0 <= self.min_quality <= 1:
            raise ValueError('tracker threshold must be in (0, 1), min_quality in [0, 1]')


@dataclass(frozen=True)
class MarkMeasurement:
    """One mark in one frame.

    ``position_px``: image column of the mark centre averaged over the exposure (NaN when
    invalid); ``quality`` in [0, 1] (valid iff >= the configured ``min_quality``);
    ``sigma_px``: estimated 1-sigma noise of the position; ``contrast``: peak relative deficit;
    ``extent_px``: length of the (blurred) mark; ``reason``: why the sample is invalid, or ''.
    """

    position_px: float
    quality: float
    sigma_px: float = float('nan')
    contrast: float = float('nan')
    extent_px: float = float('nan')
    reason: str = ''

    @property
    def valid(self):
        """Return True if the position was measured."""
        return not math.isnan(self.position_px)


@dataclass(frozen=True)
class TrackedFrame:
    """The result of one frame: index, mid-exposure time (s), measurement per mark name."""

    index: int
    time: float
    marks: dict
    meters_per_pixel: float

    def position(self, name):
        """Return the position of mark ``name`` in m (NaN when invalid)."""
        return self.marks[name].position_px * self.meters_per_pixel

    def quality(self, name):
        """Return the quality of mark ``name``."""
        return self.marks[name].quality


@dataclass(frozen=True)
class TrackResult:
    """Tracked positions of a sequence: arrays per mark name, all of the length of ``time``.

    ``position`` in m, ``position_px`` in image columns, ``quality`` in [0, 1], ``sigma_px``
    the estimated noise; invalid samples are NaN with a low quality.
    """

    time: np.ndarray
    position: dict
    position_px: dict
    quality: dict
    sigma_px: dict
    reason: dict
    meters_per_pixel: float
    fps: float
    exposure: float
    names: tuple = field(default=())

    def to_columns(self):
        """Return the position-CSV columns (DESIGN.md section 5) as an ordered dict.

        ``time,stator_position,slider_position,slider_quality,stator_quality``; needs marks
        named 'slider' and 'stator'; NaN marks an empty cell.
        """
        for name in ('slider', 'stator'):
            if name not in self.position:
                raise ValueError(f'no mark named {name!r} was tracked')
        return {'time': self.time, 'stator_position': self.position['stator'],
                'slider_position': self.position['slider'],
                'slider_quality': self.quality['slider'],
                'stator_quality': self.quality['stator']}


def parse_roi(text):
    """Parse 'X,Y,W,H' (integers, px) into a tuple; ValueError with a one-line message."""
    parts = str(text).split(',')
    try:
        values = tuple(int(p.strip()) for p in parts)
    except ValueError:
        values = ()
    if len(values) != 4:
        raise ValueError(f'ROI {text!r} must be four integers X,Y,W,H')
    return values


def check_roi(roi, frame_size=None, name='mark'):
    """Validate an ROI (x, y, w, h) against a frame size (width, height); return it as ints.

    Raises ValueError with a one-line message if the ROI is malformed, too small to track in
    (w < 16 or h < 1) or extends outside the frame.
    """
    try:
        x, y, w, h = (int(v) for v in roi)
        if any(int(v) != v for v in roi):
            raise ValueError
    except (TypeError, ValueError):
        raise ValueError(f'{name} ROI {roi!r} must be four integers (x, y, w, h)') from None
    if w < 16 or h < 1:
        raise ValueError(f'{name} ROI {x},{y},{w},{h} is too small (need w >= 16, h >= 1)')
    if x < 0 or y < 0:
        raise ValueError(f'{name} ROI {x},{y},{w},{h} starts outside the frame')
    if frame_size is not None:
        width, height = frame_size
        if x + w > width or y + h > height:
            raise ValueError(f'{name} ROI {x},{y},{w},{h} extends outside the '
                             f'{width}x{height} frame')
    return (x, y, w, h)


def check_scale(meters_per_pixel):
    """Validate the image scale (m per px): positive and finite; return it as float."""
    try:
        value = float(meters_per_pixel)
    except (TypeError, ValueError):
        raise ValueError(f'meters per pixel {meters_per_pixel!r} is not a number') from None
    if not (math.isfinite(value) and value > 0):
        raise ValueError(f'meters per pixel must be positive and finite, got {value!r}')
    return value


def _to_gray(frame):
    frame = np.asarray(frame)
    if frame.ndim == 3 and frame.shape[2] == 1:
        frame = frame[:, :, 0]
    elif frame.ndim == 3 and frame.shape[2] in (3, 4):
        code = cv2.COLOR_BGR2GRAY if frame.shape[2] == 3 else cv2.COLOR_BGRA2GRAY
        frame = cv2.cvtColor(frame, code)
    if frame.ndim != 2:
        raise ValueError(f'a frame must be a 2-D (gray) or H x W x 3 array, got shape '
                         f'{frame.shape}')
    return frame


# 8-bit sensor_msgs/Image encodings we track: encoding -> (channels, cv2 conversion to gray).
IMAGE_ENCODINGS = {'mono8': (1, None), '8UC1': (1, None),
                   'bgr8': (3, cv2.COLOR_BGR2GRAY), 'rgb8': (3, cv2.COLOR_RGB2GRAY),
                   'bgra8': (4, cv2.COLOR_BGRA2GRAY), 'rgba8': (4, cv2.COLOR_RGBA2GRAY)}


def image_to_gray(encoding, height, width, step, data):
    """Return the pixels of a sensor_msgs/Image (its fields) as a gray H x W uint8 array.

    Works on the fields of any Image object (rclpy's or rosbags'); ValueError (one line) for
    an encoding that is not 8-bit or data shorter than height x step.
    """
    if encoding not in IMAGE_ENCODINGS:
        raise ValueError(f'unsupported image encoding {encoding!r} '
                         f'(supported: {", ".join(IMAGE_ENCODINGS)})')
    channels, code = IMAGE_ENCODINGS[encoding]
    buffer = np.frombuffer(data, dtype=np.uint8)
    if step < width * channels or buffer.size < height * step:
        raise ValueError(f'{encoding} image {width} x {height}, step {step}: '
                         f'{buffer.size} bytes of data is too short')
    rows = buffer[:height * step].reshape(height, step)
    pixels = rows[:, :width * channels].reshape(height, width, channels)
    return pixels[:, :, 0] if code is None else cv2.cvtColor(pixels, code)


class FrameSource:
    """Frames from an array, a list of arrays, a video file or a folder of images.

    ``fps`` is the container's frame rate for a video (None if unknown, and for arrays and
    folders), ``frame_size`` is (width, height), ``n_frames`` the count (a video's count is
    the container's estimate). Iterating yields 2-D arrays (colour is converted to gray).
    Unreadable or missing input raises ValueError with a one-line message.
    """

    def __init__(self, source):
        """Open ``source`` and read its first frame to learn the frame size."""
        self.source = source
        self.fps = None
        self.kind = None
        self._paths = None
        if isinstance(source, (str, os.PathLike)):
            path = os.fspath(source)
            if os.path.isdir(path):
                self._open_folder(path)
            elif os.path.isfile(path):
                self._open_video(path)
            else:
                raise ValueError(f'{path}: no such file or directory')
        else:
            self._open_arrays(source)

    def _open_arrays(self, source):
        if isinstance(source, np.ndarray):
            if source.ndim == 2:
                source = source[None]
            if source.ndim not in (3, 4) or source.shape[0] == 0:
                raise ValueError(f'frames must be an N x H x W (x 3) array, got shape '
                                 f'{source.shape}')
        else:
            try:
                source = list(source)
            except TypeError:
                raise ValueError('frames must be an array, a list of arrays, a video file or '
                                 'a folder of images') from None
            if not source:
                raise ValueError('no frames')
        self.kind = 'arrays'
        self._frames = source
        first = _to_gray(source[0])
        self.frame_size = (first.shape[1], first.shape[0])
        self.n_frames = len(source)
        self.dtype = first.dtype

    def _open_folder(self, path):
        names = sorted(n for n in os.listdir(path)
                       if os.path.splitext(n)[1].lower() in IMAGE_EXTENSIONS)
        if not names:
            raise ValueError(f'{path}: no image files ({", ".join(IMAGE_EXTENSIONS)})')
        self.kind = 'folder'
        self._paths = [os.path.join(path, n) for n in names]
        first = self._read_image(self._paths[0])
        self.frame_size = (first.shape[1], first.shape[0])
        self.n_frames = len(self._paths)
        self.dtype = first.dtype

    @staticmethod
    def _read_image(path):
        image = cv2.imread(path, cv2.IMREAD_UNCHANGED)
        if image is None:
            raise ValueError(f'{path}: cannot read image')
        return _to_gray(image)

    def _open_video(self, path):
        capture = cv2.VideoCapture(path)
        try:
            ok, frame = capture.read() if capture.isOpened() else (False, None)
            if not ok or frame is None:
                raise ValueError(f'{path}: cannot read video (not a video this OpenCV build '
                                 f'decodes, or empty)')
            fps = capture.get(cv2.CAP_PROP_FPS)
            count = int(capture.get(cv2.CAP_PROP_FRAME_COUNT))
        finally:
            capture.release()
        self.kind = 'video'
        self._path = path
        self.fps = float(fps) if fps and math.isfinite(fps) and fps > 0 else None
        first = _to_gray(frame)
        self.frame_size = (first.shape[1], first.shape[0])
        self.n_frames = count if count > 0 else None
        self.dtype = first.dtype

    def __iter__(self):
        """Yield the frames as 2-D arrays, in order."""
        if self.kind == 'arrays':
            for frame in self._frames:
                yield self._checked(_to_gray(frame))
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
                    yield self._checked(_to_gray(frame))
            finally:
                capture.release()

    def _checked(self, frame):
        if (frame.shape[1], frame.shape[0]) != self.frame_size:
            raise ValueError(f'frame size {frame.shape[1]}x{frame.shape[0]} differs from the '
                             f'first frame {self.frame_size[0]}x{self.frame_size[1]}')
        return frame


def iter_frames(source):
    """Yield 2-D frames from an array, a list of arrays, a video file or a folder of images."""
    return iter(FrameSource(source))


def _default_saturation(dtype):
    if dtype == np.uint8:
        return 255.0
    if dtype == np.uint16:
        return 65535.0
    return None


def _smooth(values, width):
    if width <= 1:
        return values
    return np.convolve(values, np.full(width, 1.0 / width), mode='same')


def _extent(smoothed, peak_index, threshold):
    """Return the first and last index around ``peak_index`` where ``smoothed > threshold``."""
    below = smoothed <= threshold
    left = np.flatnonzero(below[:peak_index])
    right = np.flatnonzero(below[peak_index + 1:])
    lo = int(left[-1]) + 1 if left.size else 0
    hi = peak_index + int(right[0]) if right.size else smoothed.size - 1
    return lo, hi


def symmetric_center(deficit, start, pad, iterations=10, tolerance=1e-6):
    """Return the centre of mirror symmetry of a 1-D signal, near ``start`` (index units).

    Minimises the energy of the part of the signal that is antisymmetric about the centre by
    Gauss-Newton on its Fourier transform (band-limited interpolation, so sub-pixel shifts are
    exact for band-limited signals). ``pad`` samples are kept on both sides of the support.
    Returns NaN if it does not converge.
    """
    n = deficit.size
    nz = np.flatnonzero(deficit)
    if nz.size == 0:
        return float('nan')
    half = max(start - nz[0], nz[-1] - start) + pad
    first = int(math.floor(start - half))
    last = int(math.ceil(start + half)) + 1
    segment = np.zeros(last - first)
    lo, hi = max(first, 0), min(last, n)
    segment[lo - first:hi - first] = deficit[lo:hi]
    spectrum = np.fft.rfft(segment)
    omega = 2.0 * np.pi * np.arange(spectrum.size) / segment.size
    weight = np.full(spectrum.size, 2.0)
    weight[0] = 0.0
    if segment.size % 2 == 0:
        weight[-1] = 0.0
    center = start - first
    for _ in range(iterations):
        rotated = spectrum * np.exp(1j * omega * center)
        jacobian = rotated.real * omega
        curvature = float(np.sum(weight * jacobian * jacobian))
        if curvature <= 0:
            return float('nan')
        step = -float(np.sum(weight * rotated.imag * jacobian)) / curvature
        center += step
        if abs(step) < tolerance:
            return center + first
    return float('nan')


class MarkTracker:
    """Track one mark inside one ROI, frame by frame.

    State (all from earlier frames, in order): the previous position, to tell a still mark from
    a moving one, and the recent integrated deficits, to recognise a partly hidden mark.
    """

    def __init__(self, roi, config=None, name='mark'):
        """Create a tracker for the mark in ``roi`` (x, y, w, h, px)."""
        self.roi = check_roi(roi, name=name)
        self.config = TrackerConfig() if config is None else config
        self.name = name
        width = self.roi[2]
        u = np.linspace(-1.0, 1.0, width)
        self._basis = np.vander(u, int(self.config.baseline_degree) + 1)
        self._pinv = np.linalg.pinv(self._basis)
        self._columns = np.arange(width, dtype=float)
        self._areas = deque(maxlen=int(self.config.area_history))
        self._previous = None

    def reset(self):
        """Forget the history (for a new, unrelated sequence)."""
        self._areas.clear()
        self._previous = None

    def _fit_baseline(self, profile, keep):
        count = int(np.count_nonzero(keep))
        degree = min(self._basis.shape[1] - 1, max(count // 12 - 1, 0))
        basis = self._basis[keep, -(degree + 1):]
        coef = np.linalg.lstsq(basis, profile[keep], rcond=None)[0]
        return self._basis[:, -(degree + 1):] @ coef

    def _envelope_baseline(self, profile, iterations=8):
        """Return a first baseline that the mark's dip cannot bend: iterative clipping.

        The profile is repeatedly replaced by the larger (for dark marks) of itself and the fit,
        so the fit climbs out of the dip onto the plain plate, however wide the blurred mark.
        """
        clipped = profile
        clip = np.maximum if self.config.polarity == 'dark' else np.minimum
        for _ in range(iterations):
            baseline = self._basis @ (self._pinv @ clipped)
            clipped = clip(profile, baseline)
        return baseline

    def _deficit(self, profile, baseline):
        if self.config.polarity == 'dark':
            return 1.0 - profile / baseline
        return profile / baseline - 1.0

    def _locate(self, deficit, noise, fraction=None):
        cfg = self.config
        smoothed = _smooth(deficit, int(cfg.smoothing_px))
        k = int(np.argmax(smoothed))
        peak = float(smoothed[k])
        fraction = cfg.threshold if fraction is None else fraction
        threshold = max(fraction * peak, 3.0 * noise / math.sqrt(cfg.smoothing_px))
        lo, hi = _extent(smoothed, k, threshold)
        return k, peak, lo, hi

    def _invalid(self, reason, contrast=float('nan')):
        self._previous = None
        return MarkMeasurement(float('nan'), 0.0, contrast=contrast, reason=reason)

    def measure(self, frame):
        """Measure the mark in one frame (2-D array in DN) and return a MarkMeasurement.

        Quality = (1 - exp(-(snr / snr_scale)^2)) * exp(-(area ratio - 1)^2 / (2 tol^2)), 0 after
        a failed check (too dark, saturated, mark at the ROI edge, no mark); the position is NaN
        whenever the quality is below ``min_quality``.
        """
        cfg = self.config
        x, y, w, h = self.roi
        if frame.ndim != 2 or x + w > frame.shape[1] or y + h > frame.shape[0]:
            raise ValueError(f'{self.name} ROI {x},{y},{w},{h} extends outside the '
                             f'{frame.shape[1] if frame.ndim > 1 else 0}x{frame.shape[0]} frame')
        region = frame[y:y + h, x:x + w]
        if region.dtype == np.uint8:
            profile = cv2.reduce(region, 0, cv2.REDUCE_AVG, dtype=cv2.CV_64F)[0]
        else:
            profile = region.astype(np.float64).mean(axis=0)
        if not np.all(np.isfinite(profile)):
            return self._invalid('non-finite pixels')
        saturation = (cfg.saturation_level if cfg.saturation_level is not None
                      else _default_saturation(region.dtype))
        if saturation is not None and profile.max() >= saturation:
            return self._invalid('saturated')
        pad = int(cfg.pad_px)
        guard = pad + int(cfg.smoothing_px)
        baseline = self._envelope_baseline(profile)
        if baseline.min() < cfg.min_baseline:
            return self._invalid('too dark')
        deficit = self._deficit(profile, baseline)
        _, _, lo, hi = self._locate(deficit, 0.0, 0.25)
        margin = guard + (hi - lo) // 4
        for attempt in range(3):
            # Plain plate = everything outside the mark and a guard band; refit on it twice.
            keep = np.ones(w, dtype=bool)
            keep[max(lo - margin, 0):hi + margin + 1] = False
            if np.count_nonzero(keep) < 12:
                flat = float(np.max(np.abs(deficit))) < cfg.min_depth
                return self._invalid('low contrast' if flat else 'mark fills the ROI (widen it)')
            if attempt == 2:
                break
            baseline = self._fit_baseline(profile, keep)
            if baseline.min() < cfg.min_baseline:
                return self._invalid('too dark')
            deficit = self._deficit(profile, baseline)
            _, _, lo, hi = self._locate(deficit, 0.0)
            margin = guard
        if cfg.weight_rows and h > 1:
            profile = self._row_weighted_profile(region, lo, hi, pad)
            if profile is not None:
                baseline = self._fit_baseline(profile, keep)
                if baseline.min() < cfg.min_baseline:
                    return self._invalid('too dark')
                deficit = self._deficit(profile, baseline)
        noise = self._noise(deficit, keep)
        k, peak, lo, hi = self._locate(deficit, noise)
        snr = peak * math.sqrt(cfg.smoothing_px) / noise
        if snr < cfg.min_snr or peak < cfg.min_depth:
            return self._invalid('low contrast', contrast=peak)
        first, last = lo - pad, hi + pad
        if first < 1 or last > w - 2:
            return self._invalid('mark at the ROI edge', contrast=peak)
        if saturation is not None:
            window = region[:, max(first - guard, 0):last + guard + 1]
            if np.count_nonzero(window >= saturation) > cfg.max_saturated_fraction * window.size:
                return self._invalid('saturated', contrast=peak)
        window = deficit[first:last + 1]
        area = float(window.sum())
        if area <= 0:
            return self._invalid('low contrast', contrast=peak)
        offsets = self._columns[first:last + 1]
        centroid = float(window @ offsets) / area
        sigma_centroid = noise * math.sqrt(float(np.sum((offsets - centroid) ** 2))) / area
        # The integrated deficit does not change with blur: a jump means a partly hidden mark.
        # Rejected frames enter the history too, so a lasting change is accepted after a while.
        ratio = area / float(np.median(self._areas)) if len(self._areas) >= 3 else 1.0
        self._areas.append(area)
        position, sigma = self._position(deficit, first, last, centroid, sigma_centroid, noise,
                                         x, pad)
        q_snr = 1.0 - math.exp(-(snr / cfg.snr_scale) ** 2)
        q_area = math.exp(-0.5 * ((ratio - 1.0) / cfg.area_tolerance) ** 2)
        quality = q_snr * q_area
        extent = float(hi - lo + 1)
        if quality < cfg.min_quality or not math.isfinite(position):
            reason = 'mark area changed' if q_area < q_snr else 'low contrast'
            self._previous = None
            return MarkMeasurement(float('nan'), quality, contrast=peak, extent_px=extent,
                                   reason=reason)
        self._previous = position
        return MarkMeasurement(position, quality, sigma_px=sigma, contrast=peak,
                               extent_px=extent)

    def _row_weighted_profile(self, region, lo, hi, pad):
        w = region.shape[1]
        a, b = max(lo - pad, 0), min(hi + pad + 1, w)
        flank = max(8, (b - a) // 4)
        left, right = region[:, max(a - flank, 0):a], region[:, b:b + flank]
        if left.shape[1] + right.shape[1] == 0 or b <= a:
            return None
        outside = (left.sum(axis=1, dtype=np.float64) + right.sum(axis=1, dtype=np.float64)) / (
            left.shape[1] + right.shape[1])
        inside = region[:, a:b].mean(axis=1, dtype=np.float64)
        depth = outside - inside if self.config.polarity == 'dark' else inside - outside
        depth = np.clip(_smooth(depth, 3), 0.0, None)
        total = float(depth.sum())
        if total <= 0:
            return None
        return (depth / total) @ region.astype(np.float64)

    @staticmethod
    def _noise(deficit, keep):
        second = deficit[2:] - 2.0 * deficit[1:-1] + deficit[:-2]
        second = second[keep[1:-1]]
        if second.size < 8:
            return 1e-6
        mad = float(np.median(np.abs(second - np.median(second))))
        return max(_MAD_TO_SIGMA * mad / math.sqrt(6.0), 1e-6)

    def _position(self, deficit, first, last, centroid, sigma_centroid, noise, x0, pad):
        cfg = self.config
        if cfg.method == 'centroid':
            return centroid + x0, sigma_centroid
        if cfg.method == 'symmetric':
            weight_centroid = 0.0
        elif self._previous is None:
            weight_centroid = 1.0
        else:
            moved = abs(centroid + x0 - self._previous)
            still = cfg.still_motion_px
            weight_centroid = min(max((moved - still) / (2.0 * still), 0.0), 1.0)
        if weight_centroid >= 1.0:
            return centroid + x0, sigma_centroid
        segment = np.zeros_like(deficit)
        segment[first:last + 1] = deficit[first:last + 1]
        center = symmetric_center(segment, centroid, pad + 4)
        if not math.isfinite(center):
            return centroid + x0, sigma_centroid
        # A centre of symmetry that disagrees with the centroid by more than the noise allows
        # means an asymmetric blur (speed changing during the exposure): trust the centroid.
        if cfg.method == 'auto':
            disagreement = abs(center - centroid) / max(sigma_centroid, 1e-12)
            weight_centroid = max(weight_centroid, min(max(disagreement - 3.0, 0.0), 1.0))
        if weight_centroid >= 1.0:
            return centroid + x0, sigma_centroid
        slope = np.gradient(deficit[first:last + 1])
        information = max(float(slope @ slope) - slope.size * noise ** 2 / 2.0,
                          float(slope @ slope) * 1e-3)
        sigma_symmetric = noise / math.sqrt(information)
        position = center + weight_centroid * (centroid - center)
        sigma = sigma_symmetric + weight_centroid * (sigma_centroid - sigma_symmetric)
        return position + x0, sigma


class Tracker:
    """Track several marks (for example 'slider' and 'stator') frame by frame.

    ``rois`` maps mark names to ROIs (x, y, w, h, px); ``exposure`` (s) only sets the time
    stamps (mid-exposure); None assumes half the frame period, like the paper's camera
    (1/60 s at 30 fps). Output depends only on the ordered frames and the parameters.
    """

    def __init__(self, rois, meters_per_pixel, fps=30.0, exposure=None, start_time=0.0,
                 config=None, frame_size=None):
        """Validate the parameters (ValueError, one line) and create one MarkTracker per ROI."""
        if not rois:
            raise ValueError('need at least one mark ROI')
        self.meters_per_pixel = check_scale(meters_per_pixel)
        try:
            self.fps = float(fps)
        except (TypeError, ValueError):
            raise ValueError(f'fps {fps!r} is not a number') from None
        if not (math.isfinite(self.fps) and self.fps > 0):
            raise ValueError(f'fps must be positive and finite, got {fps!r}')
        self.exposure = 0.5 / self.fps if exposure is None else float(exposure)
        if not (0 <= self.exposure <= 1.0 / self.fps):
            raise ValueError(f'exposure must be in [0, 1/fps], got {exposure!r}')
        self.start_time = float(start_time)
        self.config = TrackerConfig() if config is None else config
        self.marks = {name: MarkTracker(check_roi(roi, frame_size, name), self.config, name)
                      for name, roi in rois.items()}
        self.index = 0

    def frame_time(self, index):
        """Return the mid-exposure time (s) of frame ``index``."""
        return self.start_time + index / self.fps + self.exposure / 2.0

    def process(self, frame, time=None):
        """Track all marks in the next frame and return a TrackedFrame.

        ``time`` (s, mid-exposure) overrides the stamp computed from the frame index (for
        example the header stamp of a received image).
        """
        frame = _to_gray(frame)
        result = TrackedFrame(
            index=self.index, time=self.frame_time(self.index) if time is None else float(time),
            marks={name: mark.measure(frame) for name, mark in self.marks.items()},
            meters_per_pixel=self.meters_per_pixel)
        self.index += 1
        return result


def detect_rois(source, names=('slider', 'stator'), margin_px=24, max_frames=60,
                mark_width_px=61, polarity='dark'):
    """Find one ROI per mark automatically, for when none is given; return {name: (x,y,w,h)}.

    Uses up to ``max_frames`` frames: a mark shows up as temporal variation along its travel
    (moving) or as a feature narrower than ``mark_width_px`` that is darker (brighter for
    ``polarity='bright'``) than its row (a black/white top-hat of the mean frame, still). The
    ``len(names)`` largest such regions become ROIs, named from top to bottom (the slider is
    the upper plate), widened by ``margin_px`` along x (plain plate for the baseline) and a
    quarter of that along y. Raises ValueError if fewer regions are found. Not for infrared
    frames: the rolling balls look like marks there.
    """
    frames = source if isinstance(source, FrameSource) else FrameSource(source)
    stack = []
    for frame in frames:
        stack.append(np.asarray(frame, dtype=np.float32))
        if len(stack) >= max_frames:
            break
    stack = np.array(stack)
    mean = stack.mean(axis=0)
    kernel = cv2.getStructuringElement(cv2.MORPH_RECT, (int(mark_width_px) | 1, 1))
    operation = cv2.MORPH_BLACKHAT if polarity == 'dark' else cv2.MORPH_TOPHAT
    activity = np.maximum(stack.std(axis=0), cv2.morphologyEx(mean, operation, kernel))
    activity = cv2.GaussianBlur(activity, (0, 0), 2.0)
    floor = float(np.median(activity))
    rows = activity.max(axis=1) - floor
    if rows.max() <= 3.0 * max(floor, 1e-6):
        raise ValueError('no marks found: give the ROIs')
    active = np.flatnonzero(rows > 0.3 * rows.max())
    bands = np.split(active, np.flatnonzero(np.diff(active) > 1) + 1)
    bands = sorted(bands, key=lambda b: -float(rows[b].sum()))[:len(names)]
    if len(bands) < len(names):
        raise ValueError(f'found {len(bands)} mark(s), expected {len(names)}: give the ROIs')
    width, height = frames.frame_size
    pad_y = max(int(margin_px) // 4, 2)
    rois = {}
    for name, band in zip(names, sorted(bands, key=lambda b: int(b[0])), strict=True):
        columns = activity[band[0]:band[-1] + 1].max(axis=0) - floor
        span = np.flatnonzero(columns > 0.3 * columns.max())
        x0 = max(int(span[0]) - int(margin_px), 0)
        x1 = min(int(span[-1]) + 1 + int(margin_px), width)
        y0 = max(int(band[0]) - pad_y, 0)
        y1 = min(int(band[-1]) + 1 + pad_y, height)
        rois[name] = (x0, y0, x1 - x0, y1 - y0)
    return rois


def track(source, rois, meters_per_pixel, fps=None, exposure=None, start_time=0.0, config=None,
          progress=None, max_frames=None, times=None):
    """Track the marks through a sequence and return a TrackResult.

    ``source``: anything FrameSource accepts. ``fps``: None takes the video's own rate (or
    raises if unknown). ``times``: optional per-frame mid-exposure stamps (s) instead of
    ``start_time + n / fps + exposure / 2``. ``progress``: optional callable(frames_done,
    frames_total_or_None), called every 100 frames and at the end. ROIs, scale and rate are
    checked before any tracking.
    """
    frames = source if isinstance(source, FrameSource) else FrameSource(source)
    check_scale(meters_per_pixel)
    times_given = None if times is None else np.asarray(times, dtype=float).ravel()
    if times_given is not None:
        if fps is None and times_given.size > 1:
            fps = 1.0 / float(np.median(np.diff(times_given)))
    if fps is None:
        if frames.fps is None:
            raise ValueError('the frame rate is unknown: give fps')
        fps = frames.fps
    tracker = Tracker(rois, meters_per_pixel, fps, exposure, start_time, config,
                      frame_size=frames.frame_size)
    names = tuple(tracker.marks)
    stamps, rows = [], []
    for frame in frames:
        if max_frames is not None and len(rows) >= max_frames:
            break
        stamp = None
        if times_given is not None:
            if len(rows) >= times_given.size:
                raise ValueError(f'{times_given.size} time stamps for more frames')
            stamp = times_given[len(rows)]
        result = tracker.process(frame, stamp)
        stamps.append(result.time)
        rows.append(result.marks)
        if progress is not None and len(rows) % 100 == 0:
            progress(len(rows), frames.n_frames)
    if progress is not None:
        progress(len(rows), frames.n_frames)
    if not rows:
        raise ValueError('no frames to track')
    px = {n: np.array([r[n].position_px for r in rows]) for n in names}
    return TrackResult(
        time=np.array(stamps), position={n: px[n] * tracker.meters_per_pixel for n in names},
        position_px=px, quality={n: np.array([r[n].quality for r in rows]) for n in names},
        sigma_px={n: np.array([r[n].sigma_px for r in rows]) for n in names},
        reason={n: [r[n].reason for r in rows] for n in names},
        meters_per_pixel=tracker.meters_per_pixel, fps=tracker.fps,
        exposure=tracker.exposure, names=names)
