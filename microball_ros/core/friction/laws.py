"""The friction laws: the static laws and the laws with memory, all with one interface.

This module owns what a friction law *is*: the memoryless laws a fit can identify
(``STATIC_LAWS``: Langevin, viscous, Coulomb, Coulomb + viscous, Stribeck), and the laws with
an internal state (LuGre, a lagged static law) that the simulation uses to test the memory
detector. Every law is a frozen dataclass with one interface (``name``, ``params``, ``force``,
``acceleration`` and the state interface ``n_states``, ``initial_state``,
``state_derivative``, ``acceleration_from_state``); static laws also give ``fit_parameters``,
``parameter_units`` and the analytic ``force_gradient`` the fits use.
Sign convention: ``a_slid = -L(v_rel)``, SI units throughout.
"""

from dataclasses import dataclass, field, fields
import math
from types import MappingProxyType
from typing import Any, ClassVar

import numpy as np
import numpy.typing as npt

from microball_ros.core.errors import InputError
from microball_ros.core.friction.langevin import (
    FloatOrArray,
    float_or_array,
    langevin,
    unit_langevin,
    unit_langevin_slope,
)

# ---------------------------------------------------------------------------------------------
# Static (memoryless) laws
# ---------------------------------------------------------------------------------------------

def _check_positive(law, names):
    for name in names:
        value = getattr(law, name)
        if not (value > 0 and math.isfinite(value)):
            raise InputError(f'{type(law).__name__}: {name} must be positive and finite, '
                             f'got {value!r}')


def _check_non_negative(law, names):
    for name in names:
        value = getattr(law, name)
        if not (value >= 0 and math.isfinite(value)):
            raise InputError(f'{type(law).__name__}: {name} must be non-negative and finite, '
                             f'got {value!r}')


class StaticLaw:
    """Mix-in for memoryless laws: the state interface with no state, and ``acceleration``.

    A subclass is a frozen dataclass whose fields are its parameters and which defines ``name``,
    ``fit_parameters`` (the fields ``fit_least_squares`` estimates, all positive),
    ``parameter_units`` (how each fitted parameter scales: 'force' m/s^2, 'velocity' m/s,
    'slowness' s/m, 'rate' 1/s, which the fit uses to make them dimensionless), ``force`` and
    ``force_gradient`` (the analytic Jacobian the fit uses).
    """

    n_states: ClassVar[int] = 0
    name: ClassVar[str]
    fit_parameters: ClassVar[tuple[str, ...]]
    parameter_units: ClassVar[tuple[str, ...]]

    @property
    def params(self) -> dict[str, float]:
        """Return the parameters as a dict, field name -> value."""
        return {f.name: getattr(self, f.name) for f in fields(self)}  # type: ignore[arg-type]

    def force(self, v_rel: float | npt.ArrayLike) -> FloatOrArray:
        """Return L(v_rel), m/s^2 (defined by each law)."""
        raise NotImplementedError

    def force_gradient(self, v_rel: npt.ArrayLike) -> tuple[np.ndarray, ...]:
        """Return dL/dp for each fitted parameter p, arrays over v_rel (defined by each law)."""
        raise NotImplementedError

    def acceleration(self, v_rel: float | npt.ArrayLike) -> FloatOrArray:
        """Return the slider acceleration -L(v_rel), m/s^2."""
        return -self.force(v_rel)

    def initial_state(self) -> np.ndarray:
        """Return the (empty) internal state."""
        return np.empty(0)

    def state_derivative(self, state: np.ndarray, v_rel: float) -> np.ndarray:
        """Return the (empty) derivative of the internal state."""
        return np.empty(0)

    def acceleration_from_state(self, state: np.ndarray, v_rel: float) -> float:
        """Return the slider acceleration -L(v_rel), m/s^2 (the state is empty)."""
        return -float(self.force(v_rel))


