"""Put a real record's samples on a uniform frame grid: gaps, dropped frames, duplicates, jitter.

A camera takes frames on a uniform clock; what a record carries can differ from that clock:
rows missing (lost marks, dropped frames), a frame written with its predecessor's stamp, stamps
taken in software with jitter. ``regularise`` assigns every usable sample to its frame slot
``round((t - t0) / dt)`` and then decides, from the stator itself, which times are right:

* stamps jittered around the frame clock (the positions are those of the grid time): the grid
  times fit a smooth oscillation better, and the samples are used on the grid as they are;
* samples truly taken at their jittered stamps: the stamps fit better, and the positions are
  resampled onto the grid by a cubic spline through each contiguous run (error stated).

Short holes (at most ``fill`` missing frames) are bridged by a cubic spline so an FFT-based
estimator can run across them; bridged samples are marked and never enter a fit or a test.
What cannot be placed on one grid (stamps off the grid by more than a third of a period, time
running backwards over more than a duplicate) is refused with one line saying why.
"""

from dataclasses import dataclass

import numpy as np
from scipy.interpolate import CubicSpline

from microball_ros.core.errors import InputError
from microball_ros.core.harmonics import harmonic_design, harmonics_below_nyquist

# Stamps further than this fraction of a frame from their slot cannot be a jittered camera.
MAX_JITTER = 0.34


@dataclass(frozen=True)
class Grid:
    """Samples on a uniform grid ``t0 + slot * dt``.

    ``time``, ``stator``, ``slider``: one entry per slot from the first to the last used slot,
    NaN where nothing was measured and nothing bridged. ``measured``: True where the sample is
    a measurement (not bridged). ``notes``: one-line descriptions of what was repaired (empty
    for a clean uniform record). ``resample_error``: estimated rms position error (m) added by
    resampling jittered samples onto the grid, 0 if not resampled. ``samples_total``: the
    rows given, ``samples_dropped``: rows that could not be placed (non-finite, duplicates).
    """

    time: np.ndarray
    stator: np.ndarray
    slider: np.ndarray
    measured: np.ndarray
    dt: float
    notes: tuple
    resample_error: float
    samples_total: int
    samples_dropped: int

    def segments(self, minimum=3):
        """Return (start, stop) of the runs of finite samples at least ``minimum`` long."""
        finite = np.isfinite(self.stator) & np.isfinite(self.slider)
        padded = np.concatenate(([False], finite, [False])).astype(int)
        edges = np.flatnonzero(np.diff(padded))
        return [(int(a), int(b)) for a, b in zip(edges[::2], edges[1::2], strict=True)
                if b - a >= minimum]


def _rough_frequency(t, x):
    """Return the stator's frequency from its mean-crossings (robust to gaps), or None."""
    y = x - np.median(x)
    up = np.flatnonzero((y[:-1] < 0) & (y[1:] >= 0))
    if len(up) < 3:
        return None
    return (len(up) - 1) / (t[up[-1]] - t[up[0]])


def _harmonic_residual(t, x, frequency, dt):
    design = harmonic_design(t, frequency, harmonics_below_nyquist(frequency, dt), 3)
    return float(np.std(x - design @ np.linalg.lstsq(design, x, rcond=None)[0]))


def _stamps_are_true(stamps, grid_time, stator, dt):
    """Return True if the stator is smoother on its stamps than on the grid (jitter is real)."""
    frequency = _rough_frequency(grid_time, stator)
    if frequency is None:
        return False
    # A stretch of a few periods is enough to tell, and keeps this cheap on long records.
    n = min(len(stator), int(20 / (frequency * dt)) + 16)
    errors = []
    for t in (stamps, grid_time):
        errors.append(_harmonic_residual(t[:n], stator[:n], frequency, dt))
    return errors[0] < errors[1]


