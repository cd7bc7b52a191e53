"""What priming measures of a plate and its mark, to choose how to track it (core.tracking.plate).

``texture_score`` / ``plate_is_textured``: whether the plate carries a texture of its own
(pixel noise is independent between the even and the odd rows, a texture is common to both);
``row_flat_field``: a pattern fixed in the image that differs between rows, left by the
row-weighted profile; ``motion_jitter``: a track's scatter about a smooth periodic motion, and
``steadier``, which compares two trackers on the same frames by it (or by their standard
errors when the motion is not periodic); ``first_positions``: each priming frame's mark from its
dip, before anything is learned; ``deep_rows``: the rows the mark is deep in; ``static_field``:
the field fixed in the image under the priming profiles, and each frame's light.
"""

import math
import warnings

import cv2
import numpy as np
from scipy.optimize import minimize_scalar

from microball_ros.core.tracking.config import TrackerConfig
from microball_ros.core.tracking.profile import light_level
from microball_ros.core.tracking.search import locate
from microball_ros.core.tracking.subpixel import deficit_centroid

TEXTURE_SCORE = 0.1
MIN_FLAT_GAIN = 0.5
HARMONICS = 4
SHAPE_FRAMES = 5  # deep_rows: the least smeared frames it looks at
# scatter_scale: standard errors scaled up to this much. Measured ratios on the bench and
# the two blind sets kept here: 0.3-1.9 mostly, 2.47 / 3.28 (the centroid behind a window
# pattern), 2.81 (lossy MPEG-4); the motion fit's failures (stick-slip, vibration, a tool in
# the ROI) 12 and more
MAX_SIGMA_SCALE = 4.0
MISFIT = 2.0  # steadier: a motion fit missing by more than this many standard errors
# pulled: a track scattering about the motion by over PULLED times its standard errors while
# the other is within STEADY times its own. Over 60 priming frames the ratio is about 1 +- 0.1
# where the errors are the noise's; on the plain plates of the bench and the two blind sets
# kept here the centroid's was 0.69-1.21 and the plate's 0.68-1.32 (a window pattern's 1.8-3.3,
# a vibration's or a motion no sinusoid fits 6-156, both tracks alike)
PULLED, STEADY = 1.5, 1.4
# agreeing: frames where two tracks differ by DISAGREE robust spreads of their difference
# (at most ODD of the frames: else they are not told from the rest) are left out
DISAGREE, ODD = 6.0, 0.25
# steadier: the two tracks' difference within AGREE times what their standard errors allow,
# plus SLACK of the first's variance (measured 0.8-1.2 on plates that track better, 1.4-1.6
# at most; 2.0-3.1 where the plate tracks worse: a whole-frame exposure, a bright blob).
AGREE, SLACK = 1.5, 0.1
DISTURBED_SIGMA = 4.0  # steadier: frames with a standard error this many times the median
DEEP_ROW = 0.4  # deep_rows: a row whose deepest point is under this of the deepest row's: out


def texture_score(regions: list[np.ndarray], marks: list[tuple[float, float]]) -> float:
    """Return how much of a plate's profile is texture: about 0 (plain) to 1 (all texture).

    ``regions``: ROI images (rows x columns); ``marks``: per region the ROI columns (first,
    last) of the mark, left out (NaN: none known). The correlation of the even-row and the
    odd-row profiles after a cubic detrend, median over the regions; 0 when none has at least
    24 plate columns and 4 rows.
    """
    values = []
    for region, (first, last) in zip(regions, marks, strict=True):
        w = region.shape[1]
        if region.ndim != 2 or region.shape[0] < 4:
            continue
        keep = np.ones(w, dtype=bool)
        if math.isfinite(first) and math.isfinite(last):
            keep[max(int(first), 0):max(int(last) + 1, 0)] = False
        if np.count_nonzero(keep) < 24:
            continue
        u = np.linspace(-1.0, 1.0, w)[keep]
        residual = []
        for rows in (region[0::2], region[1::2]):
            profile = rows.mean(axis=0, dtype=np.float64)[keep]
            residual.append(profile - np.polyval(np.polyfit(u, profile, 3), u))
        a, b = residual
        den = math.sqrt(float(a @ a) * float(b @ b))
        if den > 0:
            values.append(float(a @ b) / den)
    return float(np.median(values)) if values else 0.0


