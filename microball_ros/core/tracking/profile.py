"""The mark model: an ROI reduced to a 1-D profile along x, and the mark as a relative deficit.

Owns the model every later stage works on. The ROI's rows are averaged into a profile along
the bearing axis (``column_profile``), or averaged with weights proportional to the mark's
depth in each row, a matched filter across rows estimated from the frame itself
(``row_weighted_profile``). The plain plate under the mark is a low-degree polynomial
(``Baseline``: an envelope fit the mark's dip cannot bend, then a least-squares fit outside
the mark), which removes uneven illumination; the mark is the relative deficit
``1 - profile / baseline`` (dark marks) or its negative (bright ones), ``relative_deficit``.
``deficit_noise`` estimates the per-column noise of the deficit from the plain plate.
``light_level``: a frame's light over a profile already divided by the plate (the learned
plate tracker's, core.tracking.plate): a low-order polynomial fitted beside the mark.
Polarity detection belongs here; a static background is removed before the profile is built
(core.tracking.background).
"""

from collections.abc import Callable
import functools
import math

import cv2
import numpy as np
from scipy.ndimage import binary_dilation, label

from microball_ros.core.tracking.small_linalg import lstsq

LIGHT_ORDER = 2  # light_level: the light per frame over the ROI, a polynomial of this degree
LIGHT_FLANK = 48.0  # light_level's flank while tracking: px on either side of the mark
ONE_SIDE = 24  # light_level: a flank this long alone gives the light's slope (an ROI's end)
SUSPECT = 3.0  # light_level: a fit scattering this many times the noise is started again
SIDES_APART = 0.2  # ... from one flank alone if the two flanks' lights differ this much
# light_level without a centre, ``both``: columns this many spreads off the light the other
# way (a dark tool in a bright mark's ROI, a glint in a dark one's) are no light either
OTHER_SIDE = 6.0
DEPARTS = 0.05  # light_level: a light this far from the one expected has its flanks checked

MAD_TO_SIGMA = 1.4826
_EPS = float(np.finfo(float).eps)
# disturbed: runs of this many plate columns this many noise spreads off the plate, whose
# departure is under LOCAL of theirs CLOSE px beyond them on both sides (a bump, not a trend)
DISTURBED_RUN, DISTURBED_SPREADS, LOCAL, CLOSE = 4, 6.0, 0.25, (3, 8)
GLINT_HALO = 3  # px: a glint's columns are its saturated ones and this far beside them


def median_and_error(values) -> tuple[float, float]:
    """Return the median of ``values`` and its standard error (robust).

    The error is 1.2533 (a median's, of normal data) times the MAD's sigma over sqrt(n).
    """
    values = np.asarray(values, dtype=float)
    middle = float(np.median(values))
    spread = MAD_TO_SIGMA * float(np.median(np.abs(values - middle)))
    return middle, 1.2533 * spread / math.sqrt(values.size)


def column_profile(region: np.ndarray) -> np.ndarray:
    """Return the mean of the ROI's rows (float64, one value per column)."""
    if region.dtype in (np.uint8, np.float32):
        return cv2.reduce(region, 0, cv2.REDUCE_AVG, dtype=cv2.CV_64F)[0]
    return region.astype(np.float64).mean(axis=0)


def saturation_level(dtype: np.dtype, given: float | None = None) -> float | None:
    """Return the saturation level: ``given`` (the config's), else the pixel type's.

    The pixel type's is the level at which a sensor of that type saturates (None: unknown).
    """
    if given is not None:
        return given
    if dtype == np.uint8:
        return 255.0
    if dtype == np.uint16:
        return 65535.0
    return None


def glint_columns(region: np.ndarray, rows: np.ndarray,
                  saturation: float | None = None) -> np.ndarray | None:
    """Return the columns a glint clips in ``rows`` of ``region`` (as it is), None: none.

    Those with a pixel at ``saturation`` (the pixel type's, by default), widened by
    ``GLINT_HALO`` px either side (its halo). On a dark mark's plate a saturated pixel is a
    specular glint, not the mark (blind set 5: one riding 14 px beside a disc on a speckle
    cost 71 frames, the fit's residual refused).
    """
    level = saturation_level(region.dtype, saturation)
    if level is None:
        return None
    hot = (region[rows] >= level).any(axis=0)
    if not hot.any():
        return None
    return binary_dilation(hot, iterations=GLINT_HALO)


