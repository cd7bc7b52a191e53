"""Hard synthetic scenes for the tracker tests, rendered exactly, with known truth.

Independent of core.camera's scene (only its exact box integral is reused): two plates, each
with a mark of any polarity and shape ('bar', 'cross', 'pair' of bars, 'blob', an asymmetric
'ell': an L of strokes ``stroke`` wide, ``width`` x ``height``, centred on its bounding box),
moving along x;
optional surface texture that moves with its plate, a static texture (fixed in the image:
light added, ``static_texture`` in DN, or a transmission, ``static_transmission`` relative),
illumination flicker, a soft shadow sweeping over the plates, a camera's dark offset and gamma,
occlusions, a tool held beside a mark's path, 8- or 16-bit output. Everything is analytic:
the textures are sums of plane waves, so motion blur, pixel integration and the optical PSF
are exact factors per wave; the marks are boxes or Gaussians integrated over each pixel and
averaged over the sub-exposure positions. Truth is the exposure-averaged mark column (px).
"""

from dataclasses import dataclass, field
import math

import numpy as np
from scipy.special import ndtr

from microball_ros.core.camera import box_profile


@dataclass(frozen=True)
class PlateSpec:
    """One plate and its mark; ``contrast`` in DN (negative: a dark mark), sizes in px."""

    band: tuple = (20.0, 190.0)
    shape: str = 'bar'
    contrast: float = -100.0
    width: float = 20.0
    height: float = 50.0
    stroke: float = 6.0
    gap: float = 14.0
    texture: float = 0.0
    level: float = 170.0
    amplitude: float = 240.0
    frequency: float = 2.95
    phase: float = 0.0
    origin: float = 360.0

    def motion(self, t):
        """Return the mark centre column at times ``t`` (s)."""
        return self.origin + self.amplitude * np.sin(
            2 * math.pi * self.frequency * np.asarray(t, dtype=float) + self.phase)


@dataclass(frozen=True)
class SceneSpec:
    """The whole frame: plates, static texture, flicker, noise, bit depth."""

    plates: dict = field(default_factory=lambda: {
        'slider': PlateSpec(band=(20.0, 190.0)),
        'stator': PlateSpec(band=(290.0, 460.0), phase=1.0)})
    width: int = 720
    height: int = 480
    fps: float = 30.0
    exposure: float = 1.0 / 60.0
    gap_level: float = 40.0
    static_texture: float = 0.0
    static_transmission: float = 0.0
    flicker: float = 0.0
    gradient: tuple = (0.2, 0.1)
    vignette: float = 0.0  # the light falls off by this much from the middle to the corners
    drift: float = 0.0  # the x gradient goes from gradient[0] - drift to + drift over the video
    psf: float = 0.9
    gain: float = 20.0
    read_noise: float = 1.0
    bits: int = 8
    black: float = 0.0  # the camera's dark offset, DN (added to every pixel before noise)
    gamma: float = 1.0  # the camera's encoding: 255 (dn / 255) ** (1 / gamma), after the noise
    # A soft shadow band sweeping along x: (first frame, last frame, x at first, x at last,
    # width, penumbra, depth, tilt in degrees from the vertical), centred on the frame's
    # middle row; the light is 1 - depth * smoothstep((width / 2 + penumbra - d) /
    # (2 penumbra)), d the distance from the band's centre line.
    shadow: tuple = ()


def _waves(rng, n, amplitude, shortest=3.0, longest=40.0):
    wavelength = np.exp(rng.uniform(math.log(shortest), math.log(longest), n))
    angle = rng.uniform(0, math.pi, n)
    k = 2 * math.pi / wavelength
    kx, ky = k * np.cos(angle), k * np.sin(angle)
    phase = rng.uniform(0, 2 * math.pi, n)
    return kx, ky, phase, np.full(n, amplitude * math.sqrt(2.0 / n))


def _texture(cols, rows, waves, shifts, psf):
    """Sum of plane waves, pixel-integrated, PSF-blurred, averaged over x shifts."""
    kx, ky, phase, amp = waves
    factor = (np.sinc(kx / (2 * math.pi)) * np.sinc(ky / (2 * math.pi))
              * np.exp(-0.5 * psf ** 2 * (kx ** 2 + ky ** 2)) * amp)
    motion = np.exp(-1j * np.outer(kx, shifts)).mean(axis=1)
    ex = np.exp(1j * (np.outer(kx, cols) + phase[:, None])) * (factor * motion)[:, None]
    ey = np.exp(1j * np.outer(ky, rows))
    return np.real(ey.T @ ex)


def _gauss_profile(pixels, centers, sigma):
    edges = np.append(pixels - 0.5, pixels[-1] + 0.5)
    cdf = ndtr((edges[None, :] - np.asarray(centers)[:, None]) / sigma).mean(axis=0)
    return np.diff(cdf)