def row_flat_field(regions, weights, positions, spans, guard=8.0):
    """Return the ROI's static pattern across its rows (h x w, row-weighted mean 1), or None.

    A pattern fixed in the image that differs between rows (dust, a sensor's pixel response)
    does not divide out of the row-weighted profile: under a mark that also differs between
    rows (a cross) it leaves an error that follows the mark's place in the image. Per pixel,
    the mean over the frames of the pixel over its column's profile, with the columns the
    mark spans (plus ``guard``, at ``positions``, ROI columns) left out; the plate's own
    texture, at another place in every frame, averages out. None when what is left is not
    above what the texture and the noise leave in the means.
    """
    stack = np.array(regions, dtype=np.float64)
    profiles = np.einsum('r,nrw->nw', weights, stack)
    ratio = stack / profiles[:, None, :]
    columns = np.arange(stack.shape[2])
    for n, (p, span) in enumerate(zip(positions, spans, strict=True)):
        if math.isfinite(p):
            ratio[n][:, np.abs(columns - p) <= 0.5 * span + guard] = np.nan
        else:
            ratio[n] = np.nan
    with warnings.catch_warnings(), np.errstate(all='ignore'):
        warnings.simplefilter('ignore', RuntimeWarning)  # pixels the mark always covers
        flat = np.nanmean(ratio, axis=0)
        halves = np.nanmean(ratio[0::2], axis=0), np.nanmean(ratio[1::2], axis=0)
        count = np.count_nonzero(np.isfinite(ratio), axis=0)
    known = np.isfinite(flat) & np.isfinite(halves[0]) & np.isfinite(halves[1]) & (count >= 8)
    if np.count_nonzero(known) < 0.5 * known.size:
        return None
    # Shrunk towards 1 by the Wiener factor: the pattern is what the means over the even and
    # the odd frames share; the texture and the noise, at other places in each, they do not.
    deviation = np.where(known, flat - 1.0, 0.0)
    power = float(np.mean(deviation[known] ** 2))
    shared = float(np.mean(((halves[0] - 1.0) * (halves[1] - 1.0))[known]))
    gain = min(shared / power, 1.0) if power > 0 else 0.0
    if gain < MIN_FLAT_GAIN:
        return None
    flat = 1.0 + gain * deviation
    return flat / (weights @ flat)


def motion_jitter(tracks: list[np.ndarray], harmonics: int = HARMONICS) -> list[float]:
    """Return each track's RMS residual (px) about a smooth periodic motion fitted to it.

    ``tracks``: positions per frame (NaN: none); all are fitted on the frames where all have
    one, with one fundamental frequency (the best for the first track: the peak of its
    spectrum refined by least squares) and per track a constant, a drift and ``harmonics``
    harmonics, linear least squares. The motion of a crank-slider is smooth and periodic, so
    what is left is the tracker's noise (and any motion the fit misses, common to all).
    NaN with too few common frames.
    """
    stack = np.array(tracks, dtype=float)
    both = np.all(np.isfinite(stack), axis=0)
    t = np.flatnonzero(both).astype(float)
    parameters = 2 + 2 * int(harmonics)
    if t.size < parameters + 8:
        return [math.nan] * len(tracks)
    u = (t - t.mean()) / max(float(np.ptp(t)), 1.0)
    data = stack[:, both]

    def design(omega):
        columns = [np.ones_like(t), u]
        for k in range(1, int(harmonics) + 1):
            columns += [np.cos(k * omega * t), np.sin(k * omega * t)]
        return np.column_stack(columns)

    def residuals(omega, y):
        basis = design(omega)
        return y - basis @ np.linalg.lstsq(basis, y, rcond=None)[0]

    def cost(omega):
        r = residuals(omega, data[0])
        return float(r @ r)

    first = data[0] - np.polyval(np.polyfit(u, data[0], 1), u)
    grid = np.linspace(0.02, math.pi, 512)
    power = np.abs(np.exp(-1j * np.outer(grid, t)) @ first)
    step = float(grid[1] - grid[0])
    peak = float(grid[int(np.argmax(power))])
    omega = float(minimize_scalar(cost, bounds=(max(peak - 2 * step, 1e-3), peak + 2 * step),
                                  method='bounded', options={'xatol': 1e-8}).x)
    dof = max(t.size - parameters - 1, 1)
    return [math.sqrt(float(r @ r) / dof) for r in (residuals(omega, y) for y in data)]