@dataclass(frozen=True)
class Langevin(StaticLaw):
    """The paper's modified Langevin law L(v) = A (coth(alpha v) - 1/(alpha v)) (eq. 13).

    A (m/s^2) is the saturation level, alpha (s/m) sets where it saturates; near 0 the law is
    viscous with slope A alpha / 3 (1/s). Defaults: the paper-like reconstruction of docs/paper.md.
    """

    A: float = 1.2
    alpha: float = 110.0
    name: ClassVar[str] = 'langevin'
    fit_parameters: ClassVar[tuple[str, ...]] = ('A', 'alpha')
    parameter_units: ClassVar[tuple[str, ...]] = ('force', 'slowness')

    def __post_init__(self):
        _check_positive(self, ('A', 'alpha'))

    def force(self, v_rel: float | npt.ArrayLike) -> FloatOrArray:
        """Return L(v_rel), m/s^2."""
        return langevin(v_rel, self.A, self.alpha)

    def force_gradient(self, v_rel: npt.ArrayLike) -> tuple[np.ndarray, ...]:
        """Return (dL/dA, dL/dalpha), each an array over v_rel."""
        v = np.asarray(v_rel, dtype=float)
        x = self.alpha * v
        return np.asarray(unit_langevin(x)), self.A * v * unit_langevin_slope(x)


@dataclass(frozen=True)
class Viscous(StaticLaw):
    """Viscous friction L(v) = c v, c in 1/s."""

    c: float = 44.0
    name: ClassVar[str] = 'viscous'
    fit_parameters: ClassVar[tuple[str, ...]] = ('c',)
    parameter_units: ClassVar[tuple[str, ...]] = ('rate',)

    def __post_init__(self):
        _check_positive(self, ('c',))

    def force(self, v_rel: float | npt.ArrayLike) -> FloatOrArray:
        """Return L(v_rel), m/s^2."""
        return self.c * float_or_array(v_rel)

    def force_gradient(self, v_rel: npt.ArrayLike) -> tuple[np.ndarray, ...]:
        """Return (dL/dc,), an array over v_rel."""
        return (np.asarray(v_rel, dtype=float),)


def _smooth_sign(v_rel, v_smooth):
    """Return tanh(v_rel / v_smooth), the smoothed sign(v_rel)."""
    v = float_or_array(v_rel)
    return math.tanh(v / v_smooth) if isinstance(v, float) else np.tanh(v / v_smooth)


# Why a smoothed sign: a fixed-step explicit integrator cannot stick exactly. The slope of the
# smoothed law at 0, Fc / v_smooth, must stay below about 2.8 / dt for RK4 to be stable, so with
# dt = 1 ms and forces ~1 m/s^2 the default v_smooth is 1 mm/s (a tenth of the paper's v_rel).
DEFAULT_V_SMOOTH = 1e-3


@dataclass(frozen=True)
class Coulomb(StaticLaw):
    """Coulomb friction L(v) = Fc tanh(v / v_smooth), Fc in m/s^2, v_smooth in m/s."""

    Fc: float = 0.3
    v_smooth: float = DEFAULT_V_SMOOTH
    name: ClassVar[str] = 'coulomb'
    fit_parameters: ClassVar[tuple[str, ...]] = ('Fc',)
    parameter_units: ClassVar[tuple[str, ...]] = ('force',)

    def __post_init__(self):
        _check_positive(self, ('Fc', 'v_smooth'))

    def force(self, v_rel: float | npt.ArrayLike) -> FloatOrArray:
        """Return L(v_rel), m/s^2."""
        return self.Fc * _smooth_sign(v_rel, self.v_smooth)

    def force_gradient(self, v_rel: npt.ArrayLike) -> tuple[np.ndarray, ...]:
        """Return (dL/dFc,), an array over v_rel."""
        return (_smooth_sign(np.asarray(v_rel, dtype=float), self.v_smooth),)


