"""The memory (hysteresis) test: whether friction is a static function of the velocity.

Section II of PAPER.md: compare the phases of the fundamental components of the slider
acceleration and the relative velocity; a static (memoryless) friction law puts them pi apart,
a lag or hysteresis moves the difference off pi. Owns MemoryTest, ``memory_test`` (the phase
test with a batch-means uncertainty) and ``relative_memory_test`` (estimation of a record by
core.estimation, then the test with an honest uncertainty). ``fundamental_frequency`` (from
core.harmonics) is re-exported here as the frequency the test runs at.
"""

from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import numpy.typing as npt
from scipy import stats

from microball_ros.core.errors import InputError
from microball_ros.core.estimation import Estimate, estimate_relative
from microball_ros.core.harmonics import (
    fundamental_frequency,
    fundamental_phasor,
    harmonics_below_nyquist,
)

__all__ = ['MemoryTest', 'fundamental_frequency', 'memory_test', 'relative_memory_test']

# Normal one-sigma quantile, used to turn a Student-t interval into a one-sigma equivalent.
_ONE_SIGMA_QUANTILE = stats.norm.cdf(1.0)


@dataclass(frozen=True)
class MemoryTest:
    """Result of the memory test: fundamental phases of slider acceleration and v_rel.

    Phases (rad) are those of ``amplitude * sin(2 pi f (t - t0) + phase)`` with ``t0`` the
    first time stamp of the analysed window; amplitudes are in m/s and m/s^2.
    ``phase_difference`` is acceleration minus velocity phase folded into [0, pi] and
    ``uncertainty`` its one-sigma uncertainty (rad). ``memoryless`` is
    ``|pi - phase_difference| <= k * uncertainty + margin``. ``periods`` whole periods were
    analysed, split into ``blocks`` blocks for the uncertainty.
    """

    phase_difference: float
    uncertainty: float
    memoryless: bool
    frequency: float
    velocity_phase: float
    acceleration_phase: float
    velocity_amplitude: float
    acceleration_amplitude: float
    periods: int
    blocks: int
    k: float
    margin: float


def _wrap(angle):
    """Wrap angles into (-pi, pi]."""
    return np.pi - np.mod(np.pi - angle, 2 * np.pi)


def _memoryless(phase_difference, uncertainty, k, margin):
    """Return True when the phase difference is compatible with pi."""
    return bool(abs(np.pi - phase_difference) <= k * uncertainty + margin)