def _mark(spec, cols, rows, centers, psf):
    """Return the mark's image (DN) over the band: signed sum of separable terms."""
    row = (spec.band[0] + spec.band[1]) / 2.0
    image = np.zeros((rows.size, cols.size))
    if spec.shape == 'blob':
        sigma = math.hypot(spec.width / 2.0, psf)
        return spec.contrast * np.outer(_gauss_profile(rows, [row], sigma),
                                        _gauss_profile(cols, centers, sigma)) * (
            2 * math.pi * sigma * sigma)
    if spec.shape == 'bar':
        terms = [(0.0, spec.width / 2, spec.height / 2, 1.0)]
    elif spec.shape == 'pair':
        half = spec.gap / 2 + spec.stroke / 2
        terms = [(-half, spec.stroke / 2, spec.height / 2, 1.0),
                 (half, spec.stroke / 2, spec.height / 2, 1.0)]
    elif spec.shape == 'cross':
        s = spec.stroke / 2
        terms = [(0.0, s, spec.height / 2, 1.0), (0.0, spec.width / 2, s, 1.0),
                 (0.0, s, s, -1.0)]
    elif spec.shape == 'ell':  # the upright stroke on the left, the foot at the bottom
        s = spec.stroke / 2
        left, foot = -spec.width / 2 + s, spec.height / 2 - s
        terms = [(left, s, spec.height / 2, 1.0), (0.0, spec.width / 2, s, 1.0, foot),
                 (left, s, s, -1.0, foot)]
    else:
        raise ValueError(spec.shape)
    for offset, half_w, half_h, sign, *down in terms:
        image += sign * np.outer(box_profile(rows, [row + sum(down)], half_h, psf),
                                 box_profile(cols, np.asarray(centers) + offset, half_w, psf))
    return spec.contrast * image


@dataclass
class Scene:
    """Rendered frames, the exposure-mean truth per plate (px) and suggested ROIs.

    Truth is the centre of the mark's bounding box; an 'ell''s contrast centroid is
    ``ell_centroid`` px from it.
    """

    frames: np.ndarray
    truth: dict
    rois: dict
    spec: SceneSpec
    expected: list