def scatter_scale(positions: np.ndarray, found: list, harmonics: int = HARMONICS) -> float:
    """Return how much to scale the standard errors by: the priming track's scatter over them.

    ``positions``: the priming frames' track (NaN: none), ``found`` its measurements. A
    standard error counts the pixel noise only; what a learned plate leaves of a texture, or
    the background of a pattern fixed in the image, scatters the positions too. The track's
    scatter about a smooth periodic motion (``motion_jitter``), against the RMS of the
    standard errors there, between 1 and ``MAX_SIGMA_SCALE`` (a larger ratio is the motion
    fit's failure, not the tracker's: 1). Measured on the centroid behind a window pattern
    (the bench's ``static_bright``): 2.47 on the priming frames, 2.57 over the whole video
    (the slider; the stator 3.28, whose frames were 49 % within two standard errors at a
    limit of 2.5). ``harmonics``: the motion's (``motion_jitter``).
    """
    sigmas = np.array([m.sigma_px for m in found if m.valid])
    jitter = motion_jitter([positions], harmonics)[0]
    if sigmas.size < 8 or not math.isfinite(jitter) or not np.all(np.isfinite(sigmas)):
        return 1.0
    ratio = jitter / float(np.sqrt(np.mean(sigmas ** 2)))
    return ratio if 1.0 < ratio <= MAX_SIGMA_SCALE else 1.0


def agreeing(tracks: list[np.ndarray]) -> np.ndarray:
    """Return the frames where two tracks (NaN: none) both have a position and agree.

    Something passing over the plate (a particle) can pull one tracker's positions in a few
    frames by many times their usual difference: those frames, over ``DISAGREE`` robust
    spreads (MAD) of the difference off its median, are left out when they are at most ``ODD``
    of the frames both have (more are the trackers' difference itself, not outliers; a bias
    that follows the motion changes the difference smoothly and stays in).
    """
    both = np.all(np.isfinite(np.array(tracks, dtype=float)), axis=0)
    if np.count_nonzero(both) < 8:
        return both
    difference = tracks[0][both] - tracks[1][both]
    middle = float(np.median(difference))
    spread = 1.4826 * float(np.median(np.abs(difference - middle)))
    odd = np.abs(difference - middle) > DISAGREE * max(spread, 1e-6)
    if np.count_nonzero(odd) > ODD * difference.size:
        return both
    agree = both.copy()
    agree[np.flatnonzero(both)[odd]] = False
    return agree


