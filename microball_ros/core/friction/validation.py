"""Validation of an identified law by simulation: the paper's Fig. 9 check.

This module owns the comparison of simulated against measured slider motion at the stator's
fundamental: ``fit_sinusoid`` (amplitude and phase of one frequency with mean and linear drift
removed), ``validate`` (simulate the slider under the measured stator with a law, after a
run-in, and compare both fundamentals) and its ``ValidationResult``.
"""

from dataclasses import dataclass, replace
import math

import numpy as np
import numpy.typing as npt

from microball_ros.core.errors import InputError
from microball_ros.core.friction.laws import FrictionLaw
from microball_ros.core.friction.simulation import check_samples, simulate_slider


def fit_sinusoid(t: npt.ArrayLike, x: npt.ArrayLike, frequency: float,
                 origin: float = 0.0) -> tuple[float, float]:
    """Return (amplitude, phase): x ~ c0 + c1 t + R sin(w (t - origin) + phi), w = 2 pi frequency.

    Least squares with the mean and a linear drift fitted alongside, so slow drift does not leak
    into the fundamental; the phase is in (-pi, pi]. Give stamps since the epoch (1.7e9 s) an
    ``origin`` near them (the same one for phases to be compared): w t itself would be
    rounded to 4e-6 rad, different noise on every sample and a result that depends on the
    last bit of the frequency.
    """
    t, x = check_samples(t, x)
    w = 2.0 * math.pi * frequency
    angle = w * (t - origin)
    basis = np.column_stack([np.ones_like(t), t - t.mean(), np.sin(angle), np.cos(angle)])
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


def validate(law: FrictionLaw, t: npt.ArrayLike, stator_position: npt.ArrayLike,
             slider_position: npt.ArrayLike, frequency: float, *, dt: float = 0.001,
             run_in_periods: float = 2, max_periods: float | None = None) -> ValidationResult:
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
            raise InputError(f'max_periods must be positive, not {max_periods}')
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
        raise InputError(f'the record must be longer than the run-in of {run_in_periods} '
                         f'periods ({run_in:.3g} s)')
    simulated = np.full_like(t, np.nan)
    simulated[stator_seen] = simulate_slider(law, t[stator_seen], stator_position[stator_seen],
                                             dt=dt, run_in=run_in)
    origin = t[0]  # one phase reference for the three fits
    stator_amplitude, stator_phase = fit_sinusoid(t[stator_seen], stator_position[stator_seen],
                                                  frequency, origin)
    amplitude_simulated, phase_simulated = fit_sinusoid(t[stator_seen], simulated[stator_seen],
                                                        frequency, origin)
    amplitude_measured, phase_measured = fit_sinusoid(t[slider_seen], slider_position[slider_seen],
                                                      frequency, origin)
    return ValidationResult(
        frequency=frequency, stator_amplitude=stator_amplitude,
        slider_amplitude_simulated=amplitude_simulated,
        slider_amplitude_measured=amplitude_measured,
        phase_simulated=_lag(stator_phase, phase_simulated),
        phase_measured=_lag(stator_phase, phase_measured),
        simulated_slider_position=simulated)
