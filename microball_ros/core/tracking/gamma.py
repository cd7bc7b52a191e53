"""Frames from a gamma-encoding camera decoded to linear light (``TrackerConfig.gamma``).

The tracker's model of a moving mark is linear in the light: a smeared mark is the still mark
convolved with its motion during the exposure, so the mark's integrated deficit is the same
at any speed. Machine-vision cameras (mono8, mono16, raw Bayer) give linear values; consumer
cameras, webcams and most video encode ``v = full (light / full) ** (1 / gamma)`` (about 2.2
for sRGB and BT.709). A still mark is unharmed (the power keeps the plate and the mark's
product a product), but a smeared one is not: on a disc smeared up to 75 px (the sixth blind
set's p03, 15 frames/s, whole-period exposure) encoded with 2.2, 10-20 % of the frames were
refused as 'mark area changed' and the RMS went from 0.04-0.05 to 0.10-0.13 px.

``GammaDecoder`` undoes it before anything else sees the frame: ``full (v / full) ** gamma``,
``full`` the pixel type's largest value (255, 65535; 1.0 for float frames up to 1, else 255),
by a look-up table for 8- and 16-bit frames. A full-scale pixel stays full scale, so
saturation is still seen where it was (``saturation_level``).

With gamma 0 (the default) ``Tracker.prime`` finds it from the priming frames: each plain
plate's mark's ``smear_evidence`` (its deficit's area against its smear, over the frames
decoded by trial gammas, each frame's profile divided by the plate's own light), then
``adopted_gamma`` (the marks agree on a gamma well away from 1, or it stays 1). A linear video
is left as it is, and so is one whose marks cannot tell.
"""

import math
from typing import NamedTuple

import cv2
import numpy as np
from scipy import stats

from microball_ros.core.tracking.profile import saturation_level

GAMMA_RANGE = (0.2, 5.0)  # TrackerConfig.gamma's accepted range


def full_scale(frame: np.ndarray) -> float:
    """Return the largest value of ``frame``'s pixel type (float: 1.0 if it stays within 1)."""
    known = saturation_level(frame.dtype)  # 8- and 16-bit
    if known is not None:
        return known
    if np.issubdtype(frame.dtype, np.integer):
        return float(np.iinfo(frame.dtype).max)
    return 1.0 if float(np.nanmax(frame)) <= 1.0 else 255.0


class GammaDecoder:
    """Decode frames to linear light: ``full (v / full) ** gamma`` (gamma 1: as they are)."""

    def __init__(self, gamma: float = 1.0) -> None:
        """Create a decoder for a camera that encodes with ``gamma``."""
        self.gamma = float(gamma)
        self._tables: dict[np.dtype, np.ndarray] = {}
        self._float_full: float | None = None  # float frames: fixed by the first one

    @property
    def active(self) -> bool:
        """Return True if the decoder changes frames (gamma is not 1)."""
        return self.gamma != 1.0

    def __call__(self, frame: np.ndarray) -> np.ndarray:
        """Return ``frame`` (2-D) in linear light: float32 for 8- and 16-bit, else float64."""
        if not self.active:
            return frame
        if frame.dtype in (np.uint8, np.uint16):
            table = self._tables.get(frame.dtype)
            if table is None:
                full = full_scale(frame)
                values = np.arange(int(full) + 1, dtype=np.float64)
                table = (full * (values / full) ** self.gamma).astype(np.float32)
                self._tables[frame.dtype] = table
            if frame.dtype == np.uint8:
                return cv2.LUT(frame, table)
            return np.take(table, frame)
        if self._float_full is None:
            self._float_full = full_scale(frame)
        full = self._float_full
        values = np.clip(np.asarray(frame, dtype=np.float64), 0.0, None)
        return full * (values / full) ** self.gamma


def check_gamma(gamma: float) -> bool:
    """Return True if ``gamma`` is 0 (find it) or a camera gamma in ``GAMMA_RANGE``."""
    return gamma == 0.0 or (math.isfinite(gamma) and GAMMA_RANGE[0] <= gamma <= GAMMA_RANGE[1])