def steadier(tracks: list[np.ndarray], sigmas: list[np.ndarray], margin: float,
             misfit: float = MISFIT) -> tuple[bool, tuple[float, float]]:
    """Return whether the second track is steadier than the first, and their jitters.

    ``tracks``: two trackers' positions over the same frames (NaN: none), the first the
    reference (the centroid, unbiased for any blur); ``sigmas``: their standard errors per
    frame. Steadier: its ``motion_jitter`` is under ``margin`` times the first's or, when
    the motion is not a smooth periodic one (a slider that sticks and slips, a lag: the
    first's jitter over ``misfit`` times its standard error, what the fit misses common to
    both), its standard errors are (RMS). And in either case the two tracks agree as two
    estimates from the same pixels do when the second is efficient: the variance of their
    difference is that of the first less that of the second (Hausman), here at most
    ``AGREE`` squared times it plus ``SLACK`` times the first's. An error of the second
    that follows the motion (a bias growing with the blur) hides in the jitter, which the
    periodic fit takes up, but not in the difference: a whole-frame exposure's plate was
    0.89 times as jittery as the centroid and 1.12 times its error, its tracks apart by
    twice what their standard errors allow. Frames where either standard error is over
    ``DISTURBED_SIGMA`` times its median are left out of both tests.
    """
    jitter = motion_jitter(tracks)
    jitters = (jitter[0], jitter[1])
    both = np.all(np.isfinite(np.array(tracks, dtype=float)), axis=0)
    if np.count_nonzero(both) < 8:
        return False, jitters
    # A frame whose standard error is ``DISTURBED_SIGMA`` times the track's typical one is a
    # disturbed frame (a particle passing while priming): two such frames of a bar's plate
    # (0.14 px against 0.013) made it look less efficient than the centroid and dropped it
    for s in sigmas:
        s = np.asarray(s, dtype=float)
        both &= ~(s > DISTURBED_SIGMA * float(np.nanmedian(s[both])))
    if np.count_nonzero(both) < 8:
        return False, jitters
    rms = _rms(sigmas, both)
    if jitter[1] < margin * jitter[0]:
        better = True
    elif jitter[0] > misfit * rms[0]:
        better = rms[1] < margin * rms[0]
    else:
        better = False
    apart = float(np.var(tracks[0][both] - tracks[1][both]))
    allowed = AGREE ** 2 * max(rms[0] ** 2 - rms[1] ** 2, 0.0) + SLACK * rms[0] ** 2
    return bool(better and apart <= allowed), jitters


def plain_verdict(centroid: np.ndarray, reference: list, plate: np.ndarray, found: list,
                  margin: float) -> tuple[bool, tuple[float, float], tuple[float, float]]:
    """Return whether to keep a plain plate, the jitters, and its offset and that's error.

    ``centroid``, ``plate``: the two trackers' priming tracks (NaN: none); ``reference``,
    ``found``: their measurements. Kept only if the plate reports every frame the centroid
    does and is ``steadier`` by ``margin``, over the frames where the two agree (a particle
    passing pulls one: ``agreeing``). The centroid is exact on average for any mark and blur:
    the plate's positions are offset by the mean difference of the two tracks (its origin,
    the mid-point of the outer edges, is hundredths of a pixel off the mark's centre on
    average), whose standard error is the centre's.
    """
    lost = np.isfinite(centroid) & ~np.isfinite(plate)
    both = agreeing([centroid, plate])
    better, jitters = steadier(
        [np.where(both, track, math.nan) for track in (centroid, plate)],
        [np.array([m.sigma_px if m.valid else math.nan for m in measured])
         for measured in (reference, found)], margin)
    if np.any(lost) or not better:
        return False, jitters, (0.0, 0.0)
    difference = centroid[both] - plate[both]
    sigma = (float(np.std(difference, ddof=1) / math.sqrt(difference.size))
             if difference.size > 1 else math.nan)
    return True, jitters, (float(np.mean(difference)), sigma)


def pulled(jitters: tuple[float, float], sigmas: list[np.ndarray]) -> bool:
    """Return whether something pulls the first of two tracks of the same frames alone.

    ``jitters``: their ``motion_jitter``; ``sigmas``: their standard errors per frame (NaN:
    none). Pulled: the first scatters about the motion by over ``PULLED`` times its standard
    errors (RMS) while the second is within ``STEADY`` times its own, so the motion fit misses
    nothing common to both (a slider that sticks and slips, a vibration: both far over). A
    plain plate's centroid is pulled so by a texture too faint to score (0.36 px about the
    motion for standard errors of 0.05; a learned plate's 0.057). A fixed window pattern the
    background leaves scatters the plate too (1.8-2.2 times).
    """
    rms = _rms(sigmas)
    return bool(jitters[0] > PULLED * rms[0] and jitters[1] <= STEADY * rms[1])


