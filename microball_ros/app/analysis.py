"""Offline analysis of one position record: the paper's whole Section III-IV pipeline.

positions -> fundamental frequency -> velocity and acceleration (chosen method) -> memory test
-> Langevin fit (and the other static laws for comparison) -> validation by simulation (Fig. 9).
Pure numpy/scipy through the core; the CLI, the report and (later) the nodes call it.
"""

from dataclasses import dataclass
import math
import os

import numpy as np

from microball_ros.core import pipeline
from microball_ros.core.errors import InputError
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
    """Everything ``microball analyze`` reports about one record (a core PipelineResult)."""

    source: str
    pipeline: pipeline.PipelineResult
    window: PositionRecord  # the longest analysed run (figures, validation)
    samples_invalid: int

    method = property(lambda self: self.pipeline.options.method)
    epsilon = property(lambda self: self.pipeline.options.epsilon)
    exposure = property(lambda self: self.pipeline.options.exposure)
    fit_epsilon = property(lambda self: self.pipeline.options.fit_epsilon)
    sample_period = property(lambda self: self.pipeline.sample_period)
    fundamental_frequency = property(lambda self: self.pipeline.frequency)
    estimate = property(lambda self: self.pipeline.estimate)
    memory = property(lambda self: self.pipeline.phase_test)
    loop = property(lambda self: self.pipeline.loop)
    fit = property(lambda self: self.pipeline.fit)
    comparison = property(lambda self: self.pipeline.comparison)
    validation = property(lambda self: self.pipeline.validation)
    warnings = property(lambda self: self.pipeline.warnings)

    def to_json(self):
        """Return the JSON object of the CLI contract (docs/design.md section 5), plus extras.

        An interval end the data cannot bound (an open profile) is written as null.
        """
        result = self.pipeline
        return {
            'source': self.source,
            'method': self.method,
            'epsilon': self.epsilon,
            'epsilon_rule': 'noise-adaptive' if self.epsilon is None else 'fixed',
            'exposure': self.exposure,
            'sample_period': self.sample_period,
            'fundamental_frequency': self.fundamental_frequency,
            'samples_used': result.samples_used,
            'samples_total': result.samples_total,
            'window': {'start': float(self.window.time[0]), 'end': float(self.window.time[-1]),
                       'samples_used': result.samples_used,
                       'samples_invalid': self.samples_invalid},
            'phase_difference': self.memory.phase_difference,
            'phase_uncertainty': self.memory.uncertainty,
            'memoryless': result.memory_verdict == 'memoryless',
            'memory_verdict': result.memory_verdict,
            'memory_test': {**result.loop.to_json(),
                            'phase_test_memoryless': self.memory.memoryless,
                            'periods': self.memory.periods, 'blocks_phase': self.memory.blocks},
            'model': _model_entry(result),
            'comparison': [_comparison_entry(entry) for entry in self.comparison],
            'validation': _validation_entry(self.validation, result),
            'dynamic_model': _dynamic_entry(result.dynamic_model),
            'warnings': [{'code': code, 'message': message} for code, message in self.warnings],
        }


def _model_entry(result):
    fit = result.fit
    if fit is None:
        return {'name': 'langevin', 'A': None, 'alpha': None, 'A_ci95': [None, None],
                'alpha_ci95': [None, None], 'rmse': None, 'identifiable': False,
                'degenerate': False}
    params = fit.params
    entry = {
        'name': fit.name,
        'A': params['A'],
        'alpha': params['alpha'],
        'A_ci95': _interval(fit.ci95['A']),
        'alpha_ci95': _interval(fit.ci95['alpha']),
        'A_alpha_correlation': _finite_or_none(fit.correlation[0, 1]),
        'low_velocity_slope': params['A'] * params['alpha'] / 3.0,
        'identifiable': fit.identifiable,
        'degenerate': result.viscous_limit is not None,
        'rmse': fit.rmse,
        'sample_count': fit.n,
        'fit_epsilon': result.options.fit_epsilon,
    }
    if result.viscous_limit is not None:
        c, interval = result.viscous_limit
        entry['viscous_limit'] = {'c': c, 'c_ci95': _interval(interval)}
    return entry


def _validation_entry(validation, result):
    if validation is None:
        return None
    return {
        'periods': min(VALIDATION_PERIODS, validation.simulated_slider_position.size
                       * result.sample_period * result.frequency),
        'slider_amplitude_simulated': validation.slider_amplitude_simulated,
        'slider_amplitude_measured': validation.slider_amplitude_measured,
        'phase_simulated': validation.phase_simulated,
        'phase_measured': validation.phase_measured,
    }


