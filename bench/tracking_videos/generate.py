"""Render the tracking video set: a bearing seen from above, with per-frame ground truth.

Run: ``python bench/tracking_videos/generate.py [--out DIR] [--quick] [--cases a,b,...]``.
Independent of the project's renderer and tracker (numpy, scipy and OpenCV only).

Scene (720 x 480 px, 5.88 um/px): a fixed rig in the top and bottom bands (rows 0-47 and
432-479), the stator plate in rows 48-239 and the slider plate in rows 240-431, both wider
than the view and moving along x only. Each plate carries one mark (stator mark centred on
row 144, slider mark on row 336, both at column 360 at rest). Stator: -1.2 mm cos(w t),
w = 2 pi 2.95 Hz; slider: -1.1 mm cos(w t - 0.41), smaller and lagging.

Rendering is exact for the scene as defined: a plate is piecewise constant on cells of 1/4 px
in x (one pixel row in y, area-averaged over 4 sub-rows), and a pixel of a frame is the plate
integrated over the pixel's area and over the exposure, the motion taken piecewise linear
between 256 instants of the exposure. For a pure translation that is one convolution of each
plate row with a kernel computed in closed form (the motion's position distribution convolved
with the pixel box), so there is no sub-sample ghosting at any blur length. Occluders (a ball,
a shadow band) move independently and are composited at 64 instants of the exposure. Then a
fixed illumination field (vignetting, and in the textured case a fixed dust pattern), per-frame
flicker, optics blur (Gaussian, defocus disc), Poisson-Gaussian noise and quantisation.

Truth per frame: the mark's x at image column coordinates (column k is the centre of pixel k),
averaged over the exposure (what a blurred frame encodes), stamped at mid-exposure
``n / fps + exposure / 2``; ``*_visible`` is the fraction of the mark not covered (1 clear, 0
fully covered, then its x cell is empty); ``*_crb_px`` the Cramer-Rao bound of x from the ROI
pixels (the plate shift is the only unknown; occluders are held fixed at their exposure mean).
"""

import argparse
from dataclasses import asdict, dataclass, replace
import json
import math
import os
import sys

import cv2
import numpy as np
from scipy.ndimage import gaussian_filter
from scipy.signal import fftconvolve

WIDTH, HEIGHT = 720, 480
METERS_PER_PIXEL = 5.88e-6
OMEGA = 2 * math.pi * 2.95
STATOR_AMPLITUDE = 1.2e-3 / METERS_PER_PIXEL   # px
SLIDER_AMPLITUDE = 1.1e-3 / METERS_PER_PIXEL   # px
SLIDER_LAG = 0.41                              # rad
REST_X = 360.0
FINE = 4                                       # plate cells per pixel in x
SEGMENTS = 256                                 # piecewise-linear motion per exposure
OCCLUDER_STEPS = 64
ROI_MARGIN = 24
BANDS = {'top': (0, 48), 'stator': (48, 240), 'slider': (240, 432), 'bottom': (432, 480)}
MARK_ROW = {'stator': 144.0, 'slider': 336.0}
# mark half extents (x, y) in px, for the ROIs
MARK_HALF = {'rect': (8.5, 21.0), 'cross': (20.0, 20.0), 'bars': (13.0, 21.0),
             'blob': (15.0, 15.0)}


@dataclass(frozen=True)
class Case:
    """One video of the set: what it models and how it is rendered."""

    name: str
    description: str
    category: str = 'plain'         # plain | textured | bright (which RMS target applies)
    mark: str = 'rect'              # rect | blob | cross | bars
    polarity: str = 'dark'
    plate: str = 'plain'            # plain | textured | speckle
    contrast: float = 0.6           # dark marks: relative depth
    fps: float = 30.0
    exposure_fraction: float = 0.5  # of the frame period
    duration: float = 8.0
    bits: int = 8
    full_well: float = 6000.0       # electrons at full scale
    read_noise: float = 12.0        # electrons
    optics_sigma: float = 0.8       # px, Gaussian
    defocus_radius: float = 0.0     # px, disc
    flicker: float = 0.0            # per-frame gain uniform in 1 +- flicker
    occlusion: str = ''             # '' | partial | total
    texture_std: float = 0.05       # moving texture ('textured' plate): relative std
    speckle_depth: float = 0.4      # speckle plate: 1 - depth + depth * speckle
    static: float = 0.0             # static window pattern over the view: relative std
    gamma: float = 1.0              # the camera's encoding: full (dn / full) ** (1 / gamma)
    seed: int = 1

    @property
    def exposure(self):
        """Exposure time (s)."""
        return self.exposure_fraction / self.fps

    @property
    def n_frames(self):
        """Number of frames."""
        return int(round(self.duration * self.fps))


