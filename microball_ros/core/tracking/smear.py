"""Long motion smears (a slow frame rate, an exposure of most of the frame period).

At 15 frames/s with the whole frame period exposed, the paper's motion smears a mark over up
to half the ROI: the dip of a textured plate's mark is then a long shallow box, and a dip
centroid of it (``priming.first_positions``) is tens of pixels off. What this module gives
core.tracking.plate instead:

``smear_boxes``: per frame the box (centre, length) that best matches the deficit against
the static field (a matched filter of boxes of many lengths, scored by their sum over the
square root of their length, the signal-to-noise ratio of a box of constant depth);
``PeriodicMotion``: a smooth periodic motion (a fundamental and a harmonic, a drift) fitted
robustly to the boxes' centres (the exposure averages), which gives each frame's position
averaged over the exposure and its motion kernel (blur ``L`` and curvature ``Q`` of the path
``s + L u + Q (u^2 - 1/12)`` over the exposure, ``u`` in [-1/2, 1/2]), and, from the three
positions around a frame, the kernel of a frame in the track (``local_kernel``): the sinusoid
of the fitted frequency through them, which a central difference underestimates by a fifth at
five frames per period.
"""

from collections import deque
from collections.abc import Callable
import functools
import math
import statistics
import warnings

import numpy as np
from scipy.optimize import minimize_scalar

from microball_ros.core.tracking.priming import motion_jitter
from microball_ros.core.tracking.profile import light_level
from microball_ros.core.tracking.small_linalg import lstsq, solve
from microball_ros.core.tracking.template import sinusoid_shapes

HARMONICS = 2
OUTLIER_PX = 3.0  # a centre further than this (and 3.5 robust sigmas) from the fit is left out
SMEAR_JITTER = 0.4  # px: a long smear's plate tracking the priming frames less steadily: refused
SMEAR_BIAS = 0.5  # px: ... or registered further than this from the centroid on sharp frames
SMEAR_SHARP = 16.0  # px: a priming frame whose path is shorter is sharp (``smear_verdict``)
# ... and without 3 sharp frames the least smeared of paths up to this serve (stop 41: at 15 fps
# with 0.6-0.8 of the period exposed the sharpest were 13-26 px and every frame was refused)
REGISTER_PATH = 48.0
LONG_BLUR = 0.3  # of the ROI's width: a kernel longer than this is a long smear
# least_smeared: where the centroid finds the mark in under 8 frames, the smear boxes serve if
# their median length is over this much of the ROI (0.3 before stop 39: a textured cross
# smeared up to 116 px, its boxes' median 93 px in a 498 px ROI, then learned no plate)
BOXES_FROM = 0.1
# BlurScale: the fitted over the predicted blur, over the last SCALE_FRAMES frames predicted
# SCALE_LEAST px long or more, from SCALE_FROM of them, within SCALE_RANGE
SCALE_FRAMES, SCALE_LEAST, SCALE_FROM, SCALE_RANGE = 15, 2.0, 5, (0.8, 1.25)
_U = np.linspace(-0.5, 0.5, 33)
_PATH = np.column_stack([np.ones_like(_U), _U, _U * _U - 1.0 / 12.0])


@functools.lru_cache(maxsize=32)
def _path_design(kappa: float) -> np.ndarray:
    """Return the path's design over the exposure: 1 and template.path_knots's two shapes."""
    if kappa == 0.0:
        return _PATH
    return np.column_stack([np.ones_like(_U), *sinusoid_shapes(_U, kappa)])


def _sinc(z: np.ndarray | float) -> np.ndarray:
    """Return sin(z) / z (1 at 0)."""
    return np.sinc(np.asarray(z) / math.pi)


def smear_rows(regions: list[np.ndarray], polarity: str) -> np.ndarray:
    """Return row weights (sum 1) for the rows the mark crosses, however smeared it is.

    Per pixel the deficit against its median over the frames: a moving texture averages
    about 0 over the frames and columns, the mark's rows (dark in a part of every frame) do
    not. A row's weight is its mean deficit above the median over the rows, times the
    deficit (the profile's signal-to-noise ratio), smoothed over 3 rows.
    """
    stack = np.array(regions, dtype=np.float64)
    static = np.median(stack, axis=0)
    sign = 1.0 if polarity == 'dark' else -1.0
    deficit = sign * (1.0 - stack / np.maximum(static, 1e-9)[None])
    rows = deficit.mean(axis=(0, 2))
    rows = np.convolve(rows - np.median(rows), np.ones(3) / 3.0, mode='same')
    weights = np.clip(rows, 0.0, None) ** 2
    if not weights.sum() > 0:
        return np.full(stack.shape[1], 1.0 / stack.shape[1])
    return weights / weights.sum()


