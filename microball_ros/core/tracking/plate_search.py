"""The learned plate's search over a frame's deficit (core.tracking.plate): a matched filter."""

import math

import numpy as np
from scipy.signal import find_peaks

from microball_ros.core.tracking.plate_model import PlateModel
from microball_ros.core.tracking.search import peak_offset

SEARCH_BLURS = (0.0, 16.0, 32.0, 64.0, 96.0, 128.0)  # px; 128: a whole-period exposure
CURVED = 16.0  # px: a path curved more than this (a turning point) is not a straight blur
NEXT_GAIN = 0.3  # match_plate: a next-best match needs at least this gain
CANDIDATES = 3  # after a loss, the best matches fitted in turn (a particle beside the mark)


def search_kernels(motion, blurs: bool, kernel=None,
                   kappa: float = 0.0) -> list[tuple[float, float]]:
    """Return the (blur, curve) kernels of a search over the whole ROI (after a loss).

    ``blurs``: straight paths of ``SEARCH_BLURS``; ``motion`` (a core.tracking.smear
    PeriodicMotion, or None): a long smear's kernels at 36 phases of a period, else (with
    ``blurs``) those at 12 phases if some curve more than ``CURVED`` px (the turning points
    of a long exposure); ``kernel``: the predicted one, if any; ``kappa``: the plate's paths'
    (template.path_knots), the shape the bank's kernels are given in.
    """
    kernels = [(b, 0.0) for b in SEARCH_BLURS] if blurs else []
    if motion is not None and not blurs:
        kernels += motion.bank(36, kappa)
    elif motion is not None:
        bank = motion.bank(12, kappa)
        if max(abs(curve) for _, curve in bank) > CURVED:
            kernels += bank
    return kernels + ([kernel] if kernel is not None else [])


def match_plate(plate: PlateModel, d: np.ndarray, lo: int, hi: int, kernels, reach: float,
                count: int = 1, least: float = NEXT_GAIN,
                shaped: bool = True) -> list[tuple[float, float, float]]:
    """Return up to ``count`` (column, blur, curve): the best matches of the smeared plate.

    Columns ``lo`` to ``hi`` (exclusive) of the deficit ``d`` are candidate centres; each
    (blur, curve) of ``kernels`` smears the plate's part within ``reach`` plus the kernel's
    half-length of its origin. Score: correlation over the model's norm, a column refined by a
    parabola through its neighbours' scores. With ``count`` 1, the best. Else the peaks of
    any kernel's score that match the plate at a gain of ``least`` or more (the score of ``g``
    times the plate is ``g`` times its norm: noise peaks, as in a covered ROI, are not worth
    fitting), ``reach`` px apart, ordered by their score times ``shape_scores`` squared
    (something darker than the mark passing near it scores higher than the mark; not
    ``shaped``: the best first, then by their score); the best alone if there are none.
    Empty if no kernel has a norm.
    """
    c = plate.center
    best = None
    scores = []
    for blur, curve in kernels:
        core = min(int(math.ceil(reach + 0.5 * blur + 0.25 * abs(curve))) + 2, c - 1)
        # A bank's smears are the same in every frame searched with it: kept (not a gate's one)
        smeared = plate.smeared(blur, curve) if len(kernels) > 1 else plate.model(0.0, blur,
                                                                                  curve)
        template = smeared[c - core:c + core + 1]
        norm = math.sqrt(float(template @ template))
        if norm <= 0:
            continue
        padded = np.zeros(hi - lo + 2 * core)
        a, b = lo - core, hi + core
        padded[max(a, 0) - a:min(b, d.size) - a] = d[max(a, 0):min(b, d.size)]
        score = np.correlate(padded, template, mode='valid') / norm
        scores.append((score, blur, curve, norm, padded, template))
        k = int(np.argmax(score))
        if best is None or score[k] > best[0]:
            best = (float(score[k]), lo + k + peak_offset(score, k), blur, curve)
    if best is None:
        return []
    if count == 1:
        return [best[1:]]
    # The peaks of every kernel's score that match at a gain of ``least`` or more; shaped, most
    # like the mark first: the score times its shape's correlation with the smeared plate,
    # squared (a tool darker and wider than the mark beside it scores higher than the mark,
    # at several peaks along it, but is not shaped like it; a faint texture shaped like it
    # scores low). Else the best (its column refined), then the others by their score.
    peaks = []
    for score, blur, curve, norm, padded, template in scores:
        columns = find_peaks(score, distance=max(int(reach), 1), height=least * norm)[0]
        if shaped:
            k = int(np.argmax(score))
            if score[k] >= least * norm and k not in columns:
                columns = np.append(columns, k)
            shapes = np.clip(shape_scores(padded, template, columns), 0.0, None)
        else:
            shapes = np.ones(columns.size)
        peaks += [(float(score[k]) * shape ** 2, int(k), score, blur, curve)
                  for shape, k in zip(shapes, columns, strict=True)]
    found: list[tuple[float, float, float]] = [] if shaped else [best[1:]]
    for _, k, score, blur, curve in sorted(peaks, key=lambda peak: -peak[0]):
        if len(found) == count:
            break
        column = lo + k + peak_offset(score, k)
        if all(abs(column - other[0]) >= reach for other in found):
            found.append((column, blur, curve))
    return found or [best[1:]]


