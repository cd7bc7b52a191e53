"""A static background per ROI: a pattern fixed in the image, learned and divided out.

Owns ``StaticBackground``. A pattern that does not move with the plates (a cover glass or
window between the plates and the camera, dust on it, scratches, the sensor's own pattern)
is the same in every frame, while the mark moves: each pixel is uncovered most of the time.
From the priming frames the background is the per-pixel mean of the frames in which the
mark's footprint (its located extent plus a guard, per frame) does not cover the pixel, with
outliers (a passing particle, a mark located wrongly) clipped at four sigmas once. Every later
ROI is divided by it, normalised to a mean of 1 (a flat field), before its profile is built:
any static pattern left at the mark's scale would bias the position. Flicker and drift, which
change the level of the whole ROI, stay with the per-frame baseline.

Only when it helps: the fine part of the background (over its Gaussian smoothing of
``SMOOTH_PX``) is shrunk towards 1 by the Wiener factor ``1 - n / v`` (``v`` its variance over
the ROI, ``n`` the part of it that is the noise of the per-pixel means), and no background is
used at all when that factor is below ``MIN_GAIN``, so a plain plate is left as it was (the
mean of noisy frames would add fixed-pattern noise); nor when the background's differences
between neighbouring columns exceed what the scatter of the frames about it gives by less than
``MIN_STRUCTURE`` (a texture that moves with the plate averages into a mean smooth at the
pixel scale, about which the frames scatter far more than noise: not a static pattern), nor
when the frames' scatter about it is correlated between neighbouring columns beyond
``MAX_CORRELATION`` (noise is not; a texture moving past is, even one moving periodically,
whose mean keeps pixel-scale structure).
Pixels the mark covered in too many priming frames (a mark that hardly moves) get no fine
correction. The fine part is divided out (a transmission) or subtracted (light added, scaled
by the frame's level), whichever keeps the mark's integrated deficit steadier over the
priming frames (``area_scatter``): the wrong one leaves the pattern, darkened by the mark,
on it. Something opaque fixed in the image (a pattern under ``OPAQUE`` of the ROI's level in
most rows of a column: a tool held over the plate all along) is divided out too, but what it
hides is not restored: a mark over such columns is partly hidden (``hides``). Learned once;
not updated while tracking.
"""

import math

import cv2
import numpy as np

from microball_ros.core.tracking.profile import deficit_noise
from microball_ros.core.tracking.search import locate

MAD_TO_SIGMA = 1.4826
SMOOTH_PX = 6.0
MIN_SAMPLES = 8
MIN_FRAMES = 12
MIN_GAIN = 0.5
OPAQUE = 0.25  # of the ROI's level: a static pattern this dark in most rows hides the plate
MIN_STRUCTURE = 0.25
MAX_CORRELATION = 0.5
PROVISIONAL_FRAMES = 15
CLIP_SIGMA = 4.0
PLATE_ROUNDS = 3
PLATE_GUARD = 8
PLATE_SNR = 8.0
PLATE_SEEN = 0.9


def _smooth_known(image: np.ndarray, known: np.ndarray,
                  sigma: float) -> tuple[np.ndarray, np.ndarray]:
    """Return the Gaussian smoothing of ``image`` over the ``known`` pixels, and its weight."""
    weight = cv2.GaussianBlur(known.astype(np.float32), (0, 0), sigma,
                              borderType=cv2.BORDER_REFLECT)
    value = cv2.GaussianBlur(np.where(known, image, 0).astype(np.float32), (0, 0), sigma,
                             borderType=cv2.BORDER_REFLECT)
    return value / np.maximum(weight, 1e-6), weight


