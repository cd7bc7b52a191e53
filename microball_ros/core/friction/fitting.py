"""Identification of a static friction law from samples of (v_rel, a_slid).

This module owns the least-squares fit: ``fit_least_squares`` (nonlinear least squares of one
law in dimensionless, bounded log-parameters, polished to the stationary point, with 95 %
profile-likelihood intervals, covariance and information criteria, returned as a
``FitResult``); the paper's two-slope identification is in ``two_slope``. A fit that cannot
describe the data raises ``FitError``; input that is not fit data (lengths, NaN, an unknown
law) ``InputError``.
"""

from dataclasses import dataclass, fields
import math

import numpy as np
import numpy.typing as npt
from scipy import optimize, stats

from microball_ros.core.errors import FitError, InputError
from microball_ros.core.friction.laws import (
    DEFAULT_V_SMOOTH,
    STATIC_LAWS,
    Langevin,
    StaticLaw,
)


def check_fit_data(v: npt.ArrayLike, a: npt.ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    """Return v and a as flat float arrays; raise InputError unless equally long and finite."""
    v = np.asarray(v, dtype=float).ravel()
    a = np.asarray(a, dtype=float).ravel()
    if v.shape != a.shape:
        raise InputError(f'v and a differ in length ({len(v)} and {len(a)})')
    if not (np.all(np.isfinite(v)) and np.all(np.isfinite(a))):
        raise InputError('v and a must be finite')
    return v, a


# ---------------------------------------------------------------------------------------------
# Nonlinear least squares with profile-likelihood intervals
# ---------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class FitResult:
    """A static friction law fitted to (v_rel, a_slid) samples by least squares.

    params, ci95: fitted parameter -> value and -> (lo, hi) 95 % profile-likelihood interval
    (0 or inf where the profile does not close within a factor 1000 of the estimate, or within
    the fit's bounds).
    covariance, correlation: from the Jacobian at the optimum, rows in ``params`` order
    (natural units; for the Langevin law correlation[0, 1] is the A-alpha correlation).
    rmse: residual root mean square, m/s^2; aic, bic: Gaussian information criteria.
    """

    name: str
    params: dict[str, float]
    ci95: dict[str, tuple[float, float]]
    covariance: np.ndarray
    correlation: np.ndarray
    rmse: float
    n: int
    aic: float
    bic: float
    law: StaticLaw

    @property
    def identifiable(self) -> bool:
        """Return True if every parameter's 95 % interval is closed (positive and finite)."""
        return all(0 < lo and math.isfinite(hi) for lo, hi in self.ci95.values())


# Each fitted parameter p is fitted as theta = ln(p / s), s its unit built from the data's
# scales (F a force level of the data, V their largest |v_rel|), and theta is bounded to
# [-LOG_BOUND, LOG_BOUND]: every parameter stays within a factor 1e6 of its data scale. So no
# law is ever evaluated at a parameter that overflows, underflows to 0 or leaves its domain,
# whatever the data, and the fit is the same for data in any units.
LOG_BOUND = math.log(1e6)
# Profile searches stop a factor 1000 away from the estimate: beyond that an interval end is
# reported as 0 or inf, "not determined by these data".
_PROFILE_LIMIT = math.log(1000.0)
# Tolerances of the optimum (tight: the reported numbers) and of the profile's inner fits
# (scipy's defaults: the profile is compared with a threshold 0.6 % above the minimum or more).
_TOLERANCE = 1e-12
_PROFILE_TOLERANCE = 1e-8


def _data_scales(v, force):
    """Return (F, V): the 95 % quantile of |force| (else its maximum) and the largest |v|."""
    speed = float(np.max(np.abs(v)))
    level = float(np.quantile(np.abs(force), 0.95))
    if not level > 0:
        level = float(np.max(np.abs(force)))
    return level, speed


def _parameter_scales(law_class, force_scale, speed):
    units = {'force': force_scale, 'velocity': speed, 'slowness': 1.0 / speed,
             'rate': force_scale / speed}
    return np.array([units[unit] for unit in law_class.parameter_units])


def _initial_guess(law_class, v, force, v_smooth):
    """Return a rough positive start for law_class's fitted parameters, in units of the scales.

    v and force are in units of their scales (|v| <= 1, |force| of order 1), v_smooth too.
    """
    viscous = max(float(np.dot(v, force) / np.dot(v, v)), 1e-3)
    basis = np.column_stack([np.tanh(v / v_smooth), v])
    level, slope = np.maximum(np.linalg.lstsq(basis, force, rcond=None)[0],
                              [1e-3, viscous * 1e-3])
    if law_class is Langevin:
        return [1.5, 3.0 * viscous / 1.5]
    guesses = {'viscous': [viscous], 'coulomb': [float(np.mean(np.abs(force)))],
               'coulomb_viscous': [level, slope],
               'stribeck': [level, 1.5 * level, 0.3, slope]}  # Fc, Fs, vs, c
    return guesses[law_class.name]


class ScaledResiduals:
    """Residuals (law(s exp(theta)).acceleration(v) - a) / F of a law, theta the fitted logs.

    Dividing by the force scale F keeps sums of squares of order n whatever the data's units.
    A non-finite residual or Jacobian raises FitError (it cannot happen inside the bounds for
    data of ordinary magnitude; it is the guard for absurd ones).
    """

    def __init__(self, law_class: type[StaticLaw], v: np.ndarray, a: np.ndarray, fixed: dict,
                 scales: np.ndarray, force_scale: float):
        self.law_class, self.v, self.a, self.fixed = law_class, v, a, fixed
        self.scales, self.force_scale = scales, force_scale

    def values(self, theta: np.ndarray) -> np.ndarray:
        """Return the parameters s exp(theta) in natural units."""
        return self.scales * np.exp(theta)

    def law(self, theta: np.ndarray) -> StaticLaw:
        """Return the law at the log-parameters theta."""
        values = dict(zip(self.law_class.fit_parameters, self.values(theta).tolist(),
                          strict=True))
        return self.law_class(**values, **self.fixed)

    def residuals(self, theta: np.ndarray) -> np.ndarray:
        """Return the scaled residuals at theta."""
        r = (self.law(theta).acceleration(self.v) - self.a) / self.force_scale
        if not np.all(np.isfinite(r)):
            raise FitError(f'{self.law_class.name}: the law is not finite on these data')
        return r

    def jacobian(self, theta: np.ndarray, columns=None) -> np.ndarray:
        """Return d residuals / d theta (the acceleration is -L, and dp/dtheta = p).

        Only the given columns (all by default), in Fortran order: what LAPACK's SVD in
        least_squares wants, without copies.
        """
        gradient = self.law(theta).force_gradient(self.v)
        values = self.values(theta)
        columns = range(len(theta)) if columns is None else columns
        out = np.empty((len(self.v), len(columns)), order='F')
        for j, column in enumerate(columns):
            np.multiply(gradient[column], -values[column] / self.force_scale, out=out[:, j])
        if not np.all(np.isfinite(out)):
            raise FitError(f'{self.law_class.name}: the law is not differentiable on these data')
        return out

    def __call__(self, theta: np.ndarray) -> float:
        """Return the scaled residual sum of squares."""
        r = self.residuals(theta)
        return float(np.dot(r, r))


def _minimise(function, jacobian, start, law_name, tolerance):
    """Run bounded least squares from start, then polish; return (x, active, jac) or FitError.

    x: the log-parameters; active: bool per parameter, True on a bound; jac: the Jacobian at x.
    """
    solution = optimize.least_squares(function, np.clip(start, -LOG_BOUND, LOG_BOUND),
                                      jac=jacobian, bounds=(-LOG_BOUND, LOG_BOUND),
                                      method='trf', x_scale=1.0, xtol=tolerance,
                                      ftol=tolerance, gtol=tolerance, max_nfev=1000)
    if solution.status < 1:
        raise FitError(f'{law_name}: no convergence ({solution.message})')
    active = solution.active_mask != 0
    x = _polish(function, jacobian, solution.x, ~active)
    return x, active, jacobian(x)


def _polish(function, jacobian, x, free, max_steps=20):
    """Return x refined by Gauss-Newton steps in the free coordinates, or x if they fail.

    Why: along the A-alpha valley the sum of squares is flat to rounding, so where the trust
    region method stops depends on the last bits of its arithmetic (1e-8 relative between an
    AVX-512 and an AVX2 CPU). The Gauss-Newton iteration x -= J^+ r converges to the stationary
    point J^T r = 0, which the data fix to about 1e-14 on any CPU. Kept only if it converges
    inside the bounds without raising the sum of squares beyond rounding.
    """
    if not free.any():
        return x
    try:
        return _gauss_newton(function, jacobian, x, np.flatnonzero(free), max_steps)
    except (FitError, np.linalg.LinAlgError):  # a step off the data's domain: keep x
        return x


def _gauss_newton(function, jacobian, x, columns, max_steps):
    residuals = function(x)
    cost = float(np.dot(residuals, residuals))
    polished = x.copy()
    for _ in range(max_steps):
        step = np.linalg.lstsq(jacobian(polished)[:, columns], -residuals, rcond=None)[0]
        polished[columns] += step
        if np.any(np.abs(polished) > LOG_BOUND):
            return x
        residuals = function(polished)
        if np.all(np.abs(step) <= 1e-14 * np.maximum(1.0, np.abs(polished[columns]))):
            polished_cost = float(np.dot(residuals, residuals))
            return polished if polished_cost <= cost * (1.0 + 1e-12) else x
    return x


def _profile_bound(rss, theta_hat, index, direction, threshold, max_log_step, first_step,
                   law_name, on_bound):
    """Return the log-parameter where the profile RSS crosses threshold, or None if it does not.

    The profile fixes log-parameter ``index`` and minimises the RSS over the others (warm
    started from the previous profile point, within the bounds); the search walks away from the
    optimum in doubling steps from first_step up to max_log_step (or the bound), then refines
    the crossing by brentq. A first step just beyond the Wald interval brackets the crossing at
    once for a well-determined parameter, and brentq then needs few evaluations. Profile values
    are memoised: an inner minimisation depends slightly on its starting point, and brentq must
    see the same signs at the bracket ends as the search did. A crossing where another
    parameter has reached a bound (on_bound: those already there at the optimum) is the
    bound's doing, not the data's: None, like no crossing.
    """
    room = LOG_BOUND - direction * theta_hat[index]
    max_log_step = min(max_log_step, room)
    if not max_log_step > 0:
        return None
    free = np.arange(len(theta_hat)) != index
    free_columns = np.flatnonzero(free)
    start = theta_hat[free].copy()
    # The optimum itself is known: never re-minimise there from a far-away warm start.
    memo = {theta_hat[index]: (rss(theta_hat) - threshold, False)}

    def profile(log_value):
        """Return (RSS excess over the threshold, whether a free parameter is on a bound)."""
        if log_value not in memo:
            theta = theta_hat.copy()
            theta[index] = log_value
            pinned = False
            if free.any():
                def reduced(phi):
                    theta[free] = phi
                    return rss.residuals(theta)

                def reduced_jacobian(phi):
                    theta[free] = phi
                    return rss.jacobian(theta, free_columns)
                phi, active, _ = _minimise(reduced, reduced_jacobian, start, law_name,
                                           _PROFILE_TOLERANCE)
                start[:] = phi
                theta[free] = phi
                pinned = bool(np.any(active & ~on_bound[free]))
            memo[log_value] = (rss(theta) - threshold, pinned)
        return memo[log_value]

    def excess(log_value):
        return profile(log_value)[0]

    def crossing(inner, outer):
        found = optimize.brentq(excess, inner, outer, xtol=1e-4)
        return None if profile(found)[1] else found

    inner, step = theta_hat[index], min(first_step, max_log_step)
    while step < max_log_step:
        outer = theta_hat[index] + direction * step
        if excess(outer) > 0:
            return crossing(inner, outer)
        inner, step = outer, 2.0 * step
    outer = theta_hat[index] + direction * max_log_step
    return crossing(inner, outer) if excess(outer) > 0 else None


def _wald_interval(theta, half, scale):
    """Return the natural-unit interval of exp(theta +- half) times scale (0, inf if unknown)."""
    if not math.isfinite(half):
        return 0.0, math.inf
    low, high = theta - half, theta + half
    return (float(scale * np.exp(low)) if low > -LOG_BOUND - _PROFILE_LIMIT else 0.0,
            float(scale * np.exp(high)) if high < LOG_BOUND + _PROFILE_LIMIT else math.inf)


def fit_least_squares(v: npt.ArrayLike, a: npt.ArrayLike, law: str = 'langevin', *,
                      v_smooth: float = DEFAULT_V_SMOOTH, intervals: str = 'profile'
                      ) -> FitResult:
    """Fit a static law to samples (v_rel, a_slid) by nonlinear least squares.

    law: a name from STATIC_LAWS. The positive parameters are fitted as bounded logarithms of
    dimensionless values (each within a factor 1e6 of its data scale: LOG_BOUND) with
    scipy.optimize.least_squares (trust region reflective); the smoothing velocity of the
    Coulomb-type laws is fixed to v_smooth.

    Intervals are 95 % profile-likelihood intervals, not Wald intervals: for each parameter, the
    set of values whose profile RSS (the others re-optimised) stays below
    RSS_min (1 + F(0.95; 1, n - k) / (n - k)), exact for linear models. Why: in the paper's
    regime alpha |v_rel| <~ 1 the Langevin law is nearly L = (A alpha / 3) v, so only the product
    A alpha is well determined; the profile then follows the curved valley along A alpha = const
    and gives the honest, strongly asymmetric interval (or no upper bound at all: inf), where a
    Wald interval would be symmetric and falsely tight. The covariance and correlation from the
    Jacobian are reported too: |correlation| near 1 flags this trade-off.
    ``intervals='wald'`` gives Wald intervals of the log-parameters instead (exp(theta +-
    sqrt(F) sd), positive, asymmetric in natural units; 0 and inf where the Jacobian does not
    determine a parameter): no profile search, for laws fitted only to be compared (the
    profile is most of a fit's time on long records).

    AIC and BIC count the noise variance as a parameter: n ln(RSS/n) + 2 (k + 1) and
    n ln(RSS/n) + (k + 1) ln n.

    Raise InputError for input that is not fit data, FitError when the law cannot be fitted to
    these data: no friction at all, acceleration that does not oppose sliding, no convergence,
    a result that is not finite.
    """
    if law not in STATIC_LAWS:
        raise InputError(f'unknown law {law!r}; known: {", ".join(STATIC_LAWS)}')
    if intervals not in ('profile', 'wald'):
        raise InputError(f"intervals must be 'profile' or 'wald', got {intervals!r}")
    v, a = check_fit_data(v, a)
    law_class = STATIC_LAWS[law]
    names = law_class.fit_parameters
    n, k = len(v), len(names)
    if n <= k + 1:
        raise InputError(f'{n} samples cannot determine {k} parameters')
    if not np.any(v):
        raise InputError('all relative velocities are zero')
    force = -a
    force_scale, speed = _data_scales(v, force)
    if not force_scale > 0:
        raise FitError(f'{law}: every acceleration is zero, there is no friction to fit')
    if not np.dot(v / speed, force / force_scale) > 0:
        raise FitError(f'{law}: the acceleration does not oppose the relative velocity '
                       '(no friction law with positive parameters fits)')
    try:
        return _fit(law_class, v, a, force, force_scale, speed, v_smooth, intervals)
    except FitError:
        raise
    except (ArithmeticError, ValueError) as error:  # numpy/scipy on data no law can describe
        message = ' '.join(str(error).split()) or type(error).__name__
        raise FitError(f'{law}: {message}') from error


def _fit(law_class, v, a, force, force_scale, speed, v_smooth, intervals='profile'):
    names = law_class.fit_parameters
    n, k = len(v), len(names)
    fixed = {'v_smooth': v_smooth} if 'v_smooth' in {f.name for f in fields(law_class)} else {}
    scales = _parameter_scales(law_class, force_scale, speed)
    rss = ScaledResiduals(law_class, v, a, fixed, scales, force_scale)
    guess = _initial_guess(law_class, v / speed, force / force_scale, v_smooth / speed)
    theta0 = np.log(guess)  # the guess is dimensionless already: exp(theta) = p / s
    theta, on_bound, jac = _minimise(rss.residuals, rss.jacobian, theta0, law_class.name,
                                     _TOLERANCE)
    values = rss.values(theta)
    rss_min = rss(theta)
    if not (rss_min > 0 and math.isfinite(rss_min)):
        raise FitError(f'{law_class.name}: residual sum of squares {rss_min!r}; the information '
                       'criteria are undefined')

    # s^2 (J^T J)^-1 through the SVD of J: stays positive semi-definite when J^T J is nearly
    # singular (A and alpha trading off), where a plain inverse can give negative variances.
    # A parameter the residuals do not depend on at all (singular value 0) gets an infinite
    # variance and NaN correlations rather than a division warning.
    _, singular, vt = np.linalg.svd(jac, full_matrices=False)
    with np.errstate(divide='ignore', invalid='ignore', over='ignore'):
        log_covariance = rss_min / (n - k) * (vt.T / singular ** 2) @ vt
        covariance = log_covariance * np.outer(values, values)
        sd = np.sqrt(np.diag(covariance))
        correlation = covariance / np.outer(sd, sd)

    f95 = stats.f.ppf(0.95, 1, n - k)
    threshold = rss_min * (1.0 + f95 / (n - k))
    ci95 = {}
    wald = math.sqrt(f95) * np.sqrt(np.diag(log_covariance))
    for index, name in enumerate(names):
        if intervals == 'wald':
            ci95[name] = _wald_interval(theta[index], wald[index], scales[index])
            continue
        first_step = float(np.clip(1.5 * wald[index], 1e-3, 0.05)) if math.isfinite(
            wald[index]) else 0.05
        low, high = (_profile_bound(rss, theta, index, direction, threshold, _PROFILE_LIMIT,
                                    first_step, law_class.name, on_bound)
                     for direction in (-1, +1))
        ci95[name] = (0.0 if low is None else float(scales[index] * np.exp(low)),
                      math.inf if high is None else float(scales[index] * np.exp(high)))

    # In natural units: RSS = F^2 rss_min.
    log_likelihood_term = n * (math.log(rss_min / n) + 2.0 * math.log(force_scale))
    return FitResult(
        name=law_class.name, params=dict(zip(names, values.tolist(), strict=True)), ci95=ci95,
        covariance=covariance, correlation=correlation,
        rmse=force_scale * math.sqrt(rss_min / n), n=n,
        aic=log_likelihood_term + 2 * (k + 1), bic=log_likelihood_term + (k + 1) * math.log(n),
        law=rss.law(theta))