def regularise(time, stator, slider, valid=None, fill=2) -> Grid:
    """Return the record on its frame grid (see the module docstring); InputError if impossible.

    ``valid``: optional boolean mask (False: the sample was not measured, e.g. a lost mark).
    """
    time = np.asarray(time, dtype=float)
    stator = np.asarray(stator, dtype=float)
    slider = np.asarray(slider, dtype=float)
    if not time.shape == stator.shape == slider.shape or time.ndim != 1:
        raise InputError('time, stator and slider must be 1-D arrays of one length')
    total = len(time)
    usable = np.isfinite(time) & np.isfinite(stator) & np.isfinite(slider)
    if valid is not None:
        usable &= np.asarray(valid, dtype=bool)
    if np.count_nonzero(usable) < 8:
        raise InputError(f'only {np.count_nonzero(usable)} samples with both positions '
                         'measured; need at least 8')
    t, xs, xl = time[usable], stator[usable], slider[usable]
    steps = np.diff(t)
    backwards = np.flatnonzero(steps < 0)
    if backwards.size:
        k = int(backwards[0])
        raise InputError(f'time goes backwards at row {k + 2} ({t[k + 1]:.6g} s after '
                         f'{t[k]:.6g} s): not one record in time order')
    positive = steps[steps > 0]
    dt = float(np.median(positive))
    # Slots step by step (each step is a few frames at most, so a rough dt places them), then
    # dt and t0 by a least-squares line through the slots (stamps may be jittered), twice.
    # The line is fitted to the time since the first stamp: epoch stamps (1.7e9 s) would make
    # its slope depend on the CPU's rounding (1e-7 of dt between two BLAS kernels).
    slot = np.concatenate(([0.0], np.cumsum(np.round(steps / dt))))
    for _ in range(2):
        if slot[-1] > 0:
            dt = float(np.polyfit(slot, t - t[0], 1)[0])
        t0 = float(np.median(t - slot * dt))
        slot = np.round((t - t0) / dt)
    slot = slot.astype(np.int64)
    notes = []
    # A duplicated stamp: the frame carries its predecessor's stamp, so it belongs one slot on.
    duplicate = np.concatenate(([False], slot[1:] == slot[:-1]))
    shifted = np.zeros(len(slot), dtype=bool)
    for k in np.flatnonzero(duplicate).tolist():
        if slot[k] == slot[k - 1] and (k + 1 == len(slot) or slot[k + 1] > slot[k] + 1):
            slot[k] = slot[k] + 1
            shifted[k] = True
    # A shifted frame's stamp is known to be wrong: it gets its slot's time.
    t = np.where(shifted, t0 + slot * dt, t)
    keep = np.concatenate(([True], slot[1:] > slot[:-1]))
    dropped = int(np.count_nonzero(~keep)) + (total - len(t))
    if np.count_nonzero(duplicate):
        left_out = int(np.count_nonzero(~keep))
        notes.append(f'{int(np.count_nonzero(duplicate))} duplicated stamps, each taken as the '
                     f'next frame' + (f' ({left_out} left out: no free slot)' if left_out else ''))
    t, xs, xl, slot = t[keep], xs[keep], xl[keep], slot[keep]
    jitter = t - (t0 + slot * dt)
    worst = float(np.max(np.abs(jitter)))
    if worst > MAX_JITTER * dt:
        k = int(np.argmax(np.abs(jitter)))
        raise InputError(f'stamp {t[k]:.6g} s is {abs(jitter[k]) / dt:.2f} frames off the '
                         f'{dt * 1e3:.4g} ms frame grid: not a uniformly sampled record')
    first = int(slot[0])
    slot -= first
    n = int(slot[-1]) + 1
    grid_time = t0 + (first + np.arange(n)) * dt
    resample_error = 0.0
    if worst <= 1e-3 * dt:  # a clean clock: keep the stamps themselves where there are any
        grid_time[slot] = t
    on_grid = grid_time[slot]
    if worst > 1e-3 * dt:
        note = (f'stamps jitter by up to {worst * 1e3:.3g} ms (rms '
                f'{np.sqrt(np.mean(jitter ** 2)) * 1e3:.3g} ms) around the {dt * 1e3:.4g} ms '
                'frame grid')
        if _stamps_are_true(t, on_grid, xs, dt):
            xs, xl, resample_error = _resample(t, xs, xl, on_grid, slot)
            notes.append(f'{note}; the stamps fit the stator better than the grid, so the '
                         f'positions were resampled onto it (about {resample_error * 1e6:.2g} '
                         'um rms added)')
        else:
            notes.append(f'{note}; the positions fit the grid better than the stamps, so the '
                         'stamps were taken as jittered and the grid used')
    stator_grid = np.full(n, np.nan)
    slider_grid = np.full(n, np.nan)
    stator_grid[slot], slider_grid[slot] = xs, xl
    measured = np.zeros(n, dtype=bool)
    measured[slot] = True
    missing = n - len(slot)
    if missing:
        holes = np.diff(slot) - 1
        holes = holes[holes > 0]
        notes.append(f'{missing} missing frames in {len(holes)} gaps (longest '
                     f'{int(holes.max())} frames, {holes.max() * dt:.3g} s); gaps of up to '
                     f'{fill} frames bridged for the estimator only, longer ones split the '
                     'record')
        _bridge(grid_time, stator_grid, slider_grid, measured, fill)
    return Grid(time=grid_time, stator=stator_grid, slider=slider_grid, measured=measured,
                dt=dt, notes=tuple(notes), resample_error=resample_error, samples_total=total,
                samples_dropped=dropped)


def _resample(t, xs, xl, on_grid, slot):
    """Return the positions interpolated from their stamps to their grid times, and the error.

    The error estimate is the rms difference between the cubic spline and a linear one at the
    grid times (the spline's own error is far smaller for an oscillation sampled well).
    """
    breaks = np.flatnonzero(np.diff(slot) > 1) + 1
    out_s, out_l = xs.copy(), xl.copy()
    linear_error = []
    for a, b in zip(np.concatenate(([0], breaks)), np.concatenate((breaks, [len(t)])),
                    strict=True):
        if b - a < 4:
            continue
        span = slice(a, b)
        for source, out in ((xs, out_s), (xl, out_l)):
            out[span] = CubicSpline(t[span], source[span])(on_grid[span])
            linear_error.append(out[span] - np.interp(on_grid[span], t[span], source[span]))
    error = float(np.sqrt(np.mean(np.concatenate(linear_error) ** 2))) if linear_error else 0.0
    return out_s, out_l, 0.1 * error


def _bridge(time, stator, slider, measured, fill):
    """Fill holes of at most ``fill`` frames in place by a cubic spline of the measured samples."""
    if fill < 1:
        return
    missing = ~measured
    padded = np.concatenate(([False], missing, [False])).astype(int)
    edges = np.flatnonzero(np.diff(padded))
    holes = [(a, b) for a, b in zip(edges[::2], edges[1::2], strict=True) if b - a <= fill]
    if not holes:
        return
    for series in (stator, slider):
        for a, b in holes:
            lo, hi = max(0, a - 4), min(len(time), b + 4)
            around = np.arange(lo, hi)
            around = around[measured[around]]
            if len(around) < 4 or around[0] > a or around[-1] < b:
                continue
            series[a:b] = CubicSpline(time[around], series[around])(time[a:b])
