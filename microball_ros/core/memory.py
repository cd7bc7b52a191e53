"""The memory (hysteresis) test: whether friction is a static function of the velocity.

Section II of docs/paper.md: compare the phases of the fundamental components of the slider
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
    harmonic_design,
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

    # Blocks that a gap in the record left (nearly) empty are left out: a phase needs the
    # block's periods sampled.
    expected = per_block / frequency / dt
    full = [j for j in range(count) if np.count_nonzero(block == j) >= 0.5 * expected]
    if len(full) < 2:
        raise InputError(f'the memory test needs at least 2 sampled blocks of {per_block} '
                         f'periods, got {len(full)}')
    velocity, acceleration, total = difference(np.isin(block, full))
    spread = [_wrap(difference(block == j)[2] - total) for j in full]
    count = len(full)
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


# ---------------------------------------------------------------------------------------------
# The loop test: right for saturating static laws, from the positions of the whole record
# ---------------------------------------------------------------------------------------------

VERDICTS = ('memoryless', 'memory', 'undetermined')


@dataclass(frozen=True)
class LoopTest:
    """Whether a_slid depends on v_rel alone, from the area of the a_slid - v_rel loop.

    For any static law a = -L(v) of a periodic v the loop area is zero: the integral of a dv
    over a period is that of -L(v) dv, which vanishes whatever the shape of L (saturating,
    Stribeck, ...). The area per period is the mean of a_slid times d v_rel / dt, here computed
    harmonic by harmonic from least-squares Fourier fits of the slider and relative positions
    (so derivatives are exact, gaps need no filling and every sample counts), and normalised by
    rms(a_slid) rms(d v_rel/dt): ``correlation`` in [-1, 1], 0 for every memoryless law. For
    sinusoids it is the sine of the a - v phase's departure from pi, so ``statistic`` =
    arcsin(correlation) (rad) reads like the phase test (a first-order lag tau gives about
    atan(w tau)).

    ``uncertainty``: one sigma (rad), the larger of the block spread (batch means over blocks of
    whole periods) and the propagation of the Fourier coefficients' noise. ``bias_bound`` (rad):
    what the harmonics above Nyquist, which the samples cannot show, could contribute,
    extrapolated from the highest harmonics seen (large when the friction saturates hard or
    the frequency is near Nyquist). Verdict: 'memory' if |statistic| - k sigma - bias_bound >
    0, 'memoryless' if |statistic| + k sigma + bias_bound <= margin (no loop as large as a
    phase of ``margin``), else 'undetermined'.
    """

    verdict: str
    statistic: float
    uncertainty: float
    bias_bound: float
    correlation: float
    blocks: int
    harmonics: int
    k: float
    margin: float
    samples: int

    def to_json(self):
        """Return the test as a JSON object."""
        return {'verdict': self.verdict, 'statistic': self.statistic,
                'uncertainty': self.uncertainty, 'bias_bound': self.bias_bound,
                'correlation': self.correlation, 'blocks': self.blocks,
                'harmonics': self.harmonics, 'k': self.k, 'margin': self.margin,
                'samples': self.samples}


def _block_fit(t, columns, frequency, harmonics):
    """Return (harmonic coefficients [K, 2, ncol], residual variances [ncol], q [K, 2])."""
    design = harmonic_design(t, frequency, harmonics, 2)
    coefficients, _, rank, _ = np.linalg.lstsq(design, columns, rcond=None)
    if rank < design.shape[1]:
        return None
    residual = columns - design @ coefficients
    dof = max(1, len(t) - design.shape[1])
    variance = np.sum(residual ** 2, axis=0) / dof
    inverse = np.linalg.inv(design.T @ design)
    q = np.diag(inverse)[3:].reshape(harmonics, 2)
    return coefficients[3:].reshape(harmonics, 2, columns.shape[1]), variance, q


def _block_harmonics(frequency, dt, block_time):
    """Return the harmonics a block resolves: below Nyquist, and apart from its mirror."""
    harmonics = harmonics_below_nyquist(frequency, dt)
    while harmonics > 1 and abs(1 / dt - 2 * harmonics * frequency) * block_time < 1.0:
        harmonics -= 1
    return harmonics


def loop_test(time: npt.ArrayLike, stator: npt.ArrayLike, slider: npt.ArrayLike,
              frequency: float, *, segments=None, exposure: float = 0.0, k: float = 3.0,
              margin: float = 0.1, block_periods: float = 4.0) -> LoopTest:
    """Run the loop test on positions (NaN where not measured); see LoopTest.

    ``segments``: (start, stop) index ranges analysed separately (contiguous runs), default
    the whole arrays. Blocks are ``block_periods`` periods or more (long enough to separate
    the highest harmonic from its alias); each block gets its own frequency, refined from the
    stator's phase progression, so a slowly varying crank speed is followed.
    ``exposure`` (s): each frame's averaging over it, undone per harmonic (sinc).
    """
    time = np.asarray(time, dtype=float)
    stator = np.asarray(stator, dtype=float)
    slider = np.asarray(slider, dtype=float)
    dt = float(np.median(np.diff(time)))
    if segments is None:
        segments = [(0, len(time))]
    span = max(block_periods, 2.0) / frequency
    harmonics = _block_harmonics(frequency, dt, span * 4)
    if harmonics < 2:
        harmonics = harmonics_below_nyquist(frequency, dt)
    block_time = max(span, 1.0 / max(abs(1 / dt - 2 * harmonics * frequency), 1e-9))
    block_time = min(block_time, 16 / frequency)
    if abs(1 / dt - 2 * harmonics * frequency) * block_time < 1.0 and harmonics > 1:
        harmonics -= 1
    blocks = []
    for start, stop in segments:
        count = int((time[stop - 1] - time[start] + dt) // block_time)
        if count < 1:
            continue
        edges = np.linspace(start, stop, count + 1).astype(int)
        blocks += [(a, b) for a, b in zip(edges[:-1], edges[1:], strict=True)]
    order = np.arange(1, harmonics + 1)
    omega4 = (2 * np.pi * order * frequency) ** 4
    blur = np.sinc(order * frequency * exposure)
    records = []
    phases = []
    for a, b in blocks:
        seen = np.isfinite(stator[a:b]) & np.isfinite(slider[a:b])
        t = time[a:b][seen]
        if len(t) < 2 * harmonics + 8:
            continue
        columns = np.column_stack([slider[a:b][seen], slider[a:b][seen] - stator[a:b][seen],
                                   stator[a:b][seen]])
        fitted = _block_fit(t, columns, frequency, harmonics)
        if fitted is None:
            continue
        records.append((t, columns))
        phases.append((t[0], fitted[0][0, :, 2]))
    if len(records) < 1:
        raise InputError('the loop test needs at least one block of '
                         f'{block_time * frequency:.3g} periods of measured samples')
    local = _local_frequencies(phases, frequency)
    sums = np.zeros(4)  # W, A^2, V^2, var W
    spread = []
    tail = np.zeros(harmonics)
    for (t, columns), f in zip(records, local, strict=True):
        fitted = _block_fit(t, columns, f, harmonics)
        if fitted is None:
            continue
        coefficients, variance, q = fitted
        coefficients = coefficients / blur[:, None, None]
        q = q / blur[:, None] ** 2
        scale = omega4 * (f / frequency) ** 4
        xs, xr = coefficients[:, :, 0], coefficients[:, :, 1]
        noise_s = variance[0] * q
        w = 0.5 * scale * (np.sum(xs * xr, axis=1) - np.sum(noise_s, axis=1))
        a2 = 0.5 * np.sum(scale * np.maximum(np.sum(xs ** 2 - noise_s, axis=1), 0))
        v2 = 0.5 * np.sum(scale * np.maximum(
            np.sum(xr ** 2 - variance[1] * q, axis=1), 0))
        var_w = np.sum((0.5 * scale[:, None]) ** 2 * (
            xr ** 2 * noise_s + xs ** 2 * variance[1] * q + 2 * xs * xr * noise_s))
        sums += [np.sum(w), a2, v2, var_w]
        # Amplitudes with their noise taken out: a harmonic at the noise floor adds nothing.
        tail += 0.5 * scale * np.sqrt(np.maximum(np.sum(xs ** 2 - 2 * noise_s, axis=1), 0)
                                      * np.maximum(np.sum(xr ** 2 - 2 * variance[1] * q,
                                                          axis=1), 0))
        if a2 > 0 and v2 > 0:
            spread.append(np.sum(w) / np.sqrt(a2 * v2))
    norm = np.sqrt(sums[1] * sums[2])
    if not norm > 0:
        raise InputError('no oscillation of the slider or of the relative position')
    correlation = float(np.clip(sums[0] / norm, -1, 1))
    sigma = float(np.sqrt(max(sums[3], 0.0)) / norm)  # a noise-free record: rounding below 0
    if len(spread) >= 3:
        student = stats.t.ppf(_ONE_SIGMA_QUANTILE, len(spread) - 1)
        sigma = max(sigma, float(np.std(spread, ddof=1) / np.sqrt(len(spread)) * student))
    statistic = float(np.arcsin(correlation))
    sigma = sigma / max(np.sqrt(1 - correlation ** 2), 1e-3)
    tail = tail / norm
    if harmonics >= 3:
        # Products of harmonics of a law with a kink fall as 1/k^2: the rest sum to K times
        # the last one. The last two count, as a symmetric law has odd harmonics only.
        bias = float(harmonics * (tail[-1] + tail[-2]))
    else:
        bias = float(np.sum(tail))
    # A crank speed that varies within a block (local frequencies apart) breaks the harmonic
    # model of the block: harmonic k drifts by 2 pi k df T over it, bounded here.
    wander = float(np.max(np.abs(np.asarray(local) - frequency))) if len(local) else 0.0
    bias += 2 * np.pi * wander * block_time * harmonics  # harmonic k drifts k times faster
    if abs(statistic) - k * sigma - bias > 0:
        verdict = 'memory'
    elif abs(statistic) + k * sigma + bias <= margin:
        verdict = 'memoryless'
    else:
        verdict = 'undetermined'
    return LoopTest(verdict=verdict, statistic=statistic, uncertainty=sigma, bias_bound=bias,
                    correlation=correlation, blocks=len(records), harmonics=harmonics, k=k,
                    margin=margin, samples=int(sum(len(t) for t, _ in records)))


def _local_frequencies(phases, frequency):
    """Return each block's frequency from the stator's fundamental phase across blocks.

    ``phases``: (block start time, [cos, sin] of the stator fundamental fitted at
    ``frequency`` from that start). At a true frequency f + df the phase, referred to a common
    origin, advances by 2 pi df per second more than at f.
    """
    if len(phases) < 3:
        return [frequency] * len(phases)
    start = np.array([p[0] for p in phases])
    angle = np.array([np.arctan2(p[1][0], p[1][1]) for p in phases])
    phase = np.unwrap(angle - 2 * np.pi * frequency * (start - start[0]))
    offset = np.gradient(phase, start) / (2 * np.pi)
    if np.all(np.abs(offset) < 1e-4 * frequency):
        return [frequency] * len(phases)
    return list(frequency + offset)