def memory_test(time: npt.ArrayLike, v_rel: npt.ArrayLike, a_slid: npt.ArrayLike,
                frequency: float, *, k: float = 3.0, margin: float = 0.1, blocks: int = 8,
                harmonics: int | None = None) -> MemoryTest:
    """Compare the fundamental phases of slider acceleration and relative velocity.

    Static (memoryless) friction ``a_slid = -L(v_rel)`` puts them pi apart; a lag or
    hysteresis moves the difference off pi (a 30 ms first-order lag by about 0.5 rad at
    2.95 Hz). The fundamental at ``frequency`` (Hz) is fitted by least squares, together with
    an offset, a linear trend and ``harmonics`` harmonics (all below Nyquist by default), over
    the longest whole number of periods from the first sample (at least 4 periods).

    Uncertainty: the window is cut into ``blocks`` blocks of whole periods (at least 2 periods
    each); the spread of the block phase differences over sqrt(blocks), scaled by the Student
    t quantile to a one-sigma equivalent, is the one-sigma uncertainty (batch means). It
    includes coloured noise and slow non-stationarity, but only what is in the arrays given:
    amplitude-filtered estimates (three-stage, spectral with a cut-off) have lost the noise
    outside their kept bins, and the noise inside the fundamental bin stays, invisible, so
    their uncertainty comes out near zero. Center differences have the same fundamental phase
    (exactly so for circular three-stage) and keep the noise: pass those for an honest value.

    Verdict: ``memoryless = |pi - phase_difference| <= k * uncertainty + margin``. k = 3 keeps
    noise-made false alarms below 0.3 %. The margin (rad) covers what is not noise:
    static odd friction of a v_rel carrying odd harmonics is not exactly in antiphase (0.008
    rad measured for a 15 % third harmonic at |alpha v_rel| = 1.1, 0.036 rad for 20 % at 2.2,
    0.043 rad for a simulated bearing driven into saturation, |alpha v_rel| up to 7), and the
    estimators' own phase error on memoryless data (below 0.005 rad for three-stage and
    center differences, with drift and harmonics, 25-60 fps, 2-5 Hz), with room for what
    synthetic data lacks (blur, tracking bias). The default 0.1 rad calls a
    first-order friction lag of 5.4 ms or more at 2.95 Hz memory (atan(w tau) > 0.1), and
    also the forward difference's spurious pi - w dt/2 (0.31 rad at 2.95 Hz and 30 fps).
    :func:`relative_memory_test` runs estimation and this test with an honest uncertainty.
    """
    time = np.asarray(time, dtype=float)
    v_rel = np.asarray(v_rel, dtype=float)
    a_slid = np.asarray(a_slid, dtype=float)
    if not time.shape == v_rel.shape == a_slid.shape or time.ndim != 1 or time.size < 3:
        raise InputError('time, v_rel and a_slid must be 1-D arrays of one length (3 or more)')
    if not (np.all(np.isfinite(v_rel)) and np.all(np.isfinite(a_slid))):
        raise InputError('v_rel and a_slid must be finite')
    if not frequency > 0:
        raise InputError(f'frequency must be positive, got {frequency!r}')
    dt = float(np.median(np.diff(time)))
    t = time - time[0]
    periods = int(np.floor((t[-1] + dt) * frequency * (1 + 1e-9)))
    if periods < 4:
        raise InputError(f'the memory test needs at least 4 periods, got {periods}')
    if harmonics is None:
        harmonics = harmonics_below_nyquist(frequency, dt)
    per_block = max(2, periods // blocks)
    count = periods // per_block
    block = np.floor(t * frequency / per_block + 1e-9).astype(int)

    def difference(selected):
        velocity = fundamental_phasor(t[selected], v_rel[selected], frequency, harmonics)
        acceleration = fundamental_phasor(t[selected], a_slid[selected], frequency, harmonics)
        return velocity, acceleration, _wrap(np.angle(acceleration) - np.angle(velocity))

    velocity, acceleration, total = difference(block < count)
    spread = [_wrap(difference(block == j)[2] - total) for j in range(count)]
    student = stats.t.ppf(_ONE_SIGMA_QUANTILE, count - 1)
    uncertainty = float(np.std(spread, ddof=1) / np.sqrt(count) * student)
    phase_difference = float(abs(total))
    return MemoryTest(
        phase_difference=phase_difference, uncertainty=uncertainty,
        memoryless=_memoryless(phase_difference, uncertainty, k, margin),
        frequency=float(frequency), velocity_phase=float(np.angle(velocity)),
        acceleration_phase=float(np.angle(acceleration)),
        velocity_amplitude=float(abs(velocity)), acceleration_amplitude=float(abs(acceleration)),
        periods=count * per_block, blocks=count, k=k, margin=margin)


def relative_memory_test(time: npt.ArrayLike, stator: npt.ArrayLike, slider: npt.ArrayLike,
                         method: str = 'three-stage', *, frequency: float | None = None,
                         k: float = 3.0, margin: float = 0.1, blocks: int = 8,
                         **options: Any) -> tuple[Estimate, MemoryTest]:
    """Estimate v_rel and a_slid of a record and run the memory test with an honest uncertainty.

    Returns ``(estimate, test)``: the :func:`estimate_relative` result for ``method`` and
    ``options``, and the :func:`memory_test` of it at ``frequency`` (Hz; default the
    stator's fundamental, also used as the three-stage ``fundamental``). The uncertainty is
    the larger of the block spreads of these estimates and of center-difference estimates over
    the same span, and the verdict uses it: amplitude-filtered estimates hide their noise, the
    center differences keep it and have the same fundamental phase.
    """
    time = np.asarray(time, dtype=float)
    if frequency is None:
        frequency = fundamental_frequency(stator, float(np.median(np.diff(time))))
    if method == 'three-stage':
        options.setdefault('fundamental', frequency)
    result = estimate_relative(time, stator, slider, method, **options)
    test = memory_test(result.time, result.velocity, result.acceleration, frequency, k=k,
                       margin=margin, blocks=blocks)
    reference = estimate_relative(time, stator, slider, 'center')
    span = (reference.time >= result.time[0]) & (reference.time <= result.time[-1])
    noise = memory_test(reference.time[span], reference.velocity[span],
                        reference.acceleration[span], frequency, blocks=blocks)
    uncertainty = max(test.uncertainty, noise.uncertainty)
    return result, replace(test, uncertainty=uncertainty,
                           memoryless=_memoryless(test.phase_difference, uncertainty, k, margin))
