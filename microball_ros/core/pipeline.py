"""The one analysis of a position record: what ``microball analyze`` and friction_identifier run.

Pure (arrays in, a PipelineResult out; no files, no rclpy). Steps, one policy for every caller:

1. the samples are put on their frame grid (core.timebase: gaps, dropped frames, duplicated
   stamps, jitter); contiguous runs are analysed, short holes bridged for the estimator only;
2. the stator's fundamental; unsteady periods at the ends (a servo starting) are cut;
3. v_rel and a_slid by the chosen method on every run, covering every sample: the three-stage
   estimate over the longest whole number of periods from the start, and the same from the end
   for the samples the first leaves out (the algorithm is symmetric in time);
4. the memory tests: the paper's fundamental-phase test (reported) and the loop test
   (core.memory.loop_test), whose verdict is the result's;
5. every static law fitted (core.friction) to a_slid unfiltered (fit_epsilon) and v_rel through
   FIT_VELOCITY_FILTER, intervals widened for correlated residuals (batch means), the
   Langevin law validated by simulation (Fig. 9);
6. a degenerate (nearly linear) Langevin fit reported as its viscous limit; a dynamic model
   identified when memory is found; warnings wherever the numbers may be biased.
"""

from dataclasses import dataclass, field, replace
import math

import numpy as np

from microball_ros.core import estimation, friction
from microball_ros.core import memory as memory_tests
from microball_ros.core.errors import FitError, InputError
from microball_ros.core.harmonics import fundamental_frequency
from microball_ros.core.timebase import Grid, regularise

METHODS = ('three-stage', 'forward', 'lowpass-forward')
MIN_PERIODS = 4
NEAR_NYQUIST_SAMPLES = 7.0  # fewer samples per period: harmonics lost, estimates biased
SATURATION = 4.0  # alpha max|v_rel| beyond this: a_slid's harmonics alias at ordinary rates
VALIDATION_TOLERANCE = (0.05, 0.05)  # relative amplitude, phase (rad)
# The three-stage filter of the v_rel the laws are fitted to: a component is kept above 3 times
# the noise floor or 2 % of the largest. Measured on bench/independent (Langevin A 1.2, alpha
# 110, 30 fps, 2 um, seeds 0-4; z = (truth - estimate) / interval half-width for A):
# the display estimate's filter (4 x floor alone) biases 10 s records (A +17 %, z -0.4 to -1.6
# in all of 10 seeds); unfiltered v_rel biases 30 s ones the other way (A -3 to -6 %, z +0.1
# to +1.0, its compensated noise and aliases near Nyquist); this filter: z -0.6 to +0.5.
FIT_VELOCITY_FILTER = {'epsilon': 0.02, 'noise_floor': 3.0, 'harmonics': True}
NOISE_REPLICAS = 24  # re-estimates of the fit v_rel with fresh noise (its error's variance)
NOISE_SEED = 20050608  # fixed: the analysis is a function of its input


@dataclass(frozen=True)
class Options:
    """The analysis policy. ``epsilon`` None: the noise-adaptive amplitude threshold."""

    method: str = 'three-stage'
    epsilon: float | None = None
    fit_epsilon: float = 0.0
    exposure: float = 0.0
    k: float = 3.0
    margin: float = 0.1
    validation_periods: float = 20.0
    fill: int = 2


