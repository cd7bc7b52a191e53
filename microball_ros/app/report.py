"""Figures, estimates.csv and summary.txt of ``microball analyze --report DIR`` (Fig. 4-9).

matplotlib with the Agg backend: no display needed; nothing here changes a number. One sign
convention throughout, the paper's eq. 2: ``a_slider`` is the slider acceleration, positive
along the position axis, equal to the friction force per unit slider mass; ``v_rel`` is
v_slider - v_stator. A static law L is drawn as a_slider = -L(v_rel). Every figure carries a
note (``figure_notes``) when memory was found, the memory test could not decide, or the
analysis raised a warning; figures that show a part of the record say which part.

The figures (``FIGURES``): positions (Fig. 6), derivatives (v_rel and a_slider against time),
methods (Fig. 4/7, a_slider against v_rel per method, markers), model (Fig. 8, the fitted law
over the samples and binned means, with a residual panel), compensation (Fig. 5, against the
ground truth when the record has it: a simulated CSV's true_* columns or a bag's
/bench/ground_truth) and validation (Fig. 9). Each is drawn by ``figure_*(result, path,
truth=AUTO)``: ``truth`` is the ground_truth() dict or None, looked up when AUTO (write_report
reads it once for all).

estimates.csv keeps its contract header ``time,relative_velocity,slider_acceleration``
exactly (docs/design.md section 5: a comment or renamed header would break CSV readers of the
contract); its units and sign convention go into the sibling ``estimates.units.json`` and
summary.txt.
"""

import csv
import io
import json
import math
import os
import textwrap

import matplotlib

matplotlib.use('Agg')
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from PIL import Image  # noqa: E402

from microball_ros.app.analysis import summary_lines  # noqa: E402
from microball_ros.core import estimation, memory  # noqa: E402
from microball_ros.core.errors import BagError  # noqa: E402
from microball_ros.core.pipeline import three_stage_options  # noqa: E402

COMPARED_METHODS = ('forward', 'lowpass-forward', 'three-stage')
ESTIMATES_HEADER = ('time', 'relative_velocity', 'slider_acceleration')
ESTIMATES_UNITS = {
    'time': {'unit': 's', 'meaning': 'header.stamp of the frame (mid-exposure)'},
    'relative_velocity': {'unit': 'm/s', 'meaning': 'v_rel = v_slider - v_stator'},
    'slider_acceleration': {'unit': 'm/s^2', 'meaning': 'a_slider, positive along the position '
                            'axis; = friction force per unit slider mass (eq. 2)'},
}
GROUND_TRUTH_TOPIC = '/bench/ground_truth'
DPI = 100
V_LABEL = 'v_rel = v_slider - v_stator (mm/s)'
A_LABEL = 'a_slider = F_fric / M_slider (m/s$^2$)'
NOTE_COLOR = '#b00000'
AUTO = 'auto'  # a figure's truth argument: look the ground truth up (ground_truth)


# --- estimates.csv and summary.txt -------------------------------------------------------------

def write_estimates_csv(path, est):
    """Write time,relative_velocity,slider_acceleration, one row per estimated sample."""
    with open(path, 'w', newline='') as handle:
        writer = csv.writer(handle)
        writer.writerow(ESTIMATES_HEADER)
        for row in zip(est.time, est.velocity, est.acceleration, strict=True):
            writer.writerow([repr(float(value)) for value in row])


def write_estimates_units(path, result):
    """Write estimates.units.json: each column of estimates.csv with its unit and meaning."""
    with open(path, 'w') as handle:
        json.dump({'file': 'estimates.csv', 'method': result.method,
                   'columns': ESTIMATES_UNITS}, handle, indent=2)
        handle.write('\n')


def units_line():
    """Return the one line of summary.txt that gives estimates.csv's units."""
    return 'estimates.csv columns: ' + ', '.join(
        f"{name} ({entry['unit']}; {entry['meaning']})" for name, entry in ESTIMATES_UNITS.items())


