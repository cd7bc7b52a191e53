"""Friction laws of the microball bearing: evaluation, simulation, identification, validation.

Sign convention (PAPER.md section 7): ``v_rel = v_slider - v_stator`` and the slider
acceleration is ``a_slid = -L(v_rel)``, the friction per unit mass opposing the sliding. All
quantities are SI: m, s, m/s, m/s^2.

Every law is a frozen dataclass with one interface, so the integrator, the fits and the
validation treat them alike:

- ``name`` and ``params``;
- ``force(v_rel)``: L(v_rel) in m/s^2, with the sign of v_rel (for a law with memory, its
  steady-state value at constant v_rel), and ``acceleration(v_rel) = -force(v_rel)``;
- ``n_states``, ``initial_state()``, ``state_derivative(state, v_rel)`` and
  ``acceleration_from_state(state, v_rel)``: the internal state of a law with memory (LuGre's
  bristle deflection, a lagged force). Static laws have ``n_states == 0``.

The static laws (``STATIC_LAWS``) can be identified from samples of (v_rel, a_slid) with
``fit_least_squares``, ``compare_laws`` and, for the Langevin law, the paper's two-slope method
``fit_two_slope``. ``simulate_slider`` and ``validate`` repeat the paper's Fig. 9 check.
"""

from dataclasses import dataclass, field, fields, replace
import math
from types import MappingProxyType
from typing import ClassVar

import numpy as np
from scipy import optimize, stats
from scipy.interpolate import CubicHermiteSpline, CubicSpline

# ---------------------------------------------------------------------------------------------
# The modified Langevin function
# ---------------------------------------------------------------------------------------------

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


def _float_or_array(v):
    """Return v unchanged if it is a float (fast path for the integrator), else a float array."""
    return v if isinstance(v, float) else np.asarray(v, dtype=float)


def _unit_langevin(x):
    """Return coth(x) - 1/x: a float for a float x, else an array."""
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


def _unit_langevin_slope(x):
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


def langevin(v, A, alpha):
    """Return the modified Langevin function A (coth(alpha v) - 1/(alpha v)), m/s^2.

    Vectorised over ``v``; accurate to a few ulps everywhere, including v = 0 (value 0).
    """
    return A * _unit_langevin(alpha * _float_or_array(v))


def langevin_slope(v, A, alpha):
    """Return dL/dv = alpha A (1/(alpha v)^2 - 1/sinh(alpha v)^2), 1/s; alpha A / 3 at v = 0."""
    return alpha * A * _unit_langevin_slope(alpha * _float_or_array(v))


# ---------------------------------------------------------------------------------------------
# Static (memoryless) laws
# ---------------------------------------------------------------------------------------------

def _check_positive(law, names):
    for name in names:
        value = getattr(law, name)
        if not (value > 0 and math.isfinite(value)):
            raise ValueError(f'{type(law).__name__}: {name} must be positive and finite, '
                             f'got {value!r}')


def _check_non_negative(law, names):
    for name in names:
        value = getattr(law, name)
        if not (value >= 0 and math.isfinite(value)):
            raise ValueError(f'{type(law).__name__}: {name} must be non-negative and finite, '
                             f'got {value!r}')


class StaticLaw:
    """Mix-in for memoryless laws: the state interface with no state, and ``acceleration``.

    A subclass is a frozen dataclass whose fields are its parameters and which defines ``name``,
    ``fit_parameters`` (the fields ``fit_least_squares`` estimates, all positive), ``force``
    and ``force_gradient`` (the analytic Jacobian the fit uses).
    """

    n_states: ClassVar[int] = 0

    @property
    def params(self):
        """Return the parameters as a dict, field name -> value."""
        return {f.name: getattr(self, f.name) for f in fields(self)}

    def acceleration(self, v_rel):
        """Return the slider acceleration -L(v_rel), m/s^2."""
        return -self.force(v_rel)

    def initial_state(self):
        """Return the (empty) internal state."""
        return np.empty(0)

    def state_derivative(self, state, v_rel):
        """Return the (empty) derivative of the internal state."""
        return np.empty(0)

    def acceleration_from_state(self, state, v_rel):
        """Return the slider acceleration -L(v_rel), m/s^2 (the state is empty)."""
        return -self.force(v_rel)


