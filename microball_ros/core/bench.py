"""The simulated rig: a crank-slider stator, a slider moved by friction only, a camera.

The stator is driven by a crank of radius r (the stator amplitude) and a connecting rod of
length l; the slider obeys M a_slid = F_fric (docs/paper.md eq. 2) with any law of
``microball_ros.core.friction``, integrated by its fixed-step RK4. The camera samples both
positions at ``frame_rate``; each frame averages the motion over its exposure (motion blur) and
is stamped at mid-exposure; white noise is added to both measured positions and a slow random
drift to the slider's.

Time: the crank angle is theta = w t - pi/2, so with l = inf the stator is x = X sin(w t) as
in the paper, and a record's time 0 comes after ``settle`` seconds of run-in.
"""

from dataclasses import dataclass, field, fields, replace
import math
from types import MappingProxyType
from typing import Any

import numpy as np
import numpy.typing as npt
from scipy.signal import lfilter

from microball_ros.core import friction
from microball_ros.core.errors import InputError


def crank_slider_position(theta: npt.ArrayLike, r: float, rod: float) -> np.ndarray:
    """Return the crank-slider position x = r cos(theta) + sqrt(l^2 - r^2 sin^2 theta) - l, m.

    theta: crank angle (rad); r: crank radius (m); rod: rod length l (m, > r; math.inf gives
    the pure r cos(theta)). Expanding the root,
    x ~ r cos(theta) - r^2/(4l) + r^2/(4l) cos(2 theta):
    a second harmonic of amplitude r^2/(4l) (and the same negative offset). The root is
    evaluated as -(r sin)^2 / (sqrt(l^2 - (r sin)^2) + l), free of cancellation and exact
    for l = inf.
    """
    return crank_slider_motion(theta, 0.0, r, rod)[0]