@dataclass(frozen=True)
class PipelineResult:
    """Everything the analysis found; ``warnings`` is a tuple of (code, message)."""

    options: Options
    grid: Grid
    sample_period: float
    frequency: float
    used: np.ndarray  # grid indices of the samples estimated and fitted
    estimate: estimation.Estimate  # v_rel and a_slid at the used samples (time = their stamps)
    fit_acceleration: np.ndarray  # a_slid the laws are fitted to (fit_epsilon: unfiltered)
    phase_test: memory_tests.MemoryTest
    loop: memory_tests.LoopTest
    fit: object  # friction.FitResult or None (fit-failed)
    comparison: tuple
    validation: object  # friction.ValidationResult or None
    viscous_limit: object  # (c, (lo, hi)) when the Langevin fit is degenerate, else None
    dynamic_model: object  # dict when memory is found, else None
    runs: tuple = ()  # (start, stop) grid ranges analysed (contiguous, steady)
    warnings: tuple = field(default_factory=tuple)
    # v_rel the laws are fitted to (FIT_VELOCITY_FILTER; None: the estimate's). Why: the
    # noise-adaptive filter drops v_rel harmonics that sink below 4 x the noise floor (short
    # records: fewer samples per bin), a_slid for the fit keeps them, and the Langevin fit
    # comes out biased along its A-alpha valley (10 s records: A +17 % in every seed).
    fit_velocity: object = None
    # Replicas [replica, sample] of the fit v_rel's error from the position noise (the record
    # re-estimated with fresh white noise of the measured level added), None if unfiltered.
    # Why: the filter keeps the noise of a few bins only, coherent over the whole record, so
    # the batch means of the residuals cannot see it; the fit's intervals add its variance.
    fit_velocity_noise: object = None

    @property
    def velocity_for_fit(self) -> np.ndarray:
        """Return the v_rel samples the static and dynamic laws are fitted to."""
        if self.fit_velocity is None:
            return self.estimate.velocity
        return np.asarray(self.fit_velocity)

    @property
    def samples_used(self) -> int:
        """Return how many measured samples entered the estimates, tests and fits."""
        return int(len(self.used))

    @property
    def samples_total(self) -> int:
        """Return how many samples the input held."""
        return self.grid.samples_total

    @property
    def memory_verdict(self) -> str:
        """Return 'memoryless', 'memory' or 'undetermined'.

        The loop test's verdict for the three-stage method. The other methods reproduce the
        paper's Fig. 7(a, b): their verdict is their own fundamental-phase test, artifacts
        included (a 'method-phase-error' warning gives the loop test's).
        """
        if self.options.method != 'three-stage':
            return 'memoryless' if self.phase_test.memoryless else 'memory'
        return self.loop.verdict


def three_stage_options(options: Options, fit=False) -> dict:
    """Return the three-stage keyword options of the policy (the fit's acceleration if fit)."""
    common = {'exposure': options.exposure}
    if fit:
        return {**common, 'epsilon': options.fit_epsilon, 'noise_floor': False}
    if options.epsilon is None:  # the noise floor decides alone
        return {**common, 'epsilon': 1.0, 'noise_floor': 4.0}
    return {**common, 'epsilon': options.epsilon, 'noise_floor': False}


def _covered(x, dt, method, options, frequency):
    """Return (index, velocity, acceleration) of x over every sample the method can estimate.

    Three-stage: the estimate over the whole periods from the start (three_stage picks the
    number of periods that best fits the sampling, at least half the window), the same from
    the end for the samples it leaves out (the algorithm is symmetric in time), and, while a
    stretch in the middle is still left out (both picked about half), the same from the first
    sample left out.
    """
    if method != 'three-stage':
        est = estimation.estimate(x, dt, method)
        return est.index, est.velocity, est.acceleration
    index = np.arange(1, len(x) - 1)
    velocity = np.full(len(index), np.nan)
    acceleration = np.full(len(index), np.nan)

    def put(start, reverse):
        """Estimate x[start:] (reversed: x[:len(x) - start] backwards); fill what is left."""
        piece = x[start:] if not reverse else x[:len(x) - start][::-1]
        est = estimation.three_stage(piece, dt, fundamental=frequency, **options)
        where = start + est.index if not reverse else len(x) - 1 - start - est.index
        sign = -1.0 if reverse else 1.0
        empty = np.isnan(velocity[where - 1])
        velocity[where[empty] - 1] = sign * est.velocity[empty]
        acceleration[where[empty] - 1] = est.acceleration[empty]

    put(0, False)
    if np.isnan(velocity[-1]):
        put(0, True)
    while np.any(np.isnan(velocity)):
        first = int(np.flatnonzero(np.isnan(velocity))[0])  # sample first + 1 of x
        put(first, False)
    return index, velocity, acceleration