CASES = [
    Case('baseline', 'dark rectangle (100 x 250 um) on a plain plate, 30 fps, 1/60 s'),
    Case('bright_blob', 'IR-lit: bright Gaussian blob (sigma 5 px) on a dark plate',
         category='bright', mark='blob', polarity='bright'),
    Case('bright_rect', 'bright rectangle on a dark plate', category='bright',
         polarity='bright'),
    Case('cross', 'dark cross (40 px arms, 6 px thick) on a plain plate', mark='cross'),
    Case('bars', 'pair of dark bars (6 px wide, 20 px apart) on a plain plate', mark='bars'),
    Case('textured', 'dark rectangle on a plate with a moving random texture (std 5 %, '
         'grain 3 px), plus a fixed textured rig and a fixed dust pattern over the view',
         category='textured', plate='textured'),
    Case('speckle', 'dark rectangle on a plate covered in fine high-contrast speckle',
         category='textured', plate='speckle'),
    Case('flicker', 'baseline with illumination flicker, gain uniform in 1 +- 0.2 per frame',
         flicker=0.2),
    Case('low_contrast', 'dark rectangle 5 % deep, 16-bit PNG frames', contrast=0.05, bits=16,
         full_well=20000.0, read_noise=8.0),
    Case('partial_occlusion', 'a steel ball (48 px) rolls across part of each mark '
         '(stator frames 100-112, slider 170-182), covering up to about half of it',
         occlusion='partial'),
    Case('total_occlusion', 'a dark shadow band covers the whole stator ROI for ~10 frames '
         '(from frame 120): the stator mark has no position there', occlusion='total'),
    Case('defocus', 'baseline with a defocus disc of radius 5 px', defocus_radius=5.0),
    Case('heavy_noise', 'baseline with 600 e- full well and 20 e- read noise (~12 DN)',
         full_well=600.0, read_noise=20.0),
    Case('static_texture', 'dark rectangle on a plain plate seen through a fixed window '
         'pattern (grains of 1-4 px, 10 % std, multiplicative, plus faint additive scratches) '
         'fixed in the image over the whole view', category='textured', static=0.10),
    Case('static_cross', 'the cross through the fixed window pattern', category='textured',
         mark='cross', static=0.10),
    Case('static_bars', 'the pair of bars through the fixed window pattern',
         category='textured', mark='bars', static=0.10),
    Case('static_bright', 'bright rectangle on a dark plate through the fixed window pattern',
         category='bright', polarity='bright', static=0.10),
    Case('textured_cross', 'the cross on the moving mild texture of the textured case',
         category='textured', mark='cross', plate='textured'),
    Case('textured_bars', 'the pair of bars on the moving mild texture of the textured case',
         category='textured', mark='bars', plate='textured'),
    Case('speckle_mild', 'dark rectangle on a plate with mild speckle (20 % deep)',
         category='textured', plate='speckle', speckle_depth=0.2),
    Case('fps15', 'baseline at 15 fps (exposure half the period)', fps=15.0),
    Case('fps60', 'baseline at 60 fps', fps=60.0),
    Case('fps120', 'baseline at 120 fps', fps=120.0),
    Case('exposure_tenth', 'baseline, exposure a tenth of the frame period (1/300 s)',
         exposure_fraction=0.1),
    Case('exposure_full', 'baseline, exposure the whole frame period (1/30 s)',
         exposure_fraction=1.0),
    Case('textured_full', 'the cross on the moving mild texture, exposure the whole frame '
         'period (1/30 s)', category='textured', mark='cross', plate='textured',
         exposure_fraction=1.0),
    Case('speckle_full', 'the rectangle on fully developed speckle, exposure the whole frame '
         'period (1/30 s)', category='textured', plate='speckle', exposure_fraction=1.0),
    Case('textured_blob', 'a bright Gaussian blob (sigma 5 px) on the moving texture of the '
         'textured case', category='bright', mark='blob', polarity='bright', plate='textured'),
    Case('textured_fps15', 'the textured case at 15 fps (exposure half the period)',
         category='textured', plate='textured', fps=15.0),
    Case('gamma', 'baseline from a camera that encodes with gamma 2.2 (sRGB-like video; '
         "the CRB is the linear video's)", gamma=2.2),
    Case('cross_full', 'the cross on a plain plate, exposure the whole frame period (1/30 s)',
         mark='cross', exposure_fraction=1.0),
    Case('textured_full_seed2', 'textured_full rendered from seed 2 (its texture has a coarse '
         "dark patch on the stator's path)", category='textured', mark='cross',
         plate='textured', exposure_fraction=1.0, seed=2),
    Case('textured_fps15_e07', 'the textured case at 15 fps, 0.7 of the period exposed (no '
         'frame sharp: every frame refused before stop 41)', category='textured',
         plate='textured', fps=15.0, exposure_fraction=0.7),
]
QUICK = ('baseline', 'bright_blob', 'textured', 'total_occlusion', 'exposure_full')