# Finding the gamma from the video (``TrackerConfig.gamma`` 0, the default): in linear light a
# smeared mark's integrated deficit is the same at any smear (a convolution keeps the area);
# encoded, it changes with the smear. Per plain plate's mark, over the priming frames, the
# slope of the log area against the mark's smeared length, with the frames decoded by a trial
# gamma: the gamma where it is 0 is the camera's.
AUTO = 0.0  # TrackerConfig.gamma: find it from the priming frames
STRONG_T = 6.0  # a slope this many standard errors from 0 at gamma 1 decides...
SEEN_T = 3.0  # ...if every mark whose slope is this far agrees
ADOPTED = (1.4, 3.0)  # ...on a gamma in this range, within AGREE of each other
AGREE = 1.25
MIN_FRAMES = 20  # frames with the mark, its flanks and no saturated pixel
MIN_SPREAD = 2.0  # px between the least and the most smeared mark's length
FLANK, PAD = 10, 4  # px: the baseline's columns each side; beyond the mark's length
TRIALS = np.arange(0.5, 3.51, 0.25)  # the gammas the slope is found at (after gamma 1)
OUTLIER = 4.0  # frames off the line by more than this many robust sigmas are left out
CLEAR_FRAMES = 5  # the plate's light at a column: the median of at least this many frames


class SmearEvidence(NamedTuple):
    """One mark's evidence: the gamma that keeps its area, the slope's t at 1, the frames.

    ``gamma`` NaN: none found, or not looked for (``t`` under ``SEEN_T``).
    """

    gamma: float
    t: float
    frames: int


def smear_evidence(regions, positions, extents, polarity: str,
                   saturation: float | None = None) -> SmearEvidence | None:
    """Return a mark's ``SmearEvidence`` over frames, None if they cannot tell.

    ``regions``: the mark's rows of the ROI in each frame (as read); ``positions``: the mark's
    ROI column in each (NaN: not found); ``extents``: its smeared length (px). None with fewer
    than ``MIN_FRAMES`` usable frames or lengths spread less than ``MIN_SPREAD``. The areas
    are taken on the profiles divided by the plate's own light (``_flat``): a line between
    the flanks cannot follow a vignette's curve, whose sag under a longer smear's wider window
    took area away as if the camera encoded (a cross at a whole-frame exposure: 'gamma 1.6').
    """
    spans, lengths = [], []
    width = regions[0].shape[1] if len(regions) else 0
    clear = np.ones((len(regions), width), dtype=bool)  # the plate seen, not the mark
    for n, (region, position, extent) in enumerate(zip(regions, positions, extents,
                                                       strict=True)):
        if not (math.isfinite(position) and math.isfinite(extent)):
            clear[n] = False
            continue
        half = 0.5 * extent + PAD
        lo, hi = int(math.floor(position - half)), int(math.ceil(position + half)) + 1
        clear[n, max(lo, 0):max(hi, 0)] = False
        if lo - FLANK < 0 or hi + FLANK > width:
            continue
        if saturation is not None and float(
                np.max(region[:, lo - FLANK:hi + FLANK])) >= saturation:
            continue
        spans.append((n, lo - FLANK, hi + FLANK))
        lengths.append(float(extent))
    if len(spans) < MIN_FRAMES or max(lengths) - min(lengths) < MIN_SPREAD:
        return None
    stack = np.asarray(regions, dtype=np.float64)
    scale = float(np.median(stack.mean(axis=(1, 2))))
    if not scale > 0:
        return None
    stack /= scale
    length = np.array(lengths)
    sign = 1.0 if polarity == 'dark' else -1.0
    keep = np.ones(length.size, dtype=bool)
    as_read = _log_areas(stack, clear, spans, 1.0, sign)
    slope, t, residual = _slope(as_read, length, keep)
    if residual is None:
        return None
    spread = 1.4826 * float(np.median(np.abs(residual[keep])))
    keep &= np.abs(residual) <= OUTLIER * spread + 1e-12
    slope, t, _ = _slope(as_read, length, keep)
    if not math.isfinite(t) or np.count_nonzero(keep) < MIN_FRAMES:
        return None
    if abs(t) < SEEN_T:  # the area holds in the frames as read: no gamma to look for
        return SmearEvidence(math.nan, float(t), int(np.count_nonzero(keep)))
    slopes = [(1.0, slope)]
    for trial in TRIALS:
        if trial != 1.0:
            areas = _log_areas(stack, clear, spans, trial, sign)
            slopes.append((float(trial), _slope(areas, length, keep)[0]))
    slopes.sort()
    roots = [g0 - s0 * (g1 - g0) / (s1 - s0)
             for (g0, s0), (g1, s1) in zip(slopes[:-1], slopes[1:], strict=True)
             if math.isfinite(s0) and math.isfinite(s1) and s0 * s1 <= 0 and s1 != s0]
    gamma = min(roots, key=lambda g: abs(g - 1.0)) if roots else math.nan
    return SmearEvidence(float(gamma), float(t), int(np.count_nonzero(keep)))