def shape_scores(padded: np.ndarray, template: np.ndarray, starts: np.ndarray) -> np.ndarray:
    """Return the zero-mean normalised correlation of ``template`` at each of ``starts``.

    ``padded[start:start + template.size]`` against the template, both less their means:
    1 for the mark's own shape at any gain and light, about 0 over a flat dark object.
    """
    n = template.size
    shaped = template - template.mean()
    norm = math.sqrt(float(shaped @ shaped))
    windows = padded[starts[:, None] + np.arange(n)[None, :]]
    windows = windows - windows.mean(axis=1, keepdims=True)
    energy = np.sqrt(np.einsum('ij,ij->i', windows, windows)) * norm
    return np.where(energy > 0, windows @ shaped / np.where(energy > 0, energy, 1.0), 0.0)


def plate_level(full: PlateModel | None, s: float, sign: float, kernel,
                width: int) -> np.ndarray | None:
    """Return the plate over ``width`` ROI columns, ``1 - sign D`` smeared, its origin at s."""
    if full is None:
        return None
    j0 = int(round(s)) - full.center
    blur, curve = kernel if kernel is not None else (0.0, 0.0)
    model = full.model(s - round(s), abs(blur), curve)
    level = 1.0 - sign * model.take(np.arange(width) - j0, mode='wrap')
    return np.clip(level, 0.05, None)


def search_plate(plate: PlateModel, d: np.ndarray, prediction, kernel, motion, smeared: bool,
                 reach: float, shaped: bool = True) -> list[tuple[float, float, float]]:
    """Return the (column, blur, curve) to fit the plate at, in the order to try them.

    Gated around ``prediction`` (core.tracking.predict's; one kernel, the predicted
    ``kernel``) when there is one: that match. Else over the whole ROI with a bank of kernels
    (``search_kernels``: ``motion``'s, and straight blurs unless ``smeared``, a long smear's
    plate): the best ``CANDIDATES`` matches. ``reach`` and ``shaped``: ``match_plate``'s.
    Empty if the gate is outside the ROI.
    """
    if prediction is not None:
        gate = 6.0 * prediction.spread + 3.0
        lo = int(math.floor(prediction.column - gate))
        hi = int(math.ceil(prediction.column + gate)) + 1
        kernels = [kernel if kernel is not None else (0.0, 0.0)]
    else:
        lo, hi = 0, d.size
        kernels = search_kernels(motion, not smeared, kernel, plate.kappa)
    lo, hi = max(lo, 0), min(hi, d.size)
    if hi <= lo:
        return []
    return match_plate(plate, d, lo, hi, kernels, reach,
                       1 if prediction is not None else CANDIDATES, shaped=shaped)