def _estimate_runs(grid, runs, frequency, options):
    """Return the estimates of every run at its measured samples.

    (grid index, v_rel, a_slid, v_rel and a_slid for the fit, center-difference v_rel and
    a_slid, the fit v_rel's noise replicas [replica, sample] or None).
    """
    pieces = []
    kinds = [three_stage_options(options), three_stage_options(options, fit=True)]
    separate = options.method == 'three-stage' and options.fit_epsilon != options.epsilon
    sigma = _relative_noise(grid, runs, frequency) if separate else 0.0
    rng = np.random.default_rng(NOISE_SEED)
    for start, stop in runs:
        stator, slider = grid.stator[start:stop], grid.slider[start:stop]
        index, velocity, _ = _covered(slider - stator, grid.dt, options.method, kinds[0],
                                      frequency)
        _, _, acceleration = _covered(slider, grid.dt, options.method, kinds[0], frequency)
        replicas = None
        if separate:
            replicas = np.zeros((NOISE_REPLICAS, len(index)))
            _, _, fit_acceleration = _covered(slider, grid.dt, options.method, kinds[1],
                                              frequency)
            fit_kind = {**kinds[1], **FIT_VELOCITY_FILTER}
            _, fit_velocity, _ = _covered(slider - stator, grid.dt, options.method, fit_kind,
                                          frequency)
            for replica in replicas:
                noise = rng.normal(0.0, sigma, stop - start) if sigma > 0 else 0.0
                _, noisy, _ = _covered(slider - stator + noise, grid.dt, options.method,
                                       fit_kind, frequency)
                replica[:] = noisy - fit_velocity
        else:
            fit_acceleration, fit_velocity = acceleration, velocity
        center = estimation.center_difference(slider - stator, grid.dt)
        center_a = estimation.center_difference(slider, grid.dt)
        common = np.intersect1d(index, center.index)
        mine, theirs = np.isin(index, common), np.isin(center.index, common)
        pieces.append((start + index[mine], velocity[mine], acceleration[mine],
                       fit_velocity[mine], fit_acceleration[mine], center.velocity[theirs],
                       center_a.acceleration[theirs],
                       None if replicas is None else replicas[:, mine]))
    columns = [np.concatenate(parts) for parts in zip(*(p[:-1] for p in pieces), strict=True)]
    measured = grid.measured[columns[0]]
    noise = (np.concatenate([p[-1] for p in pieces], axis=1)[:, measured] if separate
             else None)
    return [column[measured] for column in columns] + [noise]


def _relative_noise(grid, runs, frequency):
    """Return the rms white noise (m) of the relative position, from its spectrum off harmonics.

    Over the longest run's whole periods, the bins away from every harmonic of the stator and
    above the slow band hold noise alone: for white noise of variance s^2 each |X_k|^2 is
    exponential with mean n s^2, so s^2 = median / (n ln 2). Aliased harmonics and leakage are
    a few bins, which the median ignores.
    """
    start, stop = max(runs, key=lambda r: r[1] - r[0])
    x = grid.slider[start:stop] - grid.stator[start:stop]
    cycles = frequency * grid.dt
    periods = math.floor(len(x) * cycles)
    length = min(len(x), int(round(periods / cycles))) if periods >= 1 else len(x)
    x = x[:length]
    x = x - np.polyval(np.polyfit(np.arange(length), x, 1), np.arange(length))
    power = np.abs(np.fft.rfft(x)) ** 2
    harmonic = np.arange(len(power)) / (length * cycles)
    off = (np.abs(harmonic - np.round(harmonic)) * length * cycles > 2.5) & (harmonic > 1.0)
    if np.count_nonzero(off) < 8:
        return 0.0
    return float(math.sqrt(np.median(power[off]) / (length * math.log(2))))


def _trim_unsteady_ends(grid, runs, frequency):
    """Cut stator periods off the two ends of the record while they are not steady."""
    t, x = grid.time, grid.stator - np.nanmedian(grid.stator)
    up = np.flatnonzero((x[:-1] < 0) & (x[1:] >= 0))
    if len(up) < 5:
        return runs
    crossings = t[up] - x[up] * grid.dt / (x[up + 1] - x[up])
    periods = np.diff(crossings)
    ok = np.isfinite(periods) & (periods < 1.5 / frequency)
    if np.count_nonzero(ok) < 4:
        return runs
    deviation = np.abs(periods / np.median(periods[ok]) - 1)
    spread = np.median(deviation[ok])
    steady = deviation <= max(0.01, 6 * spread)
    first = int(np.argmax(steady))
    last = len(steady) - 1 - int(np.argmax(steady[::-1]))
    lo = int(up[first]) + 1 if first > 0 else 0
    hi = int(up[last + 1]) + 1 if last < len(steady) - 1 else len(t)
    trimmed = [(max(a, lo), min(b, hi)) for a, b in runs]
    return [(a, b) for a, b in trimmed if b - a >= 3]


def _frequency(grid, runs, source):
    longest = max(runs, key=lambda r: r[1] - r[0])
    stator = grid.stator[longest[0]:longest[1]]
    if np.ptp(stator) == 0:
        raise InputError(f'{source}: the stator does not move (no oscillation)')
    try:
        frequency = fundamental_frequency(stator, grid.dt)
    except InputError:
        raise InputError(f'{source}: no oscillation found in the stator position') from None
    amplitude, _ = friction.fit_sinusoid(grid.time[longest[0]:longest[1]], stator, frequency,
                                         grid.time[longest[0]])
    if not amplitude / math.sqrt(2) > 0.5 * np.std(stator):
        raise InputError(f'{source}: no oscillation found in the stator position')
    return frequency


