"""Learning one plate from the priming frames (core.tracking.plate's step 1): ``learn_plate``.

From the ROI images of the priming frames it learns the row weights (the mark's depth per row,
in the rows it is deep in: ``deep_rows``) and, jointly (``PlateSolver``, alternating least
squares), the whole plate's deficit ``D`` seen through the ROI, the static field (illumination
and dust fixed in the image) with each frame's light (flicker and a drifting gradient: a
quadratic over the ROI), and each frame's position and kernel: first positions from the dip's
centroid (the parts of a mark, such as two bars, joined; a gain per frame divided out) and
kernels from neighbouring frames, then rounds of ``D`` (preconditioned conjugate gradients),
static field and lights (closed form), positions and kernels (fits), until the fits move the
positions under ``SETTLED`` px RMS (at most ``ROUNDS``); from the second round, what the model
misses grossly in a frame away from the mark (a particle passing) is left out of it. ``D``'s
origin is then moved to the mark's centre, the mid-point of its outer edges (half-depth
crossings, or the centre of symmetry if they are pixels off it: ``PlateModel.mark_center``).
What it learned is a ``LearnedPlate``, which the tracker keeps or drops as a whole; it learns
twice, the second time from the positions and kernels the first plate measures, on the ROI
divided by a row flat field (priming.row_flat_field: a pattern fixed in the image that differs
between rows).
"""

from dataclasses import dataclass
import math

import numpy as np

from microball_ros.core.tracking.config import TrackerConfig
from microball_ros.core.tracking.plate_model import PlateModel
from microball_ros.core.tracking.plate_solver import PlateSolver, motion_kernels
from microball_ros.core.tracking.priming import deep_rows, first_positions, static_field
from microball_ros.core.tracking.profile import row_weights
from microball_ros.core.tracking.search import dip_extent

ROUNDS, SETTLED = 16, 0.01  # the joint learning: at most 16 rounds, stopped when settled
SMEAR_ROUNDS = 8  # a long smear's plate: positions start pixels off (core.tracking.smear)
AGREE_PX, AGREE_EXTENT = 2.0, 0.25  # learn_plate's ``found``: a dip centroid that far off
WHOLE_LEVEL = 0.05  # of D's peak: the whole mark, for the rows' guard of a plain plate


@dataclass
class LearnedPlate:
    """A plate learned from the priming frames (the tracker's, see core.tracking.plate).

    ``plate``: ``D`` near the mark, its origin at the mark's centre; ``full``: the whole
    plate seen through the ROI, ``shift`` px from that centre; ``half``: the mark's half-width
    (its least smeared extent); ``outer`` / ``whole``: its reach in ``D`` at a quarter and at
    ``WHOLE_LEVEL`` of its depth (px); ``weights``: per ROI row (sum 1); ``static``: the
    static field per ROI column; ``rms``: the median residual of the frames' fits; ``flat``:
    the row flat field the ROI was divided by (None: none).
    """

    plate: PlateModel
    full: PlateModel
    shift: float
    half: float
    outer: float
    whole: float
    weights: np.ndarray
    static: np.ndarray
    rms: float
    flat: np.ndarray | None = None

    @property
    def misfit(self) -> float:
        """Return ``rms`` over the row weights' norm: the residual per pixel, to compare plates.

        A profile's noise is the pixels' times the weights' norm, so plates learned with
        other row weights are compared by this, not by ``rms`` (weights on fewer rows had a
        larger ``rms`` but fitted better: 'textured_full''s stator, 0.0035 against 0.0035 by
        ``rms``, 0.0156 against 0.0159 by this, 0.140 px RMS against 0.169).
        """
        return self.rms / max(float(np.linalg.norm(self.weights)), 1e-12)


def agree(positions: np.ndarray, extents: np.ndarray, found: np.ndarray) -> np.ndarray:
    """Return the frames whose ``positions`` agree with the mark ``found`` (NaN: lost).

    Within ``AGREE_PX`` px or ``AGREE_EXTENT`` of the median extent of it; where it was lost,
    within the median extent of its track interpolated across the loss (a mark at the ROI's
    edge the other tracker refuses is still near there; a particle is not).
    """
    known = np.isfinite(found)
    if not np.any(known) or not np.any(np.isfinite(extents)):
        return np.zeros(positions.size, dtype=bool)
    extent = float(np.nanmedian(extents))
    frames = np.arange(positions.size)
    track = np.where(known, found, np.interp(frames, frames[known], found[known]))
    tolerance = np.where(known, max(AGREE_PX, AGREE_EXTENT * extent), max(AGREE_PX, extent))
    return np.abs(positions - track) <= tolerance


