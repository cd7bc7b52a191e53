"""A mark that does not move over the priming frames (a stuck slider), on a textured plate.

A mark and its plate that never move are one pattern fixed in the image: nothing tells the
mark from the texture but its shape. The deficit centroid (core.tracking.centroid) then takes
texture dips beside the mark into it, some frames and not others: on a 6 % texture of 3 px
grain it jumps between two positions 0.7 px apart and is 0.4-1 px off on average (the second
blind set's t15: 0.40 px). ``StillMark`` instead

1. puts the mark's centre where its edges are most nearly mirror-symmetric, row by row, in
   the priming frames (core.tracking.plate_rows.edge_offset; the plate beside the mark,
   interpolated under it, divided out);
2. measures each frame's shift from there by registering the row-weighted profile over a
   fixed window against the priming frames' mean profile (a gain, a gradient of the light
   across the window, an offset and the shift, least squares linearised about no shift), so
   no dip beside the mark joins it.

A frame is not reported if the profile no longer matches (``MATCH`` times the priming
residual: something over the mark) or the mark moved over ``REACH`` px (it is no longer
still: the centroid tracker measures it from then on). Still (``is_still``): the centroid's
priming positions stay within ``STILL`` px; then no plate is learned (nothing moves to tell
it from the field fixed in the image; a textured plate's smear search took the mark's dip for
a long smear and refused every frame). Only for a plate with a texture (``TEXTURE`` of its
level beside the mark): on a plain plate the centroid is exact, and the edges of a still
mark err by the interpolation of its pixels (up to 0.006 px under 0.8 px optics, 0.05 px
under 0.5 px). Where the centroid's dip joins texture dips in some frames and not in others
(jumping by pixels), spans most of the ROI, or is lost in every frame, the centroid stays
(measured on 16 px boxes in a 120 px ROI: 3 of 24 textures of 3-10 %, errors of 8-14 px or
nothing reported).
"""

import math

import numpy as np

from microball_ros.core.tracking.plate_rows import edge_offset
from microball_ros.core.tracking.profile import row_weights
from microball_ros.core.tracking.results import MarkMeasurement

STILL = 2.0  # px: the centroid's priming positions (10th-90th percentile) within this: still
TEXTURE = 0.02  # RMS beside the mark about a parabola along each row, of its level
MOVE = 3.0  # px: the edges may move the centroid's centre this far, or its half-extent
REACH = 2.0  # px: a frame's shift beyond this: the mark moves, no longer still
MATCH = 3.0  # a frame's residual over this many times the priming median: not reported
FLANK = 8  # px of the window beside the mark


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

    @classmethod
    def learn(cls, regions, found, x, polarity: str, pad: int):
        """Return a StillMark for a mark ``is_still`` found still on a textured plate, else None.

        ``found``: the centroid's measurements of the ROIs ``regions`` (image columns, the
        ROI starting at column ``x``), at least 8. The mark is looked for within the
        centroid's half-extent of the centroid's median: the centroid of a dip joined to
        texture dips can be pixels off.
        """
        seen = _columns(found, x)
        seen = seen[np.isfinite(seen)]
        if seen.size < 8:
            return None
        extent = 0.5 * float(np.median([m.extent_px for m in found if m.valid]))
        start = float(np.median(seen))
        mean = np.mean(regions, axis=0)
        width = mean.shape[1]
        weights = row_weights(mean, int(start - extent) - 2, int(start + extent) + 3, pad,
                              polarity)
        lo, hi = max(int(start - extent) - FLANK, 0), min(int(start + extent) + FLANK + 1, width)
        columns = np.arange(width)
        beside = np.abs(columns - start) > extent + 4.0
        if weights is None or not extent > 0 or np.count_nonzero(beside) < 12 or hi - lo < 8:
            return None
        rows = mean[weights > 0][:, beside]
        fit = np.polynomial.polynomial.polyfit(columns[beside], rows.T, 2)
        trend = np.polynomial.polynomial.polyval(columns[beside], fit)
        if not float(np.sqrt(np.mean((rows - trend) ** 2))) > TEXTURE * float(rows.mean()):
            return None
        offset, asymmetry = edge_offset(regions, weights, np.full(len(regions), start),
                                        np.zeros((len(regions), 2)), extent,
                                        1.0 if polarity == 'dark' else -1.0,
                                        max(MOVE, extent))
        if not math.isfinite(asymmetry):
            return None
        still = cls(weights, lo, start + offset, weights @ mean[:, lo:hi], extent)
        still.residual = float(np.median([still._fit(region)[3] for region in regions]))
        return still if still.residual > 0 else None

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
        return MarkMeasurement(x + self.center + shift, 1.0, sigma_px=sigma,
                               extent_px=2.0 * self.extent)
