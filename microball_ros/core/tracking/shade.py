"""A shadow passing over one ROI: the light along x measured on the rows beside the mark.

Owns ``Shade``. A soft shadow (a cable, a probe, a hand between the lamp and the plates) that
sweeps over an ROI darkens it by tens of percent over a few tens of pixels: more than the
per-frame light (a gain and a low-order gradient along x, core.tracking.profile.light_level)
can follow, so the mark's deficit is wrong where its edge lies and the frame is refused
(a shadow 40 px wide and 45 % deep lost 25 of 200 frames on each of two marks). The ROI's
rows above and below the mark see the same shadow, shifted along x by its tilt, while the
mark never enters them (the plates move along x only).

Learned once, after the mark's rows are known (from priming): the mean profile of up to
``SIDE_ROWS`` rows on each side, ``GAP_ROWS`` away from the mark's rows, and of each half of
them, over the priming frames (the median over frames: the plate, its vignetting and its
dust, so dividing by it leaves the light alone), and how far a frame's side profiles depart
from a quadratic light along x (their scatter: its ``QUIET`` quantile over the priming frames,
so a shadow passing during priming leaves it alone: the test's band over frames 10-50 was
on the ROI in over half of them). Nothing is learned, and nothing ever changes, when a side
has fewer than ``MIN_SIDE`` rows or the side rows scatter over ``PLAIN_AT_MOST`` (a texture
moving with the plate; the sides then say nothing about the light).

Per frame, ``light`` returns None (the frame is measured as it is) unless the side profiles,
divided by what priming learned, depart from a quadratic by more than ``STANDS_OUT`` times
their scatter while priming and by at least ``AT_LEAST``. Then the light is the two sides'
profiles smoothed by a local cubic over ``SMOOTH_PX`` columns (a shadow's edge is soft), the
lower one shifted onto the upper one (the shift of best fit of their slopes: the shadow's
tilt), and each ROI row gets the light interpolated between them along the tilt. It is refused
(None) when the two sides depart unlike each other (``SIDES_ALIKE``: something over one side
only), when what smoothing removes stands out from the noise (``SHARP``, ``EDGE``: sharp
edges, a tool's blade or a fibre, not a shadow; a median of 3 columns first takes out a hot
pixel's spike, as a hot pixel is not shadowed), when a half of either side does not fit the
light at its rows (``AGREE``: a ball rolling over the mark is round, a shadow's edge
straight), or where the light falls below ``FLOOR`` (an opaque object: nothing left to
measure). ``Tracker`` divides the ROI by it above the camera's black level (``above_black``)
and widens the frame's standard error (core.tracking.tracker.SHADED_SIGMA).

The black level, when not given, is estimated from the marks' contrast in and out of the
shadows (``BlackLevel``): a dark offset left in the light takes contrast from a shaded mark.
Until it is known, the mark's gain guard allows for an offset up to ``BLACK_MOST`` of the
plate's level (``gain_slack``). The mark's tracker is told of each shadow (``ShadowNote``) and
judges its fit's residual with the light's own error (``error``) added to the noise.
"""

from collections import deque
import dataclasses
import math

import cv2
import numpy as np
from scipy.ndimage import median_filter
from scipy.optimize import brentq
from scipy.signal import savgol_filter

from microball_ros.core.tracking.profile import median_and_error

