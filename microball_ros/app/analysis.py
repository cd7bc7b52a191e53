"""Offline analysis of one position record: the paper's whole Section III-IV pipeline.

positions -> fundamental frequency -> velocity and acceleration (chosen method) -> memory test
-> Langevin fit (and the other static laws for comparison) -> validation by simulation (Fig. 9).
Pure numpy/scipy through the core; the CLI, the report and (later) the nodes call it.
"""

from dataclasses import dataclass
import math
import os

import numpy as np

from microball_ros.core import estimation, friction
from microball_ros.core import memory as memory_test
from microball_ros.core.errors import FitError
from microball_ros.core.records import PositionRecord, RecordError
from microball_ros.io.positions_csv import read_positions_csv

METHODS = ('three-stage', 'forward', 'lowpass-forward')
MIN_PERIODS = 4
# The Fig. 9 validation simulates the first VALIDATION_PERIODS stator periods of the window
# (friction.validate): a settled periodic response needs no more, and the integrator's cost
# grows with the record (about 75 s for an hour if it covered everything).
VALIDATION_PERIODS = 20
# A stator period further than this from the median period is not steady (steady_periods).
STEADY_TOLERANCE = 0.01


@dataclass(frozen=True)
class AnalysisResult:
    """Everything ``microball analyze`` reports about one record."""

    source: str
    method: str
    epsilon: float
    exposure: float
    fit_epsilon: object  # float for the three-stage method, else None
    sample_period: float
    fundamental_frequency: float
    window: PositionRecord  # the analysed stretch: the longest run of valid samples
    samples_invalid: int
    estimate: estimation.Estimate
    memory: memory_test.MemoryTest
    fit: friction.FitResult
    comparison: tuple  # friction.LawComparison per static law: fitted by AIC, then failed
    validation: friction.ValidationResult

    def to_json(self):
        """Return the JSON object of the CLI contract (DESIGN.md section 5), plus extras.

        An interval end the data cannot bound (an open profile) is written as null.
        """
        params = self.fit.params
        return {
            'source': self.source,
            'method': self.method,
            'epsilon': self.epsilon,
            'exposure': self.exposure,
            'sample_period': self.sample_period,
            'fundamental_frequency': self.fundamental_frequency,
            'window': {'start': float(self.window.time[0]), 'end': float(self.window.time[-1]),
                       'samples_used': len(self.window.time),
                       'samples_invalid': self.samples_invalid},
            'phase_difference': self.memory.phase_difference,
            'phase_uncertainty': self.memory.uncertainty,
            'memoryless': self.memory.memoryless,
            'memory_test': {'k': self.memory.k, 'margin': self.memory.margin,
                            'periods': self.memory.periods, 'blocks': self.memory.blocks},
            'model': {
                'name': self.fit.name,
                'A': params['A'],
                'alpha': params['alpha'],
                'A_ci95': _interval(self.fit.ci95['A']),
                'alpha_ci95': _interval(self.fit.ci95['alpha']),
                'A_alpha_correlation': _finite_or_none(self.fit.correlation[0, 1]),
                'low_velocity_slope': params['A'] * params['alpha'] / 3.0,
                'identifiable': self.fit.identifiable,
                'rmse': self.fit.rmse,
                'sample_count': self.fit.n,
                'fit_epsilon': self.fit_epsilon,
            },
            'comparison': [_comparison_entry(entry) for entry in self.comparison],
            'validation': {
                'periods': min(VALIDATION_PERIODS, len(self.window.time) * self.sample_period
                               * self.fundamental_frequency),
                'slider_amplitude_simulated': self.validation.slider_amplitude_simulated,
                'slider_amplitude_measured': self.validation.slider_amplitude_measured,
                'phase_simulated': self.validation.phase_simulated,
                'phase_measured': self.validation.phase_measured,
            },
        }