def unexplained(tracks: list[np.ndarray], sigmas: list[np.ndarray]) -> float:
    """Return the spread (px) of two tracks' difference that their standard errors leave out.

    ``tracks``: the centroid's and a plate's positions over the same frames (NaN: none),
    ``sigmas`` their standard errors. Were the plate efficient, the variance of the difference
    would be the centroid's less the plate's (``steadier``); what is over that, on the frames
    where the two agree (``agreeing``), is an error one of them does not report: a texture
    too faint to score whose pull on the centroid follows the motion (0.03-0.12 px, its
    errors 62-93 % within two standard errors), or the plate's bias growing with the blur.
    0 with fewer than 8 such frames.
    """
    both = agreeing(tracks)
    if np.count_nonzero(both) < 8:
        return 0.0
    rms = _rms(sigmas, both)
    apart = float(np.var(tracks[0][both] - tracks[1][both]))
    excess = apart - (rms[0] ** 2 - rms[1] ** 2)
    return math.sqrt(excess) if excess > 0 else 0.0


def _rms(sigmas: list[np.ndarray], frames: np.ndarray | None = None) -> list[float]:
    """Return each track's RMS standard error, over ``frames`` (a mask) or all it has."""
    out = []
    for s in sigmas:
        s = np.asarray(s, dtype=float)
        s = s[frames] if frames is not None else s[np.isfinite(s)]
        out.append(math.sqrt(float(np.mean(np.square(s)))) if s.size else math.nan)
    return out


def plate_is_textured(regions: list[np.ndarray], marks: list[tuple[float, float]],
                      threshold: float = TEXTURE_SCORE) -> bool:
    """Return True if the plate around the mark carries a texture (``texture_score``).

    Plain plates score within about 0.05 of 0, textured and speckled ones 0.5 (a fine grain,
    1.5 px) to 0.97: the threshold is between, where a weak texture still beats the centroid.
    """
    return texture_score(regions, marks) >= threshold


def first_positions(regions: list[np.ndarray], polarity: str,
                    config: TrackerConfig) -> tuple[np.ndarray, np.ndarray]:
    """Return each frame's first position and extent (ROI columns; NaN: not found).

    The strongest dip of the profile against the median profile over the frames (the
    mark is elsewhere in most of them), its extent where the smoothed deficit exceeds a
    quarter of its peak, and the deficit centroid over that extent and a pad.
    """
    profiles = np.array([r.mean(axis=0, dtype=np.float64) for r in regions])
    profiles /= np.median(profiles, axis=1)[:, None]  # flicker, before the median
    static = np.median(profiles, axis=0) * float(np.median(
        [r.mean(dtype=np.float64) for r in regions]))
    sign = 1.0 if polarity == 'dark' else -1.0
    positions = np.full(len(regions), np.nan)
    extents = np.full(len(regions), np.nan)
    if static.min() < config.min_baseline:
        return positions, extents
    for n, profile in enumerate(profiles):
        level = light_level(profile / static, polarity, order=0)
        if level is None:
            continue
        d = sign * (1.0 - profile / (static * level))
        dip = locate(d, 0.0, 0.25, config.smoothing_px, config.merge_gap_px)
        first, last = dip.lo - config.pad_px, dip.hi + config.pad_px
        if first < 1 or last > d.size - 2 or not dip.peak > config.min_depth:
            continue
        centroid, _, area = deficit_centroid(d, first, last, 1.0)
        if area > 0:
            positions[n], extents[n] = centroid, float(dip.hi - dip.lo + 1)
    return positions, extents