def motion(name):
    """Return (amplitude px, phase rad) of the plate shift s(t) = -amplitude cos(w t + phase)."""
    if name == 'stator':
        return STATOR_AMPLITUDE, 0.0
    return SLIDER_AMPLITUDE, -SLIDER_LAG


def shift(name, t):
    """Plate shift (px) at time(s) t."""
    amplitude, phase = motion(name)
    return -amplitude * np.cos(OMEGA * np.asarray(t) + phase)


def mean_shift(name, start, stop):
    """Exact mean of the plate shift over [start, stop]."""
    amplitude, phase = motion(name)
    return -amplitude * (math.sin(OMEGA * stop + phase) - math.sin(OMEGA * start + phase)) / (
        OMEGA * (stop - start))


def _ramp_integral(z, lo, hi):
    """G(z) = integral of the CDF of uniform[lo, hi] up to z, for arrays of segments."""
    width = hi - lo
    flat = width < 1e-9
    safe = np.where(flat, 1.0, width)
    inside = (z - lo) ** 2 / (2 * safe)
    out = np.where(z <= lo, 0.0, np.where(z >= hi, z - (lo + hi) / 2, inside))
    return np.where(flat, np.maximum(z - lo, 0.0), out)


def kernel(lo, hi):
    """Weights of plate cells for one exposure: motion segments [lo, hi] convolved with a pixel.

    Returns (first grid index j_lo, weights): pixel u takes sum_j w_j P[u*FINE - x0*FINE - j].
    """
    lo = np.asarray(lo, dtype=float)[:, None]
    hi = np.asarray(hi, dtype=float)[:, None]
    j_lo = math.floor((float(lo.min()) - 0.5) * FINE) - 1
    j_hi = math.ceil((float(hi.max()) + 0.5) * FINE) + 2
    v = np.arange(j_lo - 1, j_hi + 1) / FINE
    big_k = (_ramp_integral(v + 0.5, lo, hi) - _ramp_integral(v - 0.5, lo, hi)).mean(axis=0)
    return j_lo, np.diff(big_k)


class Plate:
    """One plate in plate coordinates: rows x fine cells, rendered at any motion."""

    def __init__(self, values, x0):
        self.x0 = x0
        self.unique, self.inverse = np.unique(values, axis=0, return_inverse=True)
        self.inverse = self.inverse.ravel()

    def render(self, lo, hi):
        """Image rows (rows x WIDTH) for motion segments lo[k]..hi[k] (equal durations)."""
        j_lo, weights = kernel(lo, hi)
        full = fftconvolve(self.unique, weights[None, :], axes=1)
        columns = np.arange(WIDTH) * FINE - self.x0 * FINE - j_lo
        return full[:, columns][self.inverse]


def mark_coverage(mark, dx, dy):
    """Mark coverage (0..1) at offsets dx (fine x) and dy (sub-rows) from its centre."""
    if mark == 'rect':
        return ((np.abs(dx) <= 8.5) & (np.abs(dy) <= 21)).astype(float)
    if mark == 'cross':
        return (((np.abs(dx) <= 3) & (np.abs(dy) <= 20))
                | ((np.abs(dx) <= 20) & (np.abs(dy) <= 3))).astype(float)
    if mark == 'bars':
        return ((np.abs(np.abs(dx) - 10) <= 3) & (np.abs(dy) <= 21)).astype(float)
    return np.exp(-(dx ** 2 + dy ** 2) / (2 * 5.0 ** 2))


