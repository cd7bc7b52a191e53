"""The learned plate row by row, and the mark's centre on a textured plate from its edges.

On a textured plate the mark is the plate's texture darkened (or lit) over the mark's shape,
so the plate the tracker learns (core.tracking.plate: one profile along x, the rows weighted
by the mark's depth) holds the mark and the texture together, and where in it the mark's
centre lies is a matter of definition. The mid-point of the half-depth crossings of that
profile moves with the texture at the crossings: 0.1-0.3 px on a speckle of 5-8 % against a
mark 25-30 % deep. The edges of the mark are the strongest gradients there; the texture's are
weaker and do not line up from row to row. So the centre is taken where the edges' energy,
row by row, is most nearly mirror-symmetric (``edge_center``), on each row's own plate
(``row_plates``: the frames of the priming pass, at the positions and motion kernels the
tracker measured, deconvolved row by row). On noiseless textured marks (the second blind
set's plates, 40 textures each) that is 0.02-0.10 px RMS off the shape's centre, where the
profile's crossings are 0.10-0.19 px and the mirror symmetry of the deficit itself
0.10-0.55 px (a coarse texture's slow part is far from symmetric).

A texture whose own edges are as strong as the mark's (fully developed speckle, 40 % deep
around a mark 60 % deep) makes the edge energy far from symmetric; there the row-averaged
profile, which averages the texture away before it looks for edges, is the better definition.
``edge_offset`` moves the centre by the whole of the edges' verdict when its asymmetry is
under ``ASYMMETRY_LOW``, by none of it over ``ASYMMETRY_HIGH``, and by a share in between.
A mark without edges (a Gaussian blob: its slopes are broad and a texture's slopes shift
their balance, 0.17-0.30 px on a 5 % texture; ``sharpness``) is put where its deficit is most
nearly mirror-symmetric (its crossings were 0.47 px off on a 5 % texture of 3 px grain, the
symmetry 0.15 px; the bench's textured blob 0.088 -> 0.052 px RMS).

A mark that never moves (core.tracking.still) is put at its edges the same way: ``row_plates``
then divides each row by the plate beside the mark, interpolated under it.

The texture under the mark moves with it, so where it puts the centre errs by one amount in
every frame, which the frames cannot tell but the plate can: ``edge_offset`` returns that
error's standard error, two estimates in quadrature (conservative): the rows' jackknife
(``jackknife_spread``) and the verdict again under random textures like the plate's beside
the mark (``texture_spread``). Both take the profile's crossings again too, for the share of
the centre the edges leave there (fully developed speckle: the edges not trusted, and the
spreads, which measured the verdict alone, were 0; a centre 0.17 px off got 0.07 px). On
the blind sets' 45 textured marks (the tracker's per-frame errors against the truth) the
positions' standard errors with it held 99 % of the errors within two of them, 77 % without
(0.20 px on a fine speckle whose centre was 0.16 px off); on 45 noiseless synthetic plates
of 3-10 % texture and 1-5 px grain (test_plate_rows) 91 % of the centres' errors were within
two of it (the jackknife alone 64 %, the random textures alone 84 %).
"""

import math
from typing import NamedTuple
import warnings

import numpy as np
from scipy.ndimage import gaussian_filter

from microball_ros.core.tracking.plate_model import UPSAMPLE, PlateModel, fft_size
from microball_ros.core.tracking.template import kernel_spectrum, tukey

REGULARISATION = 1e-3  # of the largest kernel power: the rows' deconvolution (PlateModel's)
LIGHT_DEGREE = 2  # each frame's light per row: a polynomial of x fitted beside the mark
STEP = 1.0 / UPSAMPLE  # edge_center's search grid, px
ROW_MARGIN = 3  # rows learned beyond the mark's deep rows (its blurred top and bottom edges)
ASYMMETRY_LOW, ASYMMETRY_HIGH = 0.3, 0.6  # edge_offset: the edges trusted fully / not at all
MAX_MOVE = 1.0  # px: a verdict further from the profile's centre is not a texture's pull
SHARP = 0.25  # 1/px: edge_offset's mark less ``sharpness`` than this has no edges to go by
JACKKNIFE_GROUPS = (4, 6, 8)  # jackknife_spread: bands of rows left out in turn
STRIP = (1.5, 4.5)  # texture_spread: the plate beside the mark, px beyond its extent
TEXTURE_DRAWS = 32  # texture_spread: random textures the verdict is taken again under
MIN_GRAIN, MAX_GRAIN = 0.3, 10.0  # px: texture_spread's Gaussian filter, least and most
GAIN_SMOOTH = 5  # noise_gain: frequencies its powers are averaged over


