"""Synthetic camera: mono8 frames of the slider and stator marks, with exact ground truth.

The scene stands in for the paper's CCD camera (720 x 480 DV frames at 30 fps): two horizontal
silicon plates, the slider at the top and the stator at the bottom, each with one etched mark
(a dark rectangle or cross on the brighter plate) that moves along x, the bearing axis. In
infrared ("night-shot") mode the 285 um balls rolling between the plates are visible too.

Image formation, in this order:

* geometry: a mark is a union of axis-aligned rectangles, so its image is a signed sum of
  separable terms; each rectangle is convolved with a Gaussian optical PSF and integrated over
  the pixel area analytically (antiderivatives of the normal CDF), so sub-pixel placement is
  exact, with no aliasing and no resampling;
* motion blur: the exposure is split into equal sub-intervals, at most ``max_substep_px`` of
  mark travel each (at least 16), and the x-profile of the mark is averaged over their midpoints
  (for any motion, not only uniform motion);
* illumination: a linear gradient across the frame times a radial vignetting;
* sensor: shot noise (``electrons_per_dn`` electrons per digital number; Poisson for small
  counts, its Gaussian limit above ``POISSON_LIMIT`` electrons), Gaussian read noise,
  rounding to 8 bits and clipping at 0 and 255 (saturation).

Ground truth per frame: the mid-exposure time, and for each mark the position at mid-exposure
and the position averaged over the exposure (the second is what a blurred frame encodes). A
position ``x`` (m) of a plate puts its mark centre at image column ``origin + x / m_per_px``,
where column ``k`` is the centre of pixel ``k``.

Default scale: 5 um per pixel, so the paper's +-1.2 mm stator stroke spans 480 of the 720
columns and a mark moving at 0.02 m/s smears over 67 px in a 1/60 s exposure.

Plate motions are given as core.motion specifications; writing the frames to a video file or
an image folder is microball_ros.io.video's job.
"""

from dataclasses import dataclass
import math
from typing import Any

import numpy as np
import numpy.typing as npt
from scipy.special import ndtr

from microball_ros.core.errors import InputError
from microball_ros.core.motion import Motion, as_motion

MARK_SHAPES = ('bar', 'cross')
PLATES = ('slider', 'stator')
_SQRT_2PI = math.sqrt(2.0 * math.pi)
_SHAPE_PROBE_STEPS = 9
_MIN_SUBSTEPS = 16
POISSON_LIMIT = 30.0