def _dynamic_entry(dynamic):
    """Return the dynamic model as JSON (core.dynamic_fit.identify_dynamic), None if none."""
    if dynamic is None:
        return None
    validation = dynamic.get('validation')
    return {'name': dynamic['name'], 'params': dynamic['params'],
            'ci95': {name: _interval(b) for name, b in dynamic['ci95'].items()},
            'aic': dynamic['aic'], 'rmse': dynamic['rmse'],
            'fixed': dynamic.get('fixed', {}), 'at_bound': dynamic.get('at_bound', []),
            'static_best': dynamic.get('static_best'), 'delta_aic': dynamic.get('delta_aic'),
            'samples': dynamic.get('samples'),
            'candidates': [{name: entry.get(name, True) for name in (
                'name', 'kind', 'ok', 'error', 'aic', 'rmse', 'determined')}
                for entry in dynamic.get('candidates', ())],
            'validation': None if validation is None else {
                'slider_amplitude_simulated': validation.slider_amplitude_simulated,
                'slider_amplitude_measured': validation.slider_amplitude_measured,
                'phase_simulated': validation.phase_simulated,
                'phase_measured': validation.phase_measured}}


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


def analyze_record(record: PositionRecord, method='three-stage', epsilon=None, fit_epsilon=0.0,
                   exposure=0.0, source='record'):
    """Run the one analysis (core.pipeline) on a record; RecordError if it cannot be used.

    ``epsilon`` None: the noise-adaptive amplitude threshold (the default); a number: the
    paper's fixed threshold. The friction model of the three-stage method is fitted to the
    velocity at that threshold and the acceleration at ``fit_epsilon``, 0 by default (nothing
    filtered): the acceleration is the response, its noise does not bias the fit and the
    intervals need it; the velocity is the regressor, whose noise biases it (errors in
    variables), so it is filtered.
    ``exposure`` (s) is the camera's: the three-stage method then undoes the averaging of
    each frame over it (estimation.three_stage).
    """
    options = pipeline.Options(method=method, epsilon=epsilon, fit_epsilon=fit_epsilon,
                               exposure=exposure, validation_periods=VALIDATION_PERIODS)
    try:
        result = pipeline.analyze_positions(record.time, record.stator_position,
                                            record.slider_position, options=options,
                                            source=source)
    except RecordError:
        raise
    except InputError as error:
        raise RecordError(str(error)) from None
    grid = result.grid
    a, b = max(result.runs, key=lambda r: r[1] - r[0])
    span = slice(a, b)
    seen = grid.measured[span]
    extra = {}
    if len(record.time) == len(grid.time) and not grid.notes:
        extra = {name: column[span][seen] for name, column in record.extra.items()}
    window = PositionRecord(time=grid.time[span][seen], stator_position=grid.stator[span][seen],
                            slider_position=grid.slider[span][seen], extra=extra)
    return AnalysisResult(source=source, pipeline=result, window=window,
                          samples_invalid=int(np.count_nonzero(~record.valid)))