def smooth(values: np.ndarray, width: int) -> np.ndarray:
    """Return a moving average of ``width`` samples (same length; ``width <= 1``: as is)."""
    if width <= 1:
        return values
    return np.convolve(values, np.full(width, 1.0 / width), mode='same')


class Baseline:
    """Polynomial model of the plain plate along an ROI of ``width`` columns.

    The basis is the Vandermonde matrix of ``degree`` on [-1, 1] (highest power first), so a
    lower degree is its last columns.
    """

    def __init__(self, width: int, degree: int):
        """Precompute the basis and its pseudo-inverse for ``width`` columns."""
        u = np.linspace(-1.0, 1.0, width)
        self.basis = np.vander(u, int(degree) + 1)
        self.pinv = np.linalg.pinv(self.basis)

    def fit(self, profile: np.ndarray, keep: np.ndarray) -> np.ndarray:
        """Return the least-squares fit to the columns ``keep`` (the plain plate), everywhere.

        The degree drops with few columns to fit: at most one per 12 columns kept.
        """
        count = int(np.count_nonzero(keep))
        degree = min(self.basis.shape[1] - 1, max(count // 12 - 1, 0))
        basis = self.basis[keep, -(degree + 1):]
        coef = lstsq(basis, profile[keep])
        return self.basis[:, -(degree + 1):] @ coef

    def envelope(self, profile: np.ndarray, polarity: str, far: np.ndarray | None = None,
                 iterations: int = 8) -> np.ndarray:
        """Return a first baseline that the mark's dip cannot bend: iterative clipping.

        The profile is repeatedly replaced by the larger (for dark marks) of itself and the fit,
        so the fit climbs out of the dip onto the plain plate, however wide the blurred mark.
        ``far``: columns that are no plate (the fit's own value stands in for them).
        """
        clipped = profile
        if far is not None:
            clipped = np.where(far, float(np.median(profile[~far])), profile)
        clip = np.maximum if polarity == 'dark' else np.minimum
        for _ in range(iterations):
            baseline = self.basis @ (self.pinv @ clipped)
            clipped = clip(profile, baseline)
            if far is not None:
                clipped[far] = baseline[far]
        return baseline


def polarity_of(profile: np.ndarray, min_skew: float = 0.5) -> str | None:
    """Return 'dark' or 'bright': the sign of the mark in a profile, or None if unclear.

    A mark is a minority of the columns that stands out from a smooth plate: the skewness of
    the profile's departure from a quadratic fitted to all its columns is negative for a dark
    mark, positive for a bright one; None when its magnitude is below ``min_skew``.
    """
    u = np.linspace(-1.0, 1.0, profile.size)
    residual = profile - np.polyval(np.polyfit(u, profile, 2), u)
    return _skew_polarity(residual, min_skew)


def polarity_of_pixels(region: np.ndarray, min_skew: float = 0.5) -> str | None:
    """Return 'dark' or 'bright' from the ROI's pixels, or None if unclear (``polarity_of``).

    The skewness of the pixels' departure from a quadratic surface fitted to them all. Where
    the column profile is unclear, because the mark holds a few of the ROI's rows and a
    texture the rest, the mark's pixels still stand out of the plate's; elsewhere the
    profile, averaging the rows' noise away, is the surer (a faint mark, fine speckle).
    """
    height, width = region.shape
    v, u = np.mgrid[-1.0:1.0:height * 1j, -1.0:1.0:width * 1j]
    design = np.stack([np.ones_like(u), u, v, u * u, u * v, v * v], axis=-1).reshape(-1, 6)
    values = region.ravel().astype(np.float64)
    residual = values - design @ np.linalg.lstsq(design, values, rcond=None)[0]
    return _skew_polarity(residual, min_skew)


def _skew_polarity(residual: np.ndarray, min_skew: float) -> str | None:
    """Return 'dark' for a negative skewness of ``residual``, 'bright' for a positive one.

    None when its magnitude is below ``min_skew`` (or the residual is flat).
    """
    spread = float(np.std(residual))
    if spread <= 0:
        return None
    skew = float(np.mean(residual ** 3)) / spread ** 3
    if abs(skew) < min_skew:
        return None
    return 'dark' if skew < 0 else 'bright'


def relative_deficit(profile: np.ndarray, baseline: np.ndarray, polarity: str) -> np.ndarray:
    """Return the mark's relative deficit: ``1 - profile / baseline`` for dark marks."""
    if polarity == 'dark':
        return 1.0 - profile / baseline
    return profile / baseline - 1.0


def row_weights(region: np.ndarray, lo: int, hi: int, pad: int,
                polarity: str, sides: tuple[bool, bool] = (True, True)) -> np.ndarray | None:
    """Return weights per ROI row proportional to the mark's depth in it (sum 1), or None.

    The depth of a row is its mean over the mark (columns ``lo - pad`` .. ``hi + pad``)
    against its mean over flanks on both sides (``sides``: the left one, the right one); None
    if there are no flanks or no depth.
    """
    w = region.shape[1]
    a, b = max(lo - pad, 0), min(hi + pad + 1, w)
    flank = max(8, (b - a) // 4)
    left = region[:, max(a - flank, 0):a if sides[0] else max(a - flank, 0)]
    right = region[:, b:b + flank if sides[1] else b]
    if left.shape[1] + right.shape[1] == 0 or b <= a:
        return None
    outside = (left.sum(axis=1, dtype=np.float64) + right.sum(axis=1, dtype=np.float64)) / (
        left.shape[1] + right.shape[1])
    inside = region[:, a:b].mean(axis=1, dtype=np.float64)
    depth = outside - inside if polarity == 'dark' else inside - outside
    depth = np.clip(smooth(depth, 3), 0.0, None)
    total = float(depth.sum())
    if total <= 0:
        return None
    return depth / total


def plate_row_weights(region: np.ndarray, plate: np.ndarray, lo: int, hi: int, pad: int,
                      polarity: str) -> np.ndarray | None:
    """Return weights per ROI row proportional to the mark's depth in it, against a plate.

    ``plate`` is the plain plate under ``region`` (same shape, this frame's light): the depth
    of a row is the mark's mean deficit in it over columns ``lo - pad`` .. ``hi + pad``, which
    a long smear, covering most columns, leaves no flanks for (``row_weights``). None if there
    is no depth.
    """
    a, b = max(lo - pad, 0), min(hi + pad + 1, region.shape[1])
    if b <= a:
        return None
    difference = plate[:, a:b] - region[:, a:b]
    depth = difference.mean(axis=1) if polarity == 'dark' else -difference.mean(axis=1)
    depth = np.clip(smooth(depth, 3), 0.0, None)
    total = float(depth.sum())
    if total <= 0:
        return None
    return depth / total


def row_weighted_profile(region: np.ndarray, lo: int, hi: int, pad: int,
                         polarity: str) -> np.ndarray | None:
    """Return the ROI's rows averaged with weights proportional to the mark's depth in each.

    The weights are ``row_weights``; None if there are none.
    """
    weights = row_weights(region, lo, hi, pad, polarity)
    if weights is None:
        return None
    return weights @ region.astype(np.float64)


def median(values: np.ndarray) -> float:
    """Return ``np.median`` of finite 1-D ``values`` (not empty), without its overheads.

    The same number (the middle value, or the mean of the two middle ones) at a fraction of
    the cost on the short profiles of every frame.
    """
    half = values.size // 2
    if values.size % 2:
        return float(np.partition(values, half)[half])
    part = np.partition(values, (half - 1, half))
    return float((part[half - 1] + part[half]) / 2.0)


def polyfit(x: np.ndarray, y: np.ndarray, order: int) -> np.ndarray:
    """Return ``np.polyfit(x, y, order)`` for float arrays (the same steps, without checks)."""
    lhs = np.vander(x, order + 1)
    scale = np.sqrt((lhs * lhs).sum(axis=0))
    lhs /= scale
    return lstsq(lhs, y, x.size * _EPS) / scale


def _fitted(u: np.ndarray, y: np.ndarray, keep: np.ndarray, order: int) -> np.ndarray:
    """Return ``np.polyval(polyfit(u[keep], y[keep], order), u)``; a line in closed form.

    A constant or a line (the light across a mark, every frame) is the least-squares line
    through the kept columns' means, to rounding as ``polyfit``'s SVD has it, at a fraction of
    its cost; a higher order, or columns all at one ``u``, goes to ``polyfit``.
    """
    x, values = u[keep], y[keep]
    mean = float(values.sum()) / values.size
    if order == 0:
        return np.full(u.size, mean)
    if order == 1:
        x_mean = float(x.sum()) / x.size
        centred = x - x_mean
        spread = float(centred @ centred)
        if spread > 0:
            slope = float(centred @ values) / spread
            return (u - x_mean) * slope + mean
    return np.polyval(polyfit(x, values, order), u)


def deficit_noise(deficit: np.ndarray, keep: np.ndarray) -> float:
    """Return the 1-sigma noise of the deficit per column, from the plain plate ``keep``.

    The robust spread (MAD) of the second difference, which a smooth baseline error does not
    reach; 1e-6 at least, and when fewer than 8 columns are available.
    """
    second = deficit[2:] - 2.0 * deficit[1:-1] + deficit[:-2]
    second = second[keep[1:-1]]
    if second.size < 8:
        return 1e-6
    mad = median(np.abs(second - median(second)))
    return max(MAD_TO_SIGMA * mad / math.sqrt(6.0), 1e-6)


def disturbed(deficit: np.ndarray, keep: np.ndarray,
              refit: Callable[[np.ndarray], np.ndarray | None] | None = None) -> np.ndarray:
    """Return the columns of the plain plate ``keep`` that something else darkens or lights.

    A particle or a shadow over the plate away from the mark bends a baseline fitted to it:
    the mark's deficit, its area and its centroid change. Its columns are the runs of at least
    ``DISTURBED_RUN`` columns of ``keep`` off the deficit's median there by more than
    ``DISTURBED_SPREADS`` times the noise (``deficit_noise``) and than half the largest such
    departure, that are local: ``CLOSE`` px beyond either end the plate (kept columns) departs
    under ``LOCAL`` as much (beyond the end away from the ROI's end only, for a run that
    reaches it: something entering the ROI). A baseline that cannot follow the plate near the
    ROI's ends departs smoothly: it is left as it is. Widened by 2 columns.

    Something dark at an ROI's end bends the baseline beside it the other way, so the run is
    not local: with ``refit`` (the deficit against a baseline fitted to the columns given, or
    None), such a run is also taken when, fitted without it, it still departs over the limit
    and the plate elsewhere under ``LOCAL`` times as much (or the limit), as a local run's sides
    (a particle at the ROI's end, 60 px from the mark, lost 13 frames and moved one 0.74 px).
    """
    off = np.zeros(deficit.size, dtype=bool)
    if np.count_nonzero(keep) < 12:
        return off
    departure = np.where(keep, np.abs(deficit - median(deficit[keep])), 0.0)
    worst, limit = float(departure.max()), DISTURBED_SPREADS * deficit_noise(deficit, keep)
    if not worst > limit:
        return off
    runs, count = label(departure > max(limit, 0.5 * worst))
    near, far = CLOSE
    for run in range(1, count + 1):
        columns = np.flatnonzero(runs == run)
        first, last = int(columns[0]), int(columns[-1])
        if columns.size < DISTURBED_RUN:
            continue
        sides = [np.arange(first - far, first - near + 1), np.arange(last + near, last + far + 1)]
        # A run at the ROI's end (something entering it) has one side
        sides = [side[(side >= 0) & (side < keep.size)] for side in sides]
        sides = [side[keep[side]] for side in sides if side.size >= 3]
        peak = float(departure[first:last + 1].max())
        if sides and all(side.size >= 3 and float(departure[side].max()) < LOCAL * peak
                         for side in sides):
            off[max(first - 2, 0):last + 3] = True
        elif refit is not None and _bends(deficit, keep, first, last, limit, refit):
            off[max(first - 2, 0):last + 3] = True
    return off & keep


def _bends(deficit, keep, first, last, limit, refit) -> bool:
    """Return True if the run ``first..last`` bends the baseline (``disturbed``'s refit)."""
    trial = keep.copy()
    trial[max(first - 2, 0):last + 3] = False
    if np.count_nonzero(trial) < 12:
        return False
    other = refit(trial)
    if other is None:
        return False
    middle = median(other[trial])
    rest = float(np.abs(other[trial] - middle).max())
    run = float(np.abs(other[first:last + 1] - middle).max())
    return rest <= max(limit, LOCAL * run) and limit < run


@functools.lru_cache(maxsize=16)
def _span(width: int) -> np.ndarray:
    """Return ``np.linspace(-1, 1, width)`` (read-only; the same every frame)."""
    u = np.linspace(-1.0, 1.0, width)
    u.flags.writeable = False
    return u


def light_level(ratio: np.ndarray, polarity: str | None, center: float = math.nan,
                extent: float = 0.0, order: int | None = None,
                flank: float | None = None, noise: float | None = None,
                expected: float | None = None, both: bool = False) -> np.ndarray | None:
    """Return this frame's light over a profile divided by the static field; None if dark.

    The light (a gain, flicker, and a low-order gradient) is the polynomial of degree
    ``LIGHT_ORDER`` fitted to ``ratio`` outside ``extent`` (px, full width) around ``center``:
    there the plate is its texture alone (or nothing, when ``ratio`` was divided by it). Refitted
    without the columns far off the fit: without a centre, those in a dip (the mark); with
    one, any (something passing over the plate). With ``flank`` (px), only the columns that
    far beyond ``extent`` on either side are used, and the light is a straight line across
    the mark; when one side is missing (an ROI's end), a line through the other if it holds
    ``ONE_SIDE`` columns (a light gradient: a textured mark 5 px from the ROI's end lost 9 of
    240 frames with a constant), else a constant. Without a centre, ``both``: the columns
    ``OTHER_SIDE`` spreads off the light the other way are left out too (a dark tool in a
    bright mark's ROI: the light through it was 0.05 at the tool's side of the ROI, every
    frame after a loss 'too dark'). With a centre, a fit that scatters over
    ``SUSPECT`` times the ``noise`` per column (if not given, from the second differences in
    the flanks) is started again from the columns near the median (a particle over a flank).

    ``expected`` (the light at the mark in recent frames, if known): when the light found
    departs from it by over ``DEPARTS`` (or none is found: it crossed 0), it is the light of
    the flank nearer to it, if that one is within ``SIDES_APART`` of it and scatters under
    half as much (something dark over one flank, a tool beside the mark, is no light: fitted
    through it, the light at the mark was 0.35-0.8 for 1; a flicker moves both flanks alike).
    """
    sign = 1.0 if polarity == 'dark' else -1.0
    order = LIGHT_ORDER if order is None else int(order)
    w = ratio.size
    u = _span(w)
    least = 4 * (order + 1) + 16
    keep = np.ones(w, dtype=bool)
    if math.isfinite(center):
        offset = np.arange(w) - center
        keep = np.abs(offset) > 0.5 * extent
        if flank is not None:
            keep &= np.abs(offset) <= 0.5 * extent + flank
            sides = sorted((np.count_nonzero(keep & (offset < 0)),
                            np.count_nonzero(keep & (offset > 0))))
            order = min(order, 1) if sides[0] >= 8 or sides[1] >= ONE_SIDE else 0
            least = 12
        if np.count_nonzero(keep) < least:
            keep = np.ones(w, dtype=bool)
    # With flanks the light is a line across the mark: it need be positive only there (a
    # large dark object beyond a flank tilts it until it crosses 0 at the ROI's far end).
    within = None if flank is None or not math.isfinite(center) else (
        np.abs(np.arange(w) - center) <= 0.5 * extent + flank)
    found = _fit_light(ratio, u, keep, order, sign, math.isfinite(center), least, within,
                       both)
    if not math.isfinite(center):
        return None if found is None else found[0]
    at = int(np.clip(round(center), 0, w - 1))
    flanks = None  # the two flanks' own fits, when needed (fitted at most once)
    if expected is not None and (found is None or _apart(float(found[0][at]), expected)
                                 > DEPARTS):
        flanks = _side_lights(ratio, u, keep, offset, order, sign, least, within)
        lights = [fit for fit in flanks if fit is not None]
        if lights:
            nearest = min(lights, key=lambda fit: _apart(float(fit[0][at]), expected))
            if _apart(float(nearest[0][at]), expected) <= SIDES_APART and (
                    found is None or nearest[1] < 0.5 * found[1]):
                return nearest[0]
    if found is None:
        return None
    # Something large over a flank (a particle) can tilt the first fit so far that its
    # columns do not stand out of the others': the fit then scatters far more than the noise.
    # It starts again from the columns near the median, and is kept if it scatters half as much.
    level, spread = found
    if noise is None:
        ends = keep & np.roll(keep, 1) & np.roll(keep, -1)  # second differences in a flank
        noise = deficit_noise(sign * (1.0 - ratio / level), ends)
    if not spread > SUSPECT * noise:
        return level
    middle = median(ratio[keep])
    near = keep & (np.abs(ratio - middle) <= 4.0 * MAD_TO_SIGMA * median(
        np.abs(ratio[keep] - middle)))
    other = _fit_light(ratio, u, near, order, sign, True, least, within) if np.count_nonzero(
        near) >= least else None
    if other is not None and other[1] < 0.5 * spread:
        return other[0]
    # ... or from one flank alone, when the two flanks' lights differ grossly at the mark:
    # something dark over most of one (a tool reaching into the ROI) holds the median there
    # (the light at a bright mark was 0.8 for 1, or 'too dark').
    left, right = flanks or _side_lights(ratio, u, keep, offset, order, sign, least, within)
    if left is None or right is None:
        return level
    apart = _apart(float(left[0][at]), float(right[0][at]))
    best = min((left, right), key=lambda fit: fit[1])
    return best[0] if apart > SIDES_APART and best[1] < 0.5 * spread else level


def _apart(a: float, b: float) -> float:
    """Return how far apart two lights are, relative to the larger."""
    return abs(a - b) / max(a, b, 1e-12)


def _side_lights(ratio, u, keep, offset, order, sign, least, within):
    """Return ``_fit_light``'s fits on the left and on the right flank alone (None: none)."""
    left, right = (_fit_light(ratio, u, keep & side, order if np.count_nonzero(keep & side)
                              >= ONE_SIDE else 0, sign, True, least, within)
                   if np.count_nonzero(keep & side) >= least else None
                   for side in (offset < 0, offset > 0))
    return left, right


def _fit_light(ratio, u, keep, order, sign, centred, least, within=None, both=False):
    """Return ``light_level``'s fit (level, the spread of the columns kept); None if dark.

    Fitted on ``keep``, then again without the columns far off the fit (``centred``: any;
    else those in a dip and, ``both``, ``OTHER_SIDE`` spreads off it the other way), at most
    3 times.
    ``within``: the columns where the light must be positive (None: all); elsewhere it is
    held at least at half its least value there.
    """
    keep = keep.copy()
    for _ in range(3):
        level = _fitted(u, ratio, keep, order)
        least_level = float(level.min() if within is None else level[within].min())
        if not least_level > 0:
            return None
        if within is not None:
            level = np.maximum(level, 0.5 * least_level)
        # Columns far off the light (the mark, found in a dip, or something passing over
        # the plate) are left out, and the light fitted again.
        d = sign * (1.0 - ratio / level)
        middle = median(d[keep])
        spread = MAD_TO_SIGMA * median(np.abs(d[keep] - middle))
        inside = np.abs(d - middle) <= 4.0 * spread if centred else (
            (d < middle + 3.0 * spread) & (d > middle - (OTHER_SIDE if both else math.inf)
                                           * spread))
        if np.count_nonzero(keep & inside) < least or np.all(inside[keep]):
            break
        keep &= inside
    return level, spread
