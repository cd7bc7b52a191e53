"""A mark that moves less than its own width over the priming frames.

Learning a plate (core.tracking.plate) starts from the mark's positions against the median
of the priming frames, where the mark is elsewhere in most of them, and learns a pattern
fixed in the image from them too. A mark that overlaps itself in every frame is in that
median: the first positions are the edges of its own ghost, and the fixed pattern takes the
mark in. Measured on a 20 px bar on a 5 % texture moving +-2 to +-8 px: 1.8-8 px RMS with
half the frames lost (+-12 px: 0.02-0.07 px). ``SmallMotion`` instead

1. finds the mark in the priming frames' mean ROI (core.tracking.still.find_mark: its smear
   over the travel), and weights the rows by its depth there;
2. learns a reference profile of the row-weighted ROI by aligning the priming frames'
   profiles: each registered on the reference, then averaged shifted back (``ROUNDS``
   rounds, starting from their mean; the mean shift is the origin);
3. registers each frame on it over a fixed window: whole-pixel shifts by correlation, then
   Gauss-Newton on the shift with a gain, a light gradient and an offset solved at each
   step (their standard error from the fit's residual);
4. puts the mark's centre where its edges are most nearly mirror-symmetric
   (core.tracking.plate_rows.edge_offset, at the registered positions), as for a still mark.

Used when the centroid's priming positions (10th-90th percentile) span less than the mark's
least-smeared extent, on plain and textured plates alike (on a weak texture the centroid of
a cross was 0.1-0.24 px off). A frame registered beyond the priming frames' travel by over
``REACH`` px is 'moved' (core.tracking.plate then learns the mark again from the frames that
follow), one that no longer matches (``MATCH`` times the priming residual) 'mark partly
hidden'. A mark without edges (a blob) keeps the half-depth mid-point of ``find_mark``'s whole
columns: plain blobs moving +-6 to +-11 px were 0.05-0.17 px RMS.
"""

import math

import numpy as np
from scipy.interpolate import CubicSpline

from microball_ros.core.tracking.plate_rows import edge_offset
from microball_ros.core.tracking.results import MarkMeasurement, with_centre
from microball_ros.core.tracking.still import (
    FLANK,
    MATCH,
    MOVE,
    REACH,
    STATIC,
    found_there,
    mark_and_rows,
)

ROUNDS = 3  # the reference's alignment rounds
STEPS = 8  # Gauss-Newton steps on a frame's shift
SETTLED = 1e-4  # px: a step this small ends them


def moves_little(found, x) -> bool:
    """Return True if the centroid's priming positions span less than the mark's extent.

    ``found``: its measurements (image columns; the ROI starts at column ``x``), at least 8
    of them valid; the span is their 10th-90th percentile, the extent the 10th percentile
    of theirs (the least smeared: a long smear's extent can exceed the travel).
    """
    seen = np.array([m.position_px - x for m in found if m.valid])
    extents = [m.extent_px for m in found if m.valid and math.isfinite(m.extent_px)]
    if seen.size < 8 or not extents:
        return False
    return float(np.subtract(*np.percentile(seen, [90, 10]))) < float(
        np.percentile(extents, 10))