@dataclass(frozen=True)
class CameraConfig:
    """Synthetic camera and scene parameters (SI units unless the name says px or dn).

    Intensities are in digital numbers (DN, 0..255) before illumination shading. The slider and
    stator bands are (top, bottom) fractions of the frame height. ``*_origin_px`` is the image
    column of a mark's centre at position 0 (None: the frame centre). Marks: 'bar' is a
    ``mark_width`` x ``mark_height`` rectangle, 'cross' two bars of ``mark_stroke`` width;
    ``mark_depth`` is the fraction of the plate brightness they absorb. ``illumination_gradient``
    is the relative change across the width and height, ``vignetting`` the relative loss in the
    corners. Noise: ``electrons_per_dn`` (photon transfer gain; shot-noise variance is
    DN / gain) and ``read_noise_dn`` (sigma). At the default 5 um/px the paper's +-1.2 mm stroke
    spans 480 px and 0.02 m/s smears a mark over 67 px in the 1/60 s exposure.
    """

    width: int = 720
    height: int = 480
    fps: float = 30.0
    exposure: float = 1.0 / 60.0
    start_time: float = 0.0
    meters_per_pixel: float = 5e-6
    slider_band: tuple = (0.04, 0.40)
    stator_band: tuple = (0.60, 0.96)
    slider_origin_px: float | None = None
    stator_origin_px: float | None = None
    mark_shape: str = 'bar'
    mark_width: float = 100e-6
    mark_height: float = 250e-6
    mark_stroke: float = 30e-6
    mark_depth: float = 0.6
    plate_level: float = 170.0
    gap_level: float = 40.0
    illumination_gradient: tuple = (0.2, 0.1)
    vignetting: float = 0.1
    psf_sigma_px: float = 0.9
    electrons_per_dn: float = 20.0
    read_noise_dn: float = 1.0
    max_substep_px: float = 0.25
    infrared: bool = False
    infrared_gap_level: float = 120.0
    ball_level: float = 35.0
    ball_diameter: float = 285e-6
    ball_pitch: float = 700e-6

    def __post_init__(self) -> None:
        """Reject parameters that cannot describe a camera, with a one-line message."""
        positive = ('width', 'height', 'fps', 'exposure', 'meters_per_pixel', 'mark_width',
                    'mark_height', 'mark_stroke', 'electrons_per_dn', 'max_substep_px',
                    'ball_diameter', 'ball_pitch')
        for name in positive:
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0):
                raise InputError(f'camera {name} must be positive and finite, got {value!r}')
        for name in ('psf_sigma_px', 'read_noise_dn', 'plate_level', 'gap_level', 'vignetting',
                     'infrared_gap_level', 'ball_level'):
            value = getattr(self, name)
            if not (np.isfinite(value) and value >= 0):
                raise InputError(f'camera {name} must be >= 0 and finite, got {value!r}')
        if self.exposure > 1.0 / self.fps:
            raise InputError(f'camera exposure {self.exposure:g} s exceeds the frame period '
                             f'{1.0 / self.fps:g} s')
        if not 0 <= self.mark_depth <= 1:
            raise InputError(f'camera mark_depth must be in [0, 1], got {self.mark_depth!r}')
        if self.mark_shape not in MARK_SHAPES:
            raise InputError(f'camera mark_shape must be one of {", ".join(MARK_SHAPES)}, '
                             f'got {self.mark_shape!r}')
        for name in ('slider_band', 'stator_band'):
            top, bottom = getattr(self, name)
            if not 0 <= top < bottom <= 1:
                raise InputError(f'camera {name} must be (top, bottom) with 0 <= top < bottom '
                                 f'<= 1, got {(top, bottom)!r}')
        if self.slider_band[1] > self.stator_band[0]:
            raise InputError('camera slider_band must lie above stator_band')

    def origin_px(self, plate: str) -> float:
        """Return the image column of the mark centre of ``plate`` at position 0."""
        origin = getattr(self, f'{_check_plate(plate)}_origin_px')
        return (self.width - 1) / 2.0 if origin is None else float(origin)

    def ball_origin_px(self) -> float:
        """Return the image column of a ball centre when both plates are at position 0.

        The balls roll without slipping, so the ball train sits at the mean of the slider and
        stator positions; the balls are spaced ``ball_pitch`` apart.
        """
        return (self.origin_px('slider') + self.origin_px('stator')) / 2.0

    def mark_row_px(self, plate: str) -> float:
        """Return the image row of the centre of the mark on ``plate``."""
        top, bottom = getattr(self, f'{_check_plate(plate)}_band')
        return (top + bottom) / 2.0 * self.height - 0.5

    def to_px(self, plate: str, position: npt.ArrayLike) -> np.ndarray:
        """Convert plate position(s) in m to the image column(s) of its mark centre."""
        return self.origin_px(plate) + np.asarray(position, dtype=float) / self.meters_per_pixel

    def frame_time(self, index: npt.ArrayLike) -> np.ndarray:
        """Return the mid-exposure time (s) of frame(s) ``index``."""
        return self.start_time + np.asarray(index, dtype=float) / self.fps + self.exposure / 2.0

    def noise_variance(self, expected: npt.ArrayLike) -> np.ndarray:
        """Return the per-pixel noise variance (DN^2) of a frame with this expected value.

        Shot noise, read noise and the rounding to integers (1/12 DN^2).
        """
        level = np.clip(np.asarray(expected, dtype=float), 0.0, None)
        return level / self.electrons_per_dn + self.read_noise_dn ** 2 + 1.0 / 12.0

    def mark_rectangles_px(self) -> tuple[tuple[float, float, float], ...]:
        """Return the mark as signed rectangles ``(half_width, half_height, sign)`` in px.

        The mark's indicator is the signed sum of the rectangles' indicators, all centred on the
        mark centre (inclusion-exclusion for a cross).
        """
        scale = self.meters_per_pixel
        half_w, half_h = self.mark_width / scale / 2.0, self.mark_height / scale / 2.0
        if self.mark_shape == 'bar':
            return ((half_w, half_h, 1.0),)
        half_s = self.mark_stroke / scale / 2.0
        return ((half_s, half_h, 1.0), (half_w, half_s, 1.0),
                (min(half_s, half_w), min(half_s, half_h), -1.0))

    def mark_half_extent_px(self) -> tuple[float, float]:
        """Return the half width and half height (px) of the mark's bounding box."""
        rects = self.mark_rectangles_px()
        return max(r[0] for r in rects), max(r[1] for r in rects)


