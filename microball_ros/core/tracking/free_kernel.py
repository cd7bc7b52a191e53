"""A frame's exposure kernel of any shape: the mark's mean position when no quadratic path fits.

The learned plate's fit (core.tracking.plate_model) smears the plate's deficit ``D`` by the
kernel of a quadratic path (blur and curvature). A slider that breaks away mid-exposure (stuck,
then slipping fast) traces no such path: its kernel is a spike and a long thin tail, the fit's
residual is two to three times the plate's noise, and the frame was refused ('poor fit')
although the mark was in plain view (the sixth blind set's stick-slip slider: 8 frames; their
quadratic fits were within 0.05 px of the truth).

Here the kernel is a histogram instead: ``D`` smeared by boxes ``BIN`` px wide placed side by
side over the path's reach, with weights >= 0 (non-negative least squares, scipy.optimize.nnls)
and an offset. A kernel is a distribution of positions, so the mark's position averaged over
the exposure is the histogram's mean (exact for any motion, as a centroid is), the mark's gain
is the weights' sum, and the mean's standard error is the active weights' least-squares one
(linearised). What uses it (core.tracking.plate) keeps it only when its residual and gain pass
the checks a quadratic fit's must and its mean lies near the quadratic fit's position.
"""

import math
from typing import NamedTuple

import numpy as np
from scipy.optimize import nnls

from microball_ros.core.tracking.motion_spectra import kernel_spectra
from microball_ros.core.tracking.plate_model import PlateModel

BIN = 0.5  # px: the width of one box of the histogram kernel
MARGIN = 3.0  # px of histogram beyond the quadratic path's reach on either side
END_SHARE = 0.05  # of the weight within two boxes of an end: the path runs on beyond it
EXTEND = 3  # times an end is moved out at most


class FreeKernel(NamedTuple):
    """The histogram kernel's fit: mean (grid px, as ``PlateModel.fit``'s delta), gain, rms."""

    delta: float
    gain: float
    rms: float
    sigma: float  # px: the mean's standard error
    bins: int  # the boxes with a weight above 0


def fit_free_kernel(plate: PlateModel, window: np.ndarray, valid: np.ndarray, delta: float,
                    reach: float, path: tuple[float, float]) -> FreeKernel | None:
    """Fit ``window`` (a frame's deficit on the plate's grid) with a histogram kernel.

    ``delta``: the quadratic fit's position (grid px from the origin); ``path``: the columns
    its path covers about it (smear.path_range); ``reach``: the plate's reach beyond the path,
    as ``fit``'s. The histogram covers the path and ``MARGIN`` px beyond either end, no more
    (noise puts weight wherever the histogram reaches, pulling the mean to its middle), but
    the quadratic path can fall short of a slip's far end: an end holding over ``END_SHARE`` of
    the weight is moved out by ``MARGIN`` and half the path, at most ``EXTEND`` times (never
    nearer the grid's ends than ``reach``: the plate's smears wrap around them). None when
    under 12 columns or no positive weight.
    """
    lowest, highest = float(plate.grid[0]) + reach, float(plate.grid[-1]) - reach
    first, last = delta + path[0] - MARGIN, delta + path[1] + MARGIN
    step = MARGIN + 0.5 * (path[1] - path[0])
    for _ in range(EXTEND + 1):
        first, last = max(first, lowest), min(last, highest)
        found = _fit_histogram(plate, window, valid, reach, first, last) if first < last else None
        if found is None:
            return None
        weights, shifts, result = found
        share = END_SHARE * result.gain
        ends = (weights[shifts < first + 2 * BIN].sum(), weights[shifts > last - 2 * BIN].sum())
        if max(ends) <= share:
            break
        first -= step if ends[0] > share else 0.0
        last += step if ends[1] > share else 0.0
    return result


def _fit_histogram(plate, window, valid, reach, first, last):
    """Return (weights, shifts, FreeKernel) of the histogram over [first, last]; None: none."""
    used = valid & (plate.grid >= first - reach) & (plate.grid <= last + reach)
    y = window[used]
    shifts = np.arange(first, last + 1e-9, BIN)
    if y.size < 12:
        return None
    boxes = kernel_spectra(plate.k, np.full(shifts.size, BIN), np.zeros(shifts.size), shifts)
    columns = np.fft.irfft(plate.spectrum[None, :] * boxes, plate.size, axis=1)[:, used].T
    y_centred = y - y.mean()  # the offset, left free, projected out
    centred = columns - columns.mean(axis=0)
    weights, _ = nnls(centred, y_centred)
    active = weights > 0
    gain = float(weights.sum())
    if not gain > 0:
        return None
    mean = float(weights @ shifts) / gain
    residual = y_centred - centred @ weights
    dof = max(y.size - int(np.count_nonzero(active)) - 1, 1)
    variance = float(residual @ residual) / dof
    # The mean's gradient in the active weights, through their least-squares covariance
    part = centred[:, active]
    gradient = (shifts[active] - mean) / gain
    spread = float(gradient @ np.linalg.pinv(part.T @ part) @ gradient) * variance
    return weights, shifts, FreeKernel(mean, gain, math.sqrt(variance),
                                       math.sqrt(max(spread, 0.0)),
                                       int(np.count_nonzero(active)))
