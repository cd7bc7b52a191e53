"""Comparison of the static laws: fit every one of them and rank them, failures included.

This module owns the ranking of ``STATIC_LAWS`` on one set of (v_rel, a_slid) samples. A
comparison is auxiliary to the analysis, so one law that cannot be fitted (no convergence, data
it cannot describe, a non-finite result) never takes the others down: ``fit_law`` turns its
``FitError`` into a ``LawComparison`` with ``ok`` false and a one-line ``error``, and
``compare_laws`` returns one entry per law, the fitted ones by AIC (best first), then the
failed ones.
"""

from collections.abc import Iterable
from dataclasses import dataclass
import math

import numpy.typing as npt

from microball_ros.core.errors import FitError
from microball_ros.core.friction.fitting import FitResult, fit_least_squares
from microball_ros.core.friction.laws import DEFAULT_V_SMOOTH, STATIC_LAWS, StaticLaw


@dataclass(frozen=True)
class LawComparison:
    """One law of a comparison: its fit, or why it could not be fitted.

    ok is True when ``fit`` holds a fit with finite AIC; else ``fit`` is None and ``error`` is
    a one-line reason. The fit's name, params, ci95, aic, bic, rmse and law read through (None
    or empty for a failed law), so a list of these reads like a list of FitResults.
    """

    name: str
    fit: FitResult | None = None
    error: str | None = None

    @property
    def ok(self) -> bool:
        """Return True if the law was fitted."""
        return self.fit is not None

    @property
    def params(self) -> dict[str, float]:
        """Return the fitted parameters (empty for a failed law)."""
        return {} if self.fit is None else dict(self.fit.params)

    @property
    def ci95(self) -> dict[str, tuple[float, float]]:
        """Return the 95 % profile intervals (empty for a failed law)."""
        return {} if self.fit is None else dict(self.fit.ci95)

    @property
    def aic(self) -> float | None:
        """Return the AIC, or None for a failed law."""
        return None if self.fit is None else self.fit.aic

    @property
    def bic(self) -> float | None:
        """Return the BIC, or None for a failed law."""
        return None if self.fit is None else self.fit.bic

    @property
    def rmse(self) -> float | None:
        """Return the residual root mean square (m/s^2), or None for a failed law."""
        return None if self.fit is None else self.fit.rmse

    @property
    def law(self) -> StaticLaw | None:
        """Return the fitted law, or None for a failed law."""
        return None if self.fit is None else self.fit.law


def one_line(error: BaseException) -> str:
    """Return an error's message on one line (its type name if it has none)."""
    return ' '.join(str(error).split()) or type(error).__name__


def fit_law(v: npt.ArrayLike, a: npt.ArrayLike, law: str, *,
            v_smooth: float = DEFAULT_V_SMOOTH, intervals: str = 'profile') -> LawComparison:
    """Fit one static law and return its LawComparison: the fit, or the FitError as a record.

    Input that is not fit data at all (InputError: lengths, NaN, an unknown law) still raises:
    it is the caller's, not the law's, problem.
    """
    try:
        fit = fit_least_squares(v, a, law, v_smooth=v_smooth, intervals=intervals)
    except FitError as error:
        return LawComparison(name=law, error=one_line(error))
    numbers = (fit.aic, fit.bic, fit.rmse, *fit.params.values())
    if not all(math.isfinite(number) for number in numbers):
        return LawComparison(name=law, error=f'{law}: the fit is not finite')
    return LawComparison(name=law, fit=fit)


def compare_laws(v: npt.ArrayLike, a: npt.ArrayLike, *,
                 v_smooth: float = DEFAULT_V_SMOOTH,
                 profile: Iterable[str] | None = None) -> list[LawComparison]:
    """Fit every static law; return one LawComparison per law, fitted by AIC, then failed ones.

    The BIC of each fit is there too. No law's failure raises: see ``fit_law``. ``profile``:
    the laws whose intervals are profile-likelihood ones (default: all); the others get Wald
    intervals of their log-parameters, which cost nothing beyond the fit (the profiles of
    five laws were 2/3 of an hour-long record's analysis).
    """
    profiled = set(STATIC_LAWS if profile is None else profile)
    entries = [fit_law(v, a, name, v_smooth=v_smooth,
                       intervals='profile' if name in profiled else 'wald')
               for name in STATIC_LAWS]
    fitted = sorted((entry for entry in entries if entry.ok),
                    key=lambda entry: math.inf if entry.aic is None else entry.aic)
    return fitted + [entry for entry in entries if not entry.ok]