def analyze_positions(time, stator, slider, valid=None, options: Options | None = None,
                      source='record') -> PipelineResult:
    """Analyse a position record (see the module docstring); InputError if it cannot be used.

    ``time`` (s), ``stator``, ``slider`` (m): one entry per sample, NaN (or ``valid`` False)
    where a mark was not measured; any order of gaps, duplicates and jitter.
    """
    options = options or Options()
    if options.method not in METHODS:
        raise InputError(f'unknown method {options.method!r}; choose one of '
                         f'{", ".join(METHODS)}')
    try:
        grid = regularise(time, stator, slider, valid, fill=options.fill)
    except InputError as error:
        raise InputError(f'{source}: {error}') from None
    runs = grid.segments(minimum=16)
    if not runs:
        raise InputError(f'{source}: no stretch of 16 consecutive samples with both marks')
    frequency = _frequency(grid, runs, source)
    per_period = 1 / (frequency * grid.dt)
    runs = [(a, b) for a, b in _trim_unsteady_ends(grid, runs, frequency)
            if b - a >= max(16, 2 * per_period + 2)]
    if runs:  # the start-up cut: the frequency of the steady motion
        frequency = _frequency(grid, runs, source)
        per_period = 1 / (frequency * grid.dt)
    periods = sum(b - a for a, b in runs) / per_period
    if periods < MIN_PERIODS:
        raise InputError(f'{source}: too short: {periods:.1f} stator periods of '
                         f'{frequency:.3g} Hz in usable stretches, need at least '
                         f'{MIN_PERIODS}')
    used, velocity, acceleration, fit_velocity, fit_acceleration, center_v, center_a, \
        velocity_noise = _estimate_runs(grid, runs, frequency, options)
    est = estimation.Estimate(time=grid.time[used], velocity=velocity,
                              acceleration=acceleration, index=used, method=options.method,
                              sample_period=grid.dt, options=three_stage_options(options))
    phase = memory_tests.memory_test(est.time, velocity, acceleration, frequency,
                                     k=options.k, margin=options.margin)
    noise = memory_tests.memory_test(est.time, center_v, center_a, frequency)
    phase = replace(phase, uncertainty=max(phase.uncertainty, noise.uncertainty))
    phase = replace(phase, memoryless=bool(abs(math.pi - phase.phase_difference)
                                           <= options.k * phase.uncertainty + options.margin))
    seen = np.where(grid.measured, 1.0, np.nan)
    loop = memory_tests.loop_test(grid.time, grid.stator * seen, grid.slider * seen, frequency,
                                  segments=runs, exposure=options.exposure, k=options.k,
                                  margin=options.margin)
    from microball_ros.core.pipeline_fit import identify  # the fitting half of the pipeline

    return identify(PipelineResult(
        options=options, grid=grid, sample_period=grid.dt, frequency=float(frequency),
        used=used, estimate=est, fit_acceleration=fit_acceleration, phase_test=phase,
        loop=loop, fit=None, comparison=(), validation=None, viscous_limit=None,
        dynamic_model=None, runs=tuple(runs), fit_velocity=fit_velocity,
        fit_velocity_noise=velocity_noise), runs, per_period)


def analyze_windows(windows, options: Options | None = None, source='windows'):
    """Analyse the union of windows' positions: the friction_identifier's entry point.

    ``windows``: iterable of (time, stator, slider) arrays, e.g. from DerivativeEstimate
    messages (their ``time``, ``stator_position``, ``slider_position``). Samples are merged by
    stamp (rounded to the nanosecond, the first window's value kept) and sorted, then analysed
    exactly as analyze_positions analyses a record holding those samples.
    """
    windows = list(windows)
    if not windows:
        raise InputError(f'{source}: no windows')
    time = np.concatenate([np.asarray(w[0], dtype=float) for w in windows])
    stator = np.concatenate([np.asarray(w[1], dtype=float) for w in windows])
    slider = np.concatenate([np.asarray(w[2], dtype=float) for w in windows])
    _, first = np.unique(np.round(time * 1e9).astype(np.int64), return_index=True)
    return analyze_positions(time[first], stator[first], slider[first], options=options,
                             source=source)


def fit_or_none(v, a, law):
    """Return the FitResult of a law, or None if it cannot be fitted."""
    try:
        return friction.fit_least_squares(v, a, law)
    except FitError:
        return None