class EdgeOffset(NamedTuple):
    """Where to put the mark's centre on its plate (``edge_offset``), and how well it is known.

    ``offset``: px to move the centre by; ``asymmetry``: the edges' (NaN: not measured);
    ``sigma``: the standard error of the centre so placed (px; NaN: not measured). A texture
    under the mark moves with it, so the error is one and the same in every frame: it adds to
    each position's standard error, and cancels in velocities and accelerations.
    """

    offset: float
    asymmetry: float
    sigma: float


def edge_offset(regions, weights, positions, kernels, extent: float, sign: float,
                most: float = MAX_MOVE, kappa: float = 0.0) -> EdgeOffset:
    """Return how far to move the mark's centre, by its edges (px), and its standard error.

    ``weights``: the tracker's row weights (the mark's rows are those above 0); the rest as
    ``row_plates``, with the positions the tracker reports. Offset 0 and asymmetry NaN if the
    edges could not be measured (the standard error then the profile's crossings'); the
    offset is 0 too if they put the centre over ``most`` px away (a mark that is not
    mirror-symmetric). Over ``MAX_MOVE`` px away, the edges are looked for about the
    deficit's own centre of symmetry (``deficit_center``). A mark without sharp edges (a
    blob) is put at that centre of symmetry, within ``MAX_MOVE`` + 1 px (a textured blob's
    half-depth mid-point was 0.47 px off on a 5 % texture; 0.15 px so).
    The standard error: ``jackknife_spread`` and ``texture_spread`` in quadrature (two
    estimates of one error, from the rows and from a texture model: see the module), and the
    part of the verdict's move not applied (edges trusted in part, a move over ``most``).
    ``kappa``: the kernels' path shape (template.path_knots; 0: quadratic).
    """
    deep = np.flatnonzero(np.asarray(weights) > 0)
    if deep.size == 0:
        return EdgeOffset(0.0, math.nan, math.nan)
    rows = np.arange(max(int(deep[0]) - ROW_MARGIN, 0),
                     min(int(deep[-1]) + ROW_MARGIN + 1, len(weights)))
    learned = row_plates(regions, rows, positions, kernels, extent, sign, kappa)
    if learned is None:
        return EdgeOffset(0.0, math.nan, math.nan)
    plates, origin = learned
    row_weights = np.asarray(weights, dtype=np.float64)[rows]
    offset, asymmetry, share, move = _verdict(plates, row_weights, origin, extent, most)
    edges = math.isfinite(asymmetry)
    if not edges:  # the centre stays at the profile's crossings: their spreads alone
        offset, share, move = 0.0, 0.0, math.nan
    # The profile's crossings keep what the verdict does not apply: that much of its move
    # is how far apart the two places it could be are (NaN: a still blob's, not measured)
    unapplied = (1.0 - share) * abs(move) if math.isfinite(move) else 0.0
    spreads = [jackknife_spread(plates, row_weights, origin, extent, most, edges),
               texture_spread(plates, row_weights, origin, extent, most, sign, edges)]
    known = [value for value in spreads if math.isfinite(value)]
    return EdgeOffset(offset, asymmetry, math.hypot(unapplied, *known) if known else math.nan)


def plate_center(plates: np.ndarray, weights: np.ndarray, origin: int, extent: float,
                 most: float = MAX_MOVE) -> tuple[float, float]:
    """Return (offset, asymmetry): ``edge_offset``'s verdict on the rows' plates.

    ``plates``: rows x grid (``row_plates``), ``weights`` their row weights; the rest as
    ``edge_offset``.
    """
    offset, asymmetry, _, _ = _verdict(plates, weights, origin, extent, most)
    return offset, asymmetry


