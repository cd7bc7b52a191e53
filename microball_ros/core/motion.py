"""Motion specifications for the synthetic camera: how a plate's position depends on time.

Owns the one form the camera and the rig accept for a plate's motion (``as_motion``: a
callable, sampled ``(times, positions)`` arrays interpolated by a cubic spline, or a number
for a still plate), and ``paper_motion``, the paper's sinusoidal stator and lagging slider,
for tests, benchmarks and demos.
"""

from collections.abc import Callable
import math
from typing import Any

import numpy as np
import numpy.typing as npt
from scipy.interpolate import make_interp_spline

from microball_ros.core.errors import InputError

# A plate's position (m) as a function of time (s), vectorised over arrays of times.
Motion = Callable[[npt.ArrayLike], np.ndarray]


def as_motion(spec: Any) -> Motion:
    """Return a vectorised position function t (s) -> x (m) from a motion specification.

    ``spec`` is a callable (used as is), a pair ``(times, positions)`` of sampled arrays
    (interpolated by a cubic spline; asking for a time outside the samples raises ValueError),
    or a number (a still plate).
    """
    if callable(spec):
        def motion(t):
            t = np.asarray(t, dtype=float)
            return np.broadcast_to(np.asarray(spec(t), dtype=float), t.shape)
        return motion
    if isinstance(spec, (int, float, np.floating, np.integer)):
        value = float(spec)
        return lambda t: np.full(np.shape(t), value)
    try:
        times, positions = (np.asarray(a, dtype=float) for a in spec)
    except (TypeError, ValueError):
        raise InputError('motion must be a callable, a number or a (times, positions) '
                         'pair') from None
    if times.ndim != 1 or times.shape != positions.shape or times.size < 2:
        raise InputError('motion samples must be two 1-D arrays of equal length >= 2')
    if np.any(np.diff(times) <= 0):
        raise InputError('motion sample times must increase strictly')
    spline = make_interp_spline(times, positions, k=min(3, times.size - 1))
    lo, hi = times[0], times[-1]

    def sampled(t):
        t = np.asarray(t, dtype=float)
        if t.size and (t.min() < lo - 1e-12 or t.max() > hi + 1e-12):
            raise InputError(f'motion samples cover t in [{lo:g}, {hi:g}] s, a frame needs '
                             f't in [{t.min():g}, {t.max():g}] s')
        return spline(t)
    return sampled


def paper_motion(stator_amplitude: float = 1.2e-3, slider_amplitude: float = 1.1e-3,
                 frequency: float = 2.95, phase_lag: float = 0.4,
                 slider_drift: float = 0.0) -> tuple[Motion, Motion]:
    """Return (stator, slider) sinusoidal position functions in the paper's regime.

    The stator follows ``A_s sin(w t)``, the slider ``A_l sin(w t - phase_lag) + drift * t``;
    positions in m, ``slider_drift`` in m/s. A convenience for tests, benchmarks and demos.
    """
    omega = 2.0 * math.pi * frequency

    def stator(t):
        return stator_amplitude * np.sin(omega * np.asarray(t, dtype=float))

    def slider(t):
        t = np.asarray(t, dtype=float)
        return slider_amplitude * np.sin(omega * t - phase_lag) + slider_drift * t
    return stator, slider