SIDE_ROWS = 8  # rows used on each side of the mark, at most
GAP_ROWS = 2  # rows left between the mark's rows and the side rows
MIN_SIDE = 3  # a side with fewer rows than this is not used (both sides are needed)
MIN_FRAMES = 12  # priming frames needed
# The sides' scatter while priming: this quantile over the frames (a shadow over the ROI in up
# to 4 of 5 priming frames leaves it that of the frames without)
QUIET = 0.2
PLAIN_AT_MOST = 0.03  # side rows scattering more about a quadratic light: a texture, no shade
STANDS_OUT = 4.0  # a frame's departure this many times priming's scatter is a shadow ...
AT_LEAST = 0.01  # ... and at least this (relative light)
SMOOTH_PX = 15  # the light along x: a cubic fitted over this many columns about each
# The most smoothing removes from a side, less SHARP times its RMS while priming (the noise),
# over EDGE of the side's range: sharp edges. On test_tracking_shade's scenes a shadow's
# penumbra of 3 / 4 / 8 px leaves 0.06 / 0.02 / under 0 of its depth, of 1-2 px 0.16-0.10,
# and a blade's edge (1.6 px) 0.14.
SHARP = 4.0
EDGE = 0.08
SIDES_ALIKE = 0.5  # the sides' departures within this ratio (a straight shadow: alike)
AGREE = 0.35  # each half side fits the light at its rows within this fraction of the departure
FLOOR = 0.25  # a light below this (relative to priming's) is an opaque object: refused
MAX_TILT = 1.5  # shifts between the sides up to this many px per row (56 degrees)
# A camera's black level not given may be up to this share of the plate's level (8-bit video
# range's 16 DN of 160). Under a light rho (relative, as read) a black level u leaves the mark
# (1 - u / rho) / (1 - u) of its contrast: p12's black of 6 DN of 154, under a shadow 45 %
# deep, 3 % less (0.948 of it where the penumbra crossed it), which the gain guard refused.
BLACK_MOST = 0.1
BLACK_SAMPLES = 4  # shaded frames needed before the black level is estimated (BlackLevel)
BLACK_DEEP = 0.85  # ... whose light at the mark is under this (a shadow deep enough to tell)
BLACK_RANGE = 0.5  # black levels (relative to the plate's level) searched
LIT_FRAMES = 15  # a mark's contrast out of the shadow: the median of its last frames so
BLACK_KEPT = 500  # the black level: the median of the last this many shaded frames' at most


@dataclasses.dataclass(frozen=True)
class ShadowNote:
    """What the mark's tracker is told of the shadow its frame was divided by.

    ``gain_slack``: how far the mark's gain may be off for a black level not known (relative,
    ``gain_slack``'s); ``error``: the light's RMS misfit at the sides (relative), an error the
    fit's residual carries on top of the noise.
    """

    gain_slack: float
    error: float


class BlackLevel:
    """The camera's black level (DN), from the marks' contrast in and out of passing shadows.

    A mark's contrast against its plate does not change with the light, but for the camera's
    offset ``b``: under a light ``rho`` (relative to priming's, as read: the offset in it) and
    divided by the light taken with ``u_used`` for the offset (both relative to the plate's
    level), it is ``g = (rho - u)(1 - u_used) / ((1 - u)(rho - u_used))`` of its contrast out
    of the shadow. A shadow's penumbra often lies across the mark: ``rho`` is per pixel of the
    mark's rows and columns, ``g`` predicted as the mean of the pixels' and solved for ``u``
    (within ``BLACK_RANGE``). Each shaded frame found whose mean light at the mark is under
    ``BLACK_DEEP`` gives one ``u``, times the plate's level there; ``value`` is the median of
    the last ``BLACK_KEPT`` once ``BLACK_SAMPLES`` are known (None before), ``sigma`` its
    standard error. On
    test_tracking_shade's scenes (offsets of 0, 6, 12 and 24 DN, plate at 150) it was within
    0.2 DN after 16-17 frames.
    """

    def __init__(self) -> None:
        self._lit: dict[str, deque[float]] = {}
        self._samples: deque[float] = deque(maxlen=BLACK_KEPT)
        self.value: float | None = None  # DN, at least 0; None with too few frames
        self.sigma = math.nan  # its standard error (the samples' MAD, 1.25 for a median)

    def lit(self, name: str, contrast: float) -> None:
        """Note mark ``name``'s contrast in a frame no shadow was divided out of."""
        if math.isfinite(contrast) and contrast > 0:
            self._lit.setdefault(name, deque(maxlen=LIT_FRAMES)).append(contrast)

    def shaded(self, name: str, contrast: float, light: np.ndarray, level: float,
               used: float) -> None:
        """Note a shaded frame's mark: its contrast, the light at it, the level, the black used.

        ``light``: as read, over the mark's rows and columns; ``level``: the plate's there (DN,
        priming's); ``used``: the black level the frame was divided with (DN).
        """
        lit = self._lit.get(name)
        if lit is None or len(lit) < 3 or not (math.isfinite(contrast) and contrast > 0
                                               and light.size and level > 0):
            return
        if not float(light.mean()) < BLACK_DEEP:
            return
        g = contrast / float(np.median(lit))
        u_used = used / level

        def excess(u: float) -> float:
            """Return the contrast a black level ``u`` predicts, less the contrast seen."""
            return float(np.mean((light - u) / (light - u_used))) * (1.0 - u_used) / (
                1.0 - u) - g

        low, high = -BLACK_RANGE, min(BLACK_RANGE, float(light.min()) - 1e-3)
        if not (low < high and excess(low) > 0.0 > excess(high)):
            return
        self._samples.append(level * float(brentq(excess, low, high, xtol=1e-5)))
        if len(self._samples) >= BLACK_SAMPLES:
            middle, self.sigma = median_and_error(self._samples)
            self.value = max(middle, 0.0)


