"""The fitting half of core.pipeline: static laws, honest intervals, validation, warnings.

``identify`` completes a PipelineResult whose estimates and memory tests are done: every static
law fitted (core.friction.compare_laws), each law's 95 % intervals widened by the ratio of a
batch-means (sandwich) variance to the independent-noise one (the residuals of estimated
accelerations are correlated: the intervals of an independent-noise fit are too narrow or too
wide by that ratio), the Langevin law validated by simulation (Fig. 9), a degenerate Langevin
fit reported as its viscous limit, a dynamic model (core.dynamic_fit: lags, Dahl, LuGre)
identified when the loop test finds memory, and the warnings.
"""

from dataclasses import replace
import math

import numpy as np
from scipy import stats

from microball_ros.core import friction
from microball_ros.core.dynamic_fit import identify_dynamic
from microball_ros.core.errors import FitError, InputError

BLOCK_PERIODS = 2.0


def _blocks(time, frequency):
    return np.floor((time - time[0]) * frequency / BLOCK_PERIODS).astype(int)


def variance_ratio(law, v, a, blocks, velocity_noise=None):
    """Return per fitted parameter the batch-means variance over the independent-noise one.

    ``velocity_noise``: optional replicas [replica, sample] of the error of v; the variance
    they cause (linearised: d theta = -(J^T J)^-1 J^T (dr/dv dv)) is added to the batch
    means', which cannot see an error coherent over the whole record.
    """
    residual = law.acceleration(v) - a
    gradient = np.column_stack(law.force_gradient(v))
    jacobian = -gradient
    hessian = jacobian.T @ jacobian
    try:
        inverse = np.linalg.inv(hessian)
    except np.linalg.LinAlgError:
        return np.ones(gradient.shape[1])
    scores = jacobian * residual[:, None]
    count = blocks.max() + 1
    per_block = np.zeros((count, gradient.shape[1]))
    np.add.at(per_block, blocks, scores)
    per_block -= per_block.mean(axis=0)
    sandwich = inverse @ (per_block.T @ per_block) @ inverse * count / max(count - 1, 1)
    iid = inverse * np.sum(residual ** 2) / max(len(v) - gradient.shape[1], 1)
    extra = np.zeros(gradient.shape[1])
    if velocity_noise is not None and len(velocity_noise):
        step = 1e-6 * float(np.max(np.abs(v)))
        slope = (law.acceleration(v + step) - law.acceleration(v - step)) / (2 * step)
        shifts = -inverse @ (jacobian.T @ (slope[:, None] * np.asarray(velocity_noise).T))
        extra = np.mean(shifts ** 2, axis=1)
    with np.errstate(invalid='ignore', divide='ignore'):
        ratio = (np.diag(sandwich) + extra) / np.diag(iid)
    return np.where(np.isfinite(ratio), ratio, 1.0)


def widen(fit, ratio, blocks_count):
    """Return the fit with each interval's log-distance from the estimate scaled by sqrt(ratio).

    With few blocks the batch variance is itself uncertain: the Student t quantile of
    blocks - 1 degrees of freedom over the normal one scales it further.
    """
    student = stats.t.ppf(0.975, max(blocks_count - 1, 1)) / stats.norm.ppf(0.975)
    scale = np.sqrt(np.maximum(ratio, 1.0)) * student
    ci95 = {}
    for (name, value), s in zip(fit.params.items(), scale, strict=True):
        lo, hi = fit.ci95[name]
        lo = value * (lo / value) ** s if lo > 0 else 0.0
        hi = value * (hi / value) ** s if math.isfinite(hi) else math.inf
        ci95[name] = (float(lo), float(hi))
    return replace(fit, ci95=ci95)


def _viscous_limit(fit, v, a, blocks, comparison=(), velocity_noise=None):
    """Return (c, 95 % interval) of the viscous limit c = A alpha / 3, batch-means widened.

    The viscous law's own fit (linear in c) where the comparison has it: in the linear regime
    the Langevin law's A and alpha are not separately determined, and when v_rel is nearly a
    pure sinusoid their covariance is singular, so the delta method's variance can come out 0
    (a zero-width interval). Else the delta method on the Langevin fit.
    """
    viscous = next((entry for entry in comparison if entry.name == 'viscous' and entry.ok),
                   None)
    if viscous is not None:
        lo, hi = viscous.ci95['c']
        if 0 < lo < hi < math.inf:
            return viscous.params['c'], (lo, hi)
    A, alpha = fit.params['A'], fit.params['alpha']
    c = A * alpha / 3
    gradient = np.array([alpha / 3, A / 3])
    ratio = float(np.max(np.maximum(variance_ratio(fit.law, v, a, blocks, velocity_noise),
                                    1.0)))
    variance = float(gradient @ fit.covariance @ gradient) * ratio
    count = int(blocks.max()) + 1
    half = stats.t.ppf(0.975, max(count - 1, 1)) * math.sqrt(max(variance, 0.0))
    return c, (c - half, c + half)


