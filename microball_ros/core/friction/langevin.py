"""The modified Langevin function of the paper (eq. 13), evaluated to a few ulps everywhere.

This module owns the numerics of L(z) = A (coth(alpha z) - 1/(alpha z)) and its slope: the
dimensionless ``unit_langevin`` (coth(x) - 1/x) and ``unit_langevin_slope`` (1/x^2 -
1/sinh(x)^2), by a continued fraction near 0 (no cancellation) and the direct formulas beyond
(no overflow), and ``langevin`` / ``langevin_slope`` in physical units. Floats stay floats (the
integrator's fast path), arrays stay arrays.
"""

import math

import numpy as np
import numpy.typing as npt

# A float for a float argument (the integrator's fast path), else a float array.
FloatOrArray = float | np.ndarray

# Below |x| = 1, coth(x) - 1/x is evaluated with Lambert's continued fraction
#   coth(x) - 1/x = x / (3 + x^2 / (5 + x^2 / (7 + ...)))
# (its truncations reproduce the series x/3 - x^3/45 + 2x^5/945 - ...). It has no cancellation,
# and 8 levels (denominators 3..17) are exact to double precision for |x| < 1. Above 1 the
# direct formula loses at most a few ulps. A 3-term series switched to the direct formula cannot
# do better than about 5e-13 relative error at any switch point.
_NEAR_ZERO = 1.0
_FRACTION_LEVELS = 8


def _langevin_over_x(x):
    """Return (coth(x) - 1/x) / x for |x| < 1 by the continued fraction (floats or arrays)."""
    x2 = x * x
    if isinstance(x2, float):
        denominator = 2.0 * _FRACTION_LEVELS + 1.0
        for level in range(_FRACTION_LEVELS - 1, 0, -1):
            denominator = (2.0 * level + 1.0) + x2 / denominator
        return 1.0 / denominator
    # In place: the fit evaluates this on every sample many times.
    denominator = np.full_like(x2, 2.0 * _FRACTION_LEVELS + 1.0)
    for level in range(_FRACTION_LEVELS - 1, 0, -1):
        np.divide(x2, denominator, out=denominator)
        denominator += 2.0 * level + 1.0
    return np.divide(1.0, denominator, out=denominator)


def _inverse_sinh_squared(x):
    """Return 1 / sinh(x)^2 without overflow for large |x| (floats or arrays)."""
    two_x = 2.0 * np.abs(x)
    return 4.0 * np.exp(-two_x) / np.expm1(-two_x) ** 2


def float_or_array(v: float | npt.ArrayLike) -> FloatOrArray:
    """Return v unchanged if it is a float (fast path for the integrator), else a float array."""
    return v if isinstance(v, float) else np.asarray(v, dtype=float)


def unit_langevin(x: FloatOrArray) -> FloatOrArray:
    """Return coth(x) - 1/x: a float for a float x, else an array (0 at x = 0, no overflow)."""
    if isinstance(x, float):
        if abs(x) < _NEAR_ZERO:
            return x * _langevin_over_x(x)
        return 1.0 / math.tanh(x) - 1.0 / x
    # The fraction everywhere (harmless far out), then the few far samples replaced: boolean
    # masks cost four times the arithmetic on fit data.
    out = x * _langevin_over_x(x)
    far = np.flatnonzero(np.abs(x) >= _NEAR_ZERO)
    if far.size:
        x_far = x[far]
        out[far] = 1.0 / np.tanh(x_far) - 1.0 / x_far
    return out


def unit_langevin_slope(x: FloatOrArray) -> FloatOrArray:
    """Return d/dx (coth(x) - 1/x) = 1/x^2 - 1/sinh(x)^2: a float for a float x, else an array."""
    # Near 0 use q = L(x)/x from the continued fraction: with coth = L + 1/x,
    # 1/x^2 - 1/sinh^2 = 1 - coth^2 + 1/x^2 = 1 - 2q - (x q)^2, which tends to 1/3.
    if isinstance(x, float):
        if abs(x) < _NEAR_ZERO:
            q = _langevin_over_x(x)
            return 1.0 - 2.0 * q - (x * q) ** 2
        return 1.0 / (x * x) - float(_inverse_sinh_squared(x))
    q = _langevin_over_x(x)
    out = 1.0 - 2.0 * q - (x * q) ** 2
    far = np.flatnonzero(np.abs(x) >= _NEAR_ZERO)
    if far.size:
        x_far = x[far]
        out[far] = 1.0 / (x_far * x_far) - _inverse_sinh_squared(x_far)
    return out


def langevin(v: float | npt.ArrayLike, A: float, alpha: float) -> FloatOrArray:
    """Return the modified Langevin function A (coth(alpha v) - 1/(alpha v)), m/s^2.

    Vectorised over ``v``; accurate to a few ulps everywhere, including v = 0 (value 0).
    """
    return A * unit_langevin(alpha * float_or_array(v))


def langevin_slope(v: float | npt.ArrayLike, A: float, alpha: float) -> FloatOrArray:
    """Return dL/dv = alpha A (1/(alpha v)^2 - 1/sinh(alpha v)^2), 1/s; alpha A / 3 at v = 0."""
    return alpha * A * unit_langevin_slope(alpha * float_or_array(v))