class StaticBackground:
    """The static texture of one ROI (h x w), learned from priming frames, or none.

    ``inverse`` is the per-pixel factor (float32) that removes it, None when the ROI has no
    texture worth removing; ``added``, when the fine pattern is light added rather than
    transmitted, what is then subtracted (times the frame's level over ``reference``);
    ``gain`` the Wiener factor used (0 when none).
    """

    def __init__(self) -> None:
        """Start with no texture (nothing is removed)."""
        self.inverse: np.ndarray | None = None
        self.added: np.ndarray | None = None
        self.reference = 1.0
        self.gain = 0.0
        self.opaque: np.ndarray | None = None  # per column: something opaque over it

    def clear(self) -> None:
        """Forget the texture."""
        self.inverse = None
        self.added = None
        self.reference = 1.0
        self.gain = 0.0
        self.opaque = None

    def hides(self, first: float, last: float) -> bool:
        """Return True if something opaque fixed in the image is over columns first..last."""
        if self.opaque is None or self.inverse is None:
            return False
        lo, hi = max(int(math.floor(first)), 0), min(int(math.ceil(last)) + 1, self.opaque.size)
        return bool(np.any(self.opaque[lo:hi]))

    @property
    def kind(self) -> str:
        """Return how the pattern is removed: 'none', 'divided' or 'subtracted'."""
        if self.inverse is None:
            return 'none'
        return 'divided' if self.added is None else 'subtracted'

    def apply(self, region: np.ndarray) -> np.ndarray:
        """Return the ROI with the static pattern removed (float32), or as it was."""
        if self.inverse is None or self.inverse.shape != region.shape:
            return region
        corrected = region.astype(np.float32) * self.inverse
        if self.added is None:
            return corrected
        level = float(cv2.mean(corrected)[0])
        return corrected - np.float32(level / self.reference) * self.added

    @staticmethod
    def provisional(regions: np.ndarray) -> np.ndarray | None:
        """Return a first background factor from a plain temporal median, to find the marks.

        The median of at most ``PROVISIONAL_FRAMES`` frames spread over ``regions``; the
        mark's passes leak into it where it dwells, so it only serves to locate the mark in
        the priming frames. None with too few frames, or when its fine part does not exceed
        the noise of such a median by half the noise of the final mean (the mark's leaks
        only add to it), so that a plain plate costs little.
        """
        n = regions.shape[0]
        if n < MIN_FRAMES:
            return None
        step = max(int(math.ceil(n / PROVISIONAL_FRAMES)), 1)
        sample = regions[::step].astype(np.float32)
        median = np.median(sample, axis=0)
        known = median > 0
        if not np.any(known):
            return None
        level = float(median[known].mean())
        smooth, _ = _smooth_known(median, known, SMOOTH_PX)
        fine = float(np.mean((median[known] / np.maximum(smooth[known], 1e-6) - 1.0) ** 2))
        # Pixel noise from frame-to-frame differences (robust: the moving mark is a minority).
        difference = sample[1:] - sample[:-1]
        sigma = MAD_TO_SIGMA * float(np.median(np.abs(difference))) / math.sqrt(2.0)
        noise = math.pi / 2.0 * (sigma / level) ** 2 / sample.shape[0]
        # What the mean of all n frames would show of a texture at half the final gate.
        if not fine > noise + 0.5 * (sigma / level) ** 2 / n:
            return None
        return np.where(known, level / np.maximum(median, 1e-3), 1.0).astype(np.float32)

    def learn(self, regions: np.ndarray, covered: np.ndarray,
              first: np.ndarray | None = None) -> None:
        """Learn the texture from ``regions`` (n x h x w) and the mark's ``covered`` columns.

        ``covered`` (n x w, bool) marks the columns the mark's footprint covers in each frame;
        a frame where the mark was not located should be covered entirely. ``first``: the
        ``provisional`` factor, against which each frame's gain (flicker) is measured. Sets
        ``inverse`` and ``gain`` (None and 0 when the texture does not stand out from the
        noise).
        """
        self.clear()
        if regions.shape[0] < MIN_FRAMES:
            return
        regions = regions.astype(np.float32)
        # Flicker: each frame brought to the common level, its gain measured against the first
        # background over the columns the mark leaves.
        free = (~covered).astype(np.float32)
        width = free.sum(axis=1)
        if np.count_nonzero(width) < MIN_FRAMES:
            return
        flat = regions if first is None else regions * first
        levels = np.einsum('ijk,ik->i', flat, free) / (np.maximum(width, 1) * regions.shape[1])
        seen = (width > 0) & (levels > 0)
        target = float(levels[seen].mean())
        regions *= np.where(seen, target / np.maximum(levels, 1e-9),
                            1.0).astype(np.float32)[:, None, None]
        use = np.broadcast_to(~covered[:, None, :], regions.shape)
        mean, variance, count = _masked_moments(regions, use)
        # One pass of clipping: a passing particle or a mark located wrongly is not averaged.
        sigma = np.sqrt(variance)
        known = count >= MIN_SAMPLES
        if np.count_nonzero(known) < 0.25 * known.size:
            return
        floor = float(np.median(sigma[known]))
        limit = CLIP_SIGMA * np.maximum(sigma, max(floor, 0.5))
        use = use & (np.abs(regions - mean) <= limit)
        mean, variance, count = _masked_moments(regions, use)
        known = count >= MIN_SAMPLES
        if np.count_nonzero(known) < 0.25 * known.size:
            return
        smooth, weight = _smooth_known(mean, known, SMOOTH_PX)
        smooth = smooth.astype(np.float64)
        if np.any(smooth[known] <= 0):
            return
        texture = mean / np.maximum(smooth, 1e-9) - 1.0
        # The part of the fine texture's variance that is the noise of the per-pixel means.
        noise = float(np.mean(variance[known] / count[known] / smooth[known] ** 2))
        total_variance = float(np.mean(texture[known] ** 2))
        if not (math.isfinite(total_variance) and total_variance > 0):
            return
        gain = max(0.0, 1.0 - noise / total_variance)
        if gain < MIN_GAIN:
            return
        # A texture that moves with the plate also leaves a mean, but one smooth at the pixel
        # scale, and its frames scatter about it far more than noise: the pixel-to-pixel
        # differences along x of the mean then fall short of what the scatter alone would
        # give. A pattern fixed in the image has them well above it.
        step = np.diff(texture, axis=1)
        both = known[:, 1:] & known[:, :-1]
        scatter = variance / np.maximum(count, 1) / np.maximum(smooth, 1e-9) ** 2
        expected = float(np.mean((scatter[:, 1:] + scatter[:, :-1])[both]))
        if not float(np.mean(step[both] ** 2)) - expected > MIN_STRUCTURE * expected:
            return
        # Noise scatters each pixel on its own; a texture moving past scatters neighbouring
        # pixels alike (its grain), even when it moves periodically and so leaves a mean
        # with pixel-scale structure.
        if _neighbour_correlation(regions - mean.astype(np.float32), use) > MAX_CORRELATION:
            return
        # The whole static pattern goes (a flat field): its smooth part, nearly noiseless, as
        # it is; its fine part shrunk by the gain; no correction far from any known pixel.
        level = float(np.mean(smooth[known]))
        flat = np.where(weight > 0.05, smooth / level, 1.0)
        fine = np.where(known, gain * texture, 0.0)
        inverse = (1.0 / np.maximum(flat * (1.0 + fine), 1e-3)).astype(np.float32)
        # The fine part as light added (scratches, glare) rather than a transmission: in the
        # flat field's units, scaled by each frame's gain. The two differ only on the mark,
        # where a transmission is darkened with it and added light is not: which one the
        # frames show is measured there (``area_scatter``).
        flat_inverse = (1.0 / np.maximum(flat, 1e-3)).astype(np.float32)
        added = (level * fine).astype(np.float32)
        reference = float(np.mean(regions * flat_inverse))
        if area_scatter(regions, covered, added, flat_inverse, reference) < area_scatter(
                regions, covered, None, inverse, reference):
            self.inverse, self.added, self.reference = flat_inverse, added, reference
        else:
            self.inverse = inverse
        self.gain = gain
        # Something opaque fixed in the image (a tool held over the plate all along): dividing
        # it out does not restore what it hides, so a mark under it is partly hidden
        self.opaque = np.mean(flat * (1.0 + fine) < OPAQUE, axis=0) > 0.5