def deep_rows(regions: list[np.ndarray], positions: np.ndarray, extents: np.ndarray,
              polarity: str, fraction: float, kernels=None,
              count: int = SHAPE_FRAMES) -> np.ndarray | None:
    """Return a mask of the ROI rows the mark is deep in, or None if it cannot tell.

    From the ``count`` least smeared frames (the blur of ``kernels``, else from neighbouring
    ``positions`` and the exposure ``fraction``): per row, the deepest point (3 x 3 px mean)
    of the relative deficit against the row's median, within half the 10th percentile of
    ``extents`` plus half the blur of the mark's position, median over the frames; rows
    under ``DEEP_ROW`` of the deepest are out, and so are the rows beyond them (the mark's
    rows are one run, about the deepest). A texture beside a small mark in a tall ROI can
    weigh as much as the mark in a row's mean deficit, never this much in its deepest point
    (10 % of texture against a mark 50 % deep).
    """
    blurs = (np.abs(np.gradient(positions)) * fraction if kernels is None
             else np.abs(np.array(kernels, dtype=float)[:, 0]))
    half = 0.5 * float(np.nanpercentile(extents, 10)) if np.any(np.isfinite(extents)) else 0.0
    usable = np.flatnonzero(np.isfinite(positions) & np.isfinite(blurs))
    chosen = usable[np.argsort(blurs[usable], kind='stable')][:count]
    if chosen.size < 3 or not half > 0:
        return None
    sign = 1.0 if polarity == 'dark' else -1.0
    peaks = []
    for n in chosen:
        region = regions[n].astype(np.float64)
        reach = half + 0.5 * float(blurs[n])
        lo = max(int(math.floor(positions[n] - reach)), 0)
        hi = min(int(math.ceil(positions[n] + reach)) + 1, region.shape[1])
        level = np.median(region, axis=1)
        if hi - lo < 3 or not np.all(level > 0):
            return None
        deficit = sign * (1.0 - region[:, lo:hi] / level[:, None])
        peaks.append(cv2.blur(deficit, (3, 3)).max(axis=1))
    peak = np.median(peaks, axis=0)
    if not float(peak.max()) > 0:
        return None
    deep = peak >= DEEP_ROW * float(peak.max())
    top = bottom = int(np.argmax(peak))  # the run of deep rows around the deepest: the mark's
    while top > 0 and deep[top - 1]:
        top -= 1
    while bottom < deep.size - 1 and deep[bottom + 1]:
        bottom += 1
    mask = np.zeros(deep.size, dtype=bool)
    mask[top:bottom + 1] = True
    return mask


def static_field(profiles: np.ndarray, positions: np.ndarray, extents: np.ndarray,
                 polarity: str, min_baseline: float) -> np.ndarray | None:
    """Return the static field of the priming profiles; divide each by its light, in place.

    ``profiles``: frames x columns (row-weighted); ``positions``, ``extents``: each frame's
    mark (NaN: none), whose columns (and 8 px beside) are left out. The field is the median
    over the frames at each column, and each frame's light (``light_level``) is fitted against
    it, twice. Columns the mark never left (a short stroke) are interpolated: the plate
    solver learns the field there with the plate. None if under a quarter of the columns are
    ever clear, the field falls under ``min_baseline`` or a frame's light cannot be fitted.
    """
    w = profiles.shape[1]
    columns = np.arange(w)
    outside = np.abs(columns[None, :] - positions[:, None]) > (extents[:, None] / 2 + 8.0)
    outside &= np.isfinite(positions)[:, None]
    static = None
    for _ in range(2):  # the static field, and each frame's light against it
        masked = np.where(outside, profiles, np.nan)
        with warnings.catch_warnings():  # columns the mark never left: NaN, no warning
            warnings.simplefilter('ignore', RuntimeWarning)
            static = np.nanmedian(masked, axis=0)
        seen = np.isfinite(static)
        if np.count_nonzero(seen) < 0.25 * w:
            return None
        static = np.interp(columns, columns[seen], static[seen])
        if static.min() < min_baseline:
            return None
        for n in np.flatnonzero(np.isfinite(positions)):
            level = light_level(profiles[n] / static, polarity, positions[n],
                                extents[n] + 16.0, 0)
            if level is None:
                return None
            profiles[n] /= level
    return static