def _comparison_entry(entry):
    """Return one law of the comparison as JSON: ok and error, and null numbers if it failed."""
    if not entry.ok:
        return {'name': entry.name, 'ok': False, 'error': entry.error, 'aic': None, 'bic': None,
                'rmse': None, 'params': None, 'ci95': None}
    return {'name': entry.name, 'ok': True, 'error': None, 'aic': entry.aic, 'bic': entry.bic,
            'rmse': entry.rmse, 'params': entry.params,
            'ci95': {name: _interval(b) for name, b in entry.ci95.items()}}


def _finite_or_none(value):
    return float(value) if math.isfinite(value) else None


def _interval(bounds):
    return [_finite_or_none(b) for b in bounds]


def _is_bag(path):
    return os.path.isdir(path) or path.endswith('.mcap')


def load_positions(path, slider_roi=None, stator_roi=None, meters_per_pixel=None,
                   progress=None):
    """Load a position record from a CSV file, a bag directory or an .mcap file.

    A bag's /tracking/positions are read; a bag with only /camera/image_raw is tracked first
    (frames.track_bag), with the ROIs and scale given here, else those the recording kept.
    ``progress(text)`` reports the tracking.
    """
    if not _is_bag(path):
        return read_positions_csv(path)
    from microball_ros.io.bags.reader import (
                                           IMAGES_TOPIC,
                                           POSITIONS_TOPIC,
                                           BagError,
                                           open_bag,
                                           read_positions,
    )

    bag = open_bag(path)
    if POSITIONS_TOPIC in bag.topics:
        return read_positions(bag)
    if IMAGES_TOPIC not in bag.topics:
        raise BagError(f'{path}: bag has neither {POSITIONS_TOPIC} nor {IMAGES_TOPIC}; it '
                       f'has: {", ".join(sorted(bag.topics)) or "no topics"}')
    from microball_ros.io.frames import track_bag, tracker_parameters

    parameters = tracker_parameters(bag, slider_roi, stator_roi, meters_per_pixel)
    if progress is not None:
        progress(f'{path} has only camera frames: tracking {bag.topics[IMAGES_TOPIC].count} '
                 f"frames (slider ROI {parameters['slider_roi']}, stator ROI "
                 f"{parameters['stator_roi']}, {parameters['meters_per_pixel']:.6g} m/px) ...")
    return track_bag(bag, parameters,
                     None if progress is None else lambda n: progress(f'tracked {n} frames'))


def recorded_exposure(path):
    """Return the camera exposure (s) a bag's recording gave its estimator, or None."""
    if not _is_bag(path):
        return None
    from microball_ros.io.bags.reader import open_bag, recorded_parameters

    exposure = recorded_parameters(open_bag(path), 'three_stage_estimator').get('exposure')
    return None if exposure is None else float(exposure)


def longest_valid_run(valid):
    """Return (start, stop) of the longest run of True in a boolean array (stop exclusive)."""
    padded = np.concatenate(([False], np.asarray(valid, dtype=bool), [False]))
    edges = np.flatnonzero(np.diff(padded.astype(int)))
    starts, stops = edges[::2], edges[1::2]
    if starts.size == 0:
        return 0, 0
    best = int(np.argmax(stops - starts))
    return int(starts[best]), int(stops[best])


def steady_periods(time, stator, tolerance=STEADY_TOLERANCE):
    """Return (start, stop) of the longest stretch of steady stator periods (stop exclusive).

    The periods are the intervals between upward crossings of the stator's median (linearly
    interpolated); a period is steady within ``tolerance`` of their median. A servo starting
    (its crank speed ramps up) or stopping makes longer periods at the ends of a run, and the
    FFT of the whole window assumes one steady oscillation: on the sample bag, the first two
    periods of start-up gave velocity errors of 10 % there against 1.2 % in steady motion.
    Return the whole range if every period is steady or there are fewer than three crossings.
    """
    x = np.asarray(stator, dtype=float) - np.median(stator)
    up = np.flatnonzero((x[:-1] < 0) & (x[1:] >= 0))
    if len(up) < 3:
        return 0, len(x)
    crossings = time[up] - x[up] * (time[up + 1] - time[up]) / (x[up + 1] - x[up])
    periods = np.diff(crossings)
    steady = np.abs(periods / np.median(periods) - 1.0) <= tolerance
    if steady.all():
        return 0, len(x)
    first, last = longest_valid_run(steady)
    return int(up[first]) + 1, int(up[last]) + 1