@dataclass(frozen=True)
class MarkTruth:
    """Ground truth of one mark (or of the ball train) over a sequence of frames.

    Positions in m (plate coordinates) and px (image column of the mark centre), at
    mid-exposure and averaged over the exposure; ``span_px`` is the (min, max) column the mark
    centre reached during all exposures.
    """

    position_mid: np.ndarray
    position_mean: np.ndarray
    pixel_mid: np.ndarray
    pixel_mean: np.ndarray
    span_px: tuple


@dataclass(frozen=True)
class GroundTruth:
    """Per-frame ground truth: mid-exposure ``time`` (s), one MarkTruth per plate (and balls)."""

    time: np.ndarray
    slider: MarkTruth
    stator: MarkTruth
    balls: MarkTruth | None = None


@dataclass(frozen=True)
class FrameTruth:
    """Ground truth of one frame; positions in m; ``*_span_px`` as in MarkTruth."""

    index: int
    time: float
    slider_mid: float
    slider_mean: float
    stator_mid: float
    stator_mean: float
    slider_span_px: tuple
    stator_span_px: tuple
    balls_mid: float = float('nan')
    balls_mean: float = float('nan')


@dataclass(frozen=True)
class RenderedVideo:
    """Frames (N x H x W uint8), their ground truth, a suggested ROI per plate and the config."""

    frames: np.ndarray
    truth: GroundTruth
    rois: dict
    config: CameraConfig


def _check_plate(plate):
    if plate not in PLATES:
        raise InputError(f'plate must be one of {", ".join(PLATES)}, got {plate!r}')
    return plate


def edge_antiderivative(u: npt.ArrayLike, sigma: float) -> np.ndarray:
    """Return the integral from -inf to ``u`` of the Gaussian-blurred unit step Phi(v / sigma).

    ``u * Phi(u / sigma) + sigma * phi(u / sigma)``; for ``sigma == 0``, ``max(u, 0)``.
    """
    u = np.asarray(u, dtype=float)
    if sigma <= 0:
        return np.maximum(u, 0.0)
    z = u / sigma
    return u * ndtr(z) + sigma * np.exp(-0.5 * z * z) / _SQRT_2PI


def box_profile(pixels: npt.ArrayLike, centers: npt.ArrayLike, half_width: float,
                sigma: float) -> np.ndarray:
    """Return the pixel-integrated, PSF-blurred profile of a 1-D box, averaged over centres.

    ``pixels`` are pixel-centre coordinates (pixel ``k`` covers [k - 0.5, k + 0.5]);
    ``centers`` are the box centres to average over (the sub-exposure positions of a moving
    mark); the box is [c - half_width, c + half_width], blurred by a Gaussian of ``sigma`` px.
    The result is exact (no sampling in x); 1 inside a wide box, 0 far outside.
    """
    pixels = np.asarray(pixels, dtype=float)
    centers = np.atleast_1d(np.asarray(centers, dtype=float))
    bounds = np.append(pixels - 0.5, pixels[-1] + 0.5) if pixels.size else pixels
    rel = bounds[None, :] - centers[:, None]
    upper = edge_antiderivative(rel + half_width, sigma).mean(axis=0)
    lower = edge_antiderivative(rel - half_width, sigma).mean(axis=0)
    return np.diff(upper - lower)