def learn_plate(regions, polarity: str, config: TrackerConfig, exposure_fraction: float,
                long_smear: bool = False, start=None, found=None,
                omega: float = 0.0) -> LearnedPlate | None:
    """Learn row weights, static field and plate from the ROI images ``regions``; None: failed.

    ``start``: (positions, kernels) per frame to start the solver from (NaN: unknown),
    instead of the dip centroids and kernels from neighbouring frames; a long smear's
    (core.tracking.smear.smear_start, ``long_smear``) brings the extents and half-width too.
    ``found``: the mark's positions per frame from another tracker (ROI columns, NaN: lost);
    a frame whose dip centroid does not ``agree`` with it is left out (its strongest dip is
    something else: a particle). ``omega``: a sinusoidal motion's (rad/frame), whose paths'
    kernels the plate is learned and fitted with (``PlateSolver.learn``); 0: quadratic paths.
    """
    cfg = config
    positions, extents = first_positions(regions, polarity, cfg)
    if found is not None:
        positions[~agree(positions, extents, np.asarray(found, dtype=float))] = np.nan
    if start is not None and len(start) > 2:  # a long smear: the extents come with it
        positions, extents = (np.array(v, dtype=float) for v in (start[0], start[2]))
    elif start is not None:
        positions = np.array(start[0], dtype=float)
        typical = float(np.nanmedian(extents)) if np.any(np.isfinite(extents)) else 0.0
        extents = np.where(np.isfinite(extents), extents, typical)
    each = [v for v in (row_weights(r, int(p - e / 2), int(p + e / 2), cfg.pad_px, polarity)
                        for r, p, e in zip(regions, positions, extents, strict=True)
                        if math.isfinite(p)) if v is not None]
    if not each:
        return None
    deep = deep_rows(regions, positions, extents, polarity, exposure_fraction,
                     None if start is None else start[1])
    median = np.median(each, axis=0)
    weights = median * deep if deep is not None and (median * deep).sum() > 0 else median
    weights /= max(float(weights.sum()), 1e-12)
    profiles = np.array([weights @ r.astype(np.float64) for r in regions])
    static = static_field(profiles, positions, extents, polarity, cfg.min_baseline)
    if static is None:
        return None
    half = 0.5 * float(np.nanpercentile(extents, 10) if start is None
                       or len(start) < 4 else start[3])
    kernels = (motion_kernels(positions, exposure_fraction) if start is None
               else np.array(start[1], dtype=float))
    solver = PlateSolver(profiles, static, 1.0 if polarity == 'dark' else -1.0)
    reach = half + cfg.pad_px
    rounds = SMEAR_ROUNDS if long_smear else ROUNDS
    rms = solver.learn(positions, kernels, reach + 8, rounds, SETTLED, exposure_fraction,
                       omega)
    if solver.plate is None:
        return None
    center = solver.plate.mark_center(reach)
    if not math.isfinite(center):
        return None
    longest = float(np.nanmax(solver.kernels[:, 0])) if np.any(
        np.isfinite(solver.kernels[:, 0])) else 0.0
    if not long_smear:
        longest = min(longest, cfg.max_blur_px)
    local = solver.plate.local(center, reach + 8.0 + longest + 16.0)
    c = local.center
    near = int(reach)
    peak = c - near + int(np.argmax(local.values[c - near:c + near + 1]))
    lo, hi = dip_extent(local.values, peak, 0.25 * float(local.values[peak]),
                        int(cfg.merge_gap_px))
    outer = max(float(c - lo), float(hi - c), reach)
    # The whole mark, its faint parts too (a cross's long arm): the rows' guard's window.
    lo, hi = dip_extent(local.values, peak, WHOLE_LEVEL * float(local.values[peak]))
    whole = max(float(c - lo), float(hi - c), outer)
    return LearnedPlate(local, solver.plate, center, half, outer, whole, weights,
                        solver.static, float(np.median(rms)) if len(rms) else 1.0)