def build_plates(case, rng):
    """Return {name: (Plate with texture and mark, Plate of the mark coverage only)}."""
    plates = {}
    for name in ('stator', 'slider'):
        amplitude, _ = motion(name)
        x0 = -int(math.ceil(amplitude)) - 16
        x1 = WIDTH + int(math.ceil(amplitude)) + 16
        top, bottom = BANDS[name]
        xs = x0 + (np.arange((x1 - x0) * FINE) + 0.5) / FINE
        sub = top + (np.arange((bottom - top) * 4) + 0.5) / 4 - 0.5
        cover = mark_coverage(case.mark, xs[None, :] - REST_X, sub[:, None] - MARK_ROW[name])
        cover = cover.reshape(bottom - top, 4, -1).mean(axis=1)
        level = (0.62 if name == 'stator' else 0.70) if case.polarity == 'dark' else (
            0.15 if name == 'stator' else 0.18)
        texture = np.ones_like(cover)
        if case.plate == 'textured':
            noise = gaussian_filter(rng.standard_normal(cover.shape), (3.0, 3.0 * FINE))
            texture = 1 + case.texture_std * noise / noise.std()
        elif case.plate == 'speckle':
            field = (gaussian_filter(rng.standard_normal(cover.shape), (0.8, 0.8 * FINE))
                     + 1j * gaussian_filter(rng.standard_normal(cover.shape),
                                            (0.8, 0.8 * FINE)))
            speckle = np.abs(field) ** 2
            texture = 1 - case.speckle_depth + case.speckle_depth * speckle / speckle.mean()
        if case.polarity == 'dark':
            values = level * texture * (1 - case.contrast * cover)
        else:
            values = level * texture + (0.80 - level) * cover
        plates[name] = (Plate(values, x0), Plate(cover, x0))
    return plates


def fixed_fields(case, rng):
    """Return the static parts: rig bands (fraction of full scale), illumination field."""
    background = np.full((HEIGHT, WIDTH), 0.45 if case.polarity == 'dark' else 0.10)
    yy, xx = np.mgrid[0:HEIGHT, 0:WIDTH]
    r2 = ((xx - WIDTH / 2) ** 2 + (yy - HEIGHT / 2) ** 2) / ((WIDTH / 2) ** 2 + (HEIGHT / 2) ** 2)
    light = 1 - 0.10 * r2
    if case.plate == 'textured':
        noise = gaussian_filter(rng.standard_normal((HEIGHT, WIDTH)), 2.0)
        background *= 1 + 0.15 * noise / noise.std()
        dust = gaussian_filter(rng.standard_normal((HEIGHT, WIDTH)), 6.0)
        light *= 1 + 0.03 * dust / dust.std()
    return background, light


def window_pattern(case):
    """Return the static pattern of a window over the view: (multiplicative, additive).

    Fixed in the image (a cover glass between the plates and the camera): grains of about 1, 2
    and 4 px in equal parts, ``case.static`` relative std in all, times the light; plus
    faint straight scratches (1 px wide, 3 % of full scale) added on top. Its own random
    stream, so the other parts of a case render as without it.
    """
    if case.static <= 0:
        return None, None
    rng = np.random.default_rng(case.seed + 1000)
    grains = [gaussian_filter(rng.standard_normal((HEIGHT, WIDTH)), s) for s in (0.5, 1.0, 2.0)]
    grain = sum(g / g.std() for g in grains)
    multiplicative = 1 + case.static * grain / grain.std()
    scratches = np.zeros((HEIGHT, WIDTH))
    yy, xx = np.mgrid[0:HEIGHT, 0:WIDTH]
    for _ in range(12):
        angle = rng.uniform(0, math.pi)
        cx, cy = rng.uniform(0, WIDTH), rng.uniform(0, HEIGHT)
        distance = np.abs((xx - cx) * math.sin(angle) - (yy - cy) * math.cos(angle))
        scratches += np.clip(1.0 - distance, 0, 1)
    return np.clip(multiplicative, 0.5, 1.5), 0.03 * np.clip(scratches, 0, 1)