@dataclass(frozen=True)
class Langevin(StaticLaw):
    """The paper's modified Langevin law L(v) = A (coth(alpha v) - 1/(alpha v)) (eq. 13).

    A (m/s^2) is the saturation level, alpha (s/m) sets where it saturates; near 0 the law is
    viscous with slope A alpha / 3 (1/s). Defaults: the paper-like reconstruction of PAPER.md.
    """

    A: float = 1.2
    alpha: float = 110.0
    name: ClassVar[str] = 'langevin'
    fit_parameters: ClassVar[tuple] = ('A', 'alpha')

    def __post_init__(self):
        _check_positive(self, ('A', 'alpha'))

    def force(self, v_rel):
        """Return L(v_rel), m/s^2."""
        return langevin(v_rel, self.A, self.alpha)

    def force_gradient(self, v_rel):
        """Return (dL/dA, dL/dalpha), each an array over v_rel."""
        v = np.asarray(v_rel, dtype=float)
        x = self.alpha * v
        return _unit_langevin(x), self.A * v * _unit_langevin_slope(x)


@dataclass(frozen=True)
class Viscous(StaticLaw):
    """Viscous friction L(v) = c v, c in 1/s."""

    c: float = 44.0
    name: ClassVar[str] = 'viscous'
    fit_parameters: ClassVar[tuple] = ('c',)

    def __post_init__(self):
        _check_positive(self, ('c',))

    def force(self, v_rel):
        """Return L(v_rel), m/s^2."""
        return self.c * _float_or_array(v_rel)

    def force_gradient(self, v_rel):
        """Return (dL/dc,), an array over v_rel."""
        return (np.asarray(v_rel, dtype=float),)


def _smooth_sign(v_rel, v_smooth):
    """Return tanh(v_rel / v_smooth), the smoothed sign(v_rel)."""
    v = _float_or_array(v_rel)
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
    fit_parameters: ClassVar[tuple] = ('Fc',)

    def __post_init__(self):
        _check_positive(self, ('Fc', 'v_smooth'))

    def force(self, v_rel):
        """Return L(v_rel), m/s^2."""
        return self.Fc * _smooth_sign(v_rel, self.v_smooth)

    def force_gradient(self, v_rel):
        """Return (dL/dFc,), an array over v_rel."""
        return (_smooth_sign(np.asarray(v_rel, dtype=float), self.v_smooth),)


@dataclass(frozen=True)
class CoulombViscous(StaticLaw):
    """Coulomb plus viscous friction L(v) = Fc tanh(v / v_smooth) + c v."""

    Fc: float = 0.1
    c: float = 25.0
    v_smooth: float = DEFAULT_V_SMOOTH
    name: ClassVar[str] = 'coulomb_viscous'
    fit_parameters: ClassVar[tuple] = ('Fc', 'c')

    def __post_init__(self):
        _check_positive(self, ('Fc', 'c', 'v_smooth'))

    def force(self, v_rel):
        """Return L(v_rel), m/s^2."""
        v = _float_or_array(v_rel)
        return self.Fc * _smooth_sign(v, self.v_smooth) + self.c * v

    def force_gradient(self, v_rel):
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
    fit_parameters: ClassVar[tuple] = ('Fc', 'Fs', 'vs', 'c')

    def __post_init__(self):
        _check_positive(self, ('Fc', 'Fs', 'vs', 'c', 'v_smooth'))

    def force(self, v_rel):
        """Return L(v_rel), m/s^2."""
        v = _float_or_array(v_rel)
        level = self.Fc + (self.Fs - self.Fc) * np.exp(-(v / self.vs) ** 2)
        return level * _smooth_sign(v, self.v_smooth) + self.c * v

    def force_gradient(self, v_rel):
        """Return (dL/dFc, dL/dFs, dL/dvs, dL/dc), each an array over v_rel."""
        v = np.asarray(v_rel, dtype=float)
        sign = _smooth_sign(v, self.v_smooth)
        u = (v / self.vs) ** 2
        bump = np.exp(-u) * sign
        return sign - bump, bump, (self.Fs - self.Fc) * 2.0 / self.vs * u * bump, v