class SmallMotion:
    """A mark's reference profile, its centre and each frame's shift (see the module)."""

    def __init__(self, weights, reference, lo, hi, limit):
        """Keep the rows' ``weights``, the ``reference`` profile (ROI columns) and the window.

        ``lo``, ``hi``: the window's columns; ``limit``: the largest shift searched (px).
        """
        self.weights = weights
        self.spline = CubicSpline(np.arange(reference.size), reference)
        self.slope = self.spline.derivative()
        self.columns = np.arange(lo, hi, dtype=float)
        self.tilt = np.linspace(-1.0, 1.0, reference.size)[lo:hi]
        self.lo, self.hi, self.limit = int(lo), int(hi), int(limit)
        shifts = np.arange(-self.limit, self.limit + 1)
        models = self.spline(self.columns[None, :] - shifts[:, None])
        models -= models.mean(axis=1, keepdims=True)
        self.shifts = shifts
        self.models = models / np.linalg.norm(models, axis=1, keepdims=True)
        self.center = 0.0  # ROI px at shift 0 (``learn``)
        self.extent = 0.0
        self.residual = 1.0
        self.centre_sigma = math.nan  # px: the centre's standard error (``learn``)
        self.reach = float(self.limit)

    @classmethod
    def learn(cls, regions, polarity: str, pad: int):
        """Return a SmallMotion for a mark that moves little, else None.

        ``regions``: the priming frames' ROIs as they are. None where the frames do not
        register on the reference (``STATIC`` of its depth), do not show the mark where the
        mean does (``found_there``), or the edges cannot be measured.
        """
        stack = np.asarray(regions, dtype=np.float64)
        mean = stack.mean(axis=0)
        found = mark_and_rows(mean, polarity, pad)
        if found is None:
            return None
        start, extent, weights = found
        width = mean.shape[1]
        margin = int(math.ceil(extent)) + FLANK
        lo, hi = int(start) - margin, int(start) + margin + 1
        limit = min(lo, width - hi)
        if limit < 2:
            return None
        profiles = np.einsum('r,nrc->nc', weights, stack)
        reference = profiles.mean(axis=0)
        for _ in range(ROUNDS):
            small = cls(weights, reference, lo, hi, limit)
            fits = [small._register(profile) for profile in profiles]
            if not all(math.isfinite(f[0]) for f in fits):
                return None
            origin = float(np.mean([f[0] for f in fits]))
            reference = _aligned(profiles, fits, origin, small.tilt, lo, hi)
            if reference is None:
                return None
        small = cls(weights, reference, lo, hi, limit)
        fits = [small._register(profile) for profile in profiles]
        shifts = np.array([f[0] for f in fits])
        small.residual = float(np.median([f[3] for f in fits]))
        depth = float(np.ptp(reference[lo:hi]))
        if not (np.all(np.isfinite(shifts)) and 0 < small.residual < STATIC * depth
                and found_there(regions, polarity, start, extent)):
            return None
        offset, asymmetry, centre_sigma = edge_offset(
            regions, weights, start + shifts, np.zeros((len(regions), 2)), extent,
            1.0 if polarity == 'dark' else -1.0, max(MOVE, extent))
        if not math.isfinite(asymmetry):
            return None
        small.center, small.extent, small.centre_sigma = start + offset, extent, centre_sigma
        small.reach = min(float(np.max(np.abs(shifts))) + REACH, float(limit))
        return small

    def _register(self, profile):
        """Return (shift px, its sigma, light, residual RMS) of a row-weighted ROI profile.

        ``light``: the gain, the light gradient's and the offset's coefficients (the profile
        over the window ~ (gain + gradient * tilt) * reference(x - shift) + offset). NaN
        where the fit fails or leaves the searched shifts.
        """
        values = profile[self.lo:self.hi]
        centred = values - values.mean()
        shift = float(self.shifts[int(np.argmax(self.models @ centred))])
        for _ in range(STEPS):
            design, coefficients, residual, jacobian = self._linear(values, shift)
            scale = float(jacobian @ jacobian)
            if not scale > 0:
                return math.nan, math.nan, None, math.nan
            step = float(jacobian @ residual) / scale
            shift += step
            if abs(shift) > self.limit:
                return math.nan, math.nan, None, math.nan
            if abs(step) < SETTLED:
                break
        full = np.column_stack([design, jacobian])
        count = values.size - full.shape[1]
        rms = math.sqrt(float(residual @ residual) / max(count, 1))
        covariance = np.linalg.pinv(full.T @ full)
        return shift, rms * math.sqrt(max(float(covariance[3, 3]), 0.0)), coefficients, rms

    def _linear(self, values, shift):
        """Return the design, light, residual and d(model)/d(shift) of ``values`` at ``shift``."""
        at = self.columns - shift
        model = self.spline(at)
        design = np.column_stack([model, self.tilt * model, np.ones(model.size)])
        coefficients = np.linalg.lstsq(design, values, rcond=None)[0]
        residual = values - design @ coefficients
        jacobian = -(coefficients[0] + coefficients[1] * self.tilt) * self.slope(at)
        return design, coefficients, residual, jacobian

    def measure(self, region, x) -> MarkMeasurement:
        """Measure one ROI (``x``: its first image column); ``reason`` 'moved' if it moved."""
        profile = self.weights @ np.asarray(region, dtype=np.float64)
        shift, sigma, light, rms = self._register(profile)
        if not abs(shift) <= self.reach:
            return MarkMeasurement(math.nan, 0.0, reason='moved')
        if light is None or not light[0] > 0 or rms > MATCH * self.residual:
            return MarkMeasurement(math.nan, 0.0, reason='mark partly hidden')
        return MarkMeasurement(x + self.center + shift, 1.0,
                               sigma_px=with_centre(sigma, self.centre_sigma),
                               extent_px=2.0 * self.extent)


def _aligned(profiles, fits, origin, tilt, lo, hi):
    """Return the profiles' mean shifted back by their shifts less ``origin``, light divided.

    ``fits``: each profile's ``_register``. Its light (gain, gradient over the window
    ``lo``:``hi`` as ``tilt``, extended linearly, and offset) is divided out; columns a
    shift leaves uncovered are not averaged. None if some column has no profile.
    """
    width = profiles.shape[1]
    columns = np.arange(width, dtype=float)
    slope = (tilt[-1] - tilt[0]) / max(hi - lo - 1, 1)
    total, count = np.zeros(width), np.zeros(width)
    for profile, (shift, _, light, _) in zip(profiles, fits, strict=True):
        at = columns + (shift - origin)
        inside = (at >= 0) & (at <= width - 1)
        gain = light[0] + light[1] * (tilt[0] + slope * (at[inside] - lo))
        total[inside] += (CubicSpline(columns, profile)(at[inside]) - light[2]) / gain
        count[inside] += 1
    if not np.all(count > 0):
        return None
    return total / count
