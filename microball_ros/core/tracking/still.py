"""A mark that does not move over the priming frames (a stuck slider), on a textured plate.

A mark and its plate that never move are one pattern fixed in the image: nothing tells the
mark from the texture but its shape. The deficit centroid (core.tracking.centroid) then takes
texture dips beside the mark into it, some frames and not others: on a 6 % texture of 3 px
grain it jumps between two positions 0.7 px apart and is 0.4-1 px off on average (the second
blind set's t15: 0.40 px); on a coarse one (grain 7.5 px) by pixels. ``StillMark`` instead

1. finds the mark in the priming frames' mean ROI, in 2-D (``find_mark``): on its own rows
   it stands out of a texture that the ROI's column profile weighs alike;
2. puts the mark's centre where its edges are most nearly mirror-symmetric, row by row, in
   the priming frames (core.tracking.plate_rows.edge_offset; the plate beside the mark,
   interpolated under it, divided out);
3. measures each frame's shift from there by registering the row-weighted profile over a
   fixed window against the priming frames' mean profile (a gain, a gradient of the light
   across the window, an offset and the shift, least squares linearised about no shift), so
   no dip beside the mark joins it.

A frame is not reported if the profile no longer matches (``MATCH`` times the priming
residual: something over the mark) or the mark moved over ``REACH`` px (it is no longer
still: core.tracking.plate learns it again from the frames that follow). Still: the
centroid's priming positions stay within ``STILL`` px (``is_still``), or the priming frames
register on the mean within ``STATIC`` of the mark's depth and ``REACH`` / 2 px and show the
mark where the mean does (``found_there``; a centroid jumping between texture dips cannot
tell). Then no plate is learned (nothing moves to tell it from the field fixed in the image;
a textured plate's smear search took the mark's dip for a long smear and refused every
frame). Only for a plate with a texture (``TEXTURE`` of its level beside the mark): on a
plain plate the centroid is exact, and the edges of a still mark err by the interpolation of
its pixels (up to 0.006 px under 0.8 px optics, 0.05 px under 0.5 px).

Measured on still marks (boxes, discs, crosses, bar pairs, bright discs and rectangles) on
textures of 3-12 % and grain 2-8 px: before step 1, 6 of 70 erred by 1.6-6.1 px or were
lost in some or all frames; now none, mean errors within 0.12 px (a bright disc on an 8 %
texture; the other 69 within 0.051 px).
"""

import math

import numpy as np
from scipy.ndimage import label, uniform_filter

from microball_ros.core.tracking.plate_rows import edge_offset
from microball_ros.core.tracking.profile import row_weights
from microball_ros.core.tracking.results import MarkMeasurement, with_centre

STILL = 2.0  # px: the centroid's priming positions (10th-90th percentile) within this: still
TEXTURE = 0.02  # RMS beside the mark about a parabola along each row, of its level
MOVE = 3.0  # px: the edges may move the found centre this far, or its half-extent
REACH = 2.0  # px: a frame's shift beyond this: the mark moves, no longer still
MATCH = 3.0  # a frame's residual over this many times the priming median: not reported
FLANK = 8  # px of the window beside the mark
HALF = 0.5  # find_mark: the mark is where the deficit exceeds this share of its peak
PART = 0.8  # find_mark: a separate part this deep on the mark's rows belongs to it
STATIC = 0.1  # a priming frame's residual RMS, of the mark's depth in the window: still
AGREE = 0.8  # found_there: the share of frames in which the mark must be found where it was


def is_still(found, x) -> bool:
    """Return True if the centroid found the mark still over the priming frames.

    ``found``: its measurements (image columns; the ROI starts at column ``x``): at least 8,
    80 % of them within ``STILL`` px.
    """
    seen = _columns(found, x)
    seen = seen[np.isfinite(seen)]
    return seen.size >= 8 and float(np.subtract(*np.percentile(seen, [90, 10]))) < STILL


def _columns(found, x) -> np.ndarray:
    """Return the ROI columns of the measurements ``found`` (NaN: none; ROI at column ``x``)."""
    return np.array([m.position_px - x if m.valid else math.nan for m in found])