STATIC_LAWS = MappingProxyType({law.name: law for law in
                                (Langevin, Viscous, Coulomb, CoulombViscous, Stribeck)})


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
    def params(self):
        """Return the parameters as a dict, field name -> value."""
        return {f.name: getattr(self, f.name) for f in fields(self)}

    def _stribeck_level(self, v_rel):
        return self.Fc + (self.Fs - self.Fc) * np.exp(-(v_rel / self.vs) ** 2)

    def force(self, v_rel):
        """Return the steady-state friction g(v) sign(v) + sigma2 v at constant v_rel, m/s^2."""
        v = _float_or_array(v_rel)
        return self._stribeck_level(v) * np.sign(v) + self.sigma2 * v

    def acceleration(self, v_rel):
        """Return the steady-state slider acceleration -force(v_rel), m/s^2."""
        return -self.force(v_rel)

    def initial_state(self):
        """Return the initial bristle deflection [z] = [0]."""
        return np.zeros(1)

    def state_derivative(self, state, v_rel):
        """Return [dz/dt]."""
        z = state[0]
        return np.array([v_rel - self.sigma0 * abs(v_rel) * z / self._stribeck_level(v_rel)])

    def acceleration_from_state(self, state, v_rel):
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
    def name(self):
        """Return 'lagged_' followed by the name of the base law."""
        return f'lagged_{self.base_law.name}'

    @property
    def params(self):
        """Return the base law's parameters plus tau."""
        return {**self.base_law.params, 'tau': self.tau}

    def force(self, v_rel):
        """Return the steady-state friction, that of the base law, m/s^2."""
        return self.base_law.force(v_rel)

    def acceleration(self, v_rel):
        """Return the steady-state slider acceleration -force(v_rel), m/s^2."""
        return -self.force(v_rel)

    def initial_state(self):
        """Return the initial lagged friction [F] = [0]."""
        return np.zeros(1)

    def state_derivative(self, state, v_rel):
        """Return [dF/dt]."""
        return np.array([(self.base_law.force(v_rel) - state[0]) / self.tau])

    def acceleration_from_state(self, state, v_rel):
        """Return the slider acceleration -F, m/s^2."""
        return -state[0]


# ---------------------------------------------------------------------------------------------
# Simulation: M a_slid = F_fric (eq. 2) by fixed-step RK4
# ---------------------------------------------------------------------------------------------

def _slider_derivative(law, state, stator_velocity):
    """Return d/dt of [x_slid, v_slid, *law states] for the given stator velocity."""
    v_rel = state[1] - stator_velocity
    law_state = state[2:]
    rate = np.empty_like(state)
    rate[0] = state[1]
    rate[1] = law.acceleration_from_state(law_state, v_rel)
    rate[2:] = law.state_derivative(law_state, v_rel)
    return rate