def optics(image, case):
    """Optics blur: defocus disc (if any) then a Gaussian; both symmetric."""
    if case.defocus_radius > 0:
        r = case.defocus_radius
        n = int(math.ceil(r)) + 1
        yy, xx = np.mgrid[-n:n + 1, -n:n + 1]
        disc = np.clip(r + 0.5 - np.hypot(xx, yy), 0, 1)
        image = cv2.filter2D(image, -1, disc / disc.sum(), borderType=cv2.BORDER_REFLECT)
    if case.optics_sigma > 0:
        image = cv2.GaussianBlur(image, (0, 0), case.optics_sigma,
                                 borderType=cv2.BORDER_REFLECT)
    return image


def occluder_alpha(case, name, t):
    """Occluder coverage (HEIGHT x WIDTH, 0..1) over mark ``name``'s region at time t, or None.

    Returns (alpha, level as fraction of full scale).
    """
    frame = t * case.fps
    yy, xx = np.ogrid[0:HEIGHT, 0:WIDTH]
    if case.occlusion == 'partial':
        start = 100 if name == 'stator' else 170
        if not start - 1 <= frame <= start + 13:
            return None
        cy = MARK_ROW[name] - 90 + 15 * (frame - start)
        cx = REST_X + float(shift(name, t)) + 18
        return np.clip(24.5 - np.hypot(xx - cx, yy - cy), 0, 1), 0.20
    if case.occlusion == 'total' and name == 'stator':
        start, enter, dwell = 120, 4.0, 10.0
        if not start - 1 <= frame <= start + 2 * enter + dwell + 1:
            return None
        f = frame - start
        park, away = MARK_ROW['stator'], -60.0
        if f < enter:
            cy = away + (park - away) * f / enter
        elif f < enter + dwell:
            cy = park
        else:
            cy = park + (away - park) * min(f - enter - dwell, enter) / enter
        return np.clip(45.5 - np.abs(yy - cy), 0, 1) * np.ones((1, WIDTH)), 0.15
    return None


def render_frame(case, plates, background, n, light, gain, window=(None, None)):
    """Noiseless frame n (DN, float) with truth, visible fractions and the CRB inputs.

    ``window``: the static (multiplicative, additive) pattern in front of everything, or Nones.
    """
    full_scale = 2 ** case.bits - 1
    start = n / case.fps
    stop = start + case.exposure
    times = np.linspace(start, stop, SEGMENTS + 1)
    image = background.copy()
    truth, deriv = {}, {}
    for name in ('stator', 'slider'):
        s = shift(name, times)
        lo, hi = np.minimum(s[:-1], s[1:]), np.maximum(s[:-1], s[1:])
        top, bottom = BANDS[name]
        image[top:bottom] = plates[name][0].render(lo, hi)
        delta = 0.02
        plus = plates[name][0].render(lo + delta, hi + delta)
        minus = plates[name][0].render(lo - delta, hi - delta)
        grad = np.zeros_like(image)
        grad[top:bottom] = (plus - minus) / (2 * delta)
        deriv[name] = grad
        truth[name] = REST_X + mean_shift(name, start, stop)
    visible = {'stator': 1.0, 'slider': 1.0}
    steps = start + (np.arange(OCCLUDER_STEPS) + 0.5) / OCCLUDER_STEPS * case.exposure
    for name in ('stator', 'slider'):
        alphas = [occluder_alpha(case, name, t) for t in steps]
        if all(a is None for a in alphas):
            continue
        top, bottom = BANDS[name]
        correction = np.zeros_like(image)
        mean_alpha = np.zeros_like(image)
        seen = []
        for t, item in zip(steps, alphas, strict=True):
            if item is None:
                seen.append(1.0)
                continue
            under = image.copy()
            for other in ('stator', 'slider'):
                s = float(shift(other, t))
                o_top, o_bottom = BANDS[other]
                under[o_top:o_bottom] = plates[other][0].render([s], [s])
            s = float(shift(name, t))
            cover = plates[name][1].render([s], [s])
            alpha, level = item
            correction += alpha * (level - under)
            mean_alpha += alpha
            seen.append(float((cover * (1 - alpha[top:bottom])).sum() / cover.sum()))
        image += correction / OCCLUDER_STEPS
        mean_alpha /= OCCLUDER_STEPS
        visible[name] = float(np.mean(seen))
        for key in deriv:
            deriv[key] *= 1 - mean_alpha
    times_window, plus_window = window
    if times_window is not None:
        light = light * times_window
        image = image + plus_window / light
    image = optics(image * light * gain * full_scale, case)
    deriv = {k: optics(v * light * gain * full_scale, case) for k, v in deriv.items()}
    return image, truth, visible, deriv


