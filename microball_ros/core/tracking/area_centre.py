"""Where an asymmetric mark's centre is: its contrast centroid (``area_offset``).

A mark symmetric in x has one centre every method agrees on. An asymmetric one (a triangle,
an L, a QR-like block) has none by symmetry; its position is then defined as the centroid of
its contrast over its area (the 2-D deficit ``c(x, y)``, every row of the mark alike), the
point a physicist means by "where the pattern is". The trackers measure other points (the
centroid of a row-weighted profile, rows where the mark is deeper weighing more, or a fit of
it): 0.8-1.4 px from the contrast centroid on a triangle and an L of 20 px (an independent
set, 2026-11-26). ``area_offset`` measures the difference in the priming frames, each frame's
deficit against a straight line per row fitted on both flanks of the mark, and returns it
only when it is clear of the noise and of ``ASYMMETRY_FLOOR`` (a symmetric mark keeps the
positions it had, to the bit).
"""

import math

import numpy as np

from microball_ros.core.tracking.profile import median_and_error

ASYMMETRY_FLOOR = 0.05  # px: an offset under this is not told from a symmetric mark's 0
ASYMMETRY_SIGMAS = 4.0  # ... nor one under this many of its standard errors
FLANK = 12  # px of plate fitted per row on each side of the mark's window
GAP = 3  # px between the window and its flanks
MIN_FRAMES = 8  # priming frames the offset needs
ROW_FRACTION = 0.05  # rows deeper than this of the deepest are the mark's (and 2 either side)
ROW_MARGIN = 2
WIDEST = 0.4  # of the ROI: a longer window (a long smear) leaves too little plate beside it
WIDEN = 4  # px: the window widened each side to see a texture's pull (area_offset)


def contrast_centroid(region: np.ndarray, lo: int, hi: int, sign: float,
                      rows: slice | None = None) -> tuple[float, np.ndarray] | None:
    """Return the contrast centroid (ROI columns) of the mark in columns ``lo..hi``; depth/row.

    Each row's plate is a straight line fitted on ``FLANK`` columns either side of the window
    (``GAP`` away from it); ``c = sign (1 - row / line)``. None if a flank is cut by the ROI,
    the plate is not positive or the contrast's area is not. The depth per row (the summed
    contrast of each ROI row) chooses the mark's rows.
    """
    w = region.shape[1]
    if lo - GAP - FLANK < 0 or hi + GAP + FLANK >= w or hi <= lo:
        return None
    block = region if rows is None else region[rows]
    block = block.astype(np.float64)
    flanks = np.r_[lo - GAP - FLANK:lo - GAP, hi + GAP + 1:hi + GAP + 1 + FLANK]
    x = flanks.astype(np.float64)
    design = np.stack([np.ones_like(x), x - x.mean()], axis=1)
    coefficients, *_ = np.linalg.lstsq(design, block[:, flanks].T, rcond=None)
    window = np.arange(lo, hi + 1)
    plate = coefficients[0][:, None] + coefficients[1][:, None] * (window - x.mean())[None, :]
    if not np.all(plate > 0):
        return None
    contrast = sign * (1.0 - block[:, window] / plate)
    area = float(contrast.sum())
    if not area > 0:
        return None
    return float((contrast.sum(axis=0) @ window) / area), contrast.sum(axis=1)


def area_offset(regions, positions, extents, polarity: str, pad: int) -> tuple[float, float]:
    """Return (offset px, its standard error): contrast centroid minus the positions; or 0s.

    ``regions``: the priming frames' ROI images; ``positions`` (ROI columns, NaN: lost) and
    ``extents`` (px) what the tracker measured in them. The window is the extent plus ``pad``
    and 2 px each side. The offset is the median over the frames (its standard error from
    their spread) on the mark's rows; (0, 0) unless it exceeds ``ASYMMETRY_FLOOR`` and
    ``ASYMMETRY_SIGMAS`` standard errors, or with under ``MIN_FRAMES`` frames measured.
    """
    sign = 1.0 if polarity == 'dark' else -1.0
    windows = []
    for region, p, e in zip(regions, positions, extents, strict=True):
        if not (math.isfinite(p) and math.isfinite(e)) or e > WIDEST * region.shape[1]:
            continue
        half = 0.5 * e + pad + 2
        windows.append((region, p, int(math.floor(p - half)), int(math.ceil(p + half))))
    depths = [found[1] for region, _, lo, hi in windows
              if (found := contrast_centroid(region, lo, hi, sign)) is not None]
    if len(depths) < MIN_FRAMES:
        return 0.0, 0.0
    depth = np.median(depths, axis=0)
    deep = np.flatnonzero(depth > ROW_FRACTION * float(depth.max()))
    if deep.size == 0:
        return 0.0, 0.0
    rows = slice(max(int(deep[0]) - ROW_MARGIN, 0), int(deep[-1]) + ROW_MARGIN + 1)
    offsets, widened = [], []
    for region, p, lo, hi in windows:
        found = contrast_centroid(region, lo, hi, sign, rows)
        if found is None:
            continue
        offsets.append(found[0] - p)
        wider = contrast_centroid(region, lo - WIDEN, hi + WIDEN, sign, rows)
        if wider is not None:
            widened.append(wider[0] - found[0])
    if len(offsets) < MIN_FRAMES:
        return 0.0, 0.0
    offset, sigma = median_and_error(np.array(offsets))  # the median and its standard error
    if len(widened) >= MIN_FRAMES:
        # A texture too faint to score moves with the mark: its pull is the same in every
        # frame, so their spread does not see it, but it grows with the window's lever arm
        # (a ring 21 % deep on a 1.3 % texture: -0.4 to -0.8 px, noiseless, as the window
        # and its flanks change). Where the window WIDEN px wider each side moves the
        # centroid by more than twice that move's standard error, the move is part of it.
        move, error = median_and_error(np.array(widened))
        if abs(move) > 2.0 * error:
            sigma = math.hypot(sigma, move)
    if abs(offset) <= max(ASYMMETRY_FLOOR, ASYMMETRY_SIGMAS * sigma):
        return 0.0, 0.0
    return offset, sigma