def comparison_lines(result, width=70):
    """Return the static-law comparison: AIC, its difference from the best, BIC, rmse; failures."""
    fitted = [entry for entry in result.comparison if entry.ok]
    lines = ['static laws (an AIC difference of 2 or less is a tie):']
    best = fitted[0].aic if fitted else 0.0
    for entry in fitted:
        lines.append(f'  {entry.name:<15} AIC {entry.aic:9.1f} (+{entry.aic - best:.1f}) '
                     f'BIC {entry.bic:9.1f} rmse {entry.rmse:.3g}')
    for entry in result.comparison:
        if not entry.ok:
            lines.extend(textwrap.wrap(f'{entry.name} not fitted: {entry.error}', width,
                                       initial_indent='  ', subsequent_indent='    '))
    return lines


def write_summary(path, result):
    """Write the printed summary of ``microball analyze``, the comparison and the CSV units."""
    with open(path, 'w') as handle:
        handle.write('\n'.join([*summary_lines(result), *comparison_lines(result, width=99),
                                units_line()]))
        handle.write('\n')


# --- what every figure must say -----------------------------------------------------------------

def figure_notes(result):
    """Return the notes every figure shows: the memory verdict unless memoryless, each warning.

    One string per note; warnings as ``[code] message``. Empty when the record is memoryless
    and nothing warns.
    """
    notes = []
    verdict, loop = result.pipeline.memory_verdict, result.loop
    if verdict != 'memoryless':
        said = {'memory': 'MEMORY FOUND (hysteresis): a static law cannot describe these data',
                'undetermined': 'MEMORY UNDETERMINED: the data cannot decide whether friction '
                                'is static'}[verdict]
        notes.append(f'{said}; loop statistic {loop.statistic:+.4f} +- {loop.uncertainty:.4f} '
                     f'rad (1 sigma), bound on unresolved harmonics {loop.bias_bound:.4f} rad')
    notes += [f'[{code}] {message}' for code, message in result.warnings]
    return notes


def _wrapped_notes(result, width_inches):
    width = max(40, int(width_inches * 15))
    lines = []
    for note in figure_notes(result):
        lines += textwrap.wrap(note, width, subsequent_indent='    ')
    return lines


def _save(fig, path, result):
    """Lay out the figure, add the notes below it (growing it to fit) and write the PNG."""
    lines = _wrapped_notes(result, fig.get_figwidth())
    width, height = fig.get_size_inches()
    extra = (len(lines) * 7.5 * 1.35 / 72 + 0.15) if lines else 0.0
    fig.set_size_inches(width, height + extra)
    fig.tight_layout(rect=(0, extra / (height + extra), 1, 1))
    if lines:
        fig.text(0.01, 0.01, '\n'.join(lines), ha='left', va='bottom', fontsize=7.5,
                 color=NOTE_COLOR, family='monospace')
    buffer = io.BytesIO()
    fig.savefig(buffer, format='png', dpi=DPI)
    plt.close(fig)
    # A 256-colour palette: a plot needs no more, and the PNG shrinks about threefold.
    with Image.open(buffer) as image:
        image.convert('RGB').quantize(256).save(path, format='PNG', optimize=True)


# --- ground truth ------------------------------------------------------------------------------

def ground_truth(result):
    """Return the record's ground truth as a dict of arrays, or None if it has none.

    Keys 'time' (s), 'relative_velocity' (m/s), 'slider_acceleration' (m/s^2), 'source'.
    A simulated CSV carries it in its true_* columns (on the analysed window); a bag of
    ``microball experiment --output`` in /bench/ground_truth (microball_msgs/BenchState,
    stamped like the frames), decoded with rosbags from the bag's own schema.
    """
    extra = result.window.extra
    if 'true_relative_velocity' in extra and 'true_slider_acceleration' in extra:
        return {'time': result.window.time,
                'relative_velocity': np.asarray(extra['true_relative_velocity'], dtype=float),
                'slider_acceleration': np.asarray(extra['true_slider_acceleration'],
                                                  dtype=float),
                'source': 'the CSV true_* columns'}
    source = str(result.source)
    if os.path.isdir(source) or source.endswith('.mcap'):
        return bag_ground_truth(source)
    return None