def smear_boxes(regions: list[np.ndarray], polarity: str, spans=None,
                rounds: int = 2, weights=None) -> tuple[np.ndarray, np.ndarray]:
    """Return each frame's box centre and length (ROI columns, px; NaN: none).

    The row-weighted profiles (``smear_rows`` unless ``weights``) over a static field (the
    median over the frames of the profiles outside the boxes found, each frame's light
    divided out first), the deficit's matched filter by boxes of 6 px to 80 % of the ROI.
    ``spans``: per frame (first, last) columns the mark is known to cover, left out of the
    static field from the start.
    """
    if weights is None:
        weights = smear_rows(regions, polarity)
    profiles = np.array([weights @ r.astype(np.float64) for r in regions])
    count, w = profiles.shape
    levels = np.median(profiles, axis=1)
    centres, sizes = np.full(count, np.nan), np.full(count, np.nan)
    if not np.all(levels > 0):  # a dark frame: no boxes
        return centres, sizes
    profiles /= levels[:, None]
    sign = 1.0 if polarity == 'dark' else -1.0
    columns = np.arange(w)
    lengths = np.unique(np.geomspace(6, 0.8 * w, 40).astype(int))
    covered = np.zeros((count, w), dtype=bool)
    if spans is not None:
        for n, (first, last) in enumerate(spans):
            if math.isfinite(first) and math.isfinite(last):
                covered[n] = (columns >= first) & (columns <= last)
    for _ in range(int(rounds)):
        masked = np.where(covered, np.nan, profiles)
        seen = np.count_nonzero(~covered, axis=0) >= max(count // 4, 3)
        if np.count_nonzero(seen) < 0.5 * w:
            break
        static = np.nanmedian(masked[:, seen], axis=0)
        static = np.interp(columns, columns[seen], static)
        for n in range(count):
            ratio = profiles[n] / static
            level = light_level(ratio, polarity, order=0)
            if level is None:
                continue
            d = sign * (1.0 - ratio / level)
            total = np.concatenate([[0.0], np.cumsum(d)])
            best = (-math.inf, math.nan, math.nan)
            for m in lengths:
                score = (total[m:] - total[:-m]) / math.sqrt(m)
                k = int(np.argmax(score))
                if score[k] > best[0]:
                    best = (float(score[k]), k + (m - 1) / 2.0, float(m))
            centres[n], sizes[n] = best[1], best[2]
            covered[n] = np.abs(columns - best[1]) <= best[2] / 2.0 + 8.0
    return centres, sizes


class PeriodicMotion:
    """A smooth periodic motion of exposure-averaged positions, per frame index.

    ``x(t) = c + r t + sum_k a_k cos(k w t) + b_k sin(k w t)`` of the path (t in frames); a
    frame's position is its average over the exposure (``fraction`` of the frame period), the
    path's harmonics times sinc(k w fraction / 2).
    """

    def __init__(self, omega: float, coefficients: np.ndarray, fraction: float,
                 harmonics: int, spread: float):
        """Keep the fitted fundamental (rad/frame), path coefficients and residual spread."""
        self.omega = float(omega)
        self.coefficients = np.asarray(coefficients, dtype=float)
        self.fraction = float(fraction)
        self.harmonics = int(harmonics)
        self.spread = float(spread)

    def path(self, t: np.ndarray) -> np.ndarray:
        """Return the path's column at times ``t`` (frames)."""
        return _design(np.asarray(t, dtype=float), self.omega, self.harmonics) @ \
            self.coefficients

    @property
    def turn(self) -> float:
        """Return how far (rad) the fundamental turns over an exposure (template.path_knots)."""
        return self.omega * self.fraction

    def kernels(self, frames: np.ndarray,
                kappa: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        """Return the exposure-averaged positions and the (blur, curve) kernels of ``frames``.

        The kernels of the paths' least-squares fit over the exposure by a quadratic, or with
        ``kappa`` by the sinusoid's shapes (template.path_knots).
        """
        frames = np.asarray(frames, dtype=float)
        times = frames[:, None] + _U[None, :] * self.fraction
        paths = self.path(times.ravel()).reshape(times.shape)
        fitted = np.linalg.lstsq(_path_design(float(kappa)), paths.T, rcond=None)[0]
        return fitted[0], np.column_stack([np.abs(fitted[1]), fitted[2]])

    def bank(self, count: int = 36, kappa: float = 0.0) -> list[tuple[float, float]]:
        """Return the kernels of ``count`` phases over one period (a search's bank)."""
        frames = np.linspace(0.0, 2.0 * math.pi / self.omega, int(count), endpoint=False)
        return [(float(b), float(c)) for b, c in self.kernels(frames, kappa)[1]]


def _design(t: np.ndarray, omega: float, harmonics: int, fraction: float = 0.0) -> np.ndarray:
    """Return the design matrix of the motion at ``t``, averaged over ``fraction`` frames."""
    columns = [np.ones_like(t), t / 100.0]
    for k in range(1, harmonics + 1):
        factor = float(_sinc(k * omega * fraction / 2.0))
        columns += [factor * np.cos(k * omega * t), factor * np.sin(k * omega * t)]
    return np.column_stack(columns)


def fit_motion(centres: np.ndarray, fraction: float,
               harmonics: int = HARMONICS) -> PeriodicMotion | None:
    """Return the periodic motion fitted robustly to per-frame centres (NaN: none), or None.

    The fundamental (below the Nyquist frequency) is the one whose sinusoid leaves the least
    median absolute residual over a grid, refined; then least squares with ``harmonics``
    harmonics, rounds leaving out centres further than ``OUTLIER_PX`` and 3.5 robust sigmas.
    """
    frames = np.flatnonzero(np.isfinite(centres))
    if frames.size < 4 * harmonics + 12:
        return None
    t = frames.astype(float)
    y = centres[frames]

    def cost(omega, k=1, keep=None):
        basis = _design(t, omega, k, fraction)
        use = np.ones(t.size, dtype=bool) if keep is None else keep
        coef = np.linalg.lstsq(basis[use], y[use], rcond=None)[0]
        return float(np.median(np.abs(y - basis @ coef))), coef

    grid = np.linspace(0.05, math.pi - 0.02, 600)
    scores = [cost(omega)[0] for omega in grid]
    step = float(grid[1] - grid[0])
    peak = float(grid[int(np.argmin(scores))])
    omega = float(minimize_scalar(lambda v: cost(v)[0], bounds=(peak - step, peak + step),
                                  method='bounded', options={'xatol': 1e-6}).x)
    keep = np.ones(t.size, dtype=bool)
    coef = None
    for _ in range(4):
        result = minimize_scalar(lambda v, use=keep: _trimmed(t, y, v, harmonics, fraction, use),
                                 bounds=(omega - step, omega + step), method='bounded',
                                 options={'xatol': 1e-7})
        omega = float(result.x)
        basis = _design(t, omega, harmonics, fraction)
        coef = np.linalg.lstsq(basis[keep], y[keep], rcond=None)[0]
        residual = np.abs(y - basis @ coef)
        scale = 1.4826 * float(np.median(residual[keep]))
        new = residual <= max(3.5 * scale, OUTLIER_PX)
        if np.count_nonzero(new) < 4 * harmonics + 12:
            return None
        if np.array_equal(new, keep):
            break
        keep = new
    if coef is None:
        return None
    residual = y - _design(t, omega, harmonics, fraction) @ coef
    spread = math.sqrt(float(np.mean(residual[keep] ** 2)))
    return PeriodicMotion(omega, coef, fraction, harmonics, spread)


def _trimmed(t, y, omega, harmonics, fraction, keep) -> float:
    """Return the residual sum of squares over ``keep`` of the least-squares motion."""
    basis = _design(t, omega, harmonics, fraction)[keep]
    coef = np.linalg.lstsq(basis, y[keep], rcond=None)[0]
    residual = y[keep] - basis @ coef
    return float(residual @ residual)


def quadratic_kernel(previous: float, column: float, following: float,
                     fraction: float) -> tuple[float, float]:
    """Return the (blur, curve) kernel of the quadratic through three positions a frame apart.

    ``fraction``: the exposure's share of the frame period (``local_kernel`` without a
    motion's frequency).
    """
    return (abs(following - previous) / 2.0 * fraction,
            (following - 2.0 * column + previous) * fraction * fraction / 2.0)


def local_kernel(previous: float, column: float, following: float, omega: float,
                 fraction: float, kappa: float = 0.0) -> tuple[float, float]:
    """Return the (blur, curve) kernel of the frame at ``column`` between its neighbours.

    The sinusoid of frequency ``omega`` (rad/frame) through the three exposure-averaged
    positions, one frame apart, gives the path over this frame's exposure (``fraction`` of
    the frame period); its quadratic fit over the exposure is the kernel, or with ``kappa``
    its fit by the sinusoid's shapes (template.path_knots).
    """
    times = np.array([-1.0, 0.0, 1.0])
    basis = _design(times, omega, 1, fraction)[:, [0, 2, 3]]
    coef = solve(basis, np.array([previous, column, following]))
    if coef is None:
        return quadratic_kernel(previous, column, following, fraction)
    u = _U * fraction
    path = coef[0] + coef[1] * np.cos(omega * u) + coef[2] * np.sin(omega * u)
    fitted = lstsq(_path_design(float(kappa)), path)
    return abs(float(fitted[1])), float(fitted[2])


class BlurScale:
    """How much longer the fits' blurs are than ``predicted_kernel``'s, over recent frames.

    A kernel through three positions a frame apart (``quadratic_kernel``) has the velocity of
    their chord: for a sinusoid ``sin(w) / w`` of the true one (0.93 at 0.62 rad/frame, the
    plain 'baseline' case), so a fit started from it took one more step and the search's
    smeared plate was short. ``scale`` is the median ratio of the fitted to the predicted blur
    over the last ``SCALE_FRAMES`` frames predicted at least ``SCALE_LEAST`` px long (1 until
    ``SCALE_FROM`` are known), within ``SCALE_RANGE``; it multiplies the predicted blur.
    """

    def __init__(self) -> None:
        """Start at 1 (no frames)."""
        self._ratios: deque[float] = deque(maxlen=SCALE_FRAMES)
        self.scale = 1.0

    def add(self, predicted: float, fitted: float) -> None:
        """Note a frame's predicted (unscaled) and fitted blur (px)."""
        if not (predicted >= SCALE_LEAST and math.isfinite(fitted)):
            return
        self._ratios.append(fitted / predicted)
        if len(self._ratios) >= SCALE_FROM:
            low, high = SCALE_RANGE
            self.scale = min(max(statistics.median(self._ratios), low), high)

    def reset(self) -> None:
        """Forget the frames."""
        self._ratios.clear()
        self.scale = 1.0


def predicted_kernel(prediction, motion: 'PeriodicMotion | None',
                     fraction: float, kappa: float = 0.0) -> tuple[float, float] | None:
    """Return the (blur, curve) kernel a frame's prediction (core.tracking.predict) gives.

    Through the previous, predicted and following positions: on ``motion``'s sinusoid when
    there is one (``local_kernel``, with ``kappa``), else the quadratic (with the frame before
    the previous known); None without a prediction.
    """
    if prediction is None:
        return None
    if motion is not None:
        return local_kernel(prediction.previous, prediction.column, prediction.following,
                            motion.omega, fraction, kappa)
    if math.isfinite(prediction.before):
        return quadratic_kernel(prediction.previous, prediction.column, prediction.following,
                                fraction)
    return None


def _box_spectrum(size: int, width: float) -> np.ndarray:
    """Return the spectrum of a box of ``width`` px (sum 1) centred on column 0."""
    k = 2.0 * math.pi * np.fft.rfftfreq(size)
    return _sinc(k * max(width, 1.0) / 2.0)


def smear_templates(motion: PeriodicMotion, frames: np.ndarray, width: int,
                    mark: float, samples: int = 129) -> np.ndarray:
    """Return each frame's smeared mark (frames x ``width``): path density times a box.

    The density of the path over the exposure (``samples`` points, split linearly between
    columns), convolved with a box of ``mark`` px, the mark's profile to first order.
    """
    frames = np.asarray(frames, dtype=float)
    u = np.linspace(-0.5, 0.5, samples)
    times = frames[:, None] + u[None, :] * motion.fraction
    columns = motion.path(times.ravel()).reshape(times.shape)
    size = int(2 ** math.ceil(math.log2(width + 2 * mark + 64)))
    left = np.floor(columns)
    part = columns - left
    index = left.astype(int) % size
    density = np.zeros((frames.size, size))
    rows = np.repeat(np.arange(frames.size), samples)
    np.add.at(density, (rows, index.ravel()), (1.0 - part).ravel() / samples)
    np.add.at(density, (rows, (index.ravel() + 1) % size), part.ravel() / samples)
    smeared = np.fft.irfft(np.fft.rfft(density, axis=1) * _box_spectrum(size, mark), size,
                           axis=1)
    return smeared[:, :width]


def refine_motion(motion: PeriodicMotion, deficits: np.ndarray, mark: float):
    """Return the motion and mark width refined on the frames' deficits (frames x columns).

    Least squares of every frame's deficit against its smeared mark (``smear_templates``)
    times a gain plus an offset (solved per frame), over the motion's path coefficients,
    frequency and the mark's width; a robust loss leaves out frames with something else in.
    """
    from scipy.optimize import least_squares

    count, width = deficits.shape
    frames = np.arange(count, dtype=float)
    ones = np.ones(width)

    def unpack(p):
        return PeriodicMotion(p[0], p[1:-1], motion.fraction, motion.harmonics,
                              motion.spread), p[-1]

    def residuals(p):
        trial, mark_px = unpack(p)
        templates = smear_templates(trial, frames, width, abs(mark_px))
        out = np.empty_like(deficits)
        for n in range(count):
            design = np.column_stack([ones, templates[n]])
            coef = np.linalg.lstsq(design, deficits[n], rcond=None)[0]
            out[n] = deficits[n] - design @ coef
        return out.ravel()

    start = np.concatenate([[motion.omega], motion.coefficients, [mark]])
    scale = np.concatenate([[1e-3], np.full(motion.coefficients.size, 1.0), [1.0]])
    result = least_squares(residuals, start, x_scale=scale, diff_step=1e-4, max_nfev=60)
    refined, mark_px = unpack(result.x)
    return refined, abs(float(mark_px)), float(np.sqrt(np.mean(result.fun ** 2)))


def smear_start(regions: list[np.ndarray], polarity: str, fraction: float):
    """Return (positions, kernels, extents, mark width, motion) for a long smear, or None.

    None unless a periodic motion fits the frames' boxes (``smear_boxes``, ``fit_motion``)
    and its longest kernel exceeds ``LONG_BLUR`` of the ROI's width. The motion is refined on
    the deficits (``refine_motion``, twice: the static field the second time from the columns
    the refined smears leave free).
    """
    weights = smear_rows(regions, polarity)
    centres, _ = smear_boxes(regions, polarity, weights=weights)
    motion = fit_motion(centres, fraction)
    count, width = len(regions), regions[0].shape[1]
    frames = np.arange(count)
    if motion is None:
        return None
    _, kernels = motion.kernels(frames)
    if not float(kernels[:, 0].max()) > LONG_BLUR * width:
        return None
    sign = 1.0 if polarity == 'dark' else -1.0
    profiles = np.array([weights @ r.astype(np.float64) for r in regions])
    profiles /= np.median(profiles, axis=1)[:, None]
    columns = np.arange(width)
    covered = np.zeros(profiles.shape, dtype=bool)
    mark = 20.0
    for _ in range(2):
        with warnings.catch_warnings():
            warnings.simplefilter('ignore', RuntimeWarning)
            static = np.nanmedian(np.where(covered, np.nan, profiles), axis=0)
        seen = np.isfinite(static)
        if np.count_nonzero(seen) < 0.5 * width:
            return None
        static = np.interp(columns, columns[seen], static[seen])
        deficits = np.zeros(profiles.shape)
        for n, profile in enumerate(profiles):
            level = light_level(profile / static, polarity, order=0)
            if level is None:
                return None
            deficits[n] = sign * (1.0 - profile / (static * level))
        motion, mark, _ = refine_motion(motion, deficits, mark)
        positions, kernels = motion.kernels(frames)
        spans = kernels[:, 0] + 0.25 * np.abs(kernels[:, 1]) + mark
        covered = np.abs(columns[None, :] - positions[:, None]) <= spans[:, None] / 2.0 + 10.0
    return positions, kernels, spans, mark, motion


def path_range(blur: float, curve: float, reach: float = 0.0) -> tuple[float, float]:
    """Return the columns (first, last) the kernel's path covers about its mean, +- ``reach``.

    The path ``blur u + curve (u^2 - 1/12)``, ``u`` in [-1/2, 1/2], at its ends and at its
    turning point if it has one.
    """
    points = [-0.5, 0.5]
    if curve != 0.0 and abs(blur / (2.0 * curve)) < 0.5:
        points.append(-blur / (2.0 * curve))
    values = [blur * u + curve * (u * u - 1.0 / 12.0) for u in points]
    return min(values) - reach, max(values) + reach


def smear_verdict(tracked: np.ndarray, centroid: Callable[[int], float],
                  motion: PeriodicMotion) -> bool:
    """Return True if a long smear's learned plate can be trusted, from its priming track.

    ``tracked``: the priming frames' positions (ROI columns, NaN: none) by the learned plate;
    ``centroid(n)``: the centroid tracker's position of priming frame ``n`` measured on its
    own (NaN: not found). A plate learned from long smears can be badly learned or
    registered pixels off: the track's scatter about a smooth periodic motion
    (``motion_jitter``, two harmonics: more alias at five frames per period) shows the first,
    its mean difference from the centroid's over the least smeared frames the second. Those
    are the frames whose path is shorter than ``SMEAR_SHARP`` px if the centroid finds 3 of
    them (it is exact on average there), else the 3 least smeared it finds with paths up to
    ``REGISTER_PATH`` px: a texture pulls the centroid of a longer smear further (0.4-0.8 px
    at 22-27 px, 15 fps, 0.7 of the period exposed), so the bound, ``SMEAR_BIAS`` px, grows
    in proportion to the longest path over ``SMEAR_SHARP``. False above it or above
    ``SMEAR_JITTER``, with fewer than 3 such frames, or with fewer than half the frames
    tracked.
    """
    count = tracked.size
    if np.count_nonzero(np.isfinite(tracked)) < 0.5 * count:
        return False
    if not motion_jitter([tracked], 2)[0] <= SMEAR_JITTER:
        return False
    _, kernels = motion.kernels(np.arange(count))
    paths = kernels[:, 0] + 0.25 * np.abs(kernels[:, 1])
    apart: list[float] = []
    longest = 0.0
    for n in np.argsort(paths, kind='stable'):
        if paths[n] > REGISTER_PATH or (len(apart) >= 3 and paths[n] >= SMEAR_SHARP):
            break
        if math.isfinite(tracked[n]):
            found = centroid(int(n))
            if math.isfinite(found):
                apart.append(float(tracked[n]) - found)
                longest = float(paths[n])
    if len(apart) < 3:
        return False
    return bool(abs(float(np.mean(apart))) <= SMEAR_BIAS * max(1.0, longest / SMEAR_SHARP))


def least_smeared(measure, frames, regions, x, polarity):
    """Return the regions and the mark's columns (first, last) to score the texture on.

    ``measure``: the centroid tracker's, on ``frames``; ``regions`` their ROIs, ``x`` the
    ROI's first column. The first 12 frames it finds the mark in; with long smears (their
    median extent over ``LONG_BLUR`` of the ROI, which hide a moving texture) the 12 least
    smeared of all, or, when it finds fewer than 8, the 12 shortest ``smear_boxes`` (if
    their median length is over ``BOXES_FROM`` of the ROI). (None, None) when it finds fewer
    than 8 and the boxes do not serve.
    """
    width = regions[0].shape[1]
    found = []
    for n, frame in enumerate(frames):
        m = measure(frame)
        if m.valid:
            found.append((m.extent_px, n, m.position_px - x))
            if len(found) == 12 and not np.median([f[0] for f in found]) > LONG_BLUR * width:
                break
    if len(found) < 8:
        centres, sizes = smear_boxes(regions, polarity)
        if (np.count_nonzero(np.isfinite(sizes)) < 8
                or not np.nanmedian(sizes) > BOXES_FROM * width):
            return None, None
        found = [(z, n, c) for n, (c, z) in enumerate(zip(centres, sizes, strict=True))
                 if math.isfinite(c)]
    found = sorted(found)[:12]
    return ([regions[n] for _, n, _ in found],
            [(c - z / 2.0 - 16.0, c + z / 2.0 + 16.0) for z, _, c in found])