def integrate_rk4(law, state, stator_velocity, dt):
    """Integrate the slider driven by friction with fixed-step 4th-order Runge-Kutta.

    ``state`` is the initial [x_slid, v_slid, *law states]; ``stator_velocity`` holds the
    stator velocity at every half step t0, t0 + dt/2, ..., t0 + N dt (2N + 1 values, what RK4
    evaluates). Return the states at the N + 1 full steps, shape (N + 1, 2 + law.n_states).
    """
    stator_velocity = np.asarray(stator_velocity, dtype=float)
    if stator_velocity.ndim != 1 or len(stator_velocity) % 2 != 1:
        raise ValueError('stator_velocity needs 2N + 1 samples, at every half step')
    y = np.array(state, dtype=float)
    if len(y) != 2 + law.n_states:
        raise ValueError(f'state has {len(y)} values, law {law.name!r} needs {2 + law.n_states}')
    n_steps = (len(stator_velocity) - 1) // 2
    states = np.empty((n_steps + 1, len(y)))
    states[0] = y
    half = 0.5 * dt
    for step in range(n_steps):
        v_start, v_mid, v_end = stator_velocity[2 * step:2 * step + 3]
        k1 = _slider_derivative(law, y, v_start)
        k2 = _slider_derivative(law, y + half * k1, v_mid)
        k3 = _slider_derivative(law, y + half * k2, v_mid)
        k4 = _slider_derivative(law, y + dt * k3, v_end)
        y = y + (dt / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
        states[step + 1] = y
    return states


def _check_samples(t, *series):
    t = np.asarray(t, dtype=float)
    arrays = [np.asarray(s, dtype=float) for s in series]
    if t.ndim != 1 or len(t) < 4:
        raise ValueError('need at least 4 samples')
    if any(a.shape != t.shape for a in arrays):
        raise ValueError('time and position arrays must have the same length')
    if not all(np.all(np.isfinite(a)) for a in (t, *arrays)):
        raise ValueError('time and positions must be finite (drop lost samples first)')
    if np.any(np.diff(t) <= 0):
        raise ValueError('time must increase strictly')
    return (t, *arrays)


def simulate_slider(law, t, stator_position, dt=0.001, slider0=None, run_in=0.0):
    """Simulate the slider under a measured stator motion; return its position at the times t.

    The stator position samples are interpolated with a cubic spline (not-a-knot), whose
    derivative gives the stator velocity; eq. 2 is integrated by RK4 with the fixed step dt and
    the slider position is read at ``t`` by cubic Hermite interpolation of the RK4 positions
    and velocities (error O(dt^4), like RK4 itself).

    slider0: initial [x_slid, v_slid] or [x_slid, v_slid, *law states]; by default the slider
    starts moving with the stator and the law in its initial state.
    run_in: seconds of the start of the stator record replayed before t[0], so the returned
    motion is past the start-up transient. Use a whole number of stator periods.
    """
    t, stator_position = _check_samples(t, stator_position)
    if not 0 <= run_in <= t[-1] - t[0]:
        raise ValueError(f'run_in must be between 0 and the record length {t[-1] - t[0]:g} s')
    stator = CubicSpline(t, stator_position)
    stator_velocity = stator.derivative()
    start = t[0] - run_in
    n_steps = math.ceil((t[-1] - start) / dt - 1e-9)
    half_steps = start + 0.5 * dt * np.arange(2 * n_steps + 1)
    # During the run-in the stator replays the start of the record, shifted back by run_in.
    replayed = np.where(half_steps < t[0], half_steps + run_in, half_steps)
    if slider0 is None:
        slider0 = (float(stator(t[0])), float(stator_velocity(t[0])))
    state0 = np.asarray(slider0, dtype=float)
    if len(state0) == 2:
        state0 = np.concatenate([state0, law.initial_state()])
    states = integrate_rk4(law, state0, stator_velocity(replayed), dt)
    return CubicHermiteSpline(half_steps[::2], states[:, 0], states[:, 1])(t)


# ---------------------------------------------------------------------------------------------
# Identification from samples of (v_rel, a_slid)
# ---------------------------------------------------------------------------------------------

def _check_fit_data(v, a):
    v = np.asarray(v, dtype=float).ravel()
    a = np.asarray(a, dtype=float).ravel()
    if v.shape != a.shape:
        raise ValueError(f'v and a differ in length ({len(v)} and {len(a)})')
    if not (np.all(np.isfinite(v)) and np.all(np.isfinite(a))):
        raise ValueError('v and a must be finite')
    return v, a


def _local_slope_at_zero(v, force, window):
    """Return the slope of force(v) at 0 from an odd cubic b1 v + b3 v^3 fitted on |v| <= window.

    The law is odd, so the odd cubic uses the samples of both signs and has no bias from the
    even terms; the cubic term absorbs the curvature inside the window.
    """
    inside = np.abs(v) <= window
    if np.count_nonzero(inside) < 8:
        raise ValueError(f'only {np.count_nonzero(inside)} samples with |v_rel| <= {window:g} m/s '
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
        raise ValueError(f'the data reach |v_rel| = {speed.max():.4g} m/s with '
                         f'{np.count_nonzero(inside)} samples within {window:g} m/s of '
                         f'v1 = {v1:g} m/s; the two-slope method needs data around v1 '
                         '(choose a smaller v1 or use fit_least_squares)')
    offset = speed[inside] - v1
    basis = np.column_stack([np.ones_like(offset), offset, offset ** 2])
    return float(np.linalg.lstsq(basis, folded[inside], rcond=None)[0][1])


@dataclass(frozen=True)
class TwoSlopeResult:
    """The Langevin law identified from its slopes at v = 0 and v = v1 (PAPER.md eq. 14)."""

    A: float
    alpha: float
    slope0: float
    slope1: float
    v1: float

    @property
    def law(self):
        """Return the identified Langevin law."""
        return Langevin(self.A, self.alpha)


def fit_two_slope(v, a, v1=0.015, window=0.003):
    """Identify A and alpha of the Langevin law from its slopes at 0 and at v1 (the paper's way).

    The slopes of L = -a against v are estimated by local regression: at 0 an odd cubic on
    |v| <= window, at v1 a quadratic on the samples whose |v| is within window of v1 (both
    signs folded by oddness). Then slope0 = A alpha / 3 and slope1 = dL/dv(v1), so the ratio
    slope1 / slope0 = 3 (1/x^2 - 1/sinh(x)^2) with x = alpha v1 depends on alpha only; it falls
    from 1 to 0 as x grows, and brentq solves it. Raise ValueError if the data do not reach v1
    or the slopes are not Langevin-like (0 < slope1 < slope0).
    """
    v, a = _check_fit_data(v, a)
    force = -a
    slope0 = _local_slope_at_zero(v, force, window)
    slope1 = _local_slope_at(v, force, v1, window)
    ratio = slope1 / slope0
    x_low, x_high = 1e-6, 1e4

    def mismatch(x):
        return 3.0 * _unit_langevin_slope(x) - ratio

    if not (slope0 > 0 and mismatch(x_high) < 0 < mismatch(x_low)):
        raise ValueError(f'slopes {slope0:.4g} 1/s at 0 and {slope1:.4g} 1/s at {v1:g} m/s do '
                         'not fit a Langevin law (needs 0 < slope at v1 < slope at 0)')
    x = optimize.brentq(mismatch, x_low, x_high, xtol=1e-14, rtol=1e-12)
    alpha = x / v1
    return TwoSlopeResult(A=3.0 * slope0 / alpha, alpha=alpha, slope0=slope0, slope1=slope1,
                          v1=v1)


@dataclass(frozen=True)
class FitResult:
    """A static friction law fitted to (v_rel, a_slid) samples by least squares.

    params, ci95: fitted parameter -> value and -> (lo, hi) 95 % profile-likelihood interval
    (0 or inf where the profile does not close within a factor 1000 of the estimate).
    covariance, correlation: from the Jacobian at the optimum, rows in ``params`` order
    (natural units; for the Langevin law correlation[0, 1] is the A-alpha correlation).
    rmse: residual root mean square, m/s^2; aic, bic: Gaussian information criteria.
    """

    name: str
    params: dict
    ci95: dict
    covariance: np.ndarray
    correlation: np.ndarray
    rmse: float
    n: int
    aic: float
    bic: float
    law: StaticLaw

    @property
    def identifiable(self):
        """Return True if every parameter's 95 % interval is closed (positive and finite)."""
        return all(0 < lo and math.isfinite(hi) for lo, hi in self.ci95.values())


def _initial_guess(law_class, v, force, v_smooth):
    """Return a rough positive starting point for the fitted parameters of law_class."""
    scale = max(float(np.quantile(np.abs(force), 0.95)), 1e-12)
    speed = max(float(np.max(np.abs(v))), 1e-12)
    viscous = max(float(np.dot(v, force) / np.dot(v, v)), scale / speed * 1e-3)
    basis = np.column_stack([np.tanh(v / v_smooth), v])
    level, slope = np.maximum(np.linalg.lstsq(basis, force, rcond=None)[0],
                              [scale * 1e-3, viscous * 1e-3])
    if law_class is Langevin:
        A = 1.5 * scale
        return [A, 3.0 * viscous / A]
    if law_class is Viscous:
        return [viscous]
    if law_class is Coulomb:
        return [float(np.mean(np.abs(force)))]
    if law_class is CoulombViscous:
        return [level, slope]
    return [level, 1.5 * level, 0.3 * speed, slope]  # Stribeck: Fc, Fs, vs, c


def _profile_bound(rss, theta_hat, index, direction, threshold, max_log_step, first_step=0.05):
    """Return the log-parameter where the profile RSS crosses threshold, or None if it does not.

    The profile fixes log-parameter ``index`` and minimises the RSS over the others (warm
    started from the previous profile point); the search walks away from the optimum in
    doubling steps from first_step up to max_log_step, then refines the crossing by brentq.
    A first step just beyond the Wald interval brackets the crossing at once for a
    well-determined parameter, and brentq then needs few evaluations. Profile values are
    memoised: an inner minimisation depends slightly on its starting point, and brentq must see
    the same signs at the bracket ends as the search did.
    """
    free = np.arange(len(theta_hat)) != index
    free_columns = np.flatnonzero(free)
    start = theta_hat[free].copy()
    # The optimum itself is known: never re-minimise there from a far-away warm start.
    memo = {theta_hat[index]: rss(theta_hat) - threshold}

    def excess(log_value):
        if log_value not in memo:
            theta = theta_hat.copy()
            theta[index] = log_value
            if free.any():
                def reduced(phi):
                    theta[free] = phi
                    return rss.residuals(theta)

                def reduced_jacobian(phi):
                    theta[free] = phi
                    return rss.jacobian(theta, free_columns)
                solution = optimize.least_squares(reduced, start, jac=reduced_jacobian)
                start[:] = solution.x
                theta[free] = solution.x
            memo[log_value] = rss(theta) - threshold
        return memo[log_value]

    inner, step = theta_hat[index], first_step
    while step < max_log_step:
        outer = theta_hat[index] + direction * step
        if excess(outer) > 0:
            return optimize.brentq(excess, inner, outer, xtol=1e-4)
        inner, step = outer, 2.0 * step
    outer = theta_hat[index] + direction * max_log_step
    return optimize.brentq(excess, inner, outer, xtol=1e-4) if excess(outer) > 0 else None


class _LogResiduals:
    """Residuals law(exp(theta)).acceleration(v) - a of a law's fitted parameters, in logs."""

    def __init__(self, law_class, v, a, fixed):
        self.law_class, self.v, self.a, self.fixed = law_class, v, a, fixed

    def law(self, theta):
        values = dict(zip(self.law_class.fit_parameters, np.exp(theta), strict=True))
        return self.law_class(**values, **self.fixed)

    def residuals(self, theta):
        return self.law(theta).acceleration(self.v) - self.a

    def jacobian(self, theta, columns=None):
        """Return d residuals / d theta (the acceleration is -L, and dp/dtheta = p).

        Only the given columns (all by default), in Fortran order: what LAPACK's SVD in
        least_squares wants, without copies.
        """
        gradient = self.law(theta).force_gradient(self.v)
        columns = range(len(theta)) if columns is None else columns
        out = np.empty((len(self.v), len(columns)), order='F')
        for j, column in enumerate(columns):
            np.multiply(gradient[column], -math.exp(theta[column]), out=out[:, j])
        return out

    def __call__(self, theta):
        """Return the residual sum of squares."""
        r = self.residuals(theta)
        return float(np.dot(r, r))


# Profile searches stop a factor 1000 away from the estimate: beyond that an interval end is
# reported as 0 or inf, "not determined by these data".
_PROFILE_LIMIT = math.log(1000.0)


def fit_least_squares(v, a, law='langevin', *, v_smooth=DEFAULT_V_SMOOTH):
    """Fit a static law to samples (v_rel, a_slid) by nonlinear least squares.

    law: a name from STATIC_LAWS. The positive parameters are fitted in logarithms with
    scipy.optimize.least_squares; the smoothing velocity of the Coulomb-type laws is fixed to
    v_smooth.

    Intervals are 95 % profile-likelihood intervals, not Wald intervals: for each parameter, the
    set of values whose profile RSS (the others re-optimised) stays below
    RSS_min (1 + F(0.95; 1, n - k) / (n - k)), exact for linear models. Why: in the paper's
    regime alpha |v_rel| <~ 1 the Langevin law is nearly L = (A alpha / 3) v, so only the product
    A alpha is well determined; the profile then follows the curved valley along A alpha = const
    and gives the honest, strongly asymmetric interval (or no upper bound at all: inf), where a
    Wald interval would be symmetric and falsely tight. The covariance and correlation from the
    Jacobian are reported too: |correlation| near 1 flags this trade-off.

    AIC and BIC count the noise variance as a parameter: n ln(RSS/n) + 2 (k + 1) and
    n ln(RSS/n) + (k + 1) ln n.
    """
    if law not in STATIC_LAWS:
        raise ValueError(f'unknown law {law!r}; known: {", ".join(STATIC_LAWS)}')
    v, a = _check_fit_data(v, a)
    law_class = STATIC_LAWS[law]
    names = law_class.fit_parameters
    n, k = len(v), len(names)
    if n <= k + 1:
        raise ValueError(f'{n} samples cannot determine {k} parameters')
    if not np.any(v):
        raise ValueError('all relative velocities are zero')
    fixed = {'v_smooth': v_smooth} if 'v_smooth' in {f.name for f in fields(law_class)} else {}
    rss = _LogResiduals(law_class, v, a, fixed)
    theta0 = np.log(_initial_guess(law_class, v, -a, v_smooth))
    solution = optimize.least_squares(rss.residuals, theta0, jac=rss.jacobian, method='lm',
                                      xtol=1e-12, ftol=1e-12)
    theta = solution.x
    values = np.exp(theta)
    rss_min = rss(theta)

    # s^2 (J^T J)^-1 through the SVD of J: stays positive semi-definite when J^T J is nearly
    # singular (A and alpha trading off), where a plain inverse can give negative variances.
    # A parameter the residuals do not depend on at all (singular value 0) gets an infinite
    # variance and NaN correlations rather than a division warning.
    _, singular, vt = np.linalg.svd(solution.jac, full_matrices=False)
    with np.errstate(divide='ignore', invalid='ignore'):
        log_covariance = rss_min / (n - k) * (vt.T / singular ** 2) @ vt
        covariance = log_covariance * np.outer(values, values)
        sd = np.sqrt(np.diag(covariance))
        correlation = covariance / np.outer(sd, sd)

    f95 = stats.f.ppf(0.95, 1, n - k)
    threshold = rss_min * (1.0 + f95 / (n - k))
    ci95 = {}
    wald = math.sqrt(f95) * np.sqrt(np.diag(log_covariance))
    for index, name in enumerate(names):
        first_step = float(np.clip(1.5 * wald[index], 1e-3, 0.05)) if math.isfinite(
            wald[index]) else 0.05
        low = _profile_bound(rss, theta, index, -1, threshold, _PROFILE_LIMIT, first_step)
        high = _profile_bound(rss, theta, index, +1, threshold, _PROFILE_LIMIT, first_step)
        ci95[name] = (0.0 if low is None else float(np.exp(low)),
                      math.inf if high is None else float(np.exp(high)))

    log_likelihood_term = n * math.log(rss_min / n)
    return FitResult(
        name=law, params=dict(zip(names, values.tolist(), strict=True)), ci95=ci95,
        covariance=covariance, correlation=correlation, rmse=math.sqrt(rss_min / n), n=n,
        aic=log_likelihood_term + 2 * (k + 1), bic=log_likelihood_term + (k + 1) * math.log(n),
        law=rss.law(theta))


def compare_laws(v, a, *, v_smooth=DEFAULT_V_SMOOTH):
    """Fit every static law and return the FitResults sorted by AIC, best first (BIC included)."""
    fits = [fit_least_squares(v, a, name, v_smooth=v_smooth) for name in STATIC_LAWS]
    return sorted(fits, key=lambda fit: fit.aic)


# ---------------------------------------------------------------------------------------------
# Validation by simulation (paper Fig. 9)
# ---------------------------------------------------------------------------------------------

def fit_sinusoid(t, x, frequency):
    """Return (amplitude, phase) of the component at frequency: x ~ c0 + c1 t + R sin(w t + phi).

    Least squares with the mean and a linear drift fitted alongside, so slow drift does not leak
    into the fundamental; the phase is in (-pi, pi].
    """
    t, x = _check_samples(t, x)
    w = 2.0 * math.pi * frequency
    basis = np.column_stack([np.ones_like(t), t - t.mean(), np.sin(w * t), np.cos(w * t)])
    _, _, sine, cosine = np.linalg.lstsq(basis, x, rcond=None)[0]
    return float(math.hypot(sine, cosine)), float(math.atan2(cosine, sine))


def _lag(phase_leader, phase_follower):
    """Return how far the follower lags the leader, wrapped to (-pi, pi]."""
    return float(-math.remainder(phase_follower - phase_leader, 2.0 * math.pi))


@dataclass(frozen=True)
class ValidationResult:
    """Simulated against measured slider motion at the fundamental (paper Fig. 9).

    Amplitudes in m; phases in rad are the slider's lag behind the stator (positive: lags).
    """

    frequency: float
    stator_amplitude: float
    slider_amplitude_simulated: float
    slider_amplitude_measured: float
    phase_simulated: float
    phase_measured: float
    simulated_slider_position: np.ndarray


def validate(law, t, stator_position, slider_position, frequency, *, dt=0.001,
             run_in_periods=2, max_periods=None):
    """Simulate the slider under the measured stator motion and compare fundamentals.

    The simulation (simulate_slider) first replays run_in_periods stator periods from the start
    of the record, so its start-up transient is over at t[0]. Amplitude and phase of each
    fundamental come from fit_sinusoid at the known frequency (mean and linear drift removed).
    NaN samples (lost marks) are left out: a lost stator sample from the stator spline, a lost
    slider sample from the measured fundamental; the simulated position is NaN where the stator
    was lost.

    max_periods: compare only the first max_periods stator periods of the record (all of it if
    None); the simulated position is NaN after them. The integrator is pure Python (about
    20 us per 1 ms step), so an hour of record would take over a minute, while a steady
    periodic response is settled after the run-in: 20 periods at 3 Hz take about 0.15 s.
    """
    t, stator_position, slider_position = (np.asarray(s, dtype=float) for s in
                                           (t, stator_position, slider_position))
    if max_periods is not None:
        if not max_periods > 0:
            raise ValueError(f'max_periods must be positive, not {max_periods}')
        compared = t < t[0] + max_periods / frequency
        simulated = np.full_like(t, np.nan)
        result = validate(law, t[compared], stator_position[compared],
                          slider_position[compared], frequency, dt=dt,
                          run_in_periods=run_in_periods)
        simulated[compared] = result.simulated_slider_position
        return replace(result, simulated_slider_position=simulated)
    stator_seen = np.isfinite(stator_position)
    slider_seen = np.isfinite(slider_position)
    run_in = run_in_periods / frequency
    if np.count_nonzero(stator_seen) < 4 or np.ptp(t[stator_seen]) < run_in:
        raise ValueError(f'the record must be longer than the run-in of {run_in_periods} '
                         f'periods ({run_in:.3g} s)')
    simulated = np.full_like(t, np.nan)
    simulated[stator_seen] = simulate_slider(law, t[stator_seen], stator_position[stator_seen],
                                             dt=dt, run_in=run_in)
    stator_amplitude, stator_phase = fit_sinusoid(t[stator_seen], stator_position[stator_seen],
                                                  frequency)
    amplitude_simulated, phase_simulated = fit_sinusoid(t[stator_seen], simulated[stator_seen],
                                                        frequency)
    amplitude_measured, phase_measured = fit_sinusoid(t[slider_seen], slider_position[slider_seen],
                                                      frequency)
    return ValidationResult(
        frequency=frequency, stator_amplitude=stator_amplitude,
        slider_amplitude_simulated=amplitude_simulated,
        slider_amplitude_measured=amplitude_measured,
        phase_simulated=_lag(stator_phase, phase_simulated),
        phase_measured=_lag(stator_phase, phase_measured),
        simulated_slider_position=simulated)
