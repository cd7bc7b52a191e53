"""Velocity and acceleration from sampled positions, and the friction memory (hysteresis) test.

Section III of Tan, Modafe & Ghodssi (ACC 2005): finite differences, the three-stage algorithm
(center difference, amplitude-based FFT filtering, per-component amplitude compensation), the
baselines it is compared with, the fundamental frequency of a record and the phase test that
decides whether friction is a static function of the relative velocity.

Conventions shared by every estimator:

* input: positions ``x`` (m), finite, sampled every ``dt`` (s);
* output: an :class:`Estimate` holding only the samples where both velocity and acceleration
  are defined, trimmed rather than padded with NaN: ``index`` points into the input and
  ``time = index * dt`` (:func:`estimate_relative` puts the caller's stamps there instead);
* every sample keeps the time stamp of the position sample it belongs to. In particular the
  forward differences are stamped at their newest sample ``n`` and so keep their delay: that
  delay is the phase error the paper criticises, not something to correct here.
"""

from dataclasses import dataclass, field, replace
from types import MappingProxyType

import numpy as np
from scipy import fft, optimize, signal, stats

# The three-stage options of the paper, and the ones recommended here (see three_stage).
PAPER_OPTIONS = MappingProxyType({'whole_periods': False, 'slow_band': 0.0, 'edges': 'trim',
                                  'detrend': False, 'max_compensation': np.inf,
                                  'exposure': 0.0, 'noise_floor': False})
RECOMMENDED_OPTIONS = MappingProxyType({'whole_periods': True, 'slow_band': 0.5, 'edges': 'trim',
                                        'detrend': False, 'max_compensation': 10.0,
                                        'exposure': 0.0, 'noise_floor': 4.0})

# Normal one-sigma quantile, used to turn a Student-t interval into a one-sigma equivalent.
_ONE_SIGMA_QUANTILE = stats.norm.cdf(1.0)


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


def _positions(x, dt, minimum):
    """Return x as a finite 1-D float array of at least ``minimum`` samples, checking dt."""
    x = np.asarray(x, dtype=float)
    if x.ndim != 1 or x.size < minimum:
        raise ValueError(f'need a 1-D array of at least {minimum} positions, got shape {x.shape}')
    if not np.all(np.isfinite(x)):
        raise ValueError('positions contain NaN or infinity; fill or cut the gaps first')
    if not (np.isfinite(dt) and dt > 0):
        raise ValueError(f'sample period must be positive, got {dt!r}')
    return x


def _estimate(method, dt, index, velocity, acceleration, **extra):
    return Estimate(time=index * dt, velocity=velocity, acceleration=acceleration, index=index,
                    method=method, sample_period=float(dt), **extra)


def forward_difference(x, dt):
    """Estimate velocity and acceleration by the paper's forward differences.

    ``v[n] = (x[n] - x[n-1]) / dt`` and ``a[n] = (x[n] - 2 x[n-1] + x[n-2]) / dt^2``, stamped
    at sample n (n = 2 .. N-1). For ``X sin(w t)`` the velocity is scaled by
    ``m1 = sin(w dt/2) / (w dt/2)`` and lags by ``w dt/2`` (eq. 7), the acceleration is scaled
    by ``m1^2`` and lags by ``w dt`` (eq. 9).
    """
    x = _positions(x, dt, 3)
    velocity = np.diff(x) / dt
    acceleration = np.diff(x, 2) / dt ** 2
    return _estimate('forward', dt, np.arange(2, x.size), velocity[1:], acceleration)