def _verdict(plates, weights, origin, extent, most) -> tuple[float, float, float, float]:
    """Return ``plate_center``'s (offset, asymmetry), the share it applies, and its whole move.

    The whole move: where the edges (a blob: its deficit's symmetry) put the centre, px from
    the origin (NaN: nowhere); the share of it applied: 1 for edges trusted fully and a
    blob's centre, the edges' trust for edges trusted in part, 0 for a move over ``most``.
    """
    around = 0.0 if most <= MAX_MOVE else deficit_center(plates, origin, extent + 3.0, most)
    if not math.isfinite(around):
        return 0.0, math.nan, 0.0, math.nan
    center, asymmetry = edge_center(plates, origin, extent + 3.0, MAX_MOVE + 1.0, around)
    if sharpness(plates, weights, origin, extent) < SHARP:
        if most > MAX_MOVE:  # a still mark's: it keeps the mid-point of where it was found
            return 0.0, asymmetry, 0.0, math.nan
        # No edges (a blob on a texture): where the deficit is most nearly mirror-symmetric
        blob = deficit_center(plates, origin, extent + 3.0, MAX_MOVE + 1.0)
        return (blob, asymmetry, 1.0, blob) if abs(blob) <= most else (0.0, asymmetry, 0.0,
                                                                          blob)
    if not abs(center) <= most:
        return 0.0, asymmetry, 0.0, center
    trust = min(max((ASYMMETRY_HIGH - asymmetry) / (ASYMMETRY_HIGH - ASYMMETRY_LOW), 0.0), 1.0)
    return center * trust, asymmetry, trust, center


def crossings_center(plates: np.ndarray, weights: np.ndarray, origin: int,
                     extent: float) -> float:
    """Return the mid-point of the rows' profile's half-depth crossings (px from the origin).

    The profile: the rows weighted by ``weights``; its crossings within ``extent`` of the
    origin (``PlateModel.mark_center``). Where the centre is where the edges do not move it
    (their asymmetry over ``ASYMMETRY_HIGH``), this is what a texture moves it by.
    """
    total = float(np.sum(weights))
    model = PlateModel(plates.shape[1], plates.shape[1] / 2.0, center=origin)
    model.values = (np.asarray(weights) @ plates) / (total if total > 0 else 1.0)
    model.spectrum = np.fft.rfft(model.values)
    return model.mark_center(extent)


def _placed(plates, weights, origin, extent, most, crossings, edges=True) -> float:
    """Return where the centre is put on ``plates``, px from where it is on the whole plates.

    ``plate_center``'s offset, plus the part of the rows' crossings' move from ``crossings``
    (the whole plates') the verdict does not replace (its share not applied): a texture moves
    the centre as much there, and the verdict alone (0 for edges not trusted) hid it.
    ``edges`` False: the crossings' move alone (the whole plates' edges were not found).
    """
    offset, share = 0.0, 0.0
    if edges:
        offset, _, share, _ = _verdict(plates, weights, origin, extent, most)
    if share >= 1.0 or not math.isfinite(crossings):
        return offset
    moved = crossings_center(plates, weights, origin, extent) - crossings
    return offset + (1.0 - share) * (moved if math.isfinite(moved) else 0.0)


def jackknife_spread(plates: np.ndarray, weights: np.ndarray, origin: int, extent: float,
                     most: float = MAX_MOVE, edges: bool = True) -> float:
    """Return the standard error of where ``edge_offset`` puts the centre, from its rows (px).

    The delete-one-group jackknife over ``JACKKNIFE_GROUPS`` contiguous bands of rows: the
    placement again without each band (``_placed``: the verdict, and the crossings where the
    verdict does not replace them), the variances of the 4, 6 and 8 bands averaged. It sees
    the texture the mark's own rows hold (a fine speckle's 0.16 px), but bands a coarse
    texture joins from row to row are not independent: alone it was 1.2-2 times low on
    synthetic plates of 1-5 px grain. NaN if fewer rows than bands.
    """
    count = plates.shape[0]
    crossings = crossings_center(plates, weights, origin, extent)
    variances = []
    for groups in JACKKNIFE_GROUPS:
        if count < groups:
            continue
        values = []
        for band in np.array_split(np.arange(count), groups):
            keep = np.ones(count, dtype=bool)
            keep[band] = False
            values.append(_placed(plates[keep], weights[keep], origin, extent, most,
                                  crossings, edges))
        spread = np.asarray(values) - np.mean(values)
        variances.append((groups - 1) / groups * float(spread @ spread))
    return math.sqrt(float(np.mean(variances))) if variances else math.nan