def bag_ground_truth(path):
    """Return a bag's /bench/ground_truth as ground_truth() does, or None if it has none."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    from microball_ros.io.bags.reader import open_bag

    bag = open_bag(path)
    info = bag.topics.get(GROUND_TRUTH_TOPIC)
    if info is None or not info.count:
        return None
    store = get_typestore(Stores.EMPTY)
    try:
        store.register(get_types_from_msg(bag.definition(info.type), info.type))
        rows = []
        for message in bag.messages(GROUND_TRUTH_TOPIC):
            state = store.deserialize_cdr(message.data, info.type)
            rows.append((state.header.stamp.sec * 1_000_000_000 + state.header.stamp.nanosec,
                         state.relative_velocity, state.slider_acceleration))
    except BagError:
        raise
    except Exception as error:  # noqa: B902 - rosbags' errors vary; report them in one line
        raise BagError(f'{path}: cannot read {GROUND_TRUTH_TOPIC}: '
                       f'{" ".join(str(error).split())}') from None
    rows.sort()
    table = np.array(rows, dtype=float).reshape(-1, 3)
    return {'time': table[:, 0] / 1e9, 'relative_velocity': table[:, 1],
            'slider_acceleration': table[:, 2], 'source': f"the bag's {GROUND_TRUTH_TOPIC}"}


def truth_at(truth, time, name, dt):
    """Return truth[name] at the stamps ``time`` (nearest stamp within dt/4, else NaN)."""
    stamps, values = truth['time'], truth[name]
    time = np.asarray(time, dtype=float)
    right = np.clip(np.searchsorted(stamps, time), 1, len(stamps) - 1)
    nearest = np.where(np.abs(stamps[right - 1] - time) <= np.abs(stamps[right] - time),
                       right - 1, right)
    return np.where(np.abs(stamps[nearest] - time) <= dt / 4, values[nearest], np.nan)


# --- spans -------------------------------------------------------------------------------------

def _span(time, frequency, periods, skip=0.0):
    """Return (mask, text) for ``periods`` periods after ``skip`` periods of ``time``."""
    total = (time[-1] - time[0]) * frequency
    start = time[0] + skip / frequency
    mask = (time >= start) & (time < start + periods / frequency)
    shown = time[mask]
    if not shown.size:
        return mask, 'nothing'
    if periods >= total - skip:
        return mask, f'all {total:.1f} periods (t = {time[0]:.2f}-{time[-1]:.2f} s)'
    return mask, (f'periods {skip + 1:.0f}-{skip + periods:.0f} of {total:.1f} '
                  f'(t = {shown[0]:.2f}-{shown[-1]:.2f} s of {time[0]:.2f}-{time[-1]:.2f} s)')


def _binned(v, a, bins=24):
    """Return (centres, means, standard deviations, counts) of a in equal-width bins of v."""
    edges = np.linspace(np.min(v), np.max(v), bins + 1)
    which = np.clip(np.digitize(v, edges) - 1, 0, bins - 1)
    counts = np.bincount(which, minlength=bins)
    sums = np.bincount(which, a, minlength=bins)
    squares = np.bincount(which, a * a, minlength=bins)
    keep = counts >= 3
    means = sums[keep] / counts[keep]
    spread = np.sqrt(np.maximum(squares[keep] / counts[keep] - means ** 2, 0.0))
    return 0.5 * (edges[:-1] + edges[1:])[keep], means, spread, counts[keep]


def _legend_outside(ax, **options):
    ax.legend(loc='upper left', bbox_to_anchor=(1.01, 1.0), fontsize=8, borderaxespad=0,
              **options)


# --- the figures -------------------------------------------------------------------------------

def figure_positions(result, path, truth=AUTO):
    """Fig. 6: measured stator and slider positions, the whole window and a stated zoom.

    The whole window is drawn per stator period (range as a band, mean as a line: drift and
    steadiness show at any length); the zoom shows every frame of the first periods.
    """
    window, frequency = result.window, result.fundamental_frequency
    t = window.time
    shown, span = _span(t, frequency, 4)
    fig, (whole, zoom) = plt.subplots(2, 1, figsize=(10, 6), height_ratios=(1, 1.4))
    period = np.floor((t - t[0]) * frequency).astype(int)
    count = np.bincount(period)
    full = count > 0
    middle = (np.bincount(period, t)[full] / count[full])
    for name, x in (('stator', window.stator_position), ('slider', window.slider_position)):
        x = x * 1e3
        low = np.full(count.size, np.inf)
        high = np.full(count.size, -np.inf)
        np.minimum.at(low, period, x)
        np.maximum.at(high, period, x)
        mean = np.bincount(period, x)[full] / count[full]
        line, = whole.plot(middle, mean, '-', lw=1.2, label=f'{name}: mean per period')
        whole.fill_between(middle, low[full], high[full], color=line.get_color(), alpha=0.25,
                           lw=0, label=f'{name}: range per period')
        zoom.plot(t[shown], x[shown], '.-', lw=0.7, ms=5, color=line.get_color(),
                  label=f'{name} (measured)')
    whole.axvspan(t[shown][0], t[shown][-1], color='0.8', zorder=0, label='zoomed below')
    whole.set_title(f'whole analysed window, t = {t[0]:.2f}-{t[-1]:.2f} s, per stator period',
                    fontsize=10)
    zoom.set_title(f'zoom: {span}; markers are the frames', fontsize=10)
    zoom.set_xlabel('time (s)')
    for ax in (whole, zoom):
        ax.set_ylabel('position (mm)')
        ax.grid(alpha=0.3)
        _legend_outside(ax)
    fig.suptitle('Measured positions (Fig. 6)', fontsize=11)
    _save(fig, path, result)


def figure_derivatives(result, path, truth=AUTO):
    """v_rel and a_slider against time (chosen method), with the ground truth when known."""
    est, frequency = result.estimate, result.fundamental_frequency
    shown, span = _span(est.time, frequency, 4, skip=1)
    truth = ground_truth(result) if truth is AUTO else truth
    fig, axes = plt.subplots(2, 1, figsize=(10, 6), sharex=True)
    t = est.time[shown]
    for ax, values, name, scale, label in (
            (axes[0], est.velocity, 'relative_velocity', 1e3, V_LABEL),
            (axes[1], est.acceleration, 'slider_acceleration', 1.0, A_LABEL)):
        if truth is not None:
            ax.plot(t, truth_at(truth, t, name, result.sample_period) * scale, '-', color='0.5',
                    lw=1.0, label=f'ground truth ({truth["source"]})')
        ax.plot(t, values[shown] * scale, 'o', ms=3.5, label=f'{result.method} estimate')
        ax.set_ylabel(label, fontsize=9)
        ax.grid(alpha=0.3)
        _legend_outside(ax)
    axes[1].set_xlabel('time (s)')
    fig.suptitle(f'Velocity and acceleration estimates against time, {span}', fontsize=10)
    _save(fig, path, result)


def _relative_estimates(result, method):
    """Return the estimates of method on the analysed window (the result's own if it matches)."""
    if method == result.method:
        return result.estimate
    window = result.window
    options = ({**three_stage_options(result.pipeline.options),
                'fundamental': result.fundamental_frequency} if method == 'three-stage' else {})
    return estimation.estimate_relative(window.time, window.stator_position,
                                        window.slider_position, method, **options)


def figure_methods(result, path, truth=AUTO):
    """Fig. 4/7: a_slider against v_rel for each estimation method, one marker per sample."""
    fig, axes = plt.subplots(1, len(COMPARED_METHODS), figsize=(13, 4.4), sharey=True,
                             sharex=True)
    frequency = result.fundamental_frequency
    for ax, method in zip(axes, COMPARED_METHODS, strict=True):
        est = _relative_estimates(result, method)
        test = memory.memory_test(est.time, est.velocity, est.acceleration, frequency)
        shown, _ = _span(est.time, frequency, math.inf, skip=2)  # the low-pass start-up
        ax.plot(est.velocity[shown] * 1e3, est.acceleration[shown], '.', ms=2.5, alpha=0.5)
        mine = ' (analysed)' if method == result.method else ''
        ax.set_title(f'{method}{mine}\nfundamental phase {test.phase_difference:.3f} +- '
                     f'{test.uncertainty:.2g} rad', fontsize=10)
        ax.set_xlabel(V_LABEL, fontsize=9)
        ax.grid(alpha=0.3)
    axes[0].set_ylabel(A_LABEL, fontsize=9)
    seconds = result.window.time[-1] - result.window.time[0] - 2 / frequency
    fig.suptitle(f'a_slider vs v_rel: every sample after the first 2 periods ({seconds:.1f} s, '
                 f'{1 / result.sample_period:.3g} fps); a phase of pi = 3.142 means no loop',
                 fontsize=10)
    _save(fig, path, result)


def figure_model(result, path, truth=AUTO):
    """Fig. 8: the fitted law over the samples and their binned means; residuals below."""
    est, fit, pipe = result.estimate, result.fit, result.pipeline
    v, a = est.velocity, pipe.fit_acceleration
    fig = plt.figure(figsize=(12, 7))
    grid = fig.add_gridspec(2, 2, width_ratios=(2, 1.25), height_ratios=(2.2, 1))
    top = fig.add_subplot(grid[0, 0])
    bottom = fig.add_subplot(grid[1, 0], sharex=top)
    side = fig.add_subplot(grid[:, 1])
    side.axis('off')
    rising = np.gradient(v) >= 0
    branches = ((rising, 'v_rel rising', 'tab:blue'), (~rising, 'v_rel falling', 'tab:orange'))
    for mask, label, color in branches:
        top.plot(v[mask] * 1e3, a[mask], '.', ms=2, alpha=0.35, color=color,
                 label=f'samples as fitted, {label}')
    centres, means, spread, _ = _binned(v, a)
    top.errorbar(centres * 1e3, means, yerr=spread, fmt='s', ms=3.5, color='k', lw=0.8,
                 capsize=2, label='bin mean +- 1 s.d. of its samples', zorder=3)
    span = np.max(np.abs(v))
    grid_v = np.linspace(-span, span, 400)
    degenerate = pipe.viscous_limit is not None
    if fit is not None:
        params = fit.params
        curve = ('Langevin fit (degenerate: A, alpha not determined)' if degenerate else
                 f"Langevin -L(v_rel): A = {params['A']:.3g} m/s$^2$, alpha = "
                 f"{params['alpha']:.3g} s/m")
        top.plot(grid_v * 1e3, fit.law.acceleration(grid_v), '-', color='red', lw=1.0,
                 label=curve, zorder=4)
        if degenerate:
            c, (lo, hi) = pipe.viscous_limit
            top.plot(grid_v * 1e3, -c * grid_v, '--', color='purple', lw=1.0, zorder=4,
                     label=f'viscous limit -c v_rel: c = {c:.4g} 1/s [{lo:.4g}, {hi:.4g}]')
        residual = a - fit.law.acceleration(v)
        for mask, _, color in branches:
            bottom.plot(v[mask] * 1e3, residual[mask], '.', ms=2, alpha=0.35, color=color)
        centres, means, spread, counts = _binned(v, residual)
        bottom.errorbar(centres * 1e3, means, yerr=2 * spread / np.sqrt(counts), fmt='s-',
                        ms=3, lw=0.8, color='k', capsize=2)
        bottom.axhline(0, color='red', lw=0.8)
        bottom.set_title('residuals; black: bin mean +- 2 s.e. (samples taken as independent)',
                         fontsize=8)
        title = (f'Friction model (Fig. 8): Langevin fit to {fit.n} samples, rmse '
                 f'{fit.rmse:.3g} m/s$^2$')
        if degenerate:
            title += '; degenerate: only its viscous limit is determined'
    else:
        bottom.text(0.5, 0.5, 'no Langevin fit: no residuals', transform=bottom.transAxes,
                    ha='center', va='center')
        title = 'Friction model (Fig. 8): no Langevin model could be fitted (see the notes)'
    if pipe.memory_verdict != 'memoryless':
        title += f"\nmemory verdict '{pipe.memory_verdict}'"
        if fit is not None:
            title += ': the curve is the best static description only, not the friction'
    fig.suptitle(title, fontsize=10)
    top.set_ylabel(A_LABEL, fontsize=9)
    top.grid(alpha=0.3)
    bottom.set_ylabel('a_slider - model (m/s$^2$)', fontsize=9)
    bottom.set_xlabel(V_LABEL, fontsize=9)
    bottom.grid(alpha=0.3)
    side.legend(*top.get_legend_handles_labels(), loc='upper left', fontsize=8,
                markerscale=3, borderaxespad=0)
    side.text(0.0, 0.62, '\n'.join(_model_text(result)), transform=side.transAxes, ha='left',
              va='top', fontsize=7, family='monospace')
    _save(fig, path, result)


def _model_text(result):
    said = [line for line in summary_lines(result) if line.startswith('static laws:')]
    lines = [wrapped for line in said for wrapped in textwrap.wrap(line, 62)] + ['']
    lines += comparison_lines(result, width=62)
    dynamic = result.pipeline.dynamic_model
    if dynamic is not None:
        lines += ['', f"dynamic model {dynamic['name']} (AIC {dynamic['aic']:.1f}, rmse "
                      f"{dynamic['rmse']:.3g}):"]
        lines += [f'  {name} = {value:.4g} [{dynamic["ci95"][name][0]:.4g}, '
                  f'{dynamic["ci95"][name][1]:.4g}]' for name, value in dynamic['params'].items()]
    return lines


def compensation(result, truth=AUTO):
    """Return (time, v_rel with stage 3, without, truth or None, relative rms errors).

    The three-stage v_rel (m/s) of the analysed window with and without stage 3 (amplitude
    compensation), the ground truth at the same stamps (NaN where none matched; None without
    ground truth) and, with a ground truth, {'with stage 3': e, 'without stage 3': e}: each
    estimate's rms error over the rms of the truth, over the matched samples.
    """
    window, frequency = result.window, result.fundamental_frequency
    common = {**three_stage_options(result.pipeline.options), 'fundamental': frequency}
    with_stage3 = estimation.estimate_relative(window.time, window.stator_position,
                                               window.slider_position, **common)
    without = estimation.estimate_relative(window.time, window.stator_position,
                                           window.slider_position, compensate=False, **common)
    truth = ground_truth(result) if truth is AUTO else truth
    errors = {}
    reference = None
    if truth is not None:
        reference = truth_at(truth, with_stage3.time, 'relative_velocity', result.sample_period)
        known = np.isfinite(reference)
        for label, est in (('without stage 3', without), ('with stage 3', with_stage3)):
            error = est.velocity[known] - reference[known]
            errors[label] = math.sqrt(np.mean(error ** 2) / np.mean(reference[known] ** 2))
    return with_stage3.time, with_stage3.velocity, without.velocity, reference, errors


def figure_compensation(result, path, truth=AUTO):
    """Fig. 5: three-stage v_rel with and without stage 3, against the ground truth if known."""
    truth = ground_truth(result) if truth is AUTO else truth
    time, with_stage3, without, reference, errors = compensation(result, truth)
    shown, span = _span(time, result.fundamental_frequency, 3, skip=1)
    t = time[shown]
    fig, ax = plt.subplots(figsize=(10, 4.2))
    if reference is not None:
        known = int(np.count_nonzero(np.isfinite(reference)))
        for label, velocity in (('without stage 3', without), ('with stage 3', with_stage3)):
            ax.plot(t, (velocity - reference)[shown] * 1e3, 'o-', ms=3, lw=0.7,
                    label=f'{label}: relative rms error {errors[label]:.2%} ({known} samples)')
        ax.axhline(0, color='0.5', lw=0.8)
        ax.set_ylabel('v_rel estimate - ground truth (mm/s)', fontsize=9)
        source = f'ground truth from {truth["source"]}'
    else:
        ax.plot(t, without[shown] * 1e3, 'o-', ms=3, lw=0.7, label='without stage 3')
        ax.plot(t, with_stage3[shown] * 1e3, 'o-', ms=3, lw=0.7, label='with stage 3')
        ax.set_ylabel(V_LABEL, fontsize=9)
        source = 'no ground truth in this record'
    ax.set_xlabel('time (s)')
    fig.suptitle(f'Amplitude compensation (stage 3) of the three-stage algorithm (Fig. 5); '
                 f'{source}\n{span}', fontsize=10)
    _legend_outside(ax)
    ax.grid(alpha=0.3)
    _save(fig, path, result)


def figure_validation(result, path, truth=AUTO):
    """Fig. 9: measured slider against the slider simulated with the identified model(s)."""
    window, validation = result.window, result.validation
    dynamic = result.pipeline.dynamic_model
    shown, span = _span(window.time, result.fundamental_frequency, 6)
    t = window.time[shown]
    measured = window.slider_position[shown]
    fig, ax = plt.subplots(figsize=(10, 4.2))
    ax.plot(t, measured * 1e3, 'o', ms=3.5, color='tab:orange', label='slider (measured)')
    ax.plot(t, window.stator_position[shown] * 1e3, '-', color='0.6', lw=0.8,
            label='stator (measured, drives the simulation)')
    runs = [('Langevin (static)', validation, '-')]
    if dynamic is not None and dynamic.get('validation') is not None:
        runs.append((f"{dynamic['name']} (dynamic)", dynamic['validation'], '--'))
    lines = []
    for name, run, style in runs:
        if run is None:
            continue
        # Friction alone moves the slider: it has no rest point, so the means are aligned.
        simulated = run.simulated_slider_position[shown]
        offset = np.nanmean(measured) - np.nanmean(simulated)
        ax.plot(t, (simulated + offset) * 1e3, style, lw=1.2,
                label=f'slider simulated with {name}, mean aligned')
        lines.append(f'{name}: amplitude {run.slider_amplitude_simulated * 1e3:.3f} mm vs '
                     f'{run.slider_amplitude_measured * 1e3:.3f} mm measured, slider-stator '
                     f'phase {run.phase_simulated:.3f} vs {run.phase_measured:.3f} rad')
    if not lines:
        lines.append('no model was fitted: nothing to simulate')
    ax.set_xlabel('time (s)')
    ax.set_ylabel('position (mm)')
    fig.suptitle('Validation by simulation (Fig. 9; RK4, 1 ms), ' + span + '\n'
                 + '\n'.join(lines), fontsize=9)
    _legend_outside(ax)
    ax.grid(alpha=0.3)
    _save(fig, path, result)


FIGURES = (('positions.png', figure_positions), ('derivatives.png', figure_derivatives),
           ('methods.png', figure_methods), ('model.png', figure_model),
           ('compensation.png', figure_compensation), ('validation.png', figure_validation))


def write_report(result, directory):
    """Write estimates.csv (+ units), summary.txt and the figures; return the paths written."""
    os.makedirs(directory, exist_ok=True)
    paths = [os.path.join(directory, name) for name in
             ('estimates.csv', 'estimates.units.json', 'summary.txt')]
    write_estimates_csv(paths[0], result.estimate)
    write_estimates_units(paths[1], result)
    write_summary(paths[2], result)
    truth = ground_truth(result)
    for name, draw in FIGURES:
        path = os.path.join(directory, name)
        draw(result, path, truth)
        paths.append(path)
    return paths
