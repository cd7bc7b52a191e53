"""Velocity and acceleration from sampled positions: the three-stage algorithm, baselines.

Section III of Tan, Modafe & Ghodssi (ACC 2005): finite differences, the three-stage algorithm
(center difference, amplitude-based FFT filtering, per-component amplitude compensation), the
baselines it is compared with (forward and center differences, low-pass + forward differences,
Savitzky-Golay, spectral). The memory test that uses these estimates is core.memory; the
harmonic model they share (fundamental frequency, design matrix) is core.harmonics.

Conventions shared by every estimator:

* input: positions ``x`` (m), finite, sampled every ``dt`` (s);
* output: an :class:`Estimate` holding only the samples where both velocity and acceleration
  are defined, trimmed rather than padded with NaN: ``index`` points into the input and
  ``time = index * dt`` (:func:`estimate_relative` puts the caller's stamps there instead);
* every sample keeps the time stamp of the position sample it belongs to. In particular the
  forward differences are stamped at their newest sample ``n`` and so keep their delay: that
  delay is the phase error the paper criticises, not something to correct here.
"""

from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any

import numpy as np
import numpy.typing as npt
from scipy import fft, signal

from microball_ros.core.errors import InputError
from microball_ros.core.harmonics import (
    check_positions,
    fundamental_frequency,
    harmonic_design,
    harmonics_below_nyquist,
)

# The three-stage options of the paper, and the ones recommended here (see three_stage).
PAPER_OPTIONS = MappingProxyType({'whole_periods': False, 'slow_band': 0.0, 'edges': 'trim',
                                  'detrend': False, 'max_compensation': np.inf,
                                  'exposure': 0.0, 'noise_floor': False, 'harmonics': False})
RECOMMENDED_OPTIONS = MappingProxyType({'whole_periods': True, 'slow_band': 0.5, 'edges': 'trim',
                                        'detrend': False, 'max_compensation': 10.0,
                                        'exposure': 0.0, 'noise_floor': 4.0,
                                        'harmonics': False})

@dataclass(frozen=True, eq=False)
class Estimate:
    """Velocity and acceleration estimates aligned sample for sample.

    ``time`` (s), ``velocity`` (m/s) and ``acceleration`` (m/s^2) have one entry per estimated
    sample; ``index`` is the position sample each belongs to. ``velocity_frequencies`` and
    ``acceleration_frequencies`` (Hz) list the Fourier components an FFT-based method kept
    (empty for the others). ``options`` records the parameters actually used, including
    resolved defaults such as the ``fundamental`` (Hz) of whole-period windowing.
    """

    time: np.ndarray
    velocity: np.ndarray
    acceleration: np.ndarray
    index: np.ndarray
    method: str
    sample_period: float
    velocity_frequencies: np.ndarray = field(default_factory=lambda: np.empty(0))
    acceleration_frequencies: np.ndarray = field(default_factory=lambda: np.empty(0))
    options: dict = field(default_factory=dict)

def _estimate(method, dt, index, velocity, acceleration, **extra):
    return Estimate(time=index * dt, velocity=velocity, acceleration=acceleration, index=index,
                    method=method, sample_period=float(dt), **extra)


def forward_difference(x: npt.ArrayLike, dt: float) -> Estimate:
    """Estimate velocity and acceleration by the paper's forward differences.

    ``v[n] = (x[n] - x[n-1]) / dt`` and ``a[n] = (x[n] - 2 x[n-1] + x[n-2]) / dt^2``, stamped
    at sample n (n = 2 .. N-1). For ``X sin(w t)`` the velocity is scaled by
    ``m1 = sin(w dt/2) / (w dt/2)`` and lags by ``w dt/2`` (eq. 7), the acceleration is scaled
    by ``m1^2`` and lags by ``w dt`` (eq. 9).
    """
    x = check_positions(x, dt, 3)
    velocity = np.diff(x) / dt
    acceleration = np.diff(x, 2) / dt ** 2
    return _estimate('forward', dt, np.arange(2, x.size), velocity[1:], acceleration)