def _flat(profiles: np.ndarray, clear: np.ndarray) -> np.ndarray:
    """Return the plate's light along the ROI (NaN where too few frames show the plate).

    ``profiles``: the frames' column profiles; ``clear``: where each frame shows the plate
    (frames x columns: not the mark, nor any column of a frame it was not found in). Per
    column, the median over those frames of each profile divided by its frame's light (a
    flicker: the median of its clear columns against the plate's light, in three rounds);
    NaN where under ``CLEAR_FRAMES`` frames show it.
    """
    enough = clear.sum(axis=0) >= CLEAR_FRAMES
    flat = np.full(profiles.shape[1], np.nan)
    if not np.any(enough):
        return flat
    seen = np.where(clear[:, enough], profiles[:, enough], np.nan)
    lit = np.any(clear[:, enough], axis=1)  # a frame the mark was not found in: none clear
    gains = np.ones((profiles.shape[0], 1))
    for _ in range(3):
        flat[enough] = np.nanmedian(seen / gains, axis=0)
        gains[lit] = np.nanmedian(seen[lit] / flat[enough], axis=1, keepdims=True)
    return flat


def _log_areas(stack: np.ndarray, clear: np.ndarray, spans, gamma: float,
               sign: float) -> np.ndarray:
    """Return the log of each window's integrated relative deficit in light ** ``gamma``.

    ``stack``: the frames' mark rows (frames x rows x columns); ``clear``: ``_flat``'s;
    ``spans``: per window, its frame and its first and last column (``FLANK`` of plate each
    side). The profile, divided by the plate's light (``_flat``), is relative to a line
    through its two flanks; NaN where that light is unknown (a mark that hardly moves covers
    its own columns).
    """
    profiles = np.mean(stack if gamma == 1.0 else stack ** gamma, axis=1)
    flat = _flat(profiles, clear)
    areas = np.full(len(spans), np.nan)
    for n, (frame, lo, hi) in enumerate(spans):
        profile = profiles[frame, lo:hi] / flat[lo:hi]  # NaN where the plate is never seen
        columns = np.r_[0:FLANK, profile.size - FLANK:profile.size]
        line = np.polyval(np.polyfit(columns, profile[columns], 1), np.arange(profile.size))
        inside = slice(FLANK, profile.size - FLANK)
        area = sign * float(np.sum(1.0 - profile[inside] / line[inside]))
        if area > 0:
            areas[n] = math.log(area)
    return areas


def _slope(values, lengths, keep):
    """Return the slope of ``values`` on ``lengths`` (rows ``keep``), its t and residuals.

    The residuals are of every row (inf where the value is not finite); (NaN, NaN, None) with
    fewer than ``MIN_FRAMES`` rows or a single length.
    """
    use = keep & np.isfinite(values)
    if np.count_nonzero(use) < MIN_FRAMES or np.ptp(lengths[use]) == 0:
        return math.nan, math.nan, None
    fit = stats.linregress(lengths[use], values[use])
    fitted = fit.intercept + fit.slope * lengths
    residual = np.where(np.isfinite(values), values - fitted, np.inf)
    t = fit.slope / fit.stderr if fit.stderr > 0 else math.inf
    return float(fit.slope), float(t), residual


def adopted_gamma(evidence: list[SmearEvidence | None]) -> float:
    """Return the gamma the marks' evidence agrees on, or 1.0 (decode nothing).

    A mark whose slope is over ``STRONG_T`` standard errors from 0 at gamma 1 decides, if every
    mark over ``SEEN_T`` has its gamma in ``ADOPTED`` and within ``AGREE`` of the others: their
    median. On the three video sets' 70 linear videos a plain mark's |t| was at most 5.1 (its
    gamma 0.98-1.03 where over 3); 10 of the bench's videos encoded with 2.2 were found at
    2.14-2.22, the longest smears too (README).
    """
    seen = [e for e in evidence if e is not None and abs(e.t) >= SEEN_T]
    if not any(abs(e.t) >= STRONG_T for e in seen):
        return 1.0
    gammas = [e.gamma for e in seen]
    if not all(math.isfinite(g) and ADOPTED[0] <= g <= ADOPTED[1] for g in gammas):
        return 1.0
    if max(gammas) > AGREE * min(gammas):
        return 1.0
    return float(np.median(gammas))