def gain_slack(least: float, black_known: bool) -> float:
    """Return how far a mark's gain may be off under a light ``least`` (see BLACK_MOST)."""
    if black_known or not least < 1.0:
        return 0.0
    return BLACK_MOST * (1.0 / max(least, FLOOR) - 1.0) / (1.0 - BLACK_MOST)


class Shade:
    """The light over one ROI from the rows beside the mark, when a shadow passes (see module).

    ``height``, ``width``: the ROI's; ``rows``: the mark's rows (first, stop) in the ROI.
    ``prime`` learns from the priming ROIs; ``light(region)`` is None or the light per pixel
    (relative to priming) to divide the ROI by. ``enabled`` is False when the sides cannot
    tell (see the module).
    """

    def __init__(self, height: int, width: int, rows: tuple[int, int]):
        first, stop = rows
        self.rows = (int(first), int(stop))
        self.height, self.width = int(height), int(width)
        self.above = np.arange(max(first - GAP_ROWS - SIDE_ROWS, 0), max(first - GAP_ROWS, 0))
        self.below = np.arange(min(stop + GAP_ROWS, height),
                               min(stop + GAP_ROWS + SIDE_ROWS, height))
        # Each side in two halves: a straight shadow is the same in all four, shifted
        halves = [part for side in (self.above, self.below)
                  for part in np.array_split(side, 2)] if min(
            self.above.size, self.below.size) >= 2 else []
        self._halves = [slice(int(part[0]), int(part[-1]) + 1) for part in halves]
        self._half_rows = np.array([float(part.mean()) for part in halves])
        counts = np.array([part.size for part in halves], dtype=float)
        self._mix = np.zeros((2, len(halves)))  # halves -> sides, by their rows
        for side in range(min(len(halves), 4) // 2):
            self._mix[side, 2 * side:2 * side + 2] = counts[2 * side:2 * side + 2] / counts[
                2 * side:2 * side + 2].sum()
        self._sides_rows = [slice(int(side[0]), int(side[-1]) + 1) if side.size else slice(0, 0)
                            for side in (self.above, self.below)]
        self.enabled = False
        self._reference: np.ndarray | None = None
        self._side_reference: np.ndarray | None = None
        self._scatter = self._roughness = math.inf
        self.error = math.nan  # the last light's RMS misfit to the half sides (``light``)
        x = np.linspace(-1.0, 1.0, self.width)
        self._basis, _ = np.linalg.qr(np.vander(x, 3))  # orthonormal: quadratics along x

    def _bands(self, region: np.ndarray) -> np.ndarray:
        """Return the mean profile of each half side, upper above, lower above, ... (4 x width)."""
        return _row_means(region, self._halves)

    def _sides(self, region: np.ndarray) -> np.ndarray:
        """Return the mean profile of the rows above and of those below the mark (2 x width)."""
        return _row_means(region, self._sides_rows)

    def _departure(self, ratio: np.ndarray) -> np.ndarray:
        """Return each side's RMS departure from its best quadratic along x."""
        # The basis is orthonormal: what it leaves is the sum of squares less its part's
        kept = ratio @ self._basis
        left = np.einsum('ij,ij->i', ratio, ratio) - np.einsum('ij,ij->i', kept, kept)
        return np.sqrt(np.maximum(left, 0.0) / self.width)

    def _rough(self, ratio: np.ndarray) -> np.ndarray:
        """Return each side's RMS of what smoothing by SMOOTH_PX removes."""
        fine = ratio - _smooth(ratio)
        return np.sqrt(np.mean(fine ** 2, axis=1))

    def prime(self, regions: list[np.ndarray]) -> None:
        """Learn the side rows' plate and their scatter from the priming ROIs (see module)."""
        self.enabled = False
        if min(self.above.size, self.below.size) < MIN_SIDE or len(regions) < MIN_FRAMES \
                or self.width < 16:
            return
        reference = np.median([self._bands(region) for region in regions], axis=0)
        sides = np.array([self._sides(region) for region in regions])
        side_reference = np.median(sides, axis=0)
        if not (np.all(np.isfinite(reference)) and np.all(np.isfinite(side_reference))
                and reference.min() > 0 and side_reference.min() > 0):
            return
        self._reference, self._side_reference = reference, side_reference
        ratios = sides / side_reference
        scatter = float(np.quantile([self._departure(r).max() for r in ratios], QUIET))
        if not scatter <= PLAIN_AT_MOST:
            return
        self._scatter = scatter
        self._roughness = float(np.quantile([self._rough(r).max() for r in ratios], QUIET))
        self.enabled = True

    def light(self, region: np.ndarray) -> np.ndarray | None:
        """Return the light over ``region`` (height x width) when a shadow is on it, else None."""
        if not self.enabled or self._reference is None or self._side_reference is None:
            return None
        departure = self._departure(self._sides(region) / self._side_reference)
        if not np.all(np.isfinite(departure)) or departure.max() < max(
                STANDS_OUT * self._scatter, AT_LEAST):
            return None
        if departure.min() < SIDES_ALIKE * departure.max():
            return None  # something over one side only
        # A hot pixel is not shadowed: a median of 3 columns leaves its spike out, and an
        # edge as it is
        bands = median_filter(self._bands(region) / self._reference, size=(1, 3), mode='nearest')
        ratio = self._mix @ bands
        smooth = _smooth(ratio)
        # Sharp edges (an object in front: a blade, a fibre) leave what smoothing cannot follow
        # (but for the ends, which one cubic fits: an edge there is not followed either)
        inner = slice(SMOOTH_PX // 2, self.width - SMOOTH_PX // 2)
        kept = np.abs(ratio - smooth)[:, inner].max(axis=1) - SHARP * self._roughness
        if np.any(kept > EDGE * (smooth.max(axis=1) - smooth.min(axis=1))):
            return None
        upper, lower = float(self.above.mean()), float(self.below.mean())
        shift = _shift(smooth[0], smooth[1], int(MAX_TILT * (lower - upper)))
        if shift is None:
            return None
        tilt = shift / (lower - upper)  # px per row: row y sees upper's at x - tilt (y - upper)
        columns = np.arange(self.width, dtype=np.float64)

        def at(rows):
            """Return the light along ``rows`` (a column of row numbers), from both sides."""
            return 0.5 * (np.interp(columns - tilt * (rows - upper), columns, smooth[0])
                          + np.interp(columns - tilt * (rows - lower), columns, smooth[1]))

        # Each half side against the light there: a straight shadow fits all four; a disc (a
        # ball rolling over the mark), or something over one side only, does not
        reach = np.abs(self._half_rows[:, None] - np.array([upper, lower])[None, :]).max()
        end = min(int(math.ceil(abs(tilt) * reach)) + 1, self.width // 4)  # extrapolated
        misfit = _smooth(bands) - at(self._half_rows[:, None])
        error = float(np.sqrt(np.mean(misfit[:, end:self.width - end] ** 2, axis=1)).max())
        if error > AGREE * float(departure.max()):
            return None
        light = at(np.arange(self.height, dtype=np.float64)[:, None])
        if light.min() < FLOOR:
            return None
        self.error = error
        return light

    def level(self, first: int, stop: int) -> float:
        """Return the sides' plate level (DN, priming's) over columns ``first`` to ``stop``."""
        if self._reference is None:
            return math.nan
        part = self._reference[:, max(first, 0):max(stop, first + 1)]
        return float(part.mean()) if part.size else math.nan

    def above_black(self, light: np.ndarray, black: float) -> np.ndarray:
        """Return ``light`` (a ratio of pixel values) as the ratio of what is above ``black``.

        The sides' plate read ``reference`` DN while priming (per column); a pixel there now
        reads ``light * reference``, of which ``black`` is the camera's offset, not light.
        """
        if black == 0.0 or self._reference is None:
            return light
        level = self._reference.mean(axis=0)  # per column
        if level.min() <= black:
            return light
        return (light * level - black) / (level - black)


def _row_means(region: np.ndarray, rows: list[slice]) -> np.ndarray:
    """Return the mean along each slice of ``region``'s rows (len(rows) x width)."""
    try:  # OpenCV's reduction: a third of numpy's time on a frame's ROI
        return np.vstack([cv2.reduce(region[part], 0, cv2.REDUCE_AVG, dtype=cv2.CV_64F)
                          for part in rows])
    except cv2.error:  # a pixel type OpenCV does not take
        return np.stack([region[part].mean(axis=0, dtype=np.float64) for part in rows])


def _smooth(ratio: np.ndarray) -> np.ndarray:
    """Return the side profiles smoothed along x by a local cubic (Savitzky-Golay, SMOOTH_PX).

    A local cubic follows a soft shadow's edge: a Gaussian of 2 px misplaced the light by 2 %
    at the ends of a 16 px penumbra 45 % deep, more than the noise of the mark's profile.
    """
    return savgol_filter(ratio, SMOOTH_PX, 3, axis=1, mode='interp')


def _shift(upper: np.ndarray, lower: np.ndarray, most: int) -> float | None:
    """Return ``s`` with ``upper(x) ~ lower(x + s)``, from their slopes; None if unclear.

    Integer shifts up to ``most`` (and a third of the width) are compared by the mean squared
    difference of the slopes over the whole width, refined by a parabola through the best
    three.
    """
    width = upper.size
    most = max(min(most, width // 3), 1)
    # Beyond the ends the slope is taken as 0: over the whole width, a dip on one side only
    # is never shifted out of the comparison
    a, b = np.gradient(upper), np.pad(np.gradient(lower), most)
    shifts = np.arange(-most, most + 1)
    cost = np.array([np.mean((a - b[most + s:most + s + width]) ** 2) for s in shifts])
    best = int(np.argmin(cost))
    if best in (0, shifts.size - 1):
        return None  # at the limit: no tilt within reach fits
    before, here, after = cost[best - 1], cost[best], cost[best + 1]
    curve = before - 2.0 * here + after
    step = 0.5 * (before - after) / curve if curve > 0 else 0.0
    return float(shifts[best] + step)