def _honest(comparison, v, a, blocks, velocity_noise=None):
    out = []
    count = int(blocks.max()) + 1
    for entry in comparison:
        if entry.ok:
            ratio = variance_ratio(entry.fit.law, v, a, blocks, velocity_noise)
            entry = replace(entry, fit=widen(entry.fit, ratio, count))
        out.append(entry)
    return tuple(out)


def _longest_measured(result, runs):
    grid = result.grid
    a, b = max(runs, key=lambda r: r[1] - r[0])
    seen = grid.measured[a:b]
    return grid.time[a:b][seen], grid.stator[a:b][seen], grid.slider[a:b][seen]


def _validate(law, result, runs):
    t, stator, slider = _longest_measured(result, runs)
    try:
        with np.errstate(all='ignore'):
            validation = friction.validate(law, t, stator, slider, result.frequency,
                                           max_periods=result.options.validation_periods)
    except (InputError, ValueError, ArithmeticError):  # a law the integrator cannot follow
        return None
    numbers = (validation.slider_amplitude_simulated, validation.phase_simulated)
    return validation if all(math.isfinite(x) for x in numbers) else None


def _inadequate(validation):
    amplitude, phase = VALIDATION_TOLERANCE
    if validation is None:
        return None
    error = (validation.slider_amplitude_simulated / validation.slider_amplitude_measured - 1)
    lag = validation.phase_simulated - validation.phase_measured
    if abs(error) > amplitude or abs(lag) > phase:
        return ('the simulated slider (Fig. 9) moves '
                f'{validation.slider_amplitude_simulated * 1e3:.3g}'
                f' mm vs {validation.slider_amplitude_measured * 1e3:.3g} mm measured '
                f'({error:+.1%}), phase {validation.phase_simulated:.3f} vs '
                f'{validation.phase_measured:.3f} rad: the model does not reproduce the motion, '
                'its intervals do not describe the friction')
    return None


VALIDATION_TOLERANCE = (0.05, 0.05)


def identify(result, runs, per_period):
    """Return the result with fits, validation, viscous limit, dynamic model and warnings."""
    warnings = [('gaps', note) for note in result.grid.notes]
    v, a = result.velocity_for_fit, result.fit_acceleration
    blocks = _blocks(result.estimate.time, result.frequency)
    # Only the Langevin law's intervals are reported as the model's: profile ones; the laws
    # fitted for comparison get Wald intervals (the profiles were most of the time of a long
    # record: 2.2 of 3.9 s for an hour at 30 fps).
    comparison = _honest(tuple(friction.compare_laws(v, a, profile=('langevin',))), v, a,
                         blocks, result.fit_velocity_noise)
    langevin = next(entry for entry in comparison if entry.name == 'langevin')
    fit = langevin.fit if langevin.ok else None
    if per_period < 7.0:
        warnings.append(('near-nyquist', f'{per_period:.2f} samples per stator period: the '
                         'harmonics of the friction are not resolved and the estimates are '
                         'biased; film faster or drive slower'))
    loop = result.loop
    if result.options.method != 'three-stage':
        warnings.append(('method-phase-error', f'{result.options.method} estimates shift the '
                         "phase of a_slid against v_rel (the paper's Fig. 7): the verdict "
                         f'is theirs; the loop test on the positions says {loop.verdict}'))
    if loop.verdict == 'undetermined':
        warnings.append(('memory-undetermined', f'the loop test cannot decide: statistic '
                         f'{loop.statistic:+.3f} rad, sigma {loop.uncertainty:.3f}, bound on '
                         f'unresolved harmonics {loop.bias_bound:.3f} rad'))
    viscous_limit = validation = dynamic = None
    if fit is None:
        warnings.append(('fit-failed', f'the Langevin law cannot be fitted: {langevin.error}'))
    else:
        reach = fit.params['alpha'] * float(np.max(np.abs(v)))
        if reach > SATURATION_REACH:
            warnings.append(('saturated', f'alpha max|v_rel| = {reach:.3g}: the friction '
                             'saturates, its sharp knee has harmonics beyond Nyquist and the '
                             'Langevin parameters are biased'))
        lo, hi = fit.ci95['alpha']
        if reach <= SATURATION_REACH and (not (lo > 0 and math.isfinite(hi)) or reach < 0.3):
            viscous_limit = _viscous_limit(fit, v, a, blocks, comparison,
                                           result.fit_velocity_noise)
            c = viscous_limit[0]
            warnings.append(('degenerate', f'the data do not reach the saturation of the '
                             f'Langevin law (alpha max|v_rel| = {reach:.2g}): only its viscous '
                             f'limit A alpha / 3 = {c:.4g} 1/s is determined'))
        note = _noise_bias(fit, v, a, result.fit_velocity_noise)
        if note:
            warnings.append(('noise-bias', note))
        validation = _validate(fit.law, result, runs)
        message = _inadequate(validation)
        if message:
            warnings.append(('model-inadequate', message))
    if result.memory_verdict == 'memory' and loop.verdict == 'memory':
        dynamic = identify_dynamic(replace(result, fit=fit, comparison=comparison), blocks)
        if dynamic is not None:
            dynamic['validation'] = (None if dynamic['law'] is None
                                     else _validate(dynamic['law'], result, runs))
            note = _dynamic_bias(dynamic, float(np.max(np.abs(v))) * result.sample_period)
            if note:
                warnings.append(('dynamic-biased', note))
    return replace(result, fit=fit, comparison=comparison, validation=validation,
                   viscous_limit=viscous_limit, dynamic_model=dynamic, warnings=tuple(warnings))


