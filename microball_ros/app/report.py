"""Figures, estimates.csv and summary.txt of ``microball analyze --report DIR`` (Fig. 4-9).

matplotlib with the Agg backend: no display needed. Each figure is drawn from an
AnalysisResult and its analysed window; nothing here changes a number. The model figure and
summary.txt also list the static-law comparison, naming any law that could not be fitted and
why; summary.txt ends with the analysis's warnings (code and message), as printed. The figures
draw the longest analysed run; they do not yet mark the warnings (a later issue).
"""

import csv
import math
import os
import textwrap

import matplotlib

matplotlib.use('Agg')
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from microball_ros.app.analysis import summary_lines  # noqa: E402
from microball_ros.core import estimation, memory  # noqa: E402
from microball_ros.core.pipeline import three_stage_options  # noqa: E402

COMPARED_METHODS = ('forward', 'lowpass-forward', 'three-stage')


def write_estimates_csv(path, est):
    """Write time,relative_velocity,slider_acceleration, one row per estimated sample."""
    with open(path, 'w', newline='') as handle:
        writer = csv.writer(handle)
        writer.writerow(['time', 'relative_velocity', 'slider_acceleration'])
        for row in zip(est.time, est.velocity, est.acceleration, strict=True):
            writer.writerow([repr(float(value)) for value in row])


def _relative_estimates(result, method):
    """Return the estimates of method on the analysed window (the result's own if it matches)."""
    if method == result.method:
        return result.estimate
    window = result.window
    options = ({**three_stage_options(result.pipeline.options),
                'fundamental': result.fundamental_frequency} if method == 'three-stage' else {})
    return estimation.estimate_relative(window.time, window.stator_position,
                                        window.slider_position, method, **options)


def _first_periods(time, periods, frequency, skip=0):
    """Select the samples of ``periods`` periods after the first ``skip`` periods."""
    start = time[0] + skip / frequency
    return (time >= start) & (time < start + periods / frequency)


def figure_positions(result, path):
    """Fig. 6/9: measured stator and slider positions, and the slider simulated with the model."""
    window, validation = result.window, result.validation
    shown = _first_periods(window.time, 4, result.fundamental_frequency)
    fig, ax = plt.subplots(figsize=(8, 4))
    t = window.time[shown]
    ax.plot(t, window.stator_position[shown] * 1e3, '.-', label='stator (measured)')
    ax.plot(t, window.slider_position[shown] * 1e3, '.-', label='slider (measured)')
    # A slider moved by friction alone has no preferred rest point: align the means (over the
    # plotted stretch, which the validation simulated; the slider may drift over a long record).
    simulated = validation.simulated_slider_position
    offset = np.nanmean(window.slider_position[shown]) - np.nanmean(simulated[shown])
    ax.plot(t, (simulated[shown] + offset) * 1e3, '--',
            label='slider (simulated with the fitted model, mean aligned)')
    ax.set_xlabel('time (s)')
    ax.set_ylabel('position (mm)')
    ax.set_title(f'Positions; slider amplitude {validation.slider_amplitude_measured * 1e3:.3f} '
                 f'mm measured, {validation.slider_amplitude_simulated * 1e3:.3f} mm simulated')
    ax.legend(loc='upper right', fontsize=8)
    ax.grid(alpha=0.3)
    _save(fig, path)


def figure_methods(result, path):
    """Fig. 4/7: slider acceleration against relative velocity for each estimation method."""
    fig, axes = plt.subplots(1, len(COMPARED_METHODS), figsize=(13, 4), sharey=True)
    window, frequency = result.window, result.fundamental_frequency
    for ax, method in zip(axes, COMPARED_METHODS, strict=True):
        est = _relative_estimates(result, method)
        test = memory.memory_test(est.time, est.velocity, est.acceleration, frequency)
        # Skip the causal low-pass filter's start-up.
        shown = _first_periods(est.time, 6, frequency, skip=2)
        ax.plot(est.velocity[shown] * 1e3, est.acceleration[shown], '-', lw=0.8)
        ax.set_title(f'{method}: phase {test.phase_difference:.3f} rad', fontsize=10)
        ax.set_xlabel('relative velocity (mm/s)')
        ax.grid(alpha=0.3)
    axes[0].set_ylabel('slider acceleration (m/s$^2$)')
    fig.suptitle(f'a_slider vs v_rel, {window.time.size} samples at '
                 f'{1 / result.sample_period:.3g} fps (pi = 3.142 means no loop)', fontsize=10)
    _save(fig, path)