def center_difference(x, dt):
    """Estimate velocity and acceleration by center differences (eqs. 5, 6).

    ``v[n] = (x[n+1] - x[n-1]) / (2 dt)`` and ``a[n] = (x[n+1] - 2 x[n] + x[n-1]) / dt^2`` for
    n = 1 .. N-2. For ``X sin(w t)`` both are in phase with the truth, scaled by
    ``sin(w dt) / (w dt)`` and ``(sin(w dt/2) / (w dt/2))^2`` (eqs. 10, 11).
    """
    x = _positions(x, dt, 3)
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
    factor = gain(wd)
    keep &= np.isfinite(factor) & (factor <= options['max_compensation'])
    # Undo the exposure's averaging (sinc(f T), in phase) along with the differences' gain.
    factor = factor / np.sinc(frequencies * options['exposure'])
    scale = np.where(keep, factor if options['compensate'] else 1.0, 0.0)
    return fft.irfft(spectrum * scale, n), frequencies[keep]


def _harmonics_below_nyquist(frequency, dt):
    """Return how many harmonics of ``frequency`` (the fundamental included) lie below Nyquist."""
    return max(1, int(np.ceil(0.5 / (frequency * dt))) - 1)


def _design(t, frequency, harmonics, order):
    """Return the least-squares design: a polynomial of ``order`` in t (-1: none), then cos/sin."""
    span = t[-1] - t[0]
    u = 2 * (t - t[0]) / span - 1
    columns = [u ** p for p in range(order + 1)]
    for k in range(1, harmonics + 1):
        angle = 2 * np.pi * k * frequency * (t - t[0])
        columns += [np.cos(angle), np.sin(angle)]
    return np.column_stack(columns)


def _whole_period_length(n, cycles_per_sample):
    """Return a length <= n spanning a whole number of periods as exactly as samples allow.

    Among the lengths of m periods, m from half the record to all of it, pick the one whose
    rounding to whole samples leaves the smallest fraction of a period (the longest on ties).
    """
    most = int(np.floor((n + 0.5) * cycles_per_sample))
    if most < 1:
        raise ValueError(f'{n} samples are less than one period of the fundamental')
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
        [drift, _design(t, frequency, _harmonics_below_nyquist(frequency, dt), -1)])
    coefficients = np.linalg.lstsq(design, x, rcond=None)[0]
    return np.polynomial.Legendre(coefficients[:order + 1], domain=[t[0], t[-1]])


def three_stage(x, dt, epsilon=0.02, *, paper=False, compensate=True, whole_periods=None,
                slow_band=None, edges=None, detrend=None, max_compensation=None,
                exposure=None, noise_floor=None, fundamental=None):
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
    x = _positions(x, dt, 5)
    options = dict(PAPER_OPTIONS if paper else RECOMMENDED_OPTIONS)
    explicit = {'whole_periods': whole_periods, 'slow_band': slow_band, 'edges': edges,
                'detrend': detrend, 'max_compensation': max_compensation,
                'exposure': exposure, 'noise_floor': noise_floor}
    options.update({name: value for name, value in explicit.items() if value is not None})
    if options['edges'] not in ('trim', 'circular'):
        raise ValueError(f"edges must be 'trim' or 'circular', got {options['edges']!r}")
    order = options['detrend']
    integer = isinstance(order, (int, np.integer)) and not isinstance(order, bool)
    if not (order is False or integer and order >= 0):
        raise ValueError(f'detrend must be a polynomial order >= 0 or False, got {order!r}')
    if not epsilon >= 0:
        raise ValueError(f'epsilon must be >= 0, got {epsilon!r}')
    if not 0 <= options['exposure'] <= dt:
        raise ValueError(f"exposure must be in [0, {dt:g}] s (at most the sample period), got "
                         f"{options['exposure']!r}")
    needs_fundamental = options['whole_periods'] or options['slow_band'] or order is not False
    if fundamental is None and needs_fundamental:
        fundamental = fundamental_frequency(x, dt)
    options.update(epsilon=epsilon, compensate=compensate, fundamental=fundamental)
    circular = options['edges'] == 'circular'

    # Length of the FFT'd center differences, and the positions they need.
    length = x.size if circular else x.size - 2
    if options['whole_periods']:
        length = _whole_period_length(length, fundamental * dt)
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