@dataclass(frozen=True)
class CoulombViscous(StaticLaw):
    """Coulomb plus viscous friction L(v) = Fc tanh(v / v_smooth) + c v."""

    Fc: float = 0.1
    c: float = 25.0
    v_smooth: float = DEFAULT_V_SMOOTH
    name: ClassVar[str] = 'coulomb_viscous'
    fit_parameters: ClassVar[tuple[str, ...]] = ('Fc', 'c')
    parameter_units: ClassVar[tuple[str, ...]] = ('force', 'rate')

    def __post_init__(self):
        _check_positive(self, ('Fc', 'c', 'v_smooth'))

    def force(self, v_rel: float | npt.ArrayLike) -> FloatOrArray:
        """Return L(v_rel), m/s^2."""
        v = float_or_array(v_rel)
        return self.Fc * _smooth_sign(v, self.v_smooth) + self.c * v

    def force_gradient(self, v_rel: npt.ArrayLike) -> tuple[np.ndarray, ...]:
        """Return (dL/dFc, dL/dc), each an array over v_rel."""
        v = np.asarray(v_rel, dtype=float)
        return _smooth_sign(v, self.v_smooth), v


@dataclass(frozen=True)
class Stribeck(StaticLaw):
    """Stribeck friction L(v) = (Fc + (Fs - Fc) exp(-(v/vs)^2)) tanh(v / v_smooth) + c v.

    Fc: Coulomb level, Fs: static (breakaway) level, both m/s^2; vs: Stribeck velocity, m/s;
    c: viscous coefficient, 1/s.
    """

    Fc: float = 0.1
    Fs: float = 0.3
    vs: float = 0.002
    c: float = 25.0
    v_smooth: float = DEFAULT_V_SMOOTH
    name: ClassVar[str] = 'stribeck'
    fit_parameters: ClassVar[tuple[str, ...]] = ('Fc', 'Fs', 'vs', 'c')
    parameter_units: ClassVar[tuple[str, ...]] = ('force', 'force', 'velocity', 'rate')

    def __post_init__(self):
        _check_positive(self, ('Fc', 'Fs', 'vs', 'c', 'v_smooth'))

    def force(self, v_rel: float | npt.ArrayLike) -> FloatOrArray:
        """Return L(v_rel), m/s^2."""
        v = float_or_array(v_rel)
        level = self.Fc + (self.Fs - self.Fc) * np.exp(-(v / self.vs) ** 2)
        return level * _smooth_sign(v, self.v_smooth) + self.c * v

    def force_gradient(self, v_rel: npt.ArrayLike) -> tuple[np.ndarray, ...]:
        """Return (dL/dFc, dL/dFs, dL/dvs, dL/dc), each an array over v_rel."""
        v = np.asarray(v_rel, dtype=float)
        sign = _smooth_sign(v, self.v_smooth)
        u = (v / self.vs) ** 2
        bump = np.exp(-u) * sign
        return sign - bump, bump, (self.Fs - self.Fc) * 2.0 / self.vs * u * bump, v


STATIC_LAWS: MappingProxyType[str, type[StaticLaw]] = MappingProxyType(
    {law.name: law for law in (Langevin, Viscous, Coulomb, CoulombViscous, Stribeck)})