def _valid_window(record, source):
    """Return the longest stretch of the record where both marks were measured."""
    start, stop = longest_valid_run(record.valid)
    if stop - start < 3:
        raise RecordError(f'{source}: no stretch of valid samples (both marks measured)')
    return _stretch(record, start, stop)


def _stretch(record, start, stop):
    span = slice(start, stop)
    return PositionRecord(time=record.time[span], stator_position=record.stator_position[span],
                          slider_position=record.slider_position[span],
                          extra={name: column[span] for name, column in record.extra.items()})


def _check_oscillation(time, stator, dt, source):
    """Return the stator's fundamental frequency, or raise if there is no usable oscillation."""
    if np.ptp(stator) == 0:
        raise RecordError(f'{source}: the stator does not move (no oscillation)')
    frequency = estimation.fundamental_frequency(stator, dt)
    amplitude, _ = friction.fit_sinusoid(time, stator, frequency)
    residual = np.std(stator - np.mean(stator))
    # A sinusoid of amplitude R has standard deviation R / sqrt(2).
    if not (frequency > 0 and amplitude / math.sqrt(2) > 0.5 * residual):
        raise RecordError(f'{source}: no oscillation found in the stator position')
    periods = (time[-1] - time[0] + dt) * frequency
    if periods < MIN_PERIODS:
        raise RecordError(f'{source}: too short: {periods:.1f} stator periods of '
                          f'{frequency:.3g} Hz, need at least {MIN_PERIODS}')
    return frequency