def find_mark(mean: np.ndarray, polarity: str) -> tuple[float, float] | None:
    """Return the mark's centre column and half-extent (px) in a still scene's mean ROI.

    The ROI's light is a quadratic surface fitted outside the mark (twice, leaving out what
    is over a quarter of the deepest deficit); the deficit against it, smoothed over 3 x 3
    px, is the mark where it exceeds ``HALF`` of its peak: the part holding the peak, and
    others as deep (``PART`` of the peak, a bar of a pair) on the same rows. Found in 2-D, a
    mark on a few of the ROI's rows stands out of a texture that the ROI's column profile
    would weigh alike. None if nothing stands out.
    """
    height, width = mean.shape
    v, u = np.mgrid[-1.0:1.0:height * 1j, -1.0:1.0:width * 1j]
    design = np.stack([np.ones_like(u), u, v, u * u, u * v, v * v], axis=-1).reshape(-1, 6)
    values = mean.ravel().astype(np.float64)
    sign = 1.0 if polarity == 'dark' else -1.0
    keep = np.ones(values.size, dtype=bool)
    for _ in range(3):
        if np.count_nonzero(keep) < 4 * design.shape[1]:
            return None
        kept = design[keep]
        light = design @ np.linalg.solve(kept.T @ kept, kept.T @ values[keep])
        if not np.all(light > 0):
            return None
        deficit = uniform_filter((sign * (1.0 - values / light)).reshape(height, width), 3,
                                 mode='nearest')
        peak = float(deficit.max())
        keep = deficit.ravel() < 0.25 * peak
    if not peak > 0:
        return None
    parts, _ = label(deficit > HALF * peak)
    main = parts[np.unravel_index(int(np.argmax(deficit)), deficit.shape)]
    main_rows = np.flatnonzero((parts == main).any(axis=1))
    chosen = np.zeros(deficit.shape, dtype=bool)
    for part in range(1, int(parts.max()) + 1):
        inside = parts == part
        rows = np.flatnonzero(inside.any(axis=1))
        if part == main or (float(deficit[inside].max()) >= PART * peak
                            and rows[0] <= main_rows[-1] and rows[-1] >= main_rows[0]):
            chosen |= inside
    columns = np.flatnonzero(chosen.any(axis=0))
    return 0.5 * float(columns[0] + columns[-1]), 0.5 * float(columns[-1] - columns[0] + 1)


def mark_and_rows(mean: np.ndarray, polarity: str, pad: int):
    """Return (centre, half-extent, row weights) of the mark in a mean ROI, or None.

    ``find_mark``'s centre and half-extent, and the rows weighted by the mark's depth there
    (profile.row_weights, ``pad`` px beyond it); None if either is not found.
    """
    found = find_mark(mean, polarity)
    if found is None:
        return None
    start, extent = found
    weights = row_weights(mean, int(start - extent) - 2, int(start + extent) + 3, pad,
                          polarity)
    if weights is None or not extent > 0:
        return None
    return start, extent, weights


def found_there(regions, polarity: str, center: float, extent: float) -> bool:
    """Return True if ``find_mark`` puts the mark within ``extent`` px of ``center``.

    In ``AGREE`` of the frames ``regions``, one by one.

    A window fixed in the image holds still features that ``find_mark`` can take for a
    mark in the frames' mean, while the mark itself moves (its smear in the mean is
    shallow): frame by frame, the moving mark is the deepest.
    """
    found = [find_mark(np.asarray(region, dtype=np.float64), polarity) for region in regions]
    near = [f is not None and abs(f[0] - center) <= extent for f in found]
    return float(np.mean(near)) >= AGREE