def texture_spread(plates: np.ndarray, weights: np.ndarray, origin: int, extent: float,
                   most: float = MAX_MOVE, sign: float = 1.0, edges: bool = True) -> float:
    """Return the standard error of where ``edge_offset`` puts the centre, from a texture model.

    The plate beside the mark (``STRIP`` px beyond ``extent``, both sides) is texture alone:
    its standard deviation and its correlation from one column, and one row, to the next
    give a Gaussian random field of the same level and grain (Gaussian-filtered noise). The
    placement (``_placed``) again on the plates times ``TEXTURE_DRAWS`` such fields (a
    texture multiplies the plate: a dark mark's deficit ``d`` becomes ``d + t (1 - d)``;
    ``sign`` -1 for a bright mark's), against the plates as they are: the RMS difference (px).
    A fixed seed: the same plates give the same answer. NaN without the plate beside the mark.
    """
    columns = np.abs(np.arange(plates.shape[1]) - origin)
    beside = (columns >= extent + STRIP[0]) & (columns <= extent + STRIP[1])
    right = beside & (np.arange(plates.shape[1]) > origin)
    strips = [plates[:, beside & right], plates[:, beside & ~right]]
    if min(strip.size for strip in strips) < 8:
        return math.nan
    level = float(np.std(np.concatenate([strip.ravel() for strip in strips])))
    grain = [_grain(np.concatenate([strip[:-1].ravel() for strip in strips]),
                    np.concatenate([strip[1:].ravel() for strip in strips])),
             _grain(np.concatenate([strip[:, :-1].ravel() for strip in strips]),
                    np.concatenate([strip[:, 1:].ravel() for strip in strips]))]
    crossings = crossings_center(plates, weights, origin, extent)
    base = _placed(plates, weights, origin, extent, most, crossings, edges)
    rng = np.random.default_rng(0)
    moved = []
    for _ in range(TEXTURE_DRAWS):
        field = gaussian_filter(rng.standard_normal(plates.shape), grain, mode='wrap')
        field *= level / float(field.std())
        moved.append(_placed(plates + field * (1.0 - sign * plates), weights, origin, extent,
                             most, crossings, edges) - base)
    return math.sqrt(float(np.mean(np.square(moved))))


def _grain(first: np.ndarray, second: np.ndarray) -> float:
    """Return the Gaussian filter's sigma (px) whose noise correlates ``first`` and ``second``.

    Neighbours one px apart in Gaussian-filtered white noise of sigma ``s`` correlate by
    ``exp(-1 / (4 s^2))``; under 0.05, ``MIN_GRAIN``.
    """
    first, second = first - first.mean(), second - second.mean()
    scale = math.sqrt(float(first @ first) * float(second @ second))
    rho = float(first @ second) / scale if scale > 0 else 0.0
    if rho <= 0.05:
        return MIN_GRAIN
    return min(0.5 / math.sqrt(-math.log(min(rho, 0.995))), MAX_GRAIN)


def sharpness(plates: np.ndarray, weights: np.ndarray, origin: int, extent: float) -> float:
    """Return how sharp the mark's edges are (1/px): its steepest slope over its peak, per row.

    ``plates``: rows x grid (deficits, origin at column ``origin``), within ``extent`` + 3 px
    of it; the rows' mean weighted by ``weights``. Measured under 0.8 px optics: 0.32-0.42 for
    boxes, discs, rings, crosses and bars (narrow strokes too), 0.12-0.20 for a Gaussian blob
    of sigma 5 px and 0.22-0.35 for sigma 2.5 px (without and with an 8 % texture).
    """
    near = slice(max(origin - int(extent) - 3, 0), origin + int(extent) + 4)
    part = plates[:, near]
    peaks = part.max(axis=1)
    slopes = np.abs(np.gradient(part, axis=1)).max(axis=1)
    ratio = np.where(peaks > 0, slopes / np.where(peaks > 0, peaks, 1.0), 0.0)
    total = float(np.sum(weights))
    return float(np.sum(weights * ratio)) / total if total > 0 else 0.0