def figure_model(result, path):
    """Fig. 8: the fitted Langevin model over the estimated samples (the data alone if none)."""
    est, fit = result.estimate, result.fit
    if fit is None:
        fig, ax = plt.subplots(figsize=(7, 4.5))
        ax.plot(est.velocity * 1e3, -est.acceleration, '.', ms=2, alpha=0.5)
        ax.set_title('no Langevin model could be fitted (see the warnings)')
        _save(fig, path)
        return
    fig, ax = plt.subplots(figsize=(7, 4.5))
    ax.plot(est.velocity * 1e3, -est.acceleration, '.', ms=2, alpha=0.5,
            label=f'{result.method} estimates')
    span = np.max(np.abs(est.velocity))
    v = np.linspace(-span, span, 400)
    params = fit.params
    ax.plot(v * 1e3, fit.law.force(v), 'r-',
            label=f"Langevin A = {params['A']:.3g} m/s$^2$, alpha = {params['alpha']:.3g} s/m")
    ax.set_xlabel('relative velocity (mm/s)')
    ax.set_ylabel('friction per unit mass, -a_slider (m/s$^2$)')
    ax.set_title(f'Friction model (rmse {fit.rmse:.3g} m/s$^2$, {fit.n} samples)')
    ax.legend(fontsize=8, loc='upper left')
    ax.text(0.98, 0.02, '\n'.join(comparison_lines(result)), transform=ax.transAxes,
            ha='right', va='bottom', fontsize=7, family='monospace',
            bbox={'facecolor': 'white', 'alpha': 0.8, 'edgecolor': '0.8'})
    ax.grid(alpha=0.3)
    _save(fig, path)


def comparison_lines(result, width=70):
    """Return the static-law comparison as short lines: AIC ranking, then each failed law."""
    lines = ['static laws by AIC:']
    for entry in result.comparison:
        if entry.ok:
            lines.append(f'  {entry.name:<16} AIC {entry.aic:10.1f}  rmse {entry.rmse:.3g}')
        else:
            lines.extend(textwrap.wrap(f'{entry.name} not fitted: {entry.error}', width,
                                       initial_indent='  ', subsequent_indent='    '))
    return lines


def figure_compensation(result, path):
    """Fig. 5: v_rel from the three-stage method with and without stage 3 (compensation).

    Against the ground truth when the record carries ``true_relative_velocity`` (a simulated
    record), else against each other.
    """
    window, frequency = result.window, result.fundamental_frequency
    common = {**three_stage_options(result.pipeline.options), 'fundamental': frequency}
    with_stage3 = estimation.estimate_relative(window.time, window.stator_position,
                                               window.slider_position, **common)
    without = estimation.estimate_relative(window.time, window.stator_position,
                                           window.slider_position, compensate=False, **common)
    truth = window.extra.get('true_relative_velocity')
    fig, ax = plt.subplots(figsize=(8, 4))
    shown = _first_periods(with_stage3.time, 3, frequency)
    t = with_stage3.time[shown]
    if truth is not None:
        reference = truth[with_stage3.index][shown]
        for label, est in (('without stage 3', without), ('with stage 3', with_stage3)):
            error = est.velocity[shown] - reference
            rel = math.sqrt(np.mean(error ** 2) / np.mean(reference ** 2))
            ax.plot(t, error * 1e3, label=f'{label}: relative rms error {rel:.2%}')
        ax.set_ylabel('v_rel error vs ground truth (mm/s)')
    else:
        ax.plot(t, without.velocity[shown] * 1e3, label='without stage 3')
        ax.plot(t, with_stage3.velocity[shown] * 1e3, label='with stage 3')
        ax.set_ylabel('relative velocity (mm/s)')
    ax.set_xlabel('time (s)')
    ax.set_title('Amplitude compensation (stage 3) of the three-stage algorithm')
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    _save(fig, path)


def _save(fig, path):
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def write_summary(path, result):
    """Write the printed summary of ``microball analyze`` and the static-law comparison."""
    with open(path, 'w') as handle:
        handle.write('\n'.join([*summary_lines(result), *comparison_lines(result, width=99)]))
        handle.write('\n')


def write_report(result, directory):
    """Write estimates.csv, summary.txt and the figures into directory; return the paths."""
    os.makedirs(directory, exist_ok=True)
    paths = [os.path.join(directory, 'estimates.csv'), os.path.join(directory, 'summary.txt')]
    write_estimates_csv(paths[0], result.estimate)
    write_summary(paths[1], result)
    for name, draw in (('positions.png', figure_positions), ('methods.png', figure_methods),
                       ('model.png', figure_model), ('compensation.png', figure_compensation)):
        path = os.path.join(directory, name)
        draw(result, path)
        paths.append(path)
    return paths
