"""The sub-pixel fit: the mark's position from its deficit over the located extent.

Owns the position estimators and their noise. The deficit centroid is the position averaged
over the exposure for any blur and any mark shape (the centroid of a convolution is the sum of
the centroids), ``deficit_centroid``. When the mark has barely moved since the previous frame
(blur negligible and symmetric) the centre of mirror symmetry is better: Gauss-Newton on the
antisymmetric energy with band-limited (Fourier) interpolation, ``symmetric_center``, which
reaches the Cramer-Rao bound for still symmetric marks. ``refine_position`` blends the two by
the motion since the previous frame and keeps the centroid when they disagree by more than 3
sigma (an asymmetric blur). A per-frame sigma from the fit's residuals belongs here.
"""

import math

import numpy as np

from microball_ros.core.tracking.config import TrackerConfig


def deficit_centroid(deficit: np.ndarray, first: int, last: int,
                     noise: float) -> tuple[float, float, float]:
    """Return (centroid, sigma, area) of ``deficit[first:last + 1]``, in column units.

    ``sigma`` is the centroid's 1-sigma noise for white deficit noise of ``noise`` per
    column; ``area`` the integrated deficit, which blur does not change. Centroid and sigma
    are NaN when the area is not positive.
    """
    window = deficit[first:last + 1]
    area = float(window.sum())
    if area <= 0:
        return float('nan'), float('nan'), area
    offsets = np.arange(first, last + 1, dtype=float)
    centroid = float(window @ offsets) / area
    sigma = noise * math.sqrt(float(np.sum((offsets - centroid) ** 2))) / area
    return centroid, sigma, area


def symmetric_center(deficit: np.ndarray, start: float, pad: int, iterations: int = 10,
                     tolerance: float = 1e-6) -> float:
    """Return the centre of mirror symmetry of a 1-D signal, near ``start`` (index units).

    Minimises the energy of the part of the signal that is antisymmetric about the centre by
    Gauss-Newton on its Fourier transform (band-limited interpolation, so sub-pixel shifts are
    exact for band-limited signals). ``pad`` samples are kept on both sides of the support.
    Returns NaN if it does not converge.
    """
    n = deficit.size
    nz = np.flatnonzero(deficit)
    if nz.size == 0:
        return float('nan')
    half = max(start - nz[0], nz[-1] - start) + pad
    first = int(math.floor(start - half))
    last = int(math.ceil(start + half)) + 1
    segment = np.zeros(last - first)
    lo, hi = max(first, 0), min(last, n)
    segment[lo - first:hi - first] = deficit[lo:hi]
    spectrum = np.fft.rfft(segment)
    omega = 2.0 * np.pi * np.arange(spectrum.size) / segment.size
    weight = np.full(spectrum.size, 2.0)
    weight[0] = 0.0
    if segment.size % 2 == 0:
        weight[-1] = 0.0
    center = start - first
    for _ in range(iterations):
        rotated = spectrum * np.exp(1j * omega * center)
        jacobian = rotated.real * omega
        curvature = float(np.sum(weight * jacobian * jacobian))
        if curvature <= 0:
            return float('nan')
        step = -float(np.sum(weight * rotated.imag * jacobian)) / curvature
        center += step
        if abs(step) < tolerance:
            return center + first
    return float('nan')


def refine_position(deficit: np.ndarray, first: int, last: int, centroid: float,
                    sigma_centroid: float, noise: float, x0: int, config: TrackerConfig,
                    previous: float | None) -> tuple[float, float]:
    """Return (position, sigma) in image columns: centroid, centre of symmetry or a blend.

    ``centroid`` and ``sigma_centroid`` are in ROI columns (``deficit_centroid``), ``x0`` is
    the ROI's first image column, ``previous`` the mark's image column in the previous frame
    (None if unknown). 'centroid' returns the centroid; 'symmetric' the centre of symmetry;
    'auto' the centroid when the mark moved by more than 3 ``still_motion_px`` since the
    previous frame (or no previous), the centre of symmetry when it moved by less than
    ``still_motion_px``, a linear blend between; and the centroid whenever the two disagree
    by more than 3 sigma. The centroid also replaces a centre of symmetry that did not converge.
    """
    pad = int(config.pad_px)
    if config.method == 'centroid':
        return centroid + x0, sigma_centroid
    if config.method == 'symmetric':
        weight_centroid = 0.0
    elif previous is None:
        weight_centroid = 1.0
    else:
        moved = abs(centroid + x0 - previous)
        still = config.still_motion_px
        weight_centroid = min(max((moved - still) / (2.0 * still), 0.0), 1.0)
    if weight_centroid >= 1.0:
        return centroid + x0, sigma_centroid
    segment = np.zeros_like(deficit)
    segment[first:last + 1] = deficit[first:last + 1]
    center = symmetric_center(segment, centroid, pad + 4)
    if not math.isfinite(center):
        return centroid + x0, sigma_centroid
    # A centre of symmetry that disagrees with the centroid by more than the noise allows
    # means an asymmetric blur (speed changing during the exposure): trust the centroid.
    if config.method == 'auto':
        disagreement = abs(center - centroid) / max(sigma_centroid, 1e-12)
        weight_centroid = max(weight_centroid, min(max(disagreement - 3.0, 0.0), 1.0))
    if weight_centroid >= 1.0:
        return centroid + x0, sigma_centroid
    slope = np.gradient(deficit[first:last + 1])
    information = max(float(slope @ slope) - slope.size * noise ** 2 / 2.0,
                      float(slope @ slope) * 1e-3)
    sigma_symmetric = noise / math.sqrt(information)
    position = center + weight_centroid * (centroid - center)
    sigma = sigma_symmetric + weight_centroid * (sigma_centroid - sigma_symmetric)
    return position + x0, sigma