# ---------------------------------------------------------------------------------------------
# Laws with memory: friction that is not a function of v_rel alone
# ---------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class LuGre:
    """The LuGre model (Canudas de Wit et al., IEEE TAC 1995), per unit mass.

    Bristle deflection z (m): dz/dt = v - sigma0 |v| z / g(v), with the Stribeck curve
    g(v) = Fc + (Fs - Fc) exp(-(v/vs)^2) (m/s^2); friction L = sigma0 z + sigma1 dz/dt + sigma2 v,
    so sigma0 is in 1/s^2 and sigma1, sigma2 in 1/s. The defaults put the paper's stator
    (1.2 mm, 2.95 Hz) in a paper-like regime (slider amplitude 0.99 mm, lag 0.37 rad,
    |v_rel| <= 9 mm/s) with a clear memory: the fundamentals of a_slid and v_rel are 0.29 rad
    away from the pi of a memoryless law. The presliding resonance sqrt(sigma0) = 32 rad/s is
    overdamped and well resolved by RK4 at 1 ms.
    """

    sigma0: float = 1000.0
    sigma1: float = 80.0
    sigma2: float = 5.0
    Fc: float = 0.15
    Fs: float = 0.5
    vs: float = 0.002
    name: ClassVar[str] = 'lugre'
    n_states: ClassVar[int] = 1

    def __post_init__(self):
        _check_positive(self, ('sigma0', 'Fc', 'Fs', 'vs'))
        _check_non_negative(self, ('sigma1', 'sigma2'))

    @property
    def params(self) -> dict[str, float]:
        """Return the parameters as a dict, field name -> value."""
        return {f.name: getattr(self, f.name) for f in fields(self)}

    def _stribeck_level(self, v_rel):
        return self.Fc + (self.Fs - self.Fc) * np.exp(-(v_rel / self.vs) ** 2)

    def force(self, v_rel: float | npt.ArrayLike) -> FloatOrArray:
        """Return the steady-state friction g(v) sign(v) + sigma2 v at constant v_rel, m/s^2."""
        v = float_or_array(v_rel)
        return self._stribeck_level(v) * np.sign(v) + self.sigma2 * v

    def acceleration(self, v_rel: float | npt.ArrayLike) -> FloatOrArray:
        """Return the steady-state slider acceleration -force(v_rel), m/s^2."""
        return -self.force(v_rel)

    def initial_state(self) -> np.ndarray:
        """Return the initial bristle deflection [z] = [0]."""
        return np.zeros(1)

    def state_derivative(self, state: np.ndarray, v_rel: float) -> np.ndarray:
        """Return [dz/dt]."""
        z = state[0]
        return np.array([v_rel - self.sigma0 * abs(v_rel) * z / self._stribeck_level(v_rel)])

    def acceleration_from_state(self, state: np.ndarray, v_rel: float) -> float:
        """Return the slider acceleration -(sigma0 z + sigma1 dz/dt + sigma2 v_rel), m/s^2."""
        z_rate = self.state_derivative(state, v_rel)[0]
        return -(self.sigma0 * state[0] + self.sigma1 * z_rate + self.sigma2 * v_rel)


@dataclass(frozen=True)
class LaggedFriction:
    """A static law seen through a first-order lag: dF/dt = (L(v_rel) - F) / tau.

    A Maxwell-like memory: at frequency w the friction lags the memoryless law by atan(w tau),
    0.58 rad for tau = 35 ms at 2.95 Hz; the lag inside the slider's feedback loop also makes it
    resonant (under the paper's stator the slider moves 1.43 mm, more than the stator's 1.2 mm).
    The state is the current friction F (m/s^2).
    """

    base_law: StaticLaw = field(default_factory=Langevin)
    tau: float = 0.035
    n_states: ClassVar[int] = 1

    def __post_init__(self):
        _check_positive(self, ('tau',))

    @property
    def name(self) -> str:
        """Return 'lagged_' followed by the name of the base law."""
        return f'lagged_{self.base_law.name}'

    @property
    def params(self) -> dict[str, Any]:
        """Return the base law's parameters plus tau."""
        return {**self.base_law.params, 'tau': self.tau}

    def force(self, v_rel: float | npt.ArrayLike) -> FloatOrArray:
        """Return the steady-state friction, that of the base law, m/s^2."""
        return self.base_law.force(v_rel)

    def acceleration(self, v_rel: float | npt.ArrayLike) -> FloatOrArray:
        """Return the steady-state slider acceleration -force(v_rel), m/s^2."""
        return -self.force(v_rel)

    def initial_state(self) -> np.ndarray:
        """Return the initial lagged friction [F] = [0]."""
        return np.zeros(1)

    def state_derivative(self, state: np.ndarray, v_rel: float) -> np.ndarray:
        """Return [dF/dt]."""
        return np.array([(self.base_law.force(v_rel) - state[0]) / self.tau])

    def acceleration_from_state(self, state: np.ndarray, v_rel: float) -> float:
        """Return the slider acceleration -F, m/s^2."""
        return -state[0]


# Any law the simulation accepts: static or with memory.
FrictionLaw = StaticLaw | LuGre | LaggedFriction
