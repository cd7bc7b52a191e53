"""The slider driven by friction: M a_slid = F_fric (eq. 2), integrated by fixed-step RK4.

This module owns the dynamics the validation (Fig. 9), the bench simulator and the tests share:
``integrate_rk4`` advances [x_slid, v_slid, *law states] under a given stator velocity at every
half step, and ``simulate_slider`` drives it with a sampled stator position (cubic spline,
optional run-in) and reads the slider position back at the sample times. ``check_samples`` is
the common validation of a sampled record (finite, same length, strictly increasing time).
"""

import math

import numpy as np
import numpy.typing as npt
from scipy.interpolate import CubicHermiteSpline, CubicSpline

from microball_ros.core.errors import InputError
from microball_ros.core.friction.laws import FrictionLaw


def _slider_derivative(law, state, stator_velocity):
    """Return d/dt of [x_slid, v_slid, *law states] for the given stator velocity."""
    v_rel = state[1] - stator_velocity
    law_state = state[2:]
    rate = np.empty_like(state)
    rate[0] = state[1]
    rate[1] = law.acceleration_from_state(law_state, v_rel)
    rate[2:] = law.state_derivative(law_state, v_rel)
    return rate


def integrate_rk4(law: FrictionLaw, state: npt.ArrayLike, stator_velocity: npt.ArrayLike,
                  dt: float) -> np.ndarray:
    """Integrate the slider driven by friction with fixed-step 4th-order Runge-Kutta.

    ``state`` is the initial [x_slid, v_slid, *law states]; ``stator_velocity`` holds the
    stator velocity at every half step t0, t0 + dt/2, ..., t0 + N dt (2N + 1 values, what RK4
    evaluates). Return the states at the N + 1 full steps, shape (N + 1, 2 + law.n_states).
    """
    stator_velocity = np.asarray(stator_velocity, dtype=float)
    if stator_velocity.ndim != 1 or len(stator_velocity) % 2 != 1:
        raise InputError('stator_velocity needs 2N + 1 samples, at every half step')
    y = np.array(state, dtype=float)
    if len(y) != 2 + law.n_states:
        raise InputError(f'state has {len(y)} values, law {law.name!r} needs '
                         f'{2 + law.n_states}')
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


def check_samples(t: npt.ArrayLike, *series: npt.ArrayLike) -> tuple[np.ndarray, ...]:
    """Return (t, *series) as float arrays; raise InputError unless they form a usable record.

    A usable record has at least 4 samples, every series as long as t, only finite values and a
    strictly increasing t.
    """
    t = np.asarray(t, dtype=float)
    arrays = [np.asarray(s, dtype=float) for s in series]
    if t.ndim != 1 or len(t) < 4:
        raise InputError('need at least 4 samples')
    if any(a.shape != t.shape for a in arrays):
        raise InputError('time and position arrays must have the same length')
    if not all(np.all(np.isfinite(a)) for a in (t, *arrays)):
        raise InputError('time and positions must be finite (drop lost samples first)')
    if np.any(np.diff(t) <= 0):
        raise InputError('time must increase strictly')
    return (t, *arrays)


def simulate_slider(law: FrictionLaw, t: npt.ArrayLike, stator_position: npt.ArrayLike,
                    dt: float = 0.001, slider0: npt.ArrayLike | None = None,
                    run_in: float = 0.0) -> np.ndarray:
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
    stamps, stator_position = check_samples(t, stator_position)
    # Time from the first sample: steps of 1 ms added to stamps since the epoch (1.7e9 s)
    # would be rounded to 2.4e-7 s each.
    time = stamps - stamps[0]
    if not 0 <= run_in <= time[-1]:
        raise InputError(f'run_in must be between 0 and the record length {time[-1]:g} s')
    stator = CubicSpline(time, stator_position)
    stator_velocity = stator.derivative()
    start = time[0] - run_in
    n_steps = math.ceil((time[-1] - start) / dt - 1e-9)
    half_steps = start + 0.5 * dt * np.arange(2 * n_steps + 1)
    # During the run-in the stator replays the start of the record, shifted back by run_in.
    replayed = np.where(half_steps < time[0], half_steps + run_in, half_steps)
    if slider0 is None:
        slider0 = (float(stator(time[0])), float(stator_velocity(time[0])))
    state0 = np.asarray(slider0, dtype=float)
    if len(state0) == 2:
        state0 = np.concatenate([state0, law.initial_state()])
    states = integrate_rk4(law, state0, stator_velocity(replayed), dt)
    return CubicHermiteSpline(half_steps[::2], states[:, 0], states[:, 1])(time)
