"""The search: where along the ROI the mark is, and how far its (blurred) dip extends.

Owns detection in the 1-D deficit of core.tracking.profile: the strongest dip of the smoothed
deficit and its extent, the columns around it where the deficit exceeds a fraction of its peak
(or three noise sigmas, whichever is higher). The whole ROI is searched in every frame, so a
lost mark is re-acquired as soon as it returns; ``locate_within`` is the strongest dip among
some columns (where the mark can be, or away from a dip found not to be the mark).
"""

import math
from typing import NamedTuple

import numpy as np

from microball_ros.core.tracking.profile import smooth


def peak_offset(score: np.ndarray, k: int) -> float:
    """Return the sub-sample offset (-0.5..0.5) of the maximum at ``k``: a parabola's vertex.

    Through the scores at k - 1, k, k + 1; 0 at either end or where they do not curve down.
    """
    if not 0 < k < score.size - 1:
        return 0.0
    left, mid, right = float(score[k - 1]), float(score[k]), float(score[k + 1])
    curvature = left - 2.0 * mid + right
    if not curvature < 0:
        return 0.0
    return float(np.clip(0.5 * (left - right) / curvature, -0.5, 0.5))


class Dip(NamedTuple):
    """The located mark: peak column, peak smoothed deficit, first and last column above."""

    column: int
    peak: float
    lo: int
    hi: int


def dip_extent(smoothed: np.ndarray, peak_index: int, threshold: float,
               gap: int = 0, widest: float = math.inf) -> tuple[int, int]:
    """Return the first and last index around ``peak_index`` where ``smoothed > threshold``.

    Runs that reach a quarter of the peak, separated from it by at most ``gap`` samples, are
    joined (a mark made of several parts, such as two bars, is one mark), unless that makes
    the extent wider than ``widest`` samples (something else beside the mark).
    """
    below = smoothed <= threshold
    left = np.flatnonzero(below[:peak_index])
    right = np.flatnonzero(below[peak_index + 1:])
    lo = int(left[-1]) + 1 if left.size else 0
    hi = peak_index + int(right[0]) if right.size else smoothed.size - 1
    if gap > 0:
        # Only a part that stands out (a quarter of the peak) is joined, not noise.
        above = np.flatnonzero(smoothed > max(threshold, 0.25 * smoothed[peak_index]))
        while True:
            before = above[(above < lo) & (above >= lo - gap - 1)]
            if not before.size:
                break
            run = np.flatnonzero(below[:int(before.min())])
            start = int(run[-1]) + 1 if run.size else 0
            if hi - start + 1 > widest:
                break
            lo = start
        while True:
            after = above[(above > hi) & (above <= hi + gap + 1)]
            if not after.size:
                break
            run = np.flatnonzero(below[int(after.max()) + 1:])
            end = int(after.max()) + int(run[0]) if run.size else smoothed.size - 1
            if end - lo + 1 > widest:
                break
            hi = end
    return lo, hi


def locate(deficit: np.ndarray, noise: float, fraction: float, smoothing_px: int,
           gap: int = 0, widest: float = math.inf) -> Dip:
    """Return the strongest dip of the deficit smoothed over ``smoothing_px`` columns.

    Its extent is where the smoothed deficit exceeds ``fraction`` of the peak and three times
    the noise of the smoothed deficit (``noise / sqrt(smoothing_px)`` per column), parts
    separated by at most ``gap`` columns joined while it stays ``widest`` columns or narrower.
    """
    smoothed = smooth(deficit, int(smoothing_px))
    return _dip(smoothed, int(np.argmax(smoothed)), noise, fraction, smoothing_px, gap, widest)


def locate_within(deficit: np.ndarray, noise: float, fraction: float, smoothing_px: int,
                  gap: int, allowed: np.ndarray, widest: float = math.inf) -> Dip | None:
    """Return the strongest dip whose peak lies in the ``allowed`` columns, as ``locate``.

    None if the largest smoothed deficit there is not a local maximum (the flank of a dip
    elsewhere) or is not above zero.
    """
    smoothed = smooth(deficit, int(smoothing_px))
    if not np.any(allowed):
        return None
    k = int(np.argmax(np.where(allowed, smoothed, -np.inf)))
    peak = float(smoothed[k])
    if not peak > 0 or (k > 0 and smoothed[k - 1] > peak) or (
            k < smoothed.size - 1 and smoothed[k + 1] > peak):
        return None
    return _dip(smoothed, k, noise, fraction, smoothing_px, gap, widest)


def _dip(smoothed: np.ndarray, k: int, noise: float, fraction: float, smoothing_px: int,
         gap: int, widest: float = math.inf) -> Dip:
    """Return the dip of the smoothed deficit whose peak is column ``k`` (see ``locate``)."""
    peak = float(smoothed[k])
    threshold = max(fraction * peak, 3.0 * noise / math.sqrt(smoothing_px))
    lo, hi = dip_extent(smoothed, k, threshold, int(gap), widest)
    return Dip(k, peak, lo, hi)