def area_scatter(regions: np.ndarray, covered: np.ndarray, added: np.ndarray | None,
                 inverse: np.ndarray, reference: float) -> float:
    """Return the spread over the priming frames of the mark's integrated deficit.

    Per frame where the mark was located: the ROI corrected by ``inverse`` (and ``added``,
    scaled by the frame's level over ``reference``), its column means, and the deficit
    summed over the mark's columns against the median of the others. Blur and position do
    not change that sum; a pattern removed the wrong way (a transmission subtracted, or
    light added divided) leaves the pattern darkened by the mark on it, which does, frame by
    frame as the mark moves over it. The spread is the median absolute deviation.
    """
    located = np.flatnonzero(covered.any(axis=1) & ~covered.all(axis=1))
    areas = []
    for i in located:
        corrected = regions[i] * inverse
        if added is not None:
            corrected = corrected - float(np.mean(corrected)) / reference * added
        profile = corrected.mean(axis=0, dtype=np.float64)
        columns = covered[i]
        level = float(np.median(profile[~columns]))
        if level > 0:
            areas.append(float(np.sum(level - profile[columns])) / level)
    if len(areas) < 3:
        return math.inf
    areas_array = np.array(areas)
    return float(np.median(np.abs(areas_array - np.median(areas_array))))


def _neighbour_correlation(residual: np.ndarray, use: np.ndarray) -> float:
    """Return the correlation of ``residual`` between neighbouring columns where ``use``."""
    pair = use[:, :, 1:] & use[:, :, :-1]
    left, right = residual[:, :, :-1][pair], residual[:, :, 1:][pair]
    norm = math.sqrt(float(np.dot(left, left)) * float(np.dot(right, right)))
    return float(np.dot(left, right)) / norm if norm > 0 else 0.0