def lowpass_forward(x, dt, cutoff=6.0, order=2):
    """Low-pass the positions with a causal Butterworth filter, then forward-difference them.

    The paper's Fig. 7(b) (cutoff in Hz). The filter starts in steady state at the first
    sample. Being causal it delays every component by its phase lag on top of the
    forward-difference lag; applied to both positions, the lag cancels between a_slid and v_rel
    only up to the extra half-sample of the forward difference.
    """
    x = _positions(x, dt, 3)
    if not 0 < cutoff < 0.5 / dt:
        raise ValueError(f'cutoff must be in (0, {0.5 / dt:g}) Hz, got {cutoff!r}')
    sos = signal.butter(order, cutoff, fs=1 / dt, output='sos')
    smooth, _ = signal.sosfilt(sos, x, zi=signal.sosfilt_zi(sos) * x[0])
    result = forward_difference(smooth, dt)
    return _estimate('lowpass-forward', dt, result.index, result.velocity, result.acceleration,
                     options={'cutoff': cutoff, 'order': order})


def savitzky_golay(x, dt, window=7, polyorder=5):
    """Estimate velocity and acceleration by Savitzky-Golay differentiating filters.

    Local least-squares polynomials of ``polyorder`` over ``window`` samples
    (scipy.signal.savgol_filter, deriv=1 and 2): zero phase inside the record, polynomial fits
    at the edges (mode='interp'), so every sample is estimated.
    """
    x = _positions(x, dt, window)
    if not 2 <= polyorder < window:
        raise ValueError(f'need 2 <= polyorder < window, got polyorder {polyorder}, '
                         f'window {window}')
    velocity = signal.savgol_filter(x, window, polyorder, deriv=1, delta=dt)
    acceleration = signal.savgol_filter(x, window, polyorder, deriv=2, delta=dt)
    return _estimate('savgol', dt, np.arange(x.size), velocity, acceleration,
                     options={'window': window, 'polyorder': polyorder})


def spectral(x, dt, cutoff=None):
    """Differentiate in the frequency domain, keeping the components at or below ``cutoff``.

    Multiplies the FFT by ``i w`` and ``-w^2`` (the Nyquist bin is dropped from the velocity);
    cutoff None keeps everything. The record is treated as periodic, so it should span whole
    periods without drift: a mismatch between its ends rings over the whole record.
    """
    x = _positions(x, dt, 3)
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


def estimate(x, dt, method='three-stage', **options):
    """Estimate velocity and acceleration of ``x`` by the named method (one of METHODS)."""
    if method not in _METHODS:
        raise ValueError(f'unknown method {method!r}; choose one of {", ".join(METHODS)}')
    return _METHODS[method](x, dt, **options)


def estimate_relative(time, stator, slider, method='three-stage', **options):
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
        raise ValueError(f'time, stator and slider differ in shape: '
                         f'{time.shape}, {stator.shape}, {slider.shape}')
    if time.size < 3:
        raise ValueError(f'need at least 3 samples, got {time.size}')
    steps = np.diff(time)
    dt = float(np.median(steps))
    if not (dt > 0 and np.all(np.abs(steps - dt) <= 0.01 * dt)):
        raise ValueError('time stamps must increase uniformly (within 1 % of the period)')
    if method == 'three-stage' and options.get('fundamental') is None:
        options['fundamental'] = fundamental_frequency(stator, dt)
    relative = estimate(slider - stator, dt, method, **options)
    absolute = estimate(slider, dt, method, **options)
    return Estimate(time=time[relative.index], velocity=relative.velocity,
                    acceleration=absolute.acceleration, index=relative.index, method=method,
                    sample_period=dt, velocity_frequencies=relative.velocity_frequencies,
                    acceleration_frequencies=absolute.acceleration_frequencies,
                    options=relative.options)