def render(spec, n_frames, seed=0, covers=(), keep_expected=False, discs=(), passing=(),
           tools=()):
    """Render ``n_frames`` frames; ``covers`` = [(plate, first, last)] frames hiding a mark.

    A cover paints the plate's own level (times the illumination) over the mark's whole
    band around its position, as a particle or a shadow would, so nothing of it is seen.
    ``discs`` = [(plate, first, last, dx, dy, radius, level)]: a disc of ``level`` DN (a
    ball) drawn at (dx, dy) px from the mark's exposure-mean centre, over the mark.
    ``passing`` = [(plate, first, last, x_first, x_last, radius, depth)]: a particle of its
    own, a disc in the mark's rows moving from column x_first (frame first) to x_last (frame
    last) at a steady speed, that lets 1 - depth of the light through.
    ``tools`` = [(plate, first, last, left, right, level, tilt)]: a tool held still over the
    plate's whole band in frames first..last, columns left..right at the band's middle row,
    its edges tilted ``tilt`` degrees from the vertical, of ``level`` DN, drawn over the mark
    (edges blurred by the PSF).
    """
    rng = np.random.default_rng(seed)
    cols = np.arange(spec.width, dtype=float)
    rows = np.arange(spec.height, dtype=float)
    static_waves = _waves(rng, 60, spec.static_texture, 2.5, 25.0)
    plate_waves = {name: _waves(rng, 60, p.texture) for name, p in spec.plates.items()}
    xn = cols / (spec.width - 1) - 0.5
    yn = rows / (spec.height - 1) - 0.5
    light = np.outer(1 + spec.gradient[1] * yn, 1 + spec.gradient[0] * xn)
    light *= 1.0 - 2.0 * spec.vignette * (xn[None, :] ** 2 + yn[:, None] ** 2)
    if spec.static_transmission:
        # Its own random stream: the other parts of a scene render as without it.
        window = _waves(np.random.default_rng(seed + 7919), 60, spec.static_transmission,
                        2.5, 25.0)
        light = light * (1 + _texture(cols, rows, window, np.zeros(1), spec.psf))
    base = np.full((spec.height, spec.width), spec.gap_level)
    for plate in spec.plates.values():
        top, bottom = (int(v) for v in plate.band)
        base[top:bottom] = plate.level
    if spec.static_texture:
        base += _texture(cols, rows, static_waves, np.zeros(1), spec.psf)
    frames, expected = [], []
    truth = {name: np.empty(n_frames) for name in spec.plates}
    flicker = 1 + spec.flicker * rng.uniform(-1, 1, n_frames)
    scale = 257.0 if spec.bits == 16 else 1.0
    for n in range(n_frames):
        times = (n + (np.arange(64) + 0.5) / 64 * spec.exposure * spec.fps) / spec.fps
        scene = base.copy()
        for name, plate in spec.plates.items():
            centers = plate.motion(times)
            truth[name][n] = centers.mean()
            top, bottom = (int(v) for v in plate.band)
            band = np.s_[top:bottom]
            if plate.texture:
                scene[band] += _texture(cols, rows[band], plate_waves[name],
                                        centers - plate.origin, spec.psf)
            scene[band] += _mark(plate, cols, rows[band], centers, spec.psf)
            for cover_plate, first, last in covers:
                if cover_plate == name and first <= n <= last:
                    c = int(round(truth[name][n]))
                    left, right = max(c - 60, 0), min(c + 60, spec.width)
                    scene[top:bottom, left:right] = plate.level
            for disc_plate, first, last, dx, dy, radius, level in discs:
                if disc_plate == name and first <= n <= last:
                    cx = truth[name][n] + dx
                    cy = (plate.band[0] + plate.band[1]) / 2.0 + dy
                    inside = np.clip(radius + 0.5 - np.hypot(cols[None, :] - cx,
                                                             rows[band][:, None] - cy), 0, 1)
                    scene[band] += inside * (level - scene[band])
        for name, first, last, left, right, level, tilt in tools:
            if not first <= n <= last:
                continue
            top, bottom = (int(v) for v in spec.plates[name].band)
            shift = math.tan(math.radians(tilt)) * (rows[top:bottom] - (top + bottom) / 2.0)
            x = cols[None, :] - shift[:, None]
            inside = ndtr((x - left) / spec.psf) - ndtr((x - right) / spec.psf)
            scene[top:bottom] += inside * (level - scene[top:bottom])
        for name, first, last, x_first, x_last, radius, depth in passing:
            if first <= n <= last:
                top, bottom = (int(v) for v in spec.plates[name].band)
                cx = x_first + (x_last - x_first) * (n - first) / max(last - first, 1)
                inside = np.clip(radius + 0.5 - np.hypot(cols[None, :] - cx,
                                                         rows[top:bottom][:, None]
                                                         - (top + bottom) / 2.0), 0, 1)
                scene[top:bottom] *= 1.0 - depth * inside
        lit = light
        if spec.drift:
            change = spec.drift * (2.0 * n / max(n_frames - 1, 1) - 1.0)
            lit = light * (1 + change * xn)[None, :]
        if spec.shadow:
            lit = lit * shadow_light(spec, n, cols, rows)
        mean = np.clip(scene * lit * flicker[n], 0, None)
        if keep_expected:
            expected.append(mean + spec.black)
        noise = np.sqrt(mean / spec.gain + spec.read_noise ** 2)
        dn = spec.black + mean + noise * rng.standard_normal(mean.shape)
        if spec.gamma != 1.0:
            dn = 255.0 * (np.clip(dn, 0.0, 255.0) / 255.0) ** (1.0 / spec.gamma)
        top_value = 65535 if spec.bits == 16 else 255
        dtype = np.uint16 if spec.bits == 16 else np.uint8
        frames.append(np.clip(np.rint(dn * scale), 0, top_value).astype(dtype))
    rois = {}
    for name, plate in spec.plates.items():
        half = max(plate.width, 2 * plate.gap + plate.stroke) / 2 + 30
        x0 = max(int(plate.origin - abs(plate.amplitude) - half), 0)
        x1 = min(int(plate.origin + abs(plate.amplitude) + half) + 1, spec.width)
        row = (plate.band[0] + plate.band[1]) / 2
        h = plate.height / 2 + 10
        rois[name] = (x0, int(row - h), x1 - x0, int(2 * h))
    return Scene(np.array(frames), truth, rois, spec, expected)


def shadow_light(spec, n, cols, rows):
    """Return the light ``spec.shadow`` lets through in frame ``n`` (rows x cols, 1 = none)."""
    first, last, x_first, x_last, width, penumbra, depth, tilt = spec.shadow
    at = x_first + (x_last - x_first) * np.clip((n - first) / max(last - first, 1), 0, 1)
    if not first <= n <= last:
        return np.ones((rows.size, cols.size))
    angle = math.radians(tilt)
    middle = (spec.height - 1) / 2.0
    d = np.abs((cols[None, :] - at) * math.cos(angle) + (rows[:, None] - middle)
               * math.sin(angle))
    t = np.clip((width / 2 + penumbra - d) / (2 * penumbra), 0, 1)
    return 1 - depth * t * t * (3 - 2 * t)


def ell_centroid(spec: PlateSpec) -> float:
    """Return the x of an 'ell''s contrast centroid from its bounding box's centre (px).

    The upright stroke (area ``stroke height``) at ``-width/2 + stroke/2``, the foot
    (``width stroke``) at 0, their overlap (``stroke^2``) counted once.
    """
    s, w, h = spec.stroke, spec.width, spec.height
    left = -w / 2 + s / 2
    return left * (s * h - s * s) / (s * h + w * s - s * s)


def plates(**changes):
    """Return the two default plates with ``changes`` applied to both."""
    from dataclasses import replace

    return {'slider': replace(PlateSpec(band=(20.0, 190.0)), **changes),
            'stator': replace(PlateSpec(band=(290.0, 460.0), phase=1.0), **changes)}
