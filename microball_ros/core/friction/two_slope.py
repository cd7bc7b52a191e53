"""The paper's own identification of the Langevin law: its slopes at v = 0 and v = v1 (eq. 14).

This module owns ``fit_two_slope`` and its ``TwoSlopeResult``: local regressions of the friction
curve give its slope at 0 (A alpha / 3) and at v1, and their ratio fixes alpha. A reproduction
of the paper; ``fitting.fit_least_squares`` is the sound route over the data's whole range.
"""

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scipy import optimize

from microball_ros.core.errors import FitError
from microball_ros.core.friction.fitting import check_fit_data
from microball_ros.core.friction.langevin import unit_langevin_slope
from microball_ros.core.friction.laws import Langevin


def _local_slope_at_zero(v, force, window):
    """Return the slope of force(v) at 0 from an odd cubic b1 v + b3 v^3 fitted on |v| <= window.

    The law is odd, so the odd cubic uses the samples of both signs and has no bias from the
    even terms; the cubic term absorbs the curvature inside the window.
    """
    inside = np.abs(v) <= window
    if np.count_nonzero(inside) < 8:
        raise FitError(f'only {np.count_nonzero(inside)} samples with |v_rel| <= {window:g} m/s '
                       'to estimate the slope at 0')
    basis = np.column_stack([v[inside], v[inside] ** 3])
    return float(np.linalg.lstsq(basis, force[inside], rcond=None)[0][0])


def _local_slope_at(v, force, v1, window):
    """Return the slope of force(v) at v1 from a quadratic fitted on |(|v| - v1)| <= window.

    The samples of both signs are folded onto v > 0 with the oddness of the law,
    (v, L) -> (|v|, sign(v) L); the slope is the linear coefficient of the quadratic in |v| - v1.
    """
    speed, folded = np.abs(v), np.sign(v) * force
    inside = np.abs(speed - v1) <= window
    if speed.max() < v1 or np.count_nonzero(inside) < 8:
        raise FitError(f'the data reach |v_rel| = {speed.max():.4g} m/s with '
                       f'{np.count_nonzero(inside)} samples within {window:g} m/s of '
                       f'v1 = {v1:g} m/s; the two-slope method needs data around v1 '
                       '(choose a smaller v1 or use fit_least_squares)')
    offset = speed[inside] - v1
    basis = np.column_stack([np.ones_like(offset), offset, offset ** 2])
    return float(np.linalg.lstsq(basis, folded[inside], rcond=None)[0][1])


@dataclass(frozen=True)
class TwoSlopeResult:
    """The Langevin law identified from its slopes at v = 0 and v = v1 (docs/paper.md eq. 14)."""

    A: float
    alpha: float
    slope0: float
    slope1: float
    v1: float

    @property
    def law(self) -> Langevin:
        """Return the identified Langevin law."""
        return Langevin(self.A, self.alpha)


def fit_two_slope(v: npt.ArrayLike, a: npt.ArrayLike, v1: float = 0.015,
                  window: float = 0.003) -> TwoSlopeResult:
    """Identify A and alpha of the Langevin law from its slopes at 0 and at v1 (the paper's way).

    The slopes of L = -a against v are estimated by local regression: at 0 an odd cubic on
    |v| <= window, at v1 a quadratic on the samples whose |v| is within window of v1 (both
    signs folded by oddness). Then slope0 = A alpha / 3 and slope1 = dL/dv(v1), so the ratio
    slope1 / slope0 = 3 (1/x^2 - 1/sinh(x)^2) with x = alpha v1 depends on alpha only; it falls
    from 1 to 0 as x grows, and brentq solves it. Raise FitError if the data do not reach v1
    or the slopes are not Langevin-like (0 < slope1 < slope0).
    """
    v, a = check_fit_data(v, a)
    force = -a
    slope0 = _local_slope_at_zero(v, force, window)
    slope1 = _local_slope_at(v, force, v1, window)
    ratio = slope1 / slope0
    x_low, x_high = 1e-6, 1e4

    def mismatch(x):
        return 3.0 * unit_langevin_slope(x) - ratio

    if not (slope0 > 0 and mismatch(x_high) < 0 < mismatch(x_low)):
        raise FitError(f'slopes {slope0:.4g} 1/s at 0 and {slope1:.4g} 1/s at {v1:g} m/s do '
                       'not fit a Langevin law (needs 0 < slope at v1 < slope at 0)')
    x = optimize.brentq(mismatch, x_low, x_high, xtol=1e-14, rtol=1e-12)
    alpha = x / v1
    return TwoSlopeResult(A=3.0 * slope0 / alpha, alpha=alpha, slope0=slope0, slope1=slope1,
                          v1=v1)