def fundamental_frequency(x, dt):
    """Return the fundamental frequency (Hz) of an oscillating record, e.g. the stator.

    The peak of the Hann-windowed, zero-padded spectrum of the linearly detrended record
    (at least two periods in the record), refined by parabolic interpolation of the log
    magnitude, then by a bounded search for the frequency whose least-squares fit of a
    harmonic series (all harmonics below Nyquist, plus a line) leaves the smallest residual.
    Harmonics do not bias it: relative error 1e-11 on 20 s of a 2.95 Hz sine at 30 fps, up
    to 2e-6 with crank-slider harmonics, drift and 5 um noise (2-5 Hz, 25-60 fps).
    """
    x = _positions(x, dt, 8)
    n = x.size
    padded = 8 * fft.next_fast_len(n)
    magnitude = np.abs(fft.rfft(signal.detrend(x) * signal.windows.hann(n), padded))
    frequencies = fft.rfftfreq(padded, dt)
    magnitude[frequencies < 2 / (n * dt)] = 0
    peak = int(np.argmax(magnitude[:-1]))
    if peak == 0 or magnitude[peak] == 0:
        raise ValueError('no oscillation found in the record')
    left, centre, right = np.log(magnitude[peak - 1:peak + 2] + np.finfo(float).tiny)
    offset = 0.5 * (left - right) / (left - 2 * centre + right)
    coarse = frequencies[peak] + offset * (frequencies[1] - frequencies[0])

    t = np.arange(n) * dt
    harmonics = _harmonics_below_nyquist(coarse, dt)

    def residual(frequency):
        design = _design(t, frequency, harmonics, 1)
        return np.sum((x - design @ np.linalg.lstsq(design, x, rcond=None)[0]) ** 2)

    half_bin = 0.5 / (n * dt)
    result = optimize.minimize_scalar(residual, bounds=(coarse - half_bin, coarse + half_bin),
                                      method='bounded', options={'xatol': 1e-10 * coarse})
    return float(result.x)


def _fundamental(t, y, frequency, harmonics):
    """Return the fundamental of y as a complex amplitude ``A e^{i phase}`` (A sin(wt + phase)).

    Least squares on a line plus the harmonic series, so offsets, a slow trend and the other
    harmonics do not leak into the fundamental even when the window is not whole periods.
    """
    design = _design(t, frequency, harmonics, 1)
    coefficients = np.linalg.lstsq(design, y, rcond=None)[0]
    cosine, sine = coefficients[2:4]
    return sine + 1j * cosine


def _wrap(angle):
    """Wrap angles into (-pi, pi]."""
    return np.pi - np.mod(np.pi - angle, 2 * np.pi)


def _memoryless(phase_difference, uncertainty, k, margin):
    """Return True when the phase difference is compatible with pi."""
    return bool(abs(np.pi - phase_difference) <= k * uncertainty + margin)


def memory_test(time, v_rel, a_slid, frequency, *, k=3.0, margin=0.1, blocks=8,
                harmonics=None):
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
        raise ValueError('time, v_rel and a_slid must be 1-D arrays of one length (3 or more)')
    if not (np.all(np.isfinite(v_rel)) and np.all(np.isfinite(a_slid))):
        raise ValueError('v_rel and a_slid must be finite')
    if not frequency > 0:
        raise ValueError(f'frequency must be positive, got {frequency!r}')
    dt = float(np.median(np.diff(time)))
    t = time - time[0]
    periods = int(np.floor((t[-1] + dt) * frequency * (1 + 1e-9)))
    if periods < 4:
        raise ValueError(f'the memory test needs at least 4 periods, got {periods}')
    if harmonics is None:
        harmonics = _harmonics_below_nyquist(frequency, dt)
    per_block = max(2, periods // blocks)
    count = periods // per_block
    block = np.floor(t * frequency / per_block + 1e-9).astype(int)

    def difference(selected):
        velocity = _fundamental(t[selected], v_rel[selected], frequency, harmonics)
        acceleration = _fundamental(t[selected], a_slid[selected], frequency, harmonics)
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


def relative_memory_test(time, stator, slider, method='three-stage', *, frequency=None, k=3.0,
                         margin=0.1, blocks=8, **options):
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
