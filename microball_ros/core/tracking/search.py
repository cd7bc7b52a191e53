"""The search: where along the ROI the mark is, and how far its (blurred) dip extends.

Owns detection in the 1-D deficit of core.tracking.profile: the strongest dip of the smoothed
deficit and its extent, the columns around it where the deficit exceeds a fraction of its peak
(or three noise sigmas, whichever is higher). The whole ROI is searched in every frame, so a
lost mark is re-acquired as soon as it returns; a search gated around the previous position
belongs here.
"""

import math
from typing import NamedTuple

import numpy as np

from microball_ros.core.tracking.profile import smooth


class Dip(NamedTuple):
    """The located mark: peak column, peak smoothed deficit, first and last column above."""

    column: int
    peak: float
    lo: int
    hi: int


def dip_extent(smoothed: np.ndarray, peak_index: int, threshold: float) -> tuple[int, int]:
    """Return the first and last index around ``peak_index`` where ``smoothed > threshold``."""
    below = smoothed <= threshold
    left = np.flatnonzero(below[:peak_index])
    right = np.flatnonzero(below[peak_index + 1:])
    lo = int(left[-1]) + 1 if left.size else 0
    hi = peak_index + int(right[0]) if right.size else smoothed.size - 1
    return lo, hi


def locate(deficit: np.ndarray, noise: float, fraction: float, smoothing_px: int) -> Dip:
    """Return the strongest dip of the deficit smoothed over ``smoothing_px`` columns.

    Its extent is where the smoothed deficit exceeds ``fraction`` of the peak and three times
    the noise of the smoothed deficit (``noise / sqrt(smoothing_px)`` per column).
    """
    smoothed = smooth(deficit, int(smoothing_px))
    k = int(np.argmax(smoothed))
    peak = float(smoothed[k])
    threshold = max(fraction * peak, 3.0 * noise / math.sqrt(smoothing_px))
    lo, hi = dip_extent(smoothed, k, threshold)
    return Dip(k, peak, lo, hi)
