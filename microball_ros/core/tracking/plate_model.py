"""The learned plate of core.tracking.plate: the plate model and its fits.

The exposure's motion kernel in frequency is core.tracking.motion_spectra's;
``PlateModel``: the plate's relative deficit ``D(u)`` in plate coordinates, smeared and
placed per frame (learned by core.tracking.plate_solver).
"""

import math

import numpy as np

from microball_ros.core.tracking.motion_spectra import (
    frequencies,
    kernel_parts,
    kernels_parts,
    smears,
)
from microball_ros.core.tracking.small_linalg import solve
from microball_ros.core.tracking.template import kernel_spectrum, tukey

UPSAMPLE = 8  # the plate model's grid: 1/8 px
ASYMMETRY_MOVE = 1.0  # px: PlateModel.mark_center's edges that far from the centre of symmetry
ASYMMETRY_GAIN = 3.0  # ... and D that much less symmetric about them: the symmetry wins
BEYOND_SAMPLES = 2.0  # PlateModel._crossing: at most this many grid samples past its samples
# PlateModel.fit_clear: columns off the fit by CLIP noise are left out, in at most
# CLEAR_ROUNDS rounds, while those left keep CLEAR_INFORMATION of the position's information
CLIP, CLEAR_ROUNDS, CLEAR_INFORMATION = 4.0, 3, 0.5
SMEARED_KEPT = 64  # PlateModel.smeared: kernels kept (a search's bank is 6-19)

_IDENTITY = np.eye(5)  # solve()'s right side for the covariance