def _noise_bias(fit, v, a, velocity_noise):
    """Return why the Langevin fit is biased by the noise in v_rel, or None (SIMEX-style).

    The noise replicas are v_rel's error once more: refitted with v + that error (the noise
    variance doubled), an estimate that moves by more than half its interval is biased by
    about that much already (errors in variables: the bias grows as the noise variance), which
    no interval width describes. Measured on bench/independent (4 seeds each): slow-linear
    (15 fps, 0.5 Hz, alpha max|v_rel| 0.08) moves log alpha by +0.6 to +0.74 against a
    half-width of 0.27-0.40 (alpha 1500-1900 for 110); paper and alpha-20 by 0.01 or less.
    """
    if velocity_noise is None or not len(velocity_noise):
        return None
    moves = []
    for error in velocity_noise[:NOISE_BIAS_REFITS]:
        try:
            refit = friction.fit_least_squares(v + error, a, 'langevin', intervals='wald')
        except (InputError, FitError, ValueError, ArithmeticError):
            continue
        moves.append([math.log(refit.params[name] / value)
                      for name, value in fit.params.items()])
    if not moves:
        return None
    for name, move in zip(fit.params, np.mean(moves, axis=0), strict=True):
        lo, hi = fit.ci95[name]
        if not (lo > 0 and math.isfinite(hi)):
            continue
        half = math.log(hi / lo) / 2.0
        if abs(move) > 0.5 * half:
            return (f'the noise in v_rel biases the Langevin fit: with the noise doubled '
                    f'{name} moves by {math.expm1(move):+.0%}, more than half its interval '
                    f'(+-{math.expm1(half):.0%}); the estimates are biased by about as much: '
                    'film with less noise, faster, or over a longer stroke')
    return None


NOISE_BIAS_REFITS = 6


def _dynamic_bias(dynamic, slid_per_frame):
    """Return why the dynamic model's intervals are known to be biased, or None.

    Measured on bench/independent (6 seeds, 30 fps; core.dynamic_fit): Dahl's sigma0 comes out
    ~4 % high with 0 of 6 intervals covering when its presliding length Fc / sigma0 is slid
    within about a frame at a reversal; LuGre's six parameters are not separately
    identifiable at 30 fps (precise, biased: Fs 0.03 for 0.25).
    """
    if dynamic['name'] == 'lugre':
        return ("LuGre's six parameters are not separately identifiable from these records: "
                'the fit describes the loop, its intervals do not bound the physical '
                'parameters')
    if dynamic['name'] == 'dahl':
        length = dynamic['params']['Fc'] / dynamic['params']['sigma0']
        if length < PRESLIDING_FRAMES * slid_per_frame:
            return (f"Dahl's presliding length {length * 1e6:.3g} um is slid in "
                    f'{length / slid_per_frame:.2g} frames at the fastest sliding: the camera '
                    'does not resolve it and sigma0 is biased (its interval does not cover)')
    return None


# Dahl's presliding length must span this many frames of the fastest sliding to be resolved.
PRESLIDING_FRAMES = 3.0


# alpha max|v_rel| beyond this: a_slid's harmonics reach Nyquist at ordinary frame rates and
# alias; measured (bench_coverage): 3.3 at the 3 mm stroke biases alpha 4 % low, no interval
# covers.
SATURATION_REACH = 2.0