def row_plates(regions, rows, positions, kernels, extent: float,
               sign: float, kappa: float = 0.0) -> tuple[np.ndarray, int] | None:
    """Return (plates, origin): each row's relative deficit in plate coordinates.

    ``regions``: the ROI per frame; ``rows``: the ROI rows to learn; ``positions``: the
    mark's column per frame (NaN: not measured), which becomes the origin; ``kernels``:
    (blur, curvature) per frame; ``extent``: the mark's half-width (px; the frame's columns
    within it and its smear are left out of the light); ``sign``: 1 for a dark mark, -1 for
    a bright one. A pattern fixed in the image (its median over the frames at each pixel,
    the mark's columns left out) and each frame's light (a polynomial of x per row, fitted
    outside the mark) are divided out; then every row's deficit is deconvolved by the
    frames' motion kernels (least squares over the frames, as ``PlateModel``; paths of
    ``kappa``'s shape, template.path_knots), keeping each frequency by how far the plate
    there outweighs the frames' noise (``noise_gain``: a faint mark in low light, t18 of the
    sixth blind set, had its centre 0.24 px off where the deconvolved noise made its edges
    look asymmetric). None if fewer than 8 frames were measured.
    """
    used = [n for n, p in enumerate(positions) if math.isfinite(p)
            and np.all(np.isfinite(kernels[n]))]
    if len(used) < 8:
        return None
    stack = np.array([regions[n][rows].astype(np.float64) for n in used])
    count, height, width = stack.shape
    columns = np.arange(width)
    spans = np.array([extent + 0.5 * abs(kernels[n][0]) + 0.25 * abs(kernels[n][1]) + 4.0
                      for n in used])
    centers = np.array([positions[n] for n in used])
    outside = np.abs(columns[None, :] - centers[:, None]) > spans[:, None]
    light = np.ones((count, height, width))
    basis = np.vander(np.linspace(-1.0, 1.0, width), LIGHT_DEGREE + 1)
    for _ in range(2):  # the fixed pattern, and each frame's light against it
        masked = np.where(outside[:, None, :], stack / light, np.nan)
        with warnings.catch_warnings():  # columns the mark never left: NaN, no warning
            warnings.simplefilter('ignore', RuntimeWarning)
            static = np.nanmedian(masked, axis=0)
        seen = np.isfinite(static)
        if not np.all(seen.any(axis=1)):
            return None
        for r in range(height):  # columns the mark never left: interpolated
            static[r] = np.interp(columns, columns[seen[r]], static[r][seen[r]])
        for i in range(count):
            keep = outside[i]
            if np.count_nonzero(keep) <= 2 * (LIGHT_DEGREE + 1):
                return None
            ratio = stack[i][:, keep] / static[:, keep]
            coef = np.linalg.lstsq(basis[keep], ratio.T, rcond=None)[0]
            light[i] = (basis @ coef).T
    reach = float(spans.max()) + 16.0
    size = fft_size(int(math.ceil(2.0 * reach + 32)))
    origin = size // 2
    k = 2.0 * np.pi * np.fft.rfftfreq(size)
    numerator = np.zeros((2, height, k.size), complex)  # the even and the odd frames'
    power = np.zeros((2, k.size))
    for i, n in enumerate(used):
        deficit = sign * (1.0 - stack[i] / (static * light[i]))
        j0 = int(round(centers[i])) - origin
        index = np.arange(j0, j0 + size)
        valid = (index >= 0) & (index < width)
        window = np.zeros((height, size))
        window[:, valid] = deficit[:, index[valid]]
        delta = centers[i] - j0 - origin
        window *= tukey(size, origin + delta, spans[i], 8.0) * valid
        spectrum = kernel_spectrum(k, kernels[n][0], kernels[n][1], kappa) * np.exp(
            -1j * k * delta)
        numerator[i % 2] += np.conj(spectrum) * np.fft.rfft(window, axis=1)
        power[i % 2] += np.abs(spectrum) ** 2
    total = power.sum(axis=0)
    whole = numerator.sum(axis=0) / (total + REGULARISATION * total.max())
    halves = numerator / (power + REGULARISATION * power.max(axis=1, keepdims=True))[:, None]
    whole *= noise_gain(whole, halves[0] - halves[1])
    plates = np.fft.irfft(whole, size, axis=1)
    return plates * tukey(size, origin, reach, 8.0), origin


