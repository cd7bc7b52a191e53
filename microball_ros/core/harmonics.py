"""The harmonic model of a periodic record: its design matrix, its fundamental frequency.

Owns what the estimators and the memory test share about records that oscillate at a
fundamental: the check every estimator makes of its input positions (``check_positions``), how
many harmonics of a frequency lie below Nyquist, the least-squares design of a polynomial plus
a harmonic series (``harmonic_design``), the fundamental frequency of a record
(``fundamental_frequency``, e.g. the stator's) and the complex amplitude of a record's
fundamental (``fundamental_phasor``), fitted together with its harmonics and a trend.
"""

import numpy as np
import numpy.typing as npt
from scipy import fft, optimize, signal

from microball_ros.core.errors import InputError


def check_positions(x: npt.ArrayLike, dt: float, minimum: int) -> np.ndarray:
    """Return x as a finite 1-D float array of at least ``minimum`` samples, checking dt."""
    x = np.asarray(x, dtype=float)
    if x.ndim != 1 or x.size < minimum:
        raise InputError(f'need a 1-D array of at least {minimum} positions, got shape {x.shape}')
    if not np.all(np.isfinite(x)):
        raise InputError('positions contain NaN or infinity; fill or cut the gaps first')
    if not (np.isfinite(dt) and dt > 0):
        raise InputError(f'sample period must be positive, got {dt!r}')
    return x


def harmonics_below_nyquist(frequency: float, dt: float) -> int:
    """Return how many harmonics of ``frequency`` (the fundamental included) lie below Nyquist."""
    return max(1, int(np.ceil(0.5 / (frequency * dt))) - 1)


def harmonic_design(t: np.ndarray, frequency: float, harmonics: int,
                    order: int) -> np.ndarray:
    """Return the least-squares design: a polynomial of ``order`` in t (-1: none), then cos/sin."""
    span = t[-1] - t[0]
    u = 2 * (t - t[0]) / span - 1
    columns = [u ** p for p in range(order + 1)]
    for k in range(1, harmonics + 1):
        angle = 2 * np.pi * k * frequency * (t - t[0])
        columns += [np.cos(angle), np.sin(angle)]
    return np.column_stack(columns)


def fundamental_frequency(x: npt.ArrayLike, dt: float) -> float:
    """Return the fundamental frequency (Hz) of an oscillating record, e.g. the stator.

    The peak of the Hann-windowed, zero-padded spectrum of the linearly detrended record
    (at least two periods in the record), refined by parabolic interpolation of the log
    magnitude, then by a bounded search for the frequency whose least-squares fit of a
    harmonic series (all harmonics below Nyquist, plus a line) leaves the smallest residual.
    Harmonics do not bias it: relative error 1e-11 on 20 s of a 2.95 Hz sine at 30 fps, up
    to 2e-6 with crank-slider harmonics, drift and 5 um noise (2-5 Hz, 25-60 fps).
    """
    x = check_positions(x, dt, 8)
    n = x.size
    padded = 8 * fft.next_fast_len(n)
    magnitude = np.abs(fft.rfft(signal.detrend(x) * signal.windows.hann(n), padded))
    frequencies = fft.rfftfreq(padded, dt)
    magnitude[frequencies < 2 / (n * dt)] = 0
    peak = int(np.argmax(magnitude[:-1]))
    if peak == 0 or magnitude[peak] == 0:
        raise InputError('no oscillation found in the record')
    left, centre, right = np.log(magnitude[peak - 1:peak + 2] + np.finfo(float).tiny)
    offset = 0.5 * (left - right) / (left - 2 * centre + right)
    coarse = frequencies[peak] + offset * (frequencies[1] - frequencies[0])

    t = np.arange(n) * dt
    harmonics = harmonics_below_nyquist(coarse, dt)

    def residual(frequency):
        design = harmonic_design(t, frequency, harmonics, 1)
        return np.sum((x - design @ np.linalg.lstsq(design, x, rcond=None)[0]) ** 2)

    half_bin = 0.5 / (n * dt)
    result = optimize.minimize_scalar(residual, bounds=(coarse - half_bin, coarse + half_bin),
                                      method='bounded', options={'xatol': 1e-10 * coarse})
    return float(result.x)


def fundamental_phasor(t: np.ndarray, y: np.ndarray, frequency: float,
                       harmonics: int) -> complex:
    """Return the fundamental of y as a complex amplitude ``A e^{i phase}`` (A sin(wt + phase)).

    Least squares on a line plus the harmonic series, so offsets, a slow trend and the other
    harmonics do not leak into the fundamental even when the window is not whole periods.
    """
    design = harmonic_design(t, frequency, harmonics, 1)
    coefficients = np.linalg.lstsq(design, y, rcond=None)[0]
    cosine, sine = coefficients[2:4]
    return sine + 1j * cosine