def center_difference(x: npt.ArrayLike, dt: float) -> Estimate:
    """Estimate velocity and acceleration by center differences (eqs. 5, 6).

    ``v[n] = (x[n+1] - x[n-1]) / (2 dt)`` and ``a[n] = (x[n+1] - 2 x[n] + x[n-1]) / dt^2`` for
    n = 1 .. N-2. For ``X sin(w t)`` both are in phase with the truth, scaled by
    ``sin(w dt) / (w dt)`` and ``(sin(w dt/2) / (w dt/2))^2`` (eqs. 10, 11).
    """
    x = check_positions(x, dt, 3)
    velocity = (x[2:] - x[:-2]) / (2 * dt)
    acceleration = np.diff(x, 2) / dt ** 2
    return _estimate('center', dt, np.arange(1, x.size - 1), velocity, acceleration)


def _velocity_gain(wd):
    """Return the compensation ``w D / sin(w D)``; inf from Nyquist on, where v_c is zero."""
    inside = wd < np.pi * (1 - 1e-9)
    return np.where(inside, 1 / np.sinc(np.where(inside, wd, 0) / np.pi), np.inf)


def _acceleration_gain(wd):
    """Return the compensation ``((w D/2) / sin(w D/2))^2``, at most (pi/2)^2 at Nyquist."""
    return 1 / np.sinc(wd / (2 * np.pi)) ** 2


def _velocity_noise_shape(wd):
    """Return the amplitude response |sin(w D)| of center-difference velocity to white noise."""
    return np.abs(np.sin(wd))


def _acceleration_noise_shape(wd):
    """Return the amplitude response sin^2(w D/2) of the center second difference."""
    return np.sin(wd / 2) ** 2


def _filter_and_compensate(crude, dt, epsilon, gain, noise_shape, options):
    """Apply stages 2 and 3 to a center-difference signal; return it and the kept frequencies.

    The DC component (exact for a ramp) and the components below the slow band are always
    kept; neither counts as the largest amplitude, so a drift cannot raise the threshold.
    """
    n = crude.size
    spectrum = fft.rfft(crude)
    frequencies = fft.rfftfreq(n, dt)
    amplitude = 2 * np.abs(spectrum) / n
    amplitude[0] /= 2
    if n % 2 == 0:
        amplitude[-1] /= 2
    slow = frequencies < options['slow_band'] * (options['fundamental'] or 0.0)
    slow[0] = True
    threshold = np.full(amplitude.shape, epsilon * amplitude[~slow].max(initial=0.0))
    wd = 2 * np.pi * frequencies * dt
    if options['noise_floor'] and np.any(~slow):
        # White position noise, seen through the difference: its amplitude follows the shape.
        shape = noise_shape(wd)
        usable = ~slow & (shape > 1e-3)
        if np.any(usable):
            level = np.median(amplitude[usable] / shape[usable])
            threshold = np.minimum(threshold, options['noise_floor'] * level * shape)
    keep = slow | (amplitude > threshold)
    if options['harmonics'] and options['fundamental']:
        # The bin nearest each harmonic of the fundamental: periodic motion lives there.
        cycles = n * options['fundamental'] * dt
        order = np.arange(1, int(frequencies[-1] / options['fundamental']) + 1)
        keep[np.clip(np.round(order * cycles).astype(int), 0, len(keep) - 1)] = True
    factor = gain(wd)
    keep &= np.isfinite(factor) & (factor <= options['max_compensation'])
    # Undo the exposure's averaging (sinc(f T), in phase) along with the differences' gain.
    factor = factor / np.sinc(frequencies * options['exposure'])
    scale = np.where(keep, factor if options['compensate'] else 1.0, 0.0)
    return fft.irfft(spectrum * scale, n), frequencies[keep]