class SyntheticCamera:
    """Render frames of the two marks moving along x; seeded, pure, frame by frame.

    Frame ``index`` uses the random stream ``default_rng([seed, index])``, so any frame can be
    rendered alone (for example by a node, on demand) and equals the same frame of a batch.
    """

    def __init__(self, config: CameraConfig | None = None, seed: int = 0):
        """Precompute the static scene (plate bands, illumination) for ``config``."""
        self.config = CameraConfig() if config is None else config
        self.seed = int(seed)
        cfg = self.config
        self._cols = np.arange(cfg.width, dtype=float)
        self._rows = np.arange(cfg.height, dtype=float)
        sigma = cfg.psf_sigma_px
        bands = {}
        for plate in PLATES:
            top, bottom = getattr(cfg, f'{plate}_band')
            top, bottom = top * cfg.height - 0.5, bottom * cfg.height - 0.5
            bands[plate] = box_profile(self._rows, [(top + bottom) / 2], (bottom - top) / 2,
                                       sigma)
        plate_rows = bands['slider'] + bands['stator']
        gap_level = cfg.infrared_gap_level if cfg.infrared else cfg.gap_level
        self._base_rows = cfg.plate_level * plate_rows + gap_level * (1.0 - plate_rows)
        gx, gy = cfg.illumination_gradient
        xn = self._cols / max(cfg.width - 1, 1) - 0.5
        yn = self._rows / max(cfg.height - 1, 1) - 0.5
        radius2 = (xn[None, :] ** 2 + yn[:, None] ** 2) / 0.5
        self._illumination = ((1.0 + gy * yn)[:, None] * (1.0 + gx * xn)[None, :]
                              * (1.0 - cfg.vignetting * radius2))
        self._mark_rows = {}
        for plate in PLATES:
            row = cfg.mark_row_px(plate)
            terms = []
            for half_w, half_h, sign in cfg.mark_rectangles_px():
                lo = max(int(math.floor(row - half_h - 6 * sigma - 2)), 0)
                hi = min(int(math.ceil(row + half_h + 6 * sigma + 2)) + 1, cfg.height)
                profile = box_profile(self._rows[lo:hi], [row], half_h, sigma)
                terms.append((lo, hi, profile, half_w, sign))
            self._mark_rows[plate] = terms
        ball_top, ball_bottom = cfg.slider_band[1], cfg.stator_band[0]
        self._ball_row = (ball_top + ball_bottom) / 2.0 * cfg.height - 0.5

    def exposure_times(self, index: int, stator: Motion, slider: Motion) -> np.ndarray:
        """Return the sub-exposure sample times (s) of frame ``index`` for these motions.

        Midpoints of equal sub-intervals, enough that no mark moves more than
        ``max_substep_px`` between samples (at least 16).
        """
        cfg = self.config
        start = cfg.start_time + index / cfg.fps
        probe = start + cfg.exposure * (np.arange(_SHAPE_PROBE_STEPS) + 0.5) / _SHAPE_PROBE_STEPS
        path = 0.0
        for motion in (stator, slider):
            x = motion(probe) / cfg.meters_per_pixel
            path = max(path, float(np.abs(np.diff(x)).sum()) * _SHAPE_PROBE_STEPS
                       / max(_SHAPE_PROBE_STEPS - 1, 1))
        n = max(_MIN_SUBSTEPS, int(math.ceil(path / cfg.max_substep_px)))
        return start + cfg.exposure * (np.arange(n) + 0.5) / n

    def expected_frame(self, index: int, stator: Any,
                       slider: Any) -> tuple[np.ndarray, FrameTruth]:
        """Return the noiseless frame (float, DN, before clipping) and its FrameTruth.

        ``stator`` and ``slider`` are motion specifications (see ``as_motion``).
        """
        cfg = self.config
        stator, slider = as_motion(stator), as_motion(slider)
        times = self.exposure_times(index, stator, slider)
        t_mid = float(cfg.frame_time(index))
        scene = np.repeat(self._base_rows[:, None], cfg.width, axis=1)
        truth: dict[str, Any] = {}
        centers = {}
        for plate, motion in (('slider', slider), ('stator', stator)):
            x = motion(times)
            px = cfg.to_px(plate, x)
            centers[plate] = x
            truth[f'{plate}_mid'] = float(motion(np.array([t_mid]))[0])
            truth[f'{plate}_mean'] = float(x.mean())
            truth[f'{plate}_span_px'] = (float(px.min()), float(px.max()))
            self._draw_mark(scene, plate, px)
        if cfg.infrared:
            balls = (centers['slider'] + centers['stator']) / 2.0
            truth['balls_mid'] = (truth['slider_mid'] + truth['stator_mid']) / 2.0
            truth['balls_mean'] = float(balls.mean())
            self._draw_balls(scene, cfg.ball_origin_px() + balls / cfg.meters_per_pixel)
        frame = scene * self._illumination
        return frame, FrameTruth(index=int(index), time=t_mid, **truth)

    def _draw_mark(self, scene, plate, px):
        cfg = self.config
        sigma = cfg.psf_sigma_px
        amplitude = cfg.mark_depth * cfg.plate_level
        for lo, hi, row_profile, half_w, sign in self._mark_rows[plate]:
            left = max(int(math.floor(px.min() - half_w - 6 * sigma - 2)), 0)
            right = min(int(math.ceil(px.max() + half_w + 6 * sigma + 2)) + 1, cfg.width)
            if right <= left:
                continue
            col_profile = box_profile(self._cols[left:right], px, half_w, sigma)
            scene[lo:hi, left:right] -= (sign * amplitude) * np.outer(row_profile, col_profile)

    def _draw_balls(self, scene, train_px):
        cfg = self.config
        radius = cfg.ball_diameter / cfg.meters_per_pixel / 2.0
        pitch = cfg.ball_pitch / cfg.meters_per_pixel
        sigma = math.sqrt(cfg.psf_sigma_px ** 2 + 1.0 / 12.0)
        path = float(np.abs(np.diff(train_px)).sum()) if train_px.size > 1 else 0.0
        n = min(max(_MIN_SUBSTEPS, int(math.ceil(path))), train_px.size)
        samples = train_px[((np.arange(n) + 0.5) * train_px.size / n).astype(int)]
        lo = max(int(math.floor(self._ball_row - radius - 4 * sigma - 1)), 0)
        hi = min(int(math.ceil(self._ball_row + radius + 4 * sigma + 1)) + 1, cfg.height)
        dy2 = (self._rows[lo:hi, None] - self._ball_row) ** 2
        k_lo = int(math.floor((-radius - samples.max()) / pitch)) - 1
        k_hi = int(math.ceil((cfg.width + radius - samples.min()) / pitch)) + 1
        for k in range(k_lo, k_hi + 1):
            centers = samples + k * pitch
            left = max(int(math.floor(centers.min() - radius - 4 * sigma - 1)), 0)
            right = min(int(math.ceil(centers.max() + radius + 4 * sigma + 1)) + 1, cfg.width)
            if right <= left:
                continue
            dx = self._cols[None, left:right, None] - centers[None, None, :]
            distance = np.sqrt(dx ** 2 + dy2[:, :, None])
            cover = ndtr((radius - distance) / sigma).mean(axis=2)
            patch = scene[lo:hi, left:right]
            patch += cover * (cfg.ball_level - patch)

    def add_noise(self, expected: np.ndarray, index: int) -> np.ndarray:
        """Return the mono8 frame for a noiseless ``expected`` frame: noise, rounding, clipping.

        Uses the random stream of frame ``index``. Shot noise is Poisson where fewer than
        ``POISSON_LIMIT`` electrons are expected and its Gaussian limit elsewhere (combined with
        the Gaussian read noise in one draw).
        """
        cfg = self.config
        rng = np.random.default_rng([self.seed, int(index)])
        mean = np.clip(expected, 0.0, None)
        gain = cfg.electrons_per_dn
        dn = mean + np.sqrt(mean / gain + cfg.read_noise_dn ** 2) * rng.standard_normal(
            mean.shape)
        low = mean * gain < POISSON_LIMIT
        if np.any(low):
            electrons = rng.poisson(mean[low] * gain)
            dn[low] = electrons / gain + cfg.read_noise_dn * rng.standard_normal(electrons.size)
        return np.clip(np.rint(dn), 0, 255).astype(np.uint8)

    def render_frame(self, index: int, stator: Any, slider: Any,
                     noise: bool = True) -> tuple[np.ndarray, FrameTruth]:
        """Return frame ``index`` (H x W uint8) and its FrameTruth.

        With ``noise=False`` the noiseless frame is only rounded and clipped.
        """
        expected, truth = self.expected_frame(index, stator, slider)
        if noise:
            return self.add_noise(expected, index), truth
        return np.clip(np.rint(expected), 0, 255).astype(np.uint8), truth

    def suggest_roi(self, plate: str, span_px: tuple[float, float],
                    margin_px: float = 24) -> tuple[int, int, int, int]:
        """Return an ROI (x, y, w, h) containing the mark of ``plate`` for centres in ``span_px``.

        ``span_px`` is the (min, max) image column of the mark centre; the ROI adds the mark's
        half size and the PSF on every side, plus ``margin_px`` along x (plain plate on both
        sides of the mark, which the tracker needs for its baseline) and a quarter of that
        along y, clipped to the frame.
        """
        cfg = self.config
        half_w, half_h = cfg.mark_half_extent_px()
        pad = 3.0 * cfg.psf_sigma_px + margin_px
        row = cfg.mark_row_px(plate)
        x0 = max(int(math.floor(min(span_px) - half_w - pad)), 0)
        x1 = min(int(math.ceil(max(span_px) + half_w + pad)) + 1, cfg.width)
        pad_y = 3.0 * cfg.psf_sigma_px + margin_px / 4.0
        y0 = max(int(math.floor(row - half_h - pad_y)), 0)
        y1 = min(int(math.ceil(row + half_h + pad_y)) + 1, cfg.height)
        if x1 <= x0 or y1 <= y0:
            raise InputError(f'the {plate} mark never enters the frame')
        return (x0, y0, x1 - x0, y1 - y0)