def crank_slider_motion(theta: npt.ArrayLike, omega: float, r: float,
                        rod: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Return (position, velocity, acceleration) of the crank-slider at a constant crank speed.

    theta: crank angle (rad); omega: crank angular velocity (rad/s); r, rod (= l) as in
    crank_slider_position. With q = sqrt(l^2 - r^2 sin^2 theta):
    dx/dtheta = -r sin - r^2 sin cos / q,
    d2x/dtheta2 = -r cos - r^2 cos(2 theta) / q - r^4 sin^2 cos^2 / q^3,
    velocity = omega dx/dtheta, acceleration = omega^2 d2x/dtheta2 (the l terms vanish for
    l = inf).
    """
    theta = np.asarray(theta, dtype=float)
    sin, cos = np.sin(theta), np.cos(theta)
    offset = r * sin
    q = np.sqrt(rod * rod - offset * offset)
    position = r * cos - offset * offset / (q + rod)
    slope = -offset - r * offset * cos / q
    curvature = -r * cos - r * r * np.cos(2.0 * theta) / q - (r * offset * cos) ** 2 / q ** 3
    return position, omega * slope, omega * omega * curvature


@dataclass(frozen=True)
class Scenario:
    """A bench configuration: the stator drive, the friction law, the camera and its errors.

    frequency: crank frequency, Hz. stator_amplitude: crank radius, m. rod_length: connecting
    rod, m (math.inf: pure sine). law: a friction law object (friction.py).
    frame_rate: camera frames per second. exposure: exposure time, s (0 <= exposure <=
    1/frame_rate); a frame reports the position averaged over its exposure, stamped at
    mid-exposure. noise_std: white Gaussian noise on both measured positions, m.
    drift_velocity, drift_time: the slider's slow random drift (surface irregularities of the
    grooves): its velocity is an Ornstein-Uhlenbeck process of rms drift_velocity (m/s) and
    correlation time drift_time (s), so the drift is smooth and wanders without bound, like
    the paper's slow random slider drift. It is added to the measured slider position only and
    kept out of the dynamics, so the ground-truth acceleration stays the friction.
    settle: seconds simulated and discarded before time 0. seed: for np.random.default_rng.
    """

    frequency: float
    stator_amplitude: float
    law: Any
    rod_length: float = math.inf
    frame_rate: float = 30.0
    exposure: float = 1.0 / 60.0
    noise_std: float = 0.0
    drift_velocity: float = 0.0
    drift_time: float = 5.0
    settle: float = 2.0
    seed: int = 0
    description: str = field(default='', compare=False)

    def __post_init__(self) -> None:
        """Reject a scenario that cannot run, with a one-line message."""
        for name in ('frequency', 'stator_amplitude', 'frame_rate', 'drift_time'):
            value = getattr(self, name)
            if not (value > 0 and math.isfinite(value)):
                raise InputError(f'scenario: {name} must be positive and finite, got {value!r}')
        for name in ('noise_std', 'drift_velocity', 'settle', 'exposure'):
            value = getattr(self, name)
            if not (value >= 0 and math.isfinite(value)):
                raise InputError(f'scenario: {name} must be non-negative and finite, '
                                 f'got {value!r}')
        if not self.rod_length > self.stator_amplitude:
            raise InputError(f'scenario: rod_length {self.rod_length!r} m must exceed the crank '
                             f'radius (stator_amplitude) {self.stator_amplitude!r} m')
        if self.exposure > 1.0 / self.frame_rate:
            raise InputError(f'scenario: exposure {self.exposure!r} s is longer than a frame '
                             f'({1.0 / self.frame_rate:.6g} s)')

    @property
    def angular_frequency(self) -> float:
        """Return the crank angular velocity 2 pi frequency, rad/s."""
        return 2.0 * math.pi * self.frequency


_PAPER = Scenario(
    frequency=2.95, stator_amplitude=1.2e-3, law=friction.Langevin(A=1.2, alpha=110.0),
    rod_length=0.05, noise_std=2e-6, drift_velocity=3e-6,
    description='the paper: 1.2 mm at 2.95 Hz (50 mm rod), Langevin A=1.2 m/s^2, '
                'alpha=110 s/m, 30 fps, 2 um noise, slow drift')

SCENARIOS = MappingProxyType({
    'paper': _PAPER,
    'paper-clean': replace(_PAPER, noise_std=0.0, drift_velocity=0.0,
                           description='the paper scenario without noise or drift'),
    # 3 mm, not more: the sharper the knee of L(v_rel) in time, the more of a_slid's harmonics
    # lie above the 15 Hz Nyquist limit of 30 fps and alias (at 5 mm, alpha |v_rel| = 7, a fit
    # of 30 fps estimates gives alpha 12 % low; at 3 mm, 4 % low).
    'saturating': replace(_PAPER, stator_amplitude=3e-3,
                          description='3 mm stroke: alpha |v_rel| reaches 3.3, L(v_rel) reaches '
                                      '0.7 A'),
    'lugre': replace(_PAPER, law=friction.LuGre(),
                     description='paper stator, LuGre friction (hysteresis, not memoryless)'),
    'lagged': replace(_PAPER, law=friction.LaggedFriction(friction.Langevin(1.2, 110.0), 0.035),
                      description='paper stator, Langevin friction behind a 35 ms first-order '
                                  'lag (hysteresis)'),
    'coulomb-viscous': replace(_PAPER, law=friction.CoulombViscous(Fc=0.1, c=25.0),
                               description='paper stator, Coulomb (0.1 m/s^2) + viscous '
                                           '(25 1/s) friction'),
})


def scenario_names() -> list[str]:
    """Return the names of the preset scenarios."""
    return list(SCENARIOS)


def get_scenario(name: str, **overrides: Any) -> Scenario:
    """Return the preset scenario ``name`` with fields replaced by ``overrides``."""
    if name not in SCENARIOS:
        raise InputError(f'unknown scenario {name!r}; known: {", ".join(SCENARIOS)}')
    known = {f.name for f in fields(Scenario)}
    unknown = sorted(set(overrides) - known)
    if unknown:
        raise InputError(f'unknown scenario field(s) {", ".join(unknown)}; '
                         f'known: {", ".join(sorted(known))}')
    return replace(SCENARIOS[name], **overrides)


@dataclass(frozen=True)
class BenchState:
    """The true state of the rig at one instant (SI units; acceleration = friction per mass)."""

    time: float
    crank_angle: float
    stator_position: float
    stator_velocity: float
    slider_position: float
    slider_velocity: float
    slider_acceleration: float

    @property
    def relative_velocity(self) -> float:
        """Return v_rel = slider velocity - stator velocity, m/s."""
        return self.slider_velocity - self.stator_velocity


class BenchIntegrator:
    """Advance the rig in time for a crank speed that may change between calls.

    The crank angle is integrated (continuous, so a speed change never makes the stator jump);
    within a step_to call the speed is constant and the slider is integrated by friction.py's
    RK4 in equal steps of at most dt that end exactly at the requested time. The rig starts at
    rest: slider resting at the stator's position, law in its initial state.
    """

    def __init__(self, scenario: Scenario, *, dt: float = 0.001, time: float = 0.0,
                 crank_angle: float = -math.pi / 2):
        if not dt > 0:
            raise InputError(f'dt must be positive, got {dt!r}')
        self.scenario = scenario
        self.dt = dt
        self.time = float(time)
        self.crank_angle = float(crank_angle)
        self.omega = 0.0
        start = crank_slider_position(self.crank_angle, scenario.stator_amplitude,
                                      scenario.rod_length)
        self._slider = np.concatenate([[float(start), 0.0], scenario.law.initial_state()])

    @property
    def state(self) -> BenchState:
        """Return the current true BenchState."""
        scenario = self.scenario
        stator_x, stator_v, _ = crank_slider_motion(
            self.crank_angle, self.omega, scenario.stator_amplitude, scenario.rod_length)
        slider_x, slider_v = self._slider[:2]
        acceleration = scenario.law.acceleration_from_state(self._slider[2:],
                                                            slider_v - float(stator_v))
        return BenchState(time=self.time, crank_angle=self.crank_angle,
                          stator_position=float(stator_x), stator_velocity=float(stator_v),
                          slider_position=float(slider_x), slider_velocity=float(slider_v),
                          slider_acceleration=float(acceleration))

    def step_to(self, t: float, omega: float) -> BenchState:
        """Advance to time t (s) with the crank turning at omega (rad/s); return the state."""
        span = t - self.time
        if span < 0:
            raise ValueError(f'cannot step back from t = {self.time!r} s to {t!r} s')
        n_steps = math.ceil(span / self.dt - 1e-9)
        self.omega = float(omega)
        if n_steps > 0:
            step = span / n_steps
            half_step_angles = self.crank_angle + self.omega * 0.5 * step * np.arange(
                2 * n_steps + 1)
            _, stator_velocity, _ = crank_slider_motion(
                half_step_angles, self.omega, self.scenario.stator_amplitude,
                self.scenario.rod_length)
            states = friction.integrate_rk4(self.scenario.law, self._slider, stator_velocity,
                                            step)
            self._slider = states[-1]
            self.crank_angle = float(half_step_angles[-1])
        self.time = float(t)
        return self.state


@dataclass(frozen=True)
class BenchRecord:
    """A simulated camera record: measured positions and the ground truth at the frame times.

    time (s, 0 after the run-in, frame k at k / frame_rate, mid-exposure); stator_position and
    slider_position (m): what the camera measures (blurred, noisy, slider drift added); true_*:
    the instantaneous rig state at the frame times; true_slider_acceleration is the friction
    per unit mass (m/s^2); true_slider_drift is the drift added to the measured slider.
    """

    time: np.ndarray
    stator_position: np.ndarray
    slider_position: np.ndarray
    true_stator_position: np.ndarray
    true_slider_position: np.ndarray
    true_stator_velocity: np.ndarray
    true_slider_velocity: np.ndarray
    true_relative_velocity: np.ndarray
    true_slider_acceleration: np.ndarray
    true_slider_drift: np.ndarray
    frame_rate: float
    scenario: Scenario

    def to_columns(self) -> dict[str, np.ndarray]:
        """Return column name -> array for a position CSV: measured first, then the truth."""
        names = ('time', 'stator_position', 'slider_position', 'true_stator_position',
                 'true_slider_position', 'true_stator_velocity', 'true_slider_velocity',
                 'true_relative_velocity', 'true_slider_acceleration', 'true_slider_drift')
        return {name: getattr(self, name) for name in names}


def slider_drift(rng: np.random.Generator, n_frames: int, period: float, velocity_rms: float,
                 correlation_time: float) -> np.ndarray:
    """Return the drift (m) at n_frames frames: the integral of an Ornstein-Uhlenbeck velocity.

    The velocity starts in its stationary distribution and follows the exact discretisation
    u[k+1] = rho u[k] + velocity_rms sqrt(1 - rho^2) xi[k], rho = exp(-period /
    correlation_time); the position integrates it by the trapezoid rule from 0.
    """
    rho = math.exp(-period / correlation_time)
    kicks = rng.standard_normal(n_frames) * velocity_rms
    kicks[1:] *= math.sqrt(1.0 - rho * rho)
    velocity = lfilter([1.0], [1.0, -rho], kicks)
    return np.concatenate([[0.0], np.cumsum(0.5 * (velocity[1:] + velocity[:-1]) * period)])


def simulate(scenario: Scenario, duration: float, *, dt: float = 0.001,
             frame_rate: float | None = None) -> BenchRecord:
    """Simulate the bench for ``duration`` seconds of frames; return a BenchRecord.

    The rig runs scenario.settle seconds first (discarded), then is sampled at frame k,
    time k / frame_rate < duration. A frame's measured position is the average of the true
    position over the exposure (Simpson's rule on its start, middle and end: error 3e-6
    relative at the paper's settings; for a sinusoid the blur scales the amplitude by
    sinc(w exposure / 2), 0.996 here, and shifts no phase), plus noise (and drift for the
    slider). Random draws come from np.random.default_rng(scenario.seed).
    """
    frame_rate = scenario.frame_rate if frame_rate is None else frame_rate
    if not (frame_rate > 0 and scenario.exposure <= 1.0 / frame_rate):
        raise InputError(f'frame_rate {frame_rate!r} must be positive with frames no shorter '
                         f'than the exposure ({scenario.exposure:g} s)')
    n_frames = math.floor(duration * frame_rate + 1e-9)
    if n_frames < 2:
        raise InputError(f'duration {duration!r} s holds fewer than 2 frames')
    omega = scenario.angular_frequency
    time = np.arange(n_frames) / frame_rate
    integrator = BenchIntegrator(scenario, dt=dt, time=-scenario.settle,
                                 crank_angle=-math.pi / 2 - omega * scenario.settle)
    # Each frame needs the rig at the start, middle and end of its exposure. Rounding can put
    # one frame's end a hair after the next one's start when exposure = 1 / frame_rate, so the
    # sequence of times is made non-decreasing.
    half_exposure = 0.5 * scenario.exposure
    instants = np.maximum.accumulate(
        np.column_stack([time - half_exposure, time, time + half_exposure]).ravel())
    states = [integrator.step_to(t, omega) for t in instants]
    positions = np.array([(s.stator_position, s.slider_position) for s in states]).reshape(
        n_frames, 3, 2)
    blurred = (positions[:, 0] + 4.0 * positions[:, 1] + positions[:, 2]) / 6.0
    truth = np.array([(s.stator_position, s.slider_position, s.stator_velocity,
                       s.slider_velocity, s.relative_velocity, s.slider_acceleration)
                      for s in states[1::3]])

    rng = np.random.default_rng(scenario.seed)
    stator_noise = rng.standard_normal(n_frames) * scenario.noise_std
    slider_noise = rng.standard_normal(n_frames) * scenario.noise_std
    drift = slider_drift(rng, n_frames, 1.0 / frame_rate, scenario.drift_velocity,
                   scenario.drift_time)
    return BenchRecord(
        time=time, stator_position=blurred[:, 0] + stator_noise,
        slider_position=blurred[:, 1] + drift + slider_noise,
        true_stator_position=truth[:, 0], true_slider_position=truth[:, 1],
        true_stator_velocity=truth[:, 2], true_slider_velocity=truth[:, 3],
        true_relative_velocity=truth[:, 4], true_slider_acceleration=truth[:, 5],
        true_slider_drift=drift, frame_rate=frame_rate, scenario=scenario)
