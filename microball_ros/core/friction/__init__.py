"""Friction laws of the microball bearing: evaluation, simulation, identification, validation.

Sign convention (docs/paper.md section 7): ``v_rel = v_slider - v_stator`` and the slider
acceleration is ``a_slid = -L(v_rel)``, the friction per unit mass opposing the sliding. All
quantities are SI: m, s, m/s, m/s^2. ``from microball_ros.core import friction`` and then
``friction.<name>`` reaches every public name of the package's modules:

- ``langevin``: the modified Langevin function and its slope, to a few ulps;
- ``laws``: the laws (``STATIC_LAWS``, ``LuGre``,
  ``LaggedFriction``), all with one interface (``force``, ``acceleration``, the state
  interface of laws with memory);
- ``simulation``: the slider driven by a law, ``integrate_rk4`` and ``simulate_slider``;
- ``fitting``: ``fit_least_squares`` (bounded, with profile-likelihood intervals);
- ``two_slope``: the paper's own ``fit_two_slope``;
- ``comparison``: ``compare_laws``, every static law fitted and ranked by AIC, a law that
  cannot be fitted recorded as a failed ``LawComparison`` instead of raising;
- ``validation``: the paper's Fig. 9 check, ``validate`` and ``fit_sinusoid``.
"""

from microball_ros.core.friction.comparison import LawComparison, compare_laws, fit_law, one_line
from microball_ros.core.friction.fitting import (
    LOG_BOUND,
    FitResult,
    ScaledResiduals,
    check_fit_data,
    fit_least_squares,
)
from microball_ros.core.friction.langevin import (
    langevin,
    langevin_slope,
    unit_langevin,
    unit_langevin_slope,
)
from microball_ros.core.friction.laws import (
    DEFAULT_V_SMOOTH,
    STATIC_LAWS,
    Coulomb,
    CoulombViscous,
    FrictionLaw,
    LaggedFriction,
    Langevin,
    LuGre,
    StaticLaw,
    Stribeck,
    Viscous,
)
from microball_ros.core.friction.simulation import check_samples, integrate_rk4, simulate_slider
from microball_ros.core.friction.two_slope import TwoSlopeResult, fit_two_slope
from microball_ros.core.friction.validation import ValidationResult, fit_sinusoid, validate

__all__ = [
    'DEFAULT_V_SMOOTH', 'LOG_BOUND', 'STATIC_LAWS', 'Coulomb', 'CoulombViscous', 'FitResult',
    'FrictionLaw', 'LaggedFriction', 'LawComparison', 'Langevin', 'LuGre', 'ScaledResiduals',
    'StaticLaw', 'Stribeck', 'TwoSlopeResult', 'ValidationResult', 'Viscous', 'check_fit_data',
    'check_samples', 'compare_laws', 'fit_law', 'fit_least_squares', 'fit_sinusoid',
    'fit_two_slope', 'integrate_rk4', 'langevin', 'langevin_slope', 'one_line',
    'simulate_slider', 'unit_langevin', 'unit_langevin_slope', 'validate',
]