class PlateModel:
    """The plate's deficit ``D`` near the mark on a periodic grid, origin at ``size // 2``."""

    def __init__(self, size: int, support: float, regularisation: float = 1e-3,
                 center: int | None = None, kappa: float = 0.0):
        """Create an empty model trusted within ``support`` px of its origin.

        ``kappa``: the frames' paths are a sinusoid's that turns this far (rad) over the
        exposure (template.path_knots), 0: quadratic; every kernel here is of that shape.
        """
        self.kappa = float(kappa)
        self.size = int(size)
        self.center = self.size // 2 if center is None else int(center)
        self.k = 2 * np.pi * np.fft.rfftfreq(self.size)
        self.regularisation = float(regularisation)
        self._num = np.zeros(self.k.size, complex)
        self._den = np.zeros(self.k.size)
        self._shape = tukey(self.size, self.center, float(support), 8.0)
        self.grid = np.arange(self.size) - self.center
        self.spectrum = np.zeros(self.k.size, complex)
        self.values = np.zeros(self.size)
        self.frames = 0
        self._smeared: dict[tuple[float, float], np.ndarray] = {}  # see ``smeared``
        self._smeared_of: np.ndarray | None = None

    def add(self, window, valid, delta, blur, curve, half) -> None:
        """Accumulate one frame's grid-aligned deficit (``delta`` = s - origin column)."""
        taper = tukey(self.size, self.center + delta, half, 8.0) * valid
        h = kernel_spectrum(self.k, blur, curve, self.kappa) * np.exp(-1j * self.k * delta)
        self._num += np.conj(h) * np.fft.rfft(window * taper)
        self._den += np.abs(h) ** 2
        self.frames += 1

    def solve(self) -> None:
        """Deconvolve what was accumulated into ``values`` and ``spectrum``."""
        floor = self.regularisation * float(self._den.max())
        self.values = np.fft.irfft(self._num / (self._den + floor), self.size) * self._shape
        self.spectrum = np.fft.rfft(self.values)

    def shift_origin(self, shift: float) -> None:
        """Move the origin by ``shift`` px: the new ``D(u)`` is the old ``D(u + shift)``."""
        self.spectrum = self.spectrum * np.exp(1j * self.k * shift)
        self.values = np.fft.irfft(self.spectrum, self.size)

    def model(self, delta, blur, curve, slope=False):
        """Return D smeared by (blur, curve) with its origin at ``center + delta`` (grid)."""
        spectrum = self.spectrum * smears(self.k, *self.frequencies(), (blur,), (curve,),
                                           (delta,), self.kappa)[0]
        if not slope:
            return np.fft.irfft(spectrum, self.size)
        return (np.fft.irfft(spectrum, self.size),
                np.fft.irfft(-1j * self.k * spectrum, self.size))

    def smeared(self, blur: float, curve: float) -> np.ndarray:
        """Return ``model(0, blur, curve)`` (read-only), kept while ``spectrum`` is the same.

        A search over the whole ROI smears the plate by the same bank of kernels in every
        frame it runs; they are computed once (at most ``SMEARED_KEPT`` kept).
        """
        if self._smeared_of is not self.spectrum or len(self._smeared) >= SMEARED_KEPT:
            self._smeared, self._smeared_of = {}, self.spectrum
        key = (float(blur), float(curve))
        found = self._smeared.get(key)
        if found is None:
            found = self.model(0.0, blur, curve)
            found.flags.writeable = False
            self._smeared[key] = found
        return found

    def mark_center(self, reach: float) -> float:
        """Return the mark's centre (px from the origin): the mid-point of its outer edges.

        On the band-limited interpolation of D: the outermost crossings, within ``reach`` of
        the origin, of the level half-way between the values 2-5 px outside and inside each
        edge; NaN when there is no mark.
        """
        fine = np.fft.irfft(self.spectrum, self.size * UPSAMPLE) * UPSAMPLE
        u = (np.arange(fine.size) - self.center * UPSAMPLE) / UPSAMPLE
        near = np.abs(u) <= reach
        peak = float(fine[near].max())
        if not peak > 0:
            return math.nan
        level_left = level_right = 0.5 * peak
        left = right = math.nan
        for _ in range(3):
            above_left = np.flatnonzero(near & (fine > level_left))
            above_right = np.flatnonzero(near & (fine > level_right))
            if above_left.size == 0 or above_right.size == 0:
                return math.nan
            left = self._crossing(fine, u, int(above_left[0]), level_left, -1)
            right = self._crossing(fine, u, int(above_right[-1]), level_right, 1)
            level_left = self._level(fine, u, left)
            level_right = self._level(fine, u, right)
        return self._symmetric(fine, u, reach, 0.5 * (left + right))

    @staticmethod
    def _symmetric(fine, u, reach, edges):
        """Return ``edges``, or the centre of symmetry of D if the edges are far off it.

        A texture dip beside a shallow part of the mark (a cross's arm 25 % deep) can cross
        the edges' level on one side only: their mid-point is then pixels off. The centre of
        symmetry (least squares of ``D(c + v) - D(c - v)``, ``|v| <= reach``) replaces it when
        it is over ``ASYMMETRY_MOVE`` px away and D is much more symmetric about it
        (``ASYMMETRY_GAIN``): the mark is symmetric, the texture beside it is not.
        """
        step = float(u[1] - u[0])
        v = np.arange(-reach, reach + step / 2, step)

        def asymmetry(c):
            a, b = np.interp(c + v, u, fine), np.interp(c - v, u, fine)
            return float(((a - b) ** 2).sum() / max(float((a * a + b * b).sum()), 1e-300))

        centres = edges + np.arange(-0.5 * reach, 0.5 * reach + step / 2, step)
        scores = np.array([asymmetry(c) for c in centres])
        best = int(np.argmin(scores))
        if (abs(float(centres[best]) - edges) > ASYMMETRY_MOVE
                and asymmetry(edges) > ASYMMETRY_GAIN * float(scores[best])):
            return float(centres[best])
        return edges

    @staticmethod
    def _crossing(fine, u, index, level, side):
        """Return u where ``fine`` crosses ``level`` between index and its outer neighbour.

        At most ``BEYOND_SAMPLES`` samples past the outer neighbour: where both are above the
        level (the mark reaches past ``mark_center``'s reach, a cross's arm near the level),
        the line through them crossed it anywhere (a textured cross's centre was put 142 px
        off its plate's mark); a crossing just past the reach is kept (the blind set's t12).
        """
        a, b = fine[index + side], fine[index]
        t = min(max((level - a) / (b - a), -BEYOND_SAMPLES), 1.0) if b != a else 0.5
        return float(u[index + side] + t * (u[index] - u[index + side]))

    @staticmethod
    def _level(fine, u, edge):
        """Return the mean of the median levels 2-5 px on either side of an edge."""
        outer = fine[(np.abs(u - edge) >= 2.0) & (np.abs(u - edge) <= 5.0) & (u < edge)]
        inner = fine[(np.abs(u - edge) >= 2.0) & (np.abs(u - edge) <= 5.0) & (u > edge)]
        return 0.5 * (float(np.median(outer)) + float(np.median(inner)))

    def fit(self, window, valid, delta, blur, curve, reach, iterations=8, best=False):
        """Fit (delta, blur, curve) with offset and gain linear; None if it fails.

        Returns (delta, blur, curve, gain, offset, rms, sigma of delta, sigma of gain), from
        the grid columns within ``reach`` + half the blur of the start (Gauss-Newton, analytic
        derivatives of the kernel's spectrum). ``best``: if the steps did not settle and an
        earlier point fitted better, return that point (a short kernel's blur and curvature
        are hardly separable: the steps can swing between them and end anywhere).
        """
        span = reach + 0.5 * abs(blur) + 0.25 * abs(curve)
        columns = np.flatnonzero(valid & (np.abs(self.grid - delta) <= span))
        count = columns.size
        if count < 12:
            return None
        used: slice | np.ndarray = columns
        if columns[-1] - columns[0] + 1 == count:  # one run (always, from grid_window)
            used = slice(int(columns[0]), int(columns[-1]) + 1)
        y = window[used]
        y_mean = float(y.mean())
        y_centred = y - y_mean
        mik, k_safe = self.frequencies()
        delta, blur, curve = float(delta), abs(float(blur)), float(curve)
        result = lowest = None
        jacobian = np.empty((5, count))
        jacobian[0] = 1.0
        for _ in range(iterations):
            kernel = kernel_parts(self.k, mik, k_safe, blur, curve, delta, self.kappa)
            kernel *= self.spectrum
            model = np.fft.irfft(kernel, self.size, axis=1)[:, used]
            m = model[0]
            m_mean = float(m.sum()) / count  # as m.mean(), without its overhead
            mc = m - m_mean
            norm = float(mc @ mc)
            if not norm > 0:
                return None
            gain = float(mc @ y_centred) / norm
            offset = y_mean - gain * m_mean
            residual = y - offset - gain * m
            jacobian[1] = m
            np.multiply(model[1:], gain, out=jacobian[2:])
            normal = jacobian @ jacobian.T
            result = ((delta, blur, curve), gain, offset, float(residual @ residual), normal)
            if best and (lowest is None or result[3] < lowest[3]):
                lowest = result
            damped = normal.copy()
            damped.flat[::6] += 1e-9 * (damped.flat[::6] + 1e-12)
            step = solve(damped, jacobian @ residual)
            if step is None:
                return None
            step_delta, step_blur, step_curve = (min(max(v, -4.0), 4.0)  # as np.clip
                                                 for v in step[2:].tolist())
            delta, blur, curve = delta + step_delta, abs(blur + step_blur), curve + step_curve
            if abs(step_delta) < 2e-3 and abs(step_blur) < 0.05 and abs(step_curve) < 0.1:
                break
        if result is None or not (math.isfinite(delta) and math.isfinite(blur)
                                  and math.isfinite(curve)):
            return None
        if lowest is not None and lowest[3] < result[3]:
            result = lowest
            delta, blur, curve = result[0]
        _, gain, offset, cost, normal = result
        variance = cost / max(count - 5, 1)
        covariance = solve(normal, _IDENTITY)
        if covariance is None:
            return None
        sigma = math.sqrt(max(float(covariance[2, 2]) * variance, 0.0))
        sigma_gain = math.sqrt(max(float(covariance[1, 1]) * variance, 0.0))
        return (delta, blur, curve, gain, offset, math.sqrt(variance), sigma, sigma_gain)

    def fit_frame(self, window, valid, delta, blur, curve, reach, limit, blurs, noise=None):
        """Return ``fit`` of a frame from (delta, blur, curve), with its fallbacks; None: none.

        A fit whose residual is over ``limit`` (a false minimum: a short kernel's blur and
        curvature are hardly separable; or steps run out at a turning point) goes on from where
        it ended and starts again at rest from each blur of ``blurs``: the best is kept. With
        ``noise`` (the residual per column), one still over ``limit`` is fitted again without
        the columns something beside the mark darkens (``fit_clear``), kept if better.
        """
        fit = self.fit(window, valid, delta, blur, curve, reach, best=True)
        if fit is None or fit[5] > limit:
            starts = [(delta, b, 0.0) for b in blurs]
            for d0, b0, c0 in starts if fit is None else [fit[:3], *starts]:
                other = self.fit(window, valid, d0, b0, c0, reach, best=True)
                if other is not None and (fit is None or other[5] < fit[5]):
                    fit = other
        if fit is not None and fit[5] > limit and noise is not None:
            clear = self.fit_clear(window, valid, fit, reach, noise)
            if clear is not None and clear[5] < fit[5]:
                fit = clear
        return fit

    def fit_clear(self, window, valid, fit, reach, noise):
        """Return ``fit`` again without the columns something beside the mark darkens.

        Something passing near the mark (a particle) adds to the deficit in some of the fit's
        columns and spoils the whole fit (gain, offset and position). The columns off the fit
        by more than ``CLIP`` times ``noise`` and half the worst, with their neighbours, are
        left out and the fit repeated, at most ``CLEAR_ROUNDS`` times. None if the columns
        left hold under ``CLEAR_INFORMATION`` of the position's information (the model's
        squared slope; a mark half covered is not measured on what is left) or a fit fails.
        """
        kept = np.array(valid, dtype=bool)
        for _ in range(CLEAR_ROUNDS):
            delta, blur, curve, gain, offset = fit[:5]
            model, slope = self.model(delta, blur, curve, slope=True)
            near = kept & (np.abs(self.grid - delta) <= reach + 0.5 * blur + 0.25 * abs(curve))
            miss = np.where(near, np.abs(window - offset - gain * model), 0.0)
            worst = float(miss.max())
            if worst <= CLIP * noise:
                break
            off = np.convolve(miss > max(CLIP * noise, 0.5 * worst), np.ones(3), 'same') > 0
            information = float((slope[near] ** 2).sum())
            kept &= ~off
            if not float((slope[near & kept] ** 2).sum()) >= CLEAR_INFORMATION * information:
                return None
            fit = self.fit(window, kept, delta, blur, curve, reach, best=True)
            if fit is None:
                return None
        return fit

    def fit_many(self, windows, valids, deltas, blurs, curves, reach, iterations=8):
        """Return ``fit`` of several frames (rows of ``windows``, ``valids``), batched.

        The same Gauss-Newton steps as ``fit``, frame by frame, vectorised over the frames;
        a frame whose columns are not one run or whose blur is 0 is fitted by ``fit``.
        """
        count = len(windows)
        results: list = [None] * count
        deltas = np.array(deltas, dtype=float)
        blurs = np.abs(np.array(blurs, dtype=float))
        curves = np.array(curves, dtype=float)
        spans = reach + 0.5 * blurs + 0.25 * np.abs(curves)
        used = valids & (np.abs(self.grid[None, :] - deltas[:, None]) <= spans[:, None])
        counts = np.count_nonzero(used, axis=1)
        first = np.argmax(used, axis=1)
        last = used.shape[1] - 1 - np.argmax(used[:, ::-1], axis=1)
        run = (counts >= 12) & (last - first + 1 == counts) & (blurs != 0.0)
        for n in np.flatnonzero(~run):
            results[n] = self.fit(windows[n], valids[n], deltas[n], blurs[n], curves[n], reach,
                                  iterations)
        batch = np.flatnonzero(run)
        if batch.size == 0:
            return results
        lo, hi = int(first[batch].min()), int(last[batch].max()) + 1
        mask = used[batch, lo:hi].astype(float)
        counts = counts[batch].astype(float)
        y = windows[batch, lo:hi] * mask
        y_mean = y.sum(axis=1) / counts
        y_centred = (y - y_mean[:, None]) * mask
        mik, k_safe = self.frequencies()
        state = np.array([deltas[batch], blurs[batch], curves[batch]])
        kept: list = [None] * batch.size  # per frame: state, gain, offset, cost, normal
        active = np.arange(batch.size)
        failed = np.zeros(batch.size, dtype=bool)
        for _ in range(iterations):
            if active.size == 0:
                break
            delta, blur, curve = state[:, active]
            parts = kernels_parts(self.k, mik, k_safe, blur, curve, self.kappa)
            parts *= (self.spectrum * np.exp(mik * delta[:, None]))[:, None, :]
            model = np.fft.irfft(parts, self.size, axis=2)[:, :, lo:hi]
            w = mask[active]
            m = model[:, 0]
            m_mean = (m * w).sum(axis=1) / counts[active]
            mc = (m - m_mean[:, None]) * w
            norm = np.einsum('ij,ij->i', mc, mc)
            bad = ~(norm > 0)
            norm[bad] = 1.0
            gain = np.einsum('ij,ij->i', mc, y_centred[active]) / norm
            offset = y_mean[active] - gain * m_mean
            residual = (y[active] - offset[:, None] - gain[:, None] * m) * w
            jacobian = np.empty((active.size, 5, hi - lo))
            jacobian[:, 0] = w
            jacobian[:, 1] = m * w
            jacobian[:, 2:] = model[:, 1:]
            jacobian[:, 2:] *= (gain[:, None] * w)[:, None, :]
            normal = jacobian @ jacobian.transpose(0, 2, 1)
            cost = np.einsum('ij,ij->i', residual, residual)
            diagonal = np.einsum('nii->ni', normal)
            damped = normal.copy()
            np.einsum('nii->ni', damped)[...] += 1e-9 * (diagonal + 1e-12)
            right = np.einsum('nij,nj->ni', jacobian, residual)
            try:
                step = np.linalg.solve(damped, right[:, :, None])[:, 2:, 0]
            except np.linalg.LinAlgError:
                step = None
            for i, n in enumerate(active):
                if not bad[i]:
                    kept[n] = (gain[i], offset[i], cost[i], normal[i])
            if step is None:  # a singular frame among them: each alone, as ``fit`` does
                for n in batch[active]:
                    results[n] = self.fit(windows[n], valids[n], deltas[n], blurs[n], curves[n],
                                          reach, iterations)
                failed[active] = True
                break
            failed[active[bad]] = True
            step = np.clip(step, -4.0, 4.0)
            state[:, active] += step.T
            state[1, active] = np.abs(state[1, active])
            moving = ~((np.abs(step[:, 0]) < 2e-3) & (np.abs(step[:, 1]) < 0.05)
                       & (np.abs(step[:, 2]) < 0.1))
            active = active[moving & ~bad]
        for i, n in enumerate(batch):
            if failed[i] or kept[i] is None or not np.all(np.isfinite(state[:, i])):
                continue
            gain, offset, cost, normal = kept[i]
            variance = cost / max(counts[i] - 5, 1)
            try:
                covariance = np.linalg.inv(normal)
            except np.linalg.LinAlgError:
                continue
            sigma = math.sqrt(max(float(covariance[2, 2]) * variance, 0.0))
            sigma_gain = math.sqrt(max(float(covariance[1, 1]) * variance, 0.0))
            results[n] = (float(state[0, i]), float(state[1, i]), float(state[2, i]),
                          float(gain), float(offset), math.sqrt(variance), sigma, sigma_gain)
        return results

    def frequencies(self) -> tuple[np.ndarray, np.ndarray]:
        """Return -ik and k with no zero, for ``kernel_parts`` (kept: ``k`` never changes)."""
        if getattr(self, '_kept_frequencies', None) is None:
            self._kept_frequencies = frequencies(self.k)
        return self._kept_frequencies

    def local(self, shift: float, support: float) -> 'PlateModel':
        """Return the part within ``support`` of ``origin + shift`` as a small model there."""
        size = fft_size(max(64, int(math.ceil(2 * support + 32))))
        local = PlateModel(size, support, kappa=self.kappa)
        index = np.arange(size) - local.center + self.center
        local.values = self.model(-shift, 0.0, 0.0).take(index, mode='wrap') * tukey(
            size, local.center, support, 8.0)
        local.spectrum = np.fft.rfft(local.values)
        return local


def fft_size(minimum: int) -> int:
    """Return the smallest size >= ``minimum`` with no prime factor above 5 (a fast FFT)."""
    size = max(int(minimum), 1)
    while True:
        rest = size
        for prime in (2, 3, 5):
            while rest % prime == 0:
                rest //= prime
        if rest == 1:
            return size
        size += 1


def grid_window(d, column, size, center):
    """Return d on a grid with its origin column ``center`` near ``column``; mask; start."""
    j0 = int(round(column)) - center
    index = np.arange(j0, j0 + size)
    valid = (index >= 0) & (index < d.size)
    window = np.zeros(size)
    window[valid] = d[index[valid]]
    return window, valid, j0