def _masked_moments(regions: np.ndarray,
                    use: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Return the per-pixel mean, variance and count of ``regions`` where ``use``."""
    count = use.sum(axis=0)
    values = np.where(use, regions, 0.0)
    total = values.sum(axis=0, dtype=np.float64)
    squares = np.einsum('ijk,ijk->jk', values, values, dtype=np.float64)
    mean = total / np.maximum(count, 1)
    variance = np.maximum(squares - count * mean ** 2, 0.0) / np.maximum(count - 1, 1)
    return mean, variance, count


class StaticPlate:
    """The plain plate of one ROI as the camera sees it, learned while priming, or none.

    For smears too long for a baseline fitted on the frame's own columns (the mark covers most
    of them): the plate (its illumination, vignetting and all) is fixed in the image, so each
    pixel's value when the mark's smear is elsewhere, divided by the frame's gain (flicker), is
    the same in every frame. ``image`` (h x w, float64) is that per-pixel mean, None when it
    could not be learned. Learned in ``PLATE_ROUNDS`` rounds: the smear located in every frame
    against the plate so far (first the temporal median of the gain-normalised profiles),
    then the per-pixel mean over the frames whose smear (plus ``PLATE_GUARD`` px) leaves the
    pixel's column, each frame divided by its gain measured on those columns. ``known``: the
    columns seen in at least ``MIN_SAMPLES`` frames (others are interpolated, and a smear
    over them is not measured against the plate: ``seen``).
    """

    def __init__(self) -> None:
        """Start with no plate."""
        self.image: np.ndarray | None = None
        self.known: np.ndarray | None = None

    def clear(self) -> None:
        """Forget the plate."""
        self.image = None
        self.known = None

    def seen(self, lo: int, hi: int) -> bool:
        """Return True if the plate was seen (not interpolated) over columns lo..hi."""
        if self.known is None:
            return False
        part = self.known[max(lo, 0):hi + 1]
        return part.size > 0 and float(part.mean()) >= PLATE_SEEN

    def profile(self, weights: np.ndarray | None, rows: slice) -> np.ndarray | None:
        """Return the plate's profile over ``rows``: row-weighted, or the rows' mean."""
        if self.image is None:
            return None
        image = self.image[rows]
        if weights is None or weights.size != image.shape[0]:
            return image.mean(axis=0)
        return weights @ image

    def learn(self, regions: np.ndarray, polarity: str, smoothing: int, gap: int) -> None:
        """Learn the plate from the priming ROIs ``regions`` (n x h x w) of a ``polarity`` mark.

        ``smoothing`` and ``gap`` (px) are the tracker's: the smear is located where the
        smoothed deficit exceeds three times its noise, parts ``gap`` apart joined.
        """
        self.clear()
        n, _, w = regions.shape
        if n < MIN_FRAMES or w < 4 * PLATE_GUARD:
            return
        sign = 1.0 if polarity == 'dark' else -1.0
        regions = regions.astype(np.float64)
        profiles = regions.mean(axis=1)
        if not np.all(profiles > 0):
            return
        gains = np.median(profiles, axis=1)
        plate = np.median(profiles / gains[:, None], axis=0)
        everywhere = np.ones(w, dtype=bool)
        covered = np.ones((n, w), dtype=bool)
        for _ in range(PLATE_ROUNDS):
            before, covered = covered, np.ones((n, w), dtype=bool)
            for i in range(n):
                ratio = profiles[i] / plate
                free = ~before[i] if not before[i].all() else everywhere
                gain = float(np.median(ratio[free]))
                deficit = sign * (1.0 - ratio / gain)
                noise = deficit_noise(deficit, everywhere)
                dip = locate(deficit, noise, 0.0, smoothing, gap)
                if dip.peak * math.sqrt(smoothing) < PLATE_SNR * noise:
                    continue  # no mark seen: the frame is left out
                covered[i] = False
                covered[i, max(dip.lo - PLATE_GUARD, 0):dip.hi + PLATE_GUARD + 1] = True
            free = ~covered
            if np.count_nonzero(free.sum(axis=0) >= MIN_SAMPLES) < 0.5 * w:
                return
            gains = np.array([float(np.median(profiles[i, free[i]] / plate[free[i]]))
                              if free[i].any() else math.nan for i in range(n)])
            use = free & np.isfinite(gains)[:, None]
            count = use.sum(axis=0)
            known = count >= MIN_SAMPLES
            if np.count_nonzero(known) < 0.5 * w:
                return
            scaled = regions / np.where(np.isfinite(gains), gains, 1.0)[:, None, None]
            image = np.einsum('ijk,ik->jk', scaled, use.astype(np.float64)) / np.maximum(
                count, 1)
            columns = np.arange(w)
            for row in image:
                row[:] = np.interp(columns, columns[known], row[known])
            plate = image.mean(axis=0)
            if not np.all(plate > 0):
                return
        self.image = image
        self.known = known