def render_frames(stator_motion: Any, slider_motion: Any, n_frames: int,
                  config: CameraConfig | None = None, seed: int = 0,
                  noise: bool = True) -> RenderedVideo:
    """Render ``n_frames`` frames of the two marks and return a RenderedVideo.

    ``stator_motion`` and ``slider_motion`` map time (s, array) to position (m): callables,
    ``(times, positions)`` sample arrays or numbers (see ``as_motion``). Slow drift, harmonics
    and the like belong in these functions. Frame n is exposed from
    ``start_time + n / fps`` for ``exposure`` seconds and stamped at mid-exposure. Frame n uses
    the random stream ``(seed, n)``; ``noise=False`` only rounds and clips. The suggested ROIs
    contain each mark over its whole travel plus plain plate on both sides. In infrared mode
    ``truth.balls`` is the ball train (one ball at ``ball_origin_px() + x / m_per_px``, the
    others every ``ball_pitch``).
    """
    if int(n_frames) != n_frames or n_frames < 1:
        raise InputError(f'n_frames must be a positive integer, got {n_frames!r}')
    camera = SyntheticCamera(config, seed)
    stator, slider = as_motion(stator_motion), as_motion(slider_motion)
    cfg = camera.config
    frames = np.empty((int(n_frames), cfg.height, cfg.width), dtype=np.uint8)
    rows = []
    for index in range(int(n_frames)):
        frames[index], frame_truth = camera.render_frame(index, stator, slider, noise=noise)
        rows.append(frame_truth)
    marks: dict[str, MarkTruth] = {}
    for plate in PLATES + (('balls',) if cfg.infrared else ()):
        mid = np.array([getattr(r, f'{plate}_mid') for r in rows])
        mean = np.array([getattr(r, f'{plate}_mean') for r in rows])
        if plate == 'balls':
            origin = cfg.ball_origin_px()
            span = (float(np.min(origin + mean / cfg.meters_per_pixel)),
                    float(np.max(origin + mean / cfg.meters_per_pixel)))
            marks[plate] = MarkTruth(mid, mean, origin + mid / cfg.meters_per_pixel,
                                     origin + mean / cfg.meters_per_pixel, span)
            continue
        spans = np.array([getattr(r, f'{plate}_span_px') for r in rows])
        marks[plate] = MarkTruth(mid, mean, cfg.to_px(plate, mid), cfg.to_px(plate, mean),
                                 (float(spans[:, 0].min()), float(spans[:, 1].max())))
    truth = GroundTruth(time=np.array([r.time for r in rows]), **marks)
    rois = {plate: camera.suggest_roi(plate, marks[plate].span_px) for plate in PLATES}
    return RenderedVideo(frames=frames, truth=truth, rois=rois, config=cfg)