def analyze_record(record: PositionRecord, method='three-stage', epsilon=0.02, fit_epsilon=0.0,
                   exposure=0.0, source='record'):
    """Run the whole analysis on a record; raise RecordError on data that cannot be analysed.

    FitError if the Langevin law cannot be fitted; another static law that cannot be fitted
    shows as a failed entry of ``comparison`` and does not stop the analysis.

    The derivatives, the figures and the memory test use ``method`` (and ``epsilon`` for the
    three-stage method). The friction model of the three-stage method is fitted to the
    velocity at ``epsilon`` and the acceleration at ``fit_epsilon``, 0 by default (nothing
    filtered). The two play different parts in a least-squares fit a = L(v):
    - the acceleration is the response: its noise does not bias the fit, and the intervals
      assume it independent from sample to sample. The amplitude filter leaves the residuals
      smooth and correlated, and the intervals come out too narrow;
    - the velocity is the regressor: its noise biases the fit (errors in variables). The
      unfiltered velocity's noise (0.14 mm/s, 1.5 % of its amplitude) pulls A down and alpha
      up along their correlated valley while A alpha / 3 stays put.
    Measured on the 'paper' scenario (exposure 1/60 s; truth A = 1.2, alpha = 110), 300 s,
    four seeds: this fit gives A = 1.18-1.20, every 95 % interval covering the truth; both
    unfiltered, A = 1.14-1.16 and no interval covers 1.2 (an hour: A = 1.153 [1.143, 1.164]);
    both at 0.02, 40 s: A = 1.184 [1.179, 1.190], too narrow.
    ``exposure`` (s) is the camera's: the three-stage method then undoes the averaging of
    each frame over its exposure (estimation.three_stage).
    """
    if method not in METHODS:
        raise RecordError(f'unknown method {method!r}; choose one of {", ".join(METHODS)}')
    window = _valid_window(record, source)
    dt = float(np.median(np.diff(window.time)))
    frequency = _check_oscillation(window.time, window.stator_position, dt, source)
    start, stop = steady_periods(window.time, window.stator_position)
    if (start, stop) != (0, len(window.time)):
        window = _stretch(window, start, stop)
        frequency = _check_oscillation(window.time, window.stator_position, dt, source)
    time, stator, slider = window.time, window.stator_position, window.slider_position
    options = {'epsilon': epsilon, 'exposure': exposure} if method == 'three-stage' else {}
    est, memory = memory_test.relative_memory_test(time, stator, slider, method,
                                                  frequency=frequency, **options)
    fitted = est
    if method == 'three-stage' and fit_epsilon != epsilon:
        fitted = estimation.estimate_relative(time, stator, slider, method,
                                              **{**options, 'epsilon': fit_epsilon},
                                              fundamental=frequency)
    # The other static laws are auxiliary: one that cannot be fitted is recorded in the
    # comparison (ok false, its error), never raised. The Langevin law is the result.
    comparison = tuple(friction.compare_laws(est.velocity, fitted.acceleration))
    langevin = next(entry for entry in comparison if entry.name == 'langevin')
    if not langevin.ok:
        raise FitError(f'{source}: the Langevin model cannot be fitted: {langevin.error}')
    fit = langevin.fit
    validation = friction.validate(fit.law, time, stator, slider, frequency,
                                   max_periods=VALIDATION_PERIODS)
    return AnalysisResult(
        source=source, method=method, epsilon=float(epsilon), exposure=float(exposure),
        fit_epsilon=float(fit_epsilon) if method == 'three-stage' else None, sample_period=dt,
        fundamental_frequency=float(frequency), window=window,
        samples_invalid=int(np.count_nonzero(~record.valid)), estimate=est, memory=memory,
        fit=fit, comparison=comparison, validation=validation)


def summary_lines(result):
    """Return the human-readable summary printed by ``microball analyze``."""
    model = result.to_json()['model']
    validation = result.validation

    def interval(bounds):
        return '[' + ', '.join('inf' if b is None else f'{b:.4g}' for b in bounds) + ']'

    verdict = 'memoryless' if result.memory.memoryless else 'HYSTERETIC (friction has memory)'
    lines = [
        f'method {result.method}, sample period {result.sample_period * 1e3:.2f} ms, '
        f'fundamental {result.fundamental_frequency:.4f} Hz, '
        f'{len(result.window.time)} samples used ({result.samples_invalid} invalid)',
        f'phase difference a_slider vs v_rel: {result.memory.phase_difference:.4f} '
        f'+- {result.memory.uncertainty:.4f} rad (pi = 3.1416): {verdict}',
        f"Langevin model: A = {model['A']:.4g} m/s^2 {interval(model['A_ci95'])}, "
        f"alpha = {model['alpha']:.4g} s/m {interval(model['alpha_ci95'])}, "
        f"corr {model['A_alpha_correlation']:+.3f}, rmse {model['rmse']:.3g} m/s^2",
        f"low-velocity slope A alpha / 3 = {model['low_velocity_slope']:.4g} 1/s; "
        f'best static law by AIC: {result.comparison[0].name}',  # fitted laws come first
        f'validation (Fig. 9): slider amplitude {validation.slider_amplitude_simulated * 1e3:.4f}'
        f' mm simulated vs {validation.slider_amplitude_measured * 1e3:.4f} mm measured, '
        f'slider-stator phase {validation.phase_simulated:.3f} vs '
        f'{validation.phase_measured:.3f} rad',
    ]
    return lines + comparison_failures(result)


def comparison_failures(result):
    """Return one line per static law of the comparison that could not be fitted."""
    return [f'comparison: {entry.name} not fitted: {entry.error}'
            for entry in result.comparison if not entry.ok]
