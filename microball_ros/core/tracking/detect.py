"""Finding a mark in one frame with no model yet: the first lock, per polarity.

Owns the single-frame detection that starts (and restarts) a mark's tracking before anything
is learned. The ROI is reduced to a profile along x, the plain plate under the mark is a
low-degree polynomial (an envelope fit the mark cannot bend, then a fit outside the mark), the
mark is the strongest dip (dark) or bump (bright) of the relative profile, checked for
signal-to-noise, for clearance from the ROI edges and for saturation, and located by its
deficit centroid (the exposure average for any blur and shape). ``detect`` runs it for one
polarity; core.tracking.mark runs it for both when the polarity is 'auto' and learns the mark
from the better one.
"""

import math
from typing import NamedTuple

import numpy as np

from microball_ros.core.tracking.config import TrackerConfig
from microball_ros.core.tracking.profile import (
    Baseline,
    deficit_noise,
    relative_deficit,
    row_weights,
)
from microball_ros.core.tracking.search import locate
from microball_ros.core.tracking.subpixel import deficit_centroid, refine_position


class Detection(NamedTuple):
    """A mark found in one frame (ROI columns), or why not (``reason``)."""

    position: float
    sigma: float
    snr: float
    peak: float
    lo: int
    hi: int
    weights: np.ndarray | None
    reason: str = ''

    @property
    def found(self) -> bool:
        """Return True if the mark was found."""
        return not self.reason


def _failed(reason, peak=math.nan):
    return Detection(math.nan, math.nan, 0.0, peak, 0, 0, None, reason)


def detect(region: np.ndarray, profile: np.ndarray, baseline: Baseline,
           config: TrackerConfig, polarity: str) -> Detection:
    """Find the mark of ``polarity`` ('dark' or 'bright') in one ROI; return a Detection.

    ``profile`` is the ROI's column mean, ``baseline`` the polynomial model of its width.
    """
    cfg = config
    w = region.shape[1]
    pad = int(cfg.pad_px)
    guard = pad + int(cfg.smoothing_px)
    base = baseline.envelope(profile, polarity)
    if base.min() < cfg.min_baseline:
        return _failed('too dark')
    deficit = relative_deficit(profile, base, polarity)
    _, _, lo, hi = locate(deficit, 0.0, 0.25, cfg.smoothing_px)
    margin = guard + (hi - lo) // 4
    keep = np.ones(w, dtype=bool)
    for attempt in range(3):
        keep = np.ones(w, dtype=bool)
        keep[max(lo - margin, 0):hi + margin + 1] = False
        if np.count_nonzero(keep) < 12:
            flat = float(np.max(np.abs(deficit))) < cfg.min_depth
            return _failed('low contrast' if flat else 'mark fills the ROI (widen it)')
        if attempt == 2:
            break
        base = baseline.fit(profile, keep)
        if base.min() < cfg.min_baseline:
            return _failed('too dark')
        deficit = relative_deficit(profile, base, polarity)
        _, _, lo, hi = locate(deficit, 0.0, cfg.threshold, cfg.smoothing_px)
        margin = guard
    weights = row_weights(region, lo, hi, pad, polarity) if (
        cfg.weight_rows and region.shape[0] > 1) else None
    if weights is not None:
        weighted = weights @ region.astype(np.float64)
        base = baseline.fit(weighted, keep)
        if base.min() < cfg.min_baseline:
            return _failed('too dark')
        deficit = relative_deficit(weighted, base, polarity)
    noise = deficit_noise(deficit, keep)
    _, peak, lo, hi = locate(deficit, noise, cfg.threshold, cfg.smoothing_px)
    snr = peak * math.sqrt(cfg.smoothing_px) / noise
    if snr < cfg.min_snr or peak < cfg.min_depth:
        return _failed('low contrast', peak)
    first, last = lo - pad, hi + pad
    if first < 1 or last > w - 2:
        return _failed('mark at the ROI edge', peak)
    centroid, sigma, area = deficit_centroid(deficit, first, last, noise)
    if area <= 0:
        return _failed('low contrast', peak)
    position, sigma = refine_position(deficit, first, last, centroid, sigma, noise, 0, cfg,
                                      None)
    return Detection(position, sigma, snr, peak, lo, hi, weights)