def noise_variance(case, mean):
    """Per-pixel variance (DN^2) of the Poisson-Gaussian model, quantisation included."""
    gain = (2 ** case.bits - 1) / case.full_well
    return gain * np.maximum(mean, 0) + (gain * case.read_noise) ** 2 + 1 / 12


def add_noise(case, mean, rng):
    """Poisson shot noise plus Gaussian read noise, quantised to the case's bit depth."""
    full_scale = 2 ** case.bits - 1
    gain = full_scale / case.full_well
    electrons = rng.poisson(np.maximum(mean, 0) / gain) + rng.normal(
        0, case.read_noise, mean.shape)
    dtype = np.uint8 if case.bits == 8 else np.uint16
    dn = electrons * gain
    if case.gamma != 1.0:  # encoded after the noise, as a camera's processing does
        dn = full_scale * (np.clip(dn, 0, full_scale) / full_scale) ** (1.0 / case.gamma)
    return np.clip(np.rint(dn), 0, full_scale).astype(dtype)


def rois(case):
    """ROIs 'X,Y,W,H' covering each mark's whole travel plus a margin."""
    out = {}
    for name in ('slider', 'stator'):
        amplitude, _ = motion(name)
        half_x, half_y = MARK_HALF[case.mark]
        x = int(math.floor(REST_X - amplitude - half_x - ROI_MARGIN))
        w = int(math.ceil(REST_X + amplitude + half_x + ROI_MARGIN)) - x
        y = int(math.floor(MARK_ROW[name] - half_y - ROI_MARGIN))
        h = int(math.ceil(MARK_ROW[name] + half_y + ROI_MARGIN)) - y
        out[name] = (x, y, w, h)
    return out


class Sink:
    """Lossless frame writer: FFV1 .mkv for 8 bits, a folder of 16-bit PNGs otherwise."""

    def __init__(self, case, folder):
        self.case = case
        self.frames = []
        if case.bits == 8:
            self.path = 'video.mkv'
            self.writer = cv2.VideoWriter(os.path.join(folder, self.path),
                                          cv2.VideoWriter_fourcc(*'FFV1'), case.fps,
                                          (WIDTH, HEIGHT), False)
            if not self.writer.isOpened():
                raise SystemExit('this OpenCV build cannot write FFV1 .mkv')
        else:
            self.path = 'frames'
            os.makedirs(os.path.join(folder, self.path), exist_ok=True)
        self.folder = folder

    def write(self, n, frame):
        """Append frame n; keep a checksum sample for the round-trip check."""
        if self.case.bits == 8:
            self.writer.write(frame)
        else:
            cv2.imwrite(os.path.join(self.folder, self.path, f'frame_{n:05d}.png'), frame)
        if n < 3:
            self.frames.append(frame)

    def close(self):
        """Finish and check that the first frames read back bit-exact."""
        if self.case.bits == 8:
            self.writer.release()
            capture = cv2.VideoCapture(os.path.join(self.folder, self.path))
            for expected in self.frames:
                ok, got = capture.read()
                if not ok or not np.array_equal(got[:, :, 0], expected):
                    raise SystemExit(f'{self.case.name}: FFV1 round trip is not lossless')
            capture.release()
        else:
            got = cv2.imread(os.path.join(self.folder, self.path, 'frame_00000.png'),
                             cv2.IMREAD_UNCHANGED)
            if not np.array_equal(got, self.frames[0]):
                raise SystemExit(f'{self.case.name}: PNG round trip is not lossless')