def noise_gain(spectra: np.ndarray, difference: np.ndarray) -> np.ndarray:
    """Return the Wiener gain per frequency of the rows' plates ``spectra`` (rows x k).

    ``difference``: the same plates learned from the even frames less the odd frames', which
    holds their noise and not the plate: the noise power of the whole is about a quarter of
    its power. Each frequency is kept by ``1 - noise / power`` (both averaged over the rows
    and over ``GAIN_SMOOTH`` neighbouring frequencies), at least 0: frequencies where the
    frames' noise, amplified by the motion kernels' deconvolution, outweighs the plate are
    left out. Noiseless frames keep nearly all (the halves differ only where the
    regularisation meets their smears' zeros: t18 noiseless, 0.005 -> 0.004 px off).
    """
    power = np.mean(np.abs(spectra) ** 2, axis=0)
    noise = 0.25 * np.mean(np.abs(difference) ** 2, axis=0)
    kernel = np.ones(GAIN_SMOOTH) / GAIN_SMOOTH
    power = np.convolve(power, kernel, mode='same')
    noise = np.convolve(noise, kernel, mode='same')
    gain = 1.0 - noise / np.where(power > 0, power, 1.0)
    gain[0] = 1.0
    return np.clip(gain, 0.0, 1.0)


def edge_center(plates: np.ndarray, origin: int, reach: float, move: float = 2.0,
                around: float = 0.0) -> tuple[float, float]:
    """Return (centre, asymmetry): where the rows' edge energy is most mirror-symmetric.

    ``plates`` (rows x grid, origin column ``origin``, from ``row_plates``) are interpolated
    to 1/``UPSAMPLE`` px; each row's edge energy is its squared slope along x; the centre
    ``c`` (px from the origin, within ``move`` of ``around``) minimises the summed squared
    differences of the energy at ``c + v`` and ``c - v``, ``|v| <= reach``, refined by a
    parabola. The asymmetry is that minimum over the energy's own sum of squares there (0: a
    mirror image; a mark that is not symmetric along x scores high). NaN if there is no edge.
    """
    energy = np.gradient(_upsampled(plates), STEP, axis=1) ** 2
    middle = origin * UPSAMPLE + int(round(around * UPSAMPLE))
    found = _mirror(energy, middle, reach, move)
    if found is None:
        return math.nan, math.nan
    center, at, best = found
    total = float((energy[:, best - int(round(reach * UPSAMPLE)):
                          best + int(round(reach * UPSAMPLE)) + 1] ** 2).sum())
    if not total > 0:
        return math.nan, math.nan
    return center + (middle - origin * UPSAMPLE) * STEP, at / total


def deficit_center(plates: np.ndarray, origin: int, reach: float, move: float) -> float:
    """Return where the rows' deficit itself is most mirror-symmetric (px from the origin).

    A coarse centre for ``edge_center`` to start from when the mark may be pixels away: the
    deficit is symmetric about the mark's centre only, its edge energy about each lone edge
    too (a window holding one edge of a wide mark is a mirror image). A texture's slow part
    moves it by tenths of a pixel. NaN if there is none within ``move``.
    """
    found = _mirror(_upsampled(plates), origin * UPSAMPLE, reach, move)
    return math.nan if found is None else found[0]


def _upsampled(plates: np.ndarray) -> np.ndarray:
    """Return ``plates`` (rows x grid) interpolated to 1/``UPSAMPLE`` px (band-limited)."""
    size = plates.shape[1]
    return np.fft.irfft(np.fft.rfft(plates, axis=1), size * UPSAMPLE, axis=1) * UPSAMPLE


def _mirror(values, middle, reach, move):
    """Return (centre px from ``middle``, score, its fine index) of ``values``' mirror symmetry.

    ``values``: rows x fine columns (1/``UPSAMPLE`` px); the centre within ``move`` px of
    the fine column ``middle`` minimising the squared differences of ``values`` at ``c + v``
    and ``c - v``, ``1/UPSAMPLE <= v <= reach``, refined by a parabola. None at the search's
    edge or out of the grid.
    """
    v = np.arange(1, int(round(reach * UPSAMPLE)) + 1)
    shifts = np.arange(-int(round(move * UPSAMPLE)), int(round(move * UPSAMPLE)) + 1)
    if middle + shifts[0] - v[-1] < 0 or middle + shifts[-1] + v[-1] >= values.shape[1]:
        return None
    scores = np.array([float(((values[:, middle + s + v] - values[:, middle + s - v]) ** 2).sum())
                       for s in shifts])
    best = int(np.argmin(scores))
    if best in (0, shifts.size - 1):
        return None
    below, at, above = scores[best - 1:best + 2]
    curvature = below - 2.0 * at + above
    step = 0.5 * (below - above) / curvature if curvature > 0 else 0.0
    return float((shifts[best] + step) * STEP), float(at), int(middle + shifts[best])