class StillMark:
    """A still mark's centre (by its edges) and its per-frame shift (see the module)."""

    def __init__(self, weights, lo, center, reference, extent):
        """Keep what ``learn`` found (see there).

        ``weights``: the rows'; ``lo``: the window's first column; ``reference``: the mean
        profile there; ``center``, ``extent``: the mark's centre (ROI px) and half-extent.
        """
        self.weights, self.lo, self.center = weights, int(lo), float(center)
        self.size, self.extent = reference.size, float(extent)
        tilt = np.linspace(-1.0, 1.0, reference.size)  # a gradient of the light
        # Each profile ~ gain * reference * (1 + tilt) + offset - gain * shift * its slope.
        self.design = np.column_stack([reference, tilt * reference, np.ones(reference.size),
                                       -np.gradient(reference)])
        self.inverse = np.linalg.pinv(self.design)
        self.variance = float(np.linalg.inv(self.design.T @ self.design)[3, 3])
        self.residual = 1.0  # the priming frames' median residual RMS (``learn``)
        self.centre_sigma = math.nan  # px: the centre's standard error (``learn``)

    @classmethod
    def learn(cls, regions, polarity: str, pad: int, still: bool):
        """Return a StillMark for a still mark on a textured plate, else None.

        ``regions``: the priming frames' ROIs as they are. The mark is found in their mean
        (``find_mark``), not where the centroid put it: the centroid of a dip joined to
        texture dips can be pixels off, or jump between frames. Still: ``still`` (the
        centroid's ``is_still``), or as the module says.
        """
        mean = np.mean(regions, axis=0)
        found = mark_and_rows(mean, polarity, pad)
        if found is None:
            return None
        start, extent, weights = found
        width = mean.shape[1]
        lo, hi = max(int(start - extent) - FLANK, 0), min(int(start + extent) + FLANK + 1, width)
        columns = np.arange(width)
        beside = np.abs(columns - start) > extent + 4.0
        if np.count_nonzero(beside) < 12 or hi - lo < 8:
            return None
        rows = mean[weights > 0][:, beside]
        fit = np.polynomial.polynomial.polyfit(columns[beside], rows.T, 2)
        trend = np.polynomial.polynomial.polyval(columns[beside], fit)
        if not float(np.sqrt(np.mean((rows - trend) ** 2))) > TEXTURE * float(rows.mean()):
            return None
        reference = weights @ mean[:, lo:hi]
        registered = cls(weights, lo, start, reference, extent)
        fits = np.array([registered._fit(region) for region in regions])
        if not still and not (
                float(np.percentile(np.abs(fits[:, 0]), 90)) <= 0.5 * REACH
                and float(np.median(fits[:, 3])) < STATIC * float(np.ptp(reference))
                and found_there(regions, polarity, start, extent)):
            return None
        offset, asymmetry, centre_sigma = edge_offset(
            regions, weights, np.full(len(regions), start), np.zeros((len(regions), 2)),
            extent, 1.0 if polarity == 'dark' else -1.0, max(MOVE, extent))
        if not math.isfinite(asymmetry):
            return None
        still_mark = cls(weights, lo, start + offset, reference, extent)
        still_mark.residual = float(np.median(fits[:, 3]))
        still_mark.centre_sigma = centre_sigma
        return still_mark if still_mark.residual > 0 else None

    def _fit(self, region):
        """Return (shift px, its sigma, gain, residual RMS) of one ROI's windowed profile."""
        profile = self.weights @ region[:, self.lo:self.lo + self.size].astype(np.float64)
        coefficients = self.inverse @ profile
        gain, moved = float(coefficients[0]), float(coefficients[3])
        residual = profile - self.design @ coefficients
        rms = math.sqrt(float(residual @ residual) / max(self.size - 4, 1))
        if not gain > 0:
            return math.nan, math.nan, gain, rms
        return moved / gain, rms * math.sqrt(self.variance) / gain, gain, rms

    def measure(self, region, x) -> MarkMeasurement:
        """Measure one ROI (``x``: its first image column); ``reason`` 'moved' if it moved."""
        shift, sigma, _, rms = self._fit(region)
        if not abs(shift) <= REACH:
            return MarkMeasurement(math.nan, 0.0, reason='moved')
        if rms > MATCH * self.residual:
            return MarkMeasurement(math.nan, 0.0, reason='mark partly hidden')
        return MarkMeasurement(x + self.center + shift, 1.0,
                               sigma_px=with_centre(sigma, self.centre_sigma),
                               extent_px=2.0 * self.extent)