def generate(case, out_dir):
    """Render one case into out_dir/<name>/: the video, truth.csv and case.json."""
    folder = os.path.join(out_dir, case.name)
    os.makedirs(folder, exist_ok=True)
    rng = np.random.default_rng(case.seed)
    plates = build_plates(case, rng)
    background, light = fixed_fields(case, rng)
    window = window_pattern(case)
    gains = 1 + case.flicker * rng.uniform(-1, 1, case.n_frames)
    roi = rois(case)
    sink = Sink(case, folder)
    rows, crb_clear = [], {'slider': [], 'stator': []}
    for n in range(case.n_frames):
        mean, truth, visible, deriv = render_frame(case, plates, background, n, light,
                                                   gains[n], window)
        var = noise_variance(case, mean)
        row = {'frame': n, 'time': n / case.fps + case.exposure / 2}
        crb = {}
        for name in ('slider', 'stator'):
            x, y, w, h = roi[name]
            fisher = float((deriv[name][y:y + h, x:x + w] ** 2 / var[y:y + h, x:x + w]).sum())
            crb[name] = 1 / math.sqrt(fisher) if fisher > 0 else math.inf
            if visible[name] >= 0.999:
                visible[name] = 1.0
                crb_clear[name].append(crb[name])
        for name in ('slider', 'stator'):
            row[f'{name}_x_px'] = truth[name] if visible[name] > 0.001 else None
        for name in ('slider', 'stator'):
            row[f'{name}_visible'] = 0.0 if visible[name] <= 0.001 else visible[name]
        for name in ('slider', 'stator'):
            row[f'{name}_crb_px'] = crb[name] if visible[name] > 0.001 else None
        rows.append(row)
        sink.write(n, add_noise(case, mean, rng))
        if n % 60 == 0:
            print(f'  {case.name}: frame {n}/{case.n_frames}', file=sys.stderr, flush=True)
    sink.close()
    with open(os.path.join(folder, 'truth.csv'), 'w') as f:
        keys = list(rows[0])
        f.write(','.join(keys) + '\n')
        for row in rows:
            f.write(','.join(_cell(row[k]) for k in keys) + '\n')
    info = {
        'name': case.name, 'description': case.description, 'category': case.category,
        'video': sink.path, 'format': 'ffv1-mkv' if case.bits == 8 else 'png16-folder',
        'width': WIDTH, 'height': HEIGHT, 'bits': case.bits, 'fps': case.fps,
        'exposure': case.exposure, 'n_frames': case.n_frames,
        'meters_per_pixel': METERS_PER_PIXEL,
        'rois': {k: ','.join(str(v) for v in r) for k, r in roi.items()},
        'crb_px': {k: float(np.sqrt(np.mean(np.square(v)))) for k, v in crb_clear.items()},
        'crb_note': 'RMS over clear frames of the per-frame bound (truth.csv *_crb_px)',
        'motion': {'stator': {'amplitude_px': STATOR_AMPLITUDE, 'phase_rad': 0.0},
                   'slider': {'amplitude_px': SLIDER_AMPLITUDE, 'phase_rad': -SLIDER_LAG},
                   'law': 'x = 360 - amplitude * cos(2 pi 2.95 t + phase)'},
        'render': asdict(case),
    }
    with open(os.path.join(folder, 'case.json'), 'w') as f:
        json.dump(info, f, indent=1)
    return info


def _cell(value):
    if value is None:
        return ''
    if isinstance(value, int):
        return str(value)
    return f'{value:.6f}' if abs(value) >= 1e-3 or value == 0 else f'{value:.6e}'


def select(names, quick):
    """Return the cases to render, by name (all by default)."""
    if names:
        wanted = [n.strip() for n in names.split(',') if n.strip()]
        known = {c.name: c for c in CASES}
        missing = [n for n in wanted if n not in known]
        if missing:
            raise SystemExit(f'unknown case(s): {", ".join(missing)}; known: '
                             f'{", ".join(known)}')
        return [known[n] for n in wanted]
    return [c for c in CASES if c.name in QUICK] if quick else list(CASES)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--out', default=os.path.join(os.path.dirname(__file__), 'out'))
    parser.add_argument('--quick', action='store_true', help=f'only {", ".join(QUICK)}')
    parser.add_argument('--cases', help='comma-separated case names')
    parser.add_argument('--frames', type=int, help='cap every case at N frames (smoke test)')
    args = parser.parse_args(argv)
    for case in select(args.cases, args.quick):
        if args.frames:
            case = replace(case, duration=min(case.duration, args.frames / case.fps))
        info = generate(case, args.out)
        print(f"{case.name}: {info['n_frames']} frames, CRB px slider "
              f"{info['crb_px']['slider']:.4f} stator {info['crb_px']['stator']:.4f}")


if __name__ == '__main__':
    main()