def summary_lines(result):
    """Return the human-readable summary printed by ``microball analyze``, warnings last.

    Statements match the evidence: the memory line states ``memory_verdict`` with the
    statistic that decided it and its one-sigma uncertainty; laws within 2 of the best AIC
    (the difference printed to 0.1) are reported as a tie, with the BIC's preference; a
    degenerate Langevin fit is reported as its viscous limit.
    """
    data = result.to_json()
    model, loop, phase = data['model'], result.loop, result.memory
    verdict = result.pipeline.memory_verdict

    def interval(bounds):
        return '[' + ', '.join('inf' if b is None else f'{b:.4g}' for b in bounds) + ']'

    def ranking():
        fitted = [entry for entry in result.comparison if entry.ok]
        if not fitted:
            return []
        best = fitted[0]
        tied = [e for e in fitted[1:] if round(e.aic - best.aic, 1) <= 2.0]
        by_bic = min(fitted, key=lambda entry: entry.bic).name
        if tied:
            names = [best.name, *(e.name for e in tied)]
            differences = ', '.join(f'{e.aic - best.aic:.1f}' for e in tied)
            plural = 's' if len(tied) > 1 else ''
            return [f'static laws: {", ".join(names[:-1])} and {names[-1]} tie by AIC '
                    f'(difference{plural} {differences}; 2 or less is no verdict); BIC prefers '
                    f'{by_bic}']
        runner = fitted[1] if len(fitted) > 1 else None
        after = ('' if runner is None else f' (next {runner.name}, AIC difference '
                 f'{runner.aic - best.aic:.1f})')
        bic = 'BIC agrees' if by_bic == best.name else f'BIC prefers {by_bic}'
        return [f'static laws: best by AIC {best.name}{after}; {bic}']

    epsilon = ('noise-adaptive threshold' if result.epsilon is None
               else f'epsilon {result.epsilon:g}')
    phase_text = (f'fundamental phase a_slider vs v_rel {phase.phase_difference:.4f} +- '
                  f'{phase.uncertainty:.4f} rad (static friction: pi = 3.1416)')
    loop_text = (f'loop statistic {loop.statistic:+.4f} +- {loop.uncertainty:.4f} rad (1 sigma; '
                 f'0 = memoryless), bound on unresolved harmonics {loop.bias_bound:.4f} rad')
    if result.method == 'three-stage':
        memory_line = f'memory verdict: {verdict}: {loop_text}; {phase_text}'
    else:
        memory_line = (f'memory verdict: {verdict}: by the {result.method} {phase_text}; the '
                       f'loop test on the positions says {loop.verdict}: {loop_text}')
    lines = [
        f'method {result.method} ({epsilon}), sample period {result.sample_period * 1e3:.2f} '
        f'ms, fundamental {result.fundamental_frequency:.4f} Hz, {data["samples_used"]} of '
        f'{data["samples_total"]} samples used ({result.samples_invalid} invalid)',
        memory_line,
    ]
    if result.fit is None:
        lines.append('Langevin model: not fitted (see warnings)')
    elif model['degenerate']:
        limit = model['viscous_limit']
        lines.append(f"Langevin model degenerate: only its viscous limit is determined, c = "
                     f"A alpha / 3 = {limit['c']:.4g} 1/s {interval(limit['c_ci95'])}; A and "
                     f"alpha separately are not; rmse {model['rmse']:.3g} m/s^2")
    else:
        lines.append(f"Langevin model: A = {model['A']:.4g} m/s^2 {interval(model['A_ci95'])}, "
                     f"alpha = {model['alpha']:.4g} s/m {interval(model['alpha_ci95'])}, "
                     f"corr {model['A_alpha_correlation']:+.3f}, rmse {model['rmse']:.3g} "
                     f"m/s^2")
        lines.append(f"low-velocity slope A alpha / 3 = {model['low_velocity_slope']:.4g} 1/s")
    lines += ranking()
    validation = result.validation
    if validation is not None:
        lines.append(
            'validation (Fig. 9): slider amplitude '
            f'{validation.slider_amplitude_simulated * 1e3:.4f}'
            f' mm simulated vs {validation.slider_amplitude_measured * 1e3:.4f} mm measured, '
            f'slider-stator phase {validation.phase_simulated:.3f} vs '
            f'{validation.phase_measured:.3f} rad')
    dynamic = data['dynamic_model']
    if dynamic is not None:
        params = ', '.join(f'{name} = {value:.4g} {interval(dynamic["ci95"][name])}'
                           for name, value in dynamic['params'].items())
        line = f"dynamic model {dynamic['name']}: {params}; AIC {dynamic['aic']:.1f}"
        if dynamic.get('delta_aic') is not None:
            line += f" ({dynamic['delta_aic']:+.1f} against {dynamic['static_best']})"
        lines.append(line)
        others = [f"{entry['name']} {entry['aic']:.1f}"
                  + ('' if entry.get('determined', True) else ' (a parameter not determined)')
                  for entry in dynamic['candidates']
                  if entry['ok'] and entry['name'] != dynamic['name']]
        if others:
            lines.append('  other models by AIC: ' + ', '.join(others))
        check = dynamic['validation']
        if check is not None:
            lines.append(
                f"  its validation (Fig. 9): slider amplitude "
                f"{check['slider_amplitude_simulated'] * 1e3:.4f} mm simulated vs "
                f"{check['slider_amplitude_measured'] * 1e3:.4f} mm measured, phase "
                f"{check['phase_simulated']:.3f} vs {check['phase_measured']:.3f} rad")
    lines += comparison_failures(result)
    return lines + [f'WARNING [{code}]: {message}' for code, message in result.warnings]


def comparison_failures(result):
    """Return one line per static law of the comparison that could not be fitted."""
    return [f'comparison: {entry.name} not fitted: {entry.error}'
            for entry in result.comparison if not entry.ok]