def _whole_period_length(n, cycles_per_sample):
    """Return a length <= n spanning a whole number of periods as exactly as samples allow.

    Among the lengths of m periods, m from half the record to all of it, pick the one whose
    rounding to whole samples leaves the smallest fraction of a period (the longest on ties).
    """
    most = int(np.floor((n + 0.5) * cycles_per_sample))
    if most < 1:
        raise InputError(f'{n} samples are less than one period of the fundamental')
    periods = np.arange((most + 1) // 2, most + 1)
    lengths = np.minimum(np.round(periods / cycles_per_sample), n)
    mismatch = np.abs(lengths * cycles_per_sample - periods)
    best = len(periods) - 1 - np.argmin(mismatch[::-1])
    return int(lengths[best])


def _trend(t, x, frequency, order, dt):
    """Fit a polynomial drift (Legendre series) jointly with harmonics of the fundamental.

    Fitting the Fourier series at the same time keeps the oscillation out of the drift (a
    straight line fitted alone to m periods of a sine picks up a slope of order 1/m^2).
    """
    drift = np.polynomial.legendre.legvander(2 * (t - t[0]) / (t[-1] - t[0]) - 1, order)
    design = np.column_stack(
        [drift, harmonic_design(t, frequency, harmonics_below_nyquist(frequency, dt), -1)])
    coefficients = np.linalg.lstsq(design, x, rcond=None)[0]
    return np.polynomial.Legendre(coefficients[:order + 1], domain=[t[0], t[-1]])


def three_stage(x: npt.ArrayLike, dt: float, epsilon: float = 0.02, *, paper: bool = False,
                compensate: bool = True, whole_periods: bool | None = None,
                slow_band: float | None = None, edges: str | None = None,
                detrend: int | bool | None = None, max_compensation: float | None = None,
                exposure: float | None = None, noise_floor: float | bool | None = None,
                harmonics: bool | None = None, fundamental: float | None = None) -> Estimate:
    """Estimate velocity and acceleration by the paper's three-stage algorithm (Fig. 3).

    1. center difference of the positions;
    2. FFT, dropping every component whose amplitude is <= ``epsilon`` times the largest one;
    3. scaling of each kept component at w_k by ``(w_k dt) / sin(w_k dt)`` (velocity) or
       ``((w_k dt/2) / sin(w_k dt/2))^2`` (acceleration), then the inverse FFT.

    ``compensate=False`` skips stage 3 (Fig. 5). The DC component is always kept and never
    scaled (center differences of a ramp are exact). ``paper=True`` starts from PAPER_OPTIONS,
    the algorithm as published; the default starts from RECOMMENDED_OPTIONS. Each option
    passed explicitly overrides the preset:

    * ``whole_periods``: estimate only the first samples spanning the whole number of periods
      of ``fundamental`` (Hz; estimated from ``x`` by :func:`fundamental_frequency` if None)
      that best fits the sampling, so a periodic signal does not leak into extra FFT bins that
      the filter then cuts (the paper's "extra frequency components" of Section III-B);
    * ``noise_floor``: False for the paper's rule. A number k lowers the filter's threshold to
      k times the noise floor where that is below ``epsilon`` times the largest component:
      a component is kept if it exceeds either. The floor follows white position noise
      through the difference (|sin w D| for velocity, sin^2(w D/2) for acceleration), scaled
      by the median of amplitude / shape above the slow band, which for a periodic record
      analysed over whole periods is noise (the harmonics are a handful of bins). Noise
      amplitudes are Rayleigh distributed, so a pure-noise bin exceeds k times their median
      with probability 2^(-k^2), 1.5e-5 for k = 4. Why: a fixed epsilon deletes the
      friction's real harmonics below epsilon of the fundamental. Measured by
      bench/bench_estimation.py ('paper' scenario, 5 seeds, relative RMS error of v_rel /
      a_slid at 1, 3, 10 um noise): epsilon 0.02 alone 2.3 / 2.3 %, 2.3 / 2.3 %, 2.1 / 3.4 %;
      with k = 4: 0.46 / 0.43 %, 0.62 / 0.50 %, 1.3 / 2.7 %;
    * ``harmonics``: True keeps, besides what the threshold keeps, the bin nearest every
      harmonic of ``fundamental`` below Nyquist (the factor cap still applies). Why: a steady
      periodic record has its signal at the harmonics only, and a real harmonic under the
      threshold is a bias, not noise. At 15 fps, 1.5 Hz (10 samples per period, 2 um) the third
      harmonic of a Langevin slider's v_rel (0.4 % of the fundamental) sinks under 3 x the
      noise floor; fitting without it put the Langevin law's curvature 3 times too low (A +60 %,
      alpha -40 %, no interval covering). The noise in those few bins is unbiased;
    * ``slow_band``: components below ``slow_band * fundamental`` are never filtered out. Slow
      drift of the slider is real motion with well under ``epsilon`` of the largest velocity
      amplitude, which the paper's filter deletes; position noise hardly reaches these
      frequencies (it is multiplied by w). Better than removing a polynomial (``detrend``):
      it needs no order and adapts to the record length;
    * ``edges``: 'trim' loses one sample at each end, as center differences need both
      neighbours; 'circular' differences the window as periodic, keeps every sample and makes
      stages 1 + 3 the exact spectral derivative of the kept components, but the jump between
      the window's ends (any drift) then spreads over every bin, and circular differences
      sum to zero so the mean velocity is lost: it needs whole periods and ``detrend``;
    * ``detrend``: order of a polynomial fitted jointly with the harmonics of the fundamental
      and removed before stage 1, its exact derivatives added back afterwards (so the drift
      velocity stays in the estimate); False for none;
    * ``max_compensation``: the velocity factor diverges at Nyquist (x59 at 14.75 Hz for
      30 fps). Components whose factor exceeds it are dropped, never amplified; the Nyquist
      bin itself is always dropped from the velocity, which center differences cancel. The
      acceleration factor is at most (pi/2)^2 = 2.47.
    * ``exposure``: the camera's exposure time (s), 0 for instantaneous samples. A camera
      frame measures a moving mark's position averaged over the exposure (its blurred
      centroid), which scales the component at f by sinc(f T) = sin(pi f T) / (pi f T) with no
      phase shift; stage 3 then divides that out too. At 1/60 s: 0.4 % at 2.95 Hz, 3.6 % at
      its third harmonic, enough to bias a Langevin fit (tracked frames of the paper
      scenario: A +1.1 %, alpha -1.2 % without it).

    Measured (test_core_estimation: mean of 10 records of 19.7 s at 30 fps, 2.95 Hz, 2nd and
    3rd harmonics in v_rel, 200 um slider drift, 3 um noise; relative RMS error of v_rel /
    a_slid): paper 7.1 % / 6.3 % (leakage, worst at the ends); + whole periods 0.60 % / 0.72 %;
    + slow band 0.41 % / 0.72 %; + noise floor (all recommended) 0.41 % / 0.68 % (this record's
    harmonics are 5-10 %, above epsilon; see noise_floor for the bench's 1 % ones); circular
    edges with detrend=1 instead of trim 0.80 % / 0.77 % (drift that is not a polynomial still
    jumps at the wrap); center difference alone 8.0 % / 4.5 %. Without noise or drift the
    slow-band errors are 0.31 % / 0.70 %, and 0.05 % with epsilon = 0: what remains is
    harmonics under the threshold.
    """
    x = check_positions(x, dt, 5)
    options: dict[str, Any] = dict(PAPER_OPTIONS if paper else RECOMMENDED_OPTIONS)
    explicit = {'whole_periods': whole_periods, 'slow_band': slow_band, 'edges': edges,
                'detrend': detrend, 'max_compensation': max_compensation,
                'exposure': exposure, 'noise_floor': noise_floor, 'harmonics': harmonics}
    options.update({name: value for name, value in explicit.items() if value is not None})
    if options['edges'] not in ('trim', 'circular'):
        raise InputError(f"edges must be 'trim' or 'circular', got {options['edges']!r}")
    order = options['detrend']
    integer = isinstance(order, (int, np.integer)) and not isinstance(order, bool)
    if not (order is False or integer and order >= 0):
        raise InputError(f'detrend must be a polynomial order >= 0 or False, got {order!r}')
    if not epsilon >= 0:
        raise InputError(f'epsilon must be >= 0, got {epsilon!r}')
    if not 0 <= options['exposure'] <= dt:
        raise InputError(f"exposure must be in [0, {dt:g}] s (at most the sample period), got "
                         f"{options['exposure']!r}")
    needs_fundamental = options['whole_periods'] or options['slow_band'] or order is not False
    if fundamental is None and needs_fundamental:
        fundamental = fundamental_frequency(x, dt)
    options.update(epsilon=epsilon, compensate=compensate, fundamental=fundamental)
    circular = options['edges'] == 'circular'

    # Length of the FFT'd center differences, and the positions they need.
    length = x.size if circular else x.size - 2
    if options['whole_periods']:
        length = _whole_period_length(length, options['fundamental'] * dt)
    window = x[:length] if circular else x[:length + 2]
    t = np.arange(window.size) * dt
    if order is not False:
        trend = _trend(t, window, fundamental, order, dt)
        window = window - trend(t)
    if circular:
        after, middle, before = np.roll(window, -1), window, np.roll(window, 1)
        index = np.arange(length)
    else:
        after, middle, before = window[2:], window[1:-1], window[:-2]
        index = np.arange(1, length + 1)

    velocity, velocity_frequencies = _filter_and_compensate(
        (after - before) / (2 * dt), dt, epsilon, _velocity_gain, _velocity_noise_shape, options)
    acceleration, acceleration_frequencies = _filter_and_compensate(
        (after - 2 * middle + before) / dt ** 2, dt, epsilon, _acceleration_gain,
        _acceleration_noise_shape, options)
    if order is not False:
        velocity += trend.deriv(1)(index * dt)
        acceleration += trend.deriv(2)(index * dt)
    return _estimate('three-stage', dt, index, velocity, acceleration,
                     velocity_frequencies=velocity_frequencies,
                     acceleration_frequencies=acceleration_frequencies, options=options)


def lowpass_forward(x: npt.ArrayLike, dt: float, cutoff: float = 6.0, order: int = 2) -> Estimate:
    """Low-pass the positions with a causal Butterworth filter, then forward-difference them.

    The paper's Fig. 7(b) (cutoff in Hz). The filter starts in steady state at the first
    sample. Being causal it delays every component by its phase lag on top of the
    forward-difference lag; applied to both positions, the lag cancels between a_slid and v_rel
    only up to the extra half-sample of the forward difference.
    """
    x = check_positions(x, dt, 3)
    if not 0 < cutoff < 0.5 / dt:
        raise InputError(f'cutoff must be in (0, {0.5 / dt:g}) Hz, got {cutoff!r}')
    sos = signal.butter(order, cutoff, fs=1 / dt, output='sos')
    smooth, _ = signal.sosfilt(sos, x, zi=signal.sosfilt_zi(sos) * x[0])
    result = forward_difference(smooth, dt)
    return _estimate('lowpass-forward', dt, result.index, result.velocity, result.acceleration,
                     options={'cutoff': cutoff, 'order': order})


def savitzky_golay(x: npt.ArrayLike, dt: float, window: int = 7, polyorder: int = 5) -> Estimate:
    """Estimate velocity and acceleration by Savitzky-Golay differentiating filters.

    Local least-squares polynomials of ``polyorder`` over ``window`` samples
    (scipy.signal.savgol_filter, deriv=1 and 2): zero phase inside the record, polynomial fits
    at the edges (mode='interp'), so every sample is estimated.
    """
    x = check_positions(x, dt, window)
    if not 2 <= polyorder < window:
        raise InputError(f'need 2 <= polyorder < window, got polyorder {polyorder}, '
                         f'window {window}')
    velocity = signal.savgol_filter(x, window, polyorder, deriv=1, delta=dt)
    acceleration = signal.savgol_filter(x, window, polyorder, deriv=2, delta=dt)
    return _estimate('savgol', dt, np.arange(x.size), velocity, acceleration,
                     options={'window': window, 'polyorder': polyorder})


def spectral(x: npt.ArrayLike, dt: float, cutoff: float | None = None) -> Estimate:
    """Differentiate in the frequency domain, keeping the components at or below ``cutoff``.

    Multiplies the FFT by ``i w`` and ``-w^2`` (the Nyquist bin is dropped from the velocity);
    cutoff None keeps everything. The record is treated as periodic, so it should span whole
    periods without drift: a mismatch between its ends rings over the whole record.
    """
    x = check_positions(x, dt, 3)
    spectrum = fft.rfft(x)
    frequencies = fft.rfftfreq(x.size, dt)
    keep = frequencies <= (np.inf if cutoff is None else cutoff)
    keep_velocity = keep & (frequencies < 0.5 / dt)
    iw = 2j * np.pi * frequencies
    velocity = fft.irfft(spectrum * iw * keep_velocity, x.size)
    acceleration = fft.irfft(spectrum * iw ** 2 * keep, x.size)
    return _estimate('spectral', dt, np.arange(x.size), velocity, acceleration,
                     velocity_frequencies=frequencies[keep_velocity],
                     acceleration_frequencies=frequencies[keep], options={'cutoff': cutoff})


_METHODS = MappingProxyType({
    'three-stage': three_stage,
    'forward': forward_difference,
    'center': center_difference,
    'lowpass-forward': lowpass_forward,
    'savgol': savitzky_golay,
    'spectral': spectral,
})
METHODS = tuple(_METHODS)


def estimate(x: npt.ArrayLike, dt: float, method: str = 'three-stage', **options: Any) -> Estimate:
    """Estimate velocity and acceleration of ``x`` by the named method (one of METHODS)."""
    if method not in _METHODS:
        raise InputError(f'unknown method {method!r}; choose one of {", ".join(METHODS)}')
    return _METHODS[method](x, dt, **options)


def estimate_relative(time: npt.ArrayLike, stator: npt.ArrayLike, slider: npt.ArrayLike,
                      method: str = 'three-stage', **options: Any) -> Estimate:
    """Estimate the relative velocity and the slider acceleration on one time base.

    As in the paper, the velocity is estimated from the relative position
    ``slider - stator`` and the acceleration from the slider position (for the linear methods
    this equals ``v_slider - v_stator``; the amplitude filter of the three-stage method is not
    linear). Both go through the same method and options, with the three-stage fundamental
    taken from the stator unless given, so the two share their samples. ``time`` holds the
    stamps of the positions (uniform sampling); the result's ``time`` holds theirs.
    """
    time = np.asarray(time, dtype=float)
    stator = np.asarray(stator, dtype=float)
    slider = np.asarray(slider, dtype=float)
    if not time.shape == stator.shape == slider.shape:
        raise InputError(f'time, stator and slider differ in shape: '
                         f'{time.shape}, {stator.shape}, {slider.shape}')
    if time.size < 3:
        raise InputError(f'need at least 3 samples, got {time.size}')
    steps = np.diff(time)
    dt = float(np.median(steps))
    if not (dt > 0 and np.all(np.abs(steps - dt) <= 0.01 * dt)):
        raise InputError('time stamps must increase uniformly (within 1 % of the period)')
    if method == 'three-stage' and options.get('fundamental') is None:
        options['fundamental'] = fundamental_frequency(stator, dt)
    relative = estimate(slider - stator, dt, method, **options)
    absolute = estimate(slider, dt, method, **options)
    return Estimate(time=time[relative.index], velocity=relative.velocity,
                    acceleration=absolute.acceleration, index=relative.index, method=method,
                    sample_period=dt, velocity_frequencies=relative.velocity_frequencies,
                    acceleration_frequencies=absolute.acceleration_frequencies,
                    options=relative.options)
