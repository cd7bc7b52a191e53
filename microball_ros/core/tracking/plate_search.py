"""The learned plate's search over a frame's deficit (core.tracking.plate): a matched filter."""

import math

import numpy as np

from microball_ros.core.tracking.plate_model import PlateModel
from microball_ros.core.tracking.search import peak_offset


def match_plate(plate: PlateModel, d: np.ndarray, lo: int, hi: int, kernels, reach: float):
    """Return (column, blur, curve): the best match of the smeared plate in ``d``, or None.

    Columns ``lo`` to ``hi`` (exclusive) of the deficit ``d`` are candidate centres; each
    (blur, curve) of ``kernels`` smears the plate's part within ``reach`` plus the kernel's
    half-length of its origin. Score: correlation over the model's norm, the best column
    refined by a parabola through its neighbours' scores.
    """
    c = plate.center
    best = None
    for blur, curve in kernels:
        core = min(int(math.ceil(reach + 0.5 * blur + 0.25 * abs(curve))) + 2, c - 1)
        template = plate.model(0.0, blur, curve)[c - core:c + core + 1]
        norm = math.sqrt(float(template @ template))
        if norm <= 0:
            continue
        padded = np.zeros(hi - lo + 2 * core)
        a, b = lo - core, hi + core
        padded[max(a, 0) - a:min(b, d.size) - a] = d[max(a, 0):min(b, d.size)]
        score = np.correlate(padded, template, mode='valid') / norm
        k = int(np.argmax(score))
        if best is None or score[k] > best[0]:
            best = (float(score[k]), lo + k + peak_offset(score, k), blur, curve)
    return None if best is None else best[1:]


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
