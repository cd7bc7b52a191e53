"""One mark on a plate whose texture moves with it: the learned plate, registered per frame.

Owns PlateMarkTracker (same interface as CentroidMarkTracker) and the texture test
``plate_is_textured``. Priming decides per ROI whether the plate is textured: pixel noise is
independent between the even and the odd rows while a texture on the plate is common to both,
so the correlation of their profiles outside the mark (after a cubic detrend) is about 0 on a
plain plate and close to 1 on a textured one (``texture_score``). On a plain plate the tracker
*is* the centroid tracker (core.tracking.centroid): every frame is measured by it, unchanged.

On a textured plate the texture moves with the mark, so near the mark the plate's relative
deficit ``D(u)`` (mark and texture, plate coordinates) is the same in every frame, smeared by
the exposure's motion kernel ``K`` (core.tracking.template: a quadratic path, blur ``L``,
curvature ``Q``). A frame's deficit is ``d(x) = c + g (D * K)(x - s)`` with ``s`` the position
averaged over the exposure. The tracker

1. learns from the priming frames the row weights (the mark's depth per row) and, jointly
   (``PlateSolver``, alternating least squares), the whole plate's deficit ``D`` seen through
   the ROI, the static field (illumination and dust fixed in the image) with a gain per frame,
   and each frame's position and kernel: first positions from the dip's centroid and kernels
   from neighbouring frames, then rounds of ``D`` (preconditioned conjugate gradients, exact
   for partial coverage), static field and gains (closed form), positions and kernels (fits).
   ``D``'s origin is then moved to the mark's centre, the mid-point of its two outer edges
   (half-depth crossings against the levels on either side of each edge), which a
   multiplicative texture hardly moves (a centroid is pulled by it);
2. per frame divides the row-weighted profile by the static field (a gain, flicker, is
   fitted below), searches the mark by a matched filter of ``D`` smeared by the predicted
   motion, gated around the position predicted from the recent track (``TrackPredictor``,
   core.tracking.predict's recurrence, vectorised) so texture dips never win, over the whole
   ROI after a loss;
3. fits ``s``, ``L`` and ``Q`` (Gauss-Newton, ``c`` and ``g`` solved linearly): the texture,
   common to data and model, is signal rather than error;
4. checks the mark clear of the ROI edges, its contrast ``g`` against recent frames (a covered
   mark loses contrast) and the fit's residual against the residuals while priming: a failed
   check gives NaN with a quality below ``min_quality``; positions are never invented.
"""

from collections import deque
import math

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

from microball_ros.core.tracking.centroid import CentroidMarkTracker
from microball_ros.core.tracking.config import TrackerConfig
from microball_ros.core.tracking.image import Roi, check_roi, roi_region
from microball_ros.core.tracking.predict import Prediction
from microball_ros.core.tracking.profile import default_saturation, row_weights
from microball_ros.core.tracking.results import MarkMeasurement
from microball_ros.core.tracking.search import locate
from microball_ros.core.tracking.subpixel import deficit_centroid
from microball_ros.core.tracking.template import SEGMENTS, kernel_spectrum, tukey

TEXTURE_SCORE = 0.5
ROUNDS = 4
UPSAMPLE = 8
SEARCH_BLURS = (0.0, 16.0, 32.0, 64.0)


def texture_score(regions: list[np.ndarray], marks: list[tuple[float, float]]) -> float:
    """Return how much of a plate's profile is texture: about 0 (plain) to 1 (all texture).

    ``regions``: ROI images (rows x columns); ``marks``: per region the ROI columns (first,
    last) of the mark, left out (NaN: none known). The correlation of the even-row and the
    odd-row profiles after a cubic detrend, median over the regions; 0 when none has at least
    24 plate columns and 4 rows.
    """
    values = []
    for region, (first, last) in zip(regions, marks, strict=True):
        w = region.shape[1]
        if region.ndim != 2 or region.shape[0] < 4:
            continue
        keep = np.ones(w, dtype=bool)
        if math.isfinite(first) and math.isfinite(last):
            keep[max(int(first), 0):max(int(last) + 1, 0)] = False
        if np.count_nonzero(keep) < 24:
            continue
        u = np.linspace(-1.0, 1.0, w)[keep]
        residual = []
        for rows in (region[0::2], region[1::2]):
            profile = rows.mean(axis=0, dtype=np.float64)[keep]
            residual.append(profile - np.polyval(np.polyfit(u, profile, 3), u))
        a, b = residual
        den = math.sqrt(float(a @ a) * float(b @ b))
        if den > 0:
            values.append(float(a @ b) / den)
    return float(np.median(values)) if values else 0.0


def plate_is_textured(regions: list[np.ndarray], marks: list[tuple[float, float]],
                      threshold: float = TEXTURE_SCORE) -> bool:
    """Return True if the plate around the mark carries a texture (``texture_score``).

    Plain plates score within about 0.05 of 0, the textured and speckled ones 0.95 or more.
    """
    return texture_score(regions, marks) >= threshold


_U = np.linspace(-0.5, 0.5, SEGMENTS + 1)
_U2 = _U * _U - 1.0 / 12.0
_MID_L = (_U[1:] + _U[:-1]) / 2.0 - float(np.mean((_U[1:] + _U[:-1]) / 2.0))
_MID_Q = (_U2[1:] + _U2[:-1]) / 2.0 - float(np.mean((_U2[1:] + _U2[:-1]) / 2.0))
_WIDTH_L = np.diff(_U)
_WIDTH_Q = np.diff(_U2)


def kernel_derivatives(k: np.ndarray, blur: float, curve: float):
    """Return the motion kernel's spectrum (as template.kernel_spectrum) and d/dblur, d/dcurve.

    The kernel is the distribution of ``blur u + curve (u^2 - 1/12)``, ``u`` uniform in
    [-1/2, 1/2], as ``SEGMENTS`` straight segments of equal duration.
    """
    mid = blur * _MID_L + curve * _MID_Q
    z = np.outer(0.5 * (blur * _WIDTH_L + curve * _WIDTH_Q), k)
    rotor = np.exp(np.outer(mid, -1j * k))
    sinc = np.sinc(z * (1.0 / np.pi))
    d_sinc = rotor * ((np.cos(z) - sinc) / np.where(np.abs(z) < 1e-12, 1.0, z)) * k
    common = rotor * sinc
    spectrum = common.mean(axis=0)
    ik = -1j * k
    d_blur = (common * (_MID_L[:, None] * ik)
              + d_sinc * (0.5 * _WIDTH_L)[:, None]).mean(axis=0)
    d_curve = (common * (_MID_Q[:, None] * ik)
               + d_sinc * (0.5 * _WIDTH_Q)[:, None]).mean(axis=0)
    return spectrum, d_blur, d_curve


def kernel_spectra(k: np.ndarray, blurs: np.ndarray, curves: np.ndarray,
                   shifts: np.ndarray) -> np.ndarray:
    """Return the spectra of several kernels (rows), each shifted by ``shifts`` (px)."""
    mid = (np.outer(blurs, _MID_L) + np.outer(curves, _MID_Q)
           + np.asarray(shifts, dtype=float)[:, None])
    half = 0.5 * (np.outer(blurs, _WIDTH_L) + np.outer(curves, _WIDTH_Q))
    sinc = np.sinc(half[:, :, None] * (k / np.pi))
    return (np.exp(mid[:, :, None] * (-1j * k)) * sinc).mean(axis=1)


class TrackPredictor:
    """Linear prediction of a mark's column from its recent track (as core.tracking.predict).

    The same recurrence ``x[n] = sum a_i x[n - i] + b`` fitted by least squares over the last
    ``history`` frames, vectorised; constant velocity, then the last position, with less.
    """

    def __init__(self, order: int = 4, history: int = 60):
        """Keep ``history`` frames and fit a recurrence of ``order`` past values."""
        self.order = int(order)
        self._track: deque[float] = deque(maxlen=int(history))

    def reset(self) -> None:
        """Forget the track."""
        self._track.clear()

    def add(self, column: float) -> None:
        """Append this frame's column (NaN when the mark was lost)."""
        self._track.append(float(column))

    def predict(self) -> Prediction | None:
        """Return the prediction for the next frame, or None without any recent position."""
        track = np.array(self._track)
        if track.size == 0 or not math.isfinite(track[-1]):
            return None
        previous = float(track[-1])
        before = float(track[-2]) if track.size >= 2 else math.nan
        p = self.order
        if track.size > 3 * (p + 1) and np.all(np.isfinite(track[-p:])):
            windows = sliding_window_view(track, p + 1)
            windows = windows[np.all(np.isfinite(windows), axis=1)]
            if len(windows) >= 3 * (p + 1):
                design = np.column_stack([windows[:, -2::-1], np.ones(len(windows))])
                goal = windows[:, -1]
                coef, *_ = np.linalg.lstsq(design, goal, rcond=None)
                residual = goal - design @ coef
                spread = math.sqrt(float(residual @ residual) / max(len(goal) - p - 1, 1))
                recent = track[-p:][::-1]
                column = float(coef[:-1] @ recent + coef[-1])
                following = float(coef[:-1] @ np.concatenate([[column], recent[:-1]])
                                  + coef[-1])
                return Prediction(column, following, previous, before, max(spread, 0.05))
        if math.isfinite(before):
            velocity = previous - before
            return Prediction(previous + velocity, previous + 2 * velocity, previous, before,
                              math.inf)
        return Prediction(previous, previous, previous, before, math.inf)


class PlateModel:
    """The plate's deficit ``D`` near the mark on a periodic grid, origin at ``size // 2``."""

    def __init__(self, size: int, support: float, regularisation: float = 1e-3,
                 center: int | None = None):
        """Create an empty model trusted within ``support`` px of its origin."""
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

    def add(self, window, valid, delta, blur, curve, half) -> None:
        """Accumulate one frame's grid-aligned deficit (``delta`` = s - origin column)."""
        taper = tukey(self.size, self.center + delta, half, 8.0) * valid
        h = kernel_spectrum(self.k, blur, curve) * np.exp(-1j * self.k * delta)
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
        spectrum = self.spectrum * kernel_spectrum(self.k, blur, curve) * np.exp(
            -1j * self.k * delta)
        if not slope:
            return np.fft.irfft(spectrum, self.size)
        return (np.fft.irfft(spectrum, self.size),
                np.fft.irfft(-1j * self.k * spectrum, self.size))

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
        return 0.5 * (left + right)

    @staticmethod
    def _crossing(fine, u, index, level, side):
        """Return u where ``fine`` crosses ``level`` between index and its outer neighbour."""
        a, b = fine[index + side], fine[index]
        t = (level - a) / (b - a) if b != a else 0.5
        return float(u[index + side] + t * (u[index] - u[index + side]))

    @staticmethod
    def _level(fine, u, edge):
        """Return the mean of the median levels 2-5 px on either side of an edge."""
        outer = fine[(np.abs(u - edge) >= 2.0) & (np.abs(u - edge) <= 5.0) & (u < edge)]
        inner = fine[(np.abs(u - edge) >= 2.0) & (np.abs(u - edge) <= 5.0) & (u > edge)]
        return 0.5 * (float(np.median(outer)) + float(np.median(inner)))

    def fit(self, window, valid, delta, blur, curve, reach, iterations=8):
        """Fit (delta, blur, curve) with offset and gain linear; None if it fails.

        Returns (delta, blur, curve, gain, offset, rms, sigma of delta), from the grid
        columns within ``reach`` + half the blur of the start (Gauss-Newton, analytic
        derivatives of the kernel's spectrum).
        """
        span = reach + 0.5 * abs(blur) + 0.25 * abs(curve)
        used = valid & (np.abs(self.grid - delta) <= span)
        count = int(np.count_nonzero(used))
        if count < 12:
            return None
        y = window[used]
        state = np.array([delta, abs(blur), curve], dtype=float)
        result = None
        ik = -1j * self.k
        for _ in range(iterations):
            spectrum, d_blur, d_curve = kernel_derivatives(self.k, state[1], state[2])
            shifted = self.spectrum * np.exp(ik * state[0])
            stack = np.fft.irfft(np.stack([shifted * spectrum, ik * shifted * spectrum,
                                           shifted * d_blur, shifted * d_curve]), self.size,
                                 axis=1)[:, used]
            m = stack[0]
            m_mean, y_mean = float(m.mean()), float(y.mean())
            mc = m - m_mean
            norm = float(mc @ mc)
            if not norm > 0:
                return None
            gain = float(mc @ (y - y_mean)) / norm
            offset = y_mean - gain * m_mean
            residual = y - offset - gain * m
            jacobian = np.column_stack([np.ones(count), m, gain * stack[1], gain * stack[2],
                                        gain * stack[3]])
            normal = jacobian.T @ jacobian
            result = (state.copy(), gain, offset, float(residual @ residual), normal)
            try:
                step = np.linalg.solve(normal + 1e-9 * np.diag(np.diag(normal) + 1e-12),
                                       jacobian.T @ residual)
            except np.linalg.LinAlgError:
                return None
            step = np.clip(step[2:], -4.0, 4.0)
            state = state + step
            state[1] = abs(state[1])
            if abs(step[0]) < 2e-3 and abs(step[1]) < 0.05 and abs(step[2]) < 0.1:
                break
        if result is None or not np.all(np.isfinite(state)):
            return None
        _, gain, offset, cost, normal = result
        variance = cost / max(count - 5, 1)
        try:
            covariance = np.linalg.inv(normal)
        except np.linalg.LinAlgError:
            return None
        sigma = math.sqrt(max(float(covariance[2, 2]) * variance, 0.0))
        return (float(state[0]), float(state[1]), float(state[2]), gain, offset,
                math.sqrt(variance), sigma)

    def local(self, shift: float, support: float) -> 'PlateModel':
        """Return the part within ``support`` of ``origin + shift`` as a small model there."""
        size = 64
        while size < 2 * support + 32:
            size *= 2
        local = PlateModel(size, support)
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


class PlateSolver:
    """The plate seen through one ROI, learned from frames by alternating least squares.

    Model of frame n's profile: ``gain_n * static(x) * (1 - sign * (D * K_n)(x - s_n))``,
    ``D`` the whole plate's relative deficit on one grid (every column any frame saw), ``K_n``
    the exposure's motion kernel. Rounds of: ``D`` given the rest (preconditioned conjugate
    gradients on the normal equations, circular convolutions by FFT, batched over frames);
    ``static`` and the gains given ``D`` (closed form); each frame's position and kernel
    given both (``PlateModel.fit``).
    """

    def __init__(self, profiles: np.ndarray, static: np.ndarray, sign: float,
                 regularisation: float = 0.05, iterations: int = 60):
        """Keep the frames' profiles (frames x columns) and a first static field."""
        self.profiles = profiles
        self.static = static.copy()
        self.sign = float(sign)
        self.gains = np.ones(len(profiles))
        self.regularisation = float(regularisation)
        self.iterations = int(iterations)
        self.plate: PlateModel | None = None
        self.kernels = np.full((len(profiles), 2), np.nan)
        self.positions = np.full(len(profiles), np.nan)

    def learn(self, positions, kernels, reach, rounds) -> list[float]:
        """Learn from first positions and kernels (NaN: unknown); return the fits' residuals."""
        count, w = self.profiles.shape
        positions = np.array(positions, dtype=float)
        kernels = np.array(kernels, dtype=float)
        ok = np.isfinite(positions) & np.all(np.isfinite(kernels), axis=1)
        if np.count_nonzero(ok) < 8:
            return []
        margin = float(np.max(np.abs(kernels[ok, 0]))) + abs(float(
            np.max(np.abs(kernels[ok, 1])))) + 48.0
        center = int(math.ceil(float(positions[ok].max()) + margin))
        size = fft_size(int(math.ceil(center + w - float(positions[ok].min()) + margin)))
        plate = PlateModel(size, float(size), center=center)
        values = np.zeros(size)
        rms: list[float] = []
        for round_ in range(rounds):
            use = np.flatnonzero(ok)
            if use.size < 8:
                return []
            j0 = np.rint(positions[use]).astype(int) - center
            delta = positions[use] - j0 - center
            spectra = kernel_spectra(plate.k, kernels[use, 0], kernels[use, 1], delta)
            rows = np.arange(use.size)[:, None]
            cols = np.arange(w)[None, :] - j0[:, None]
            mask = np.zeros((use.size, size))
            mask[rows, cols] = 1.0
            data = np.zeros((use.size, size))
            ratio = self.profiles[use] / (self.gains[use][:, None] * self.static[None, :])
            data[rows, cols] = self.sign * (1.0 - ratio)
            values = self._solve(values, spectra, mask, data, w / size)
            plate.values = values
            plate.spectrum = np.fft.rfft(values)
            model = 1.0 - self.sign * np.fft.irfft(plate.spectrum * spectra, size,
                                                   axis=1)[rows, cols]
            measured, gains = self.profiles[use], self.gains[use]
            for _ in range(2):
                static = ((gains[:, None] * measured * model).sum(axis=0)
                          / (gains[:, None] ** 2 * model ** 2).sum(axis=0))
                gains = ((measured * static * model).sum(axis=1)
                         / ((static * model) ** 2).sum(axis=1))
                scale = float(np.median(gains))
                gains, static = gains / scale, static * scale
            self.static, self.gains[use] = static, gains
            if round_ == rounds - 1:
                break
            rms = []
            longest = float(np.max(np.abs(kernels[use, 0])) + np.max(np.abs(kernels[use, 1])))
            local = plate.local(0.0, reach + 2.0 * longest + 16.0)
            for n in use:
                d = self.sign * (1.0 - self.profiles[n] / (self.gains[n] * self.static))
                window, valid, start = grid_window(d, positions[n], local.size, local.center)
                fit = local.fit(window, valid, positions[n] - start - local.center,
                                kernels[n, 0], kernels[n, 1], reach, iterations=2)
                moved = (math.nan if fit is None
                         else fit[0] + start + local.center - positions[n])
                if not abs(moved) <= 8.0:
                    ok[n] = False
                    continue
                positions[n] += moved
                kernels[n] = fit[1:3]
                rms.append(fit[5])
        self.plate, self.kernels, self.positions = plate, kernels, positions
        return rms

    def _solve(self, start, spectra, mask, data, coverage):
        """Return the regularised least-squares plate (PCG from ``start``)."""
        size = start.size
        conj = np.conj(spectra)
        lam = self.regularisation
        diagonal = coverage * (np.abs(spectra) ** 2).sum(axis=0) + lam

        def normal(x):
            model = np.fft.irfft(spectra * np.fft.rfft(x), size, axis=1) * mask
            return np.fft.irfft((conj * np.fft.rfft(model, axis=1)).sum(axis=0), size) + lam * x

        def precondition(r):
            return np.fft.irfft(np.fft.rfft(r) / diagonal, size)

        b = np.fft.irfft((conj * np.fft.rfft(data, axis=1)).sum(axis=0), size)
        x = start.copy()
        r = b - normal(x)
        z = precondition(r)
        p = z.copy()
        rz = float(r @ z)
        goal = 1e-10 * float(b @ b)
        for _ in range(self.iterations):
            q = normal(p)
            alpha = rz / float(p @ q)
            x += alpha * p
            r -= alpha * q
            if float(r @ r) < goal:
                break
            z = precondition(r)
            rz_new = float(r @ z)
            p = z + (rz_new / rz) * p
            rz = rz_new
        return x


class PlateMarkTracker:
    """Track one mark, with the plate's texture learned when it has one (see the module).

    Same interface as CentroidMarkTracker; until ``prime`` has found a textured plate (and
    on plain plates) it measures exactly like it.
    """

    def __init__(self, roi: Roi, config: TrackerConfig | None = None, name: str = 'mark',
                 exposure_fraction: float = 0.5):
        """Create a tracker for the mark in ``roi`` (x, y, w, h, px)."""
        self.roi = check_roi(roi, name=name)
        self.config = TrackerConfig() if config is None else config
        self.name = name
        self.exposure_fraction = float(exposure_fraction)
        self._fallback = CentroidMarkTracker(self.roi, self.config, name, exposure_fraction)
        self.plate: PlateModel | None = None
        self.texture = 0.0
        self.weights: np.ndarray | None = None
        self.static: np.ndarray | None = None
        self._half = 8.0
        self._rms = 1.0
        self._predictor = TrackPredictor()
        self._gains: deque[float] = deque(maxlen=int(self.config.area_history))

    @property
    def polarity(self) -> str | None:
        """Return the mark's polarity ('dark' or 'bright'), None until it is known."""
        return self._fallback.polarity

    @polarity.setter
    def polarity(self, value: str | None) -> None:
        self._fallback.polarity = value

    @property
    def textured(self) -> bool:
        """Return True once priming found a textured plate and learned it."""
        return self.plate is not None

    @property
    def learned(self) -> dict:
        """Return what was learned: polarity, and for a textured plate the plate near the mark."""
        if self.plate is None:
            return self._fallback.learned
        return {'polarity': self.polarity, 'half_width': self._half,
                'template': self.plate.values.copy(), 'center': self.plate.center,
                'texture': self.texture}

    def reset(self) -> None:
        """Forget the track (what was learned is kept)."""
        self._predictor.reset()
        self._gains.clear()
        polarity = self._fallback.polarity
        self._fallback.reset()
        self._fallback.polarity = polarity

    # -- learning --------------------------------------------------------------------------
    def prime(self, frames) -> None:
        """Learn the polarity, whether the plate is textured, and if so the plate; restart."""
        frames = list(frames)
        self._fallback.prime(frames)
        if self.polarity is None or len(frames) < 12:
            return
        regions = [roi_region(frame, self.roi, self.name) for frame in frames]
        x = self.roi[0]
        sample, marks = [], []
        for region, frame in zip(regions, frames, strict=True):
            m = self._fallback.measure(frame)
            if m.valid:
                sample.append(region)
                marks.append((m.position_px - x - m.extent_px / 2.0 - 16.0,
                              m.position_px - x + m.extent_px / 2.0 + 16.0))
                if len(sample) == 12:
                    break
        self.reset()
        if len(sample) < 8:
            return
        self.texture = texture_score(sample, marks)
        if self.texture < TEXTURE_SCORE:
            return
        self._learn(regions)
        self.reset()

    def _learn(self, regions) -> None:
        """Learn row weights, static field and plate; leave ``plate`` None on failure."""
        cfg = self.config
        w = self.roi[2]
        positions, extents = self._first_positions(regions)
        weights = [row_weights(r, int(p - e / 2), int(p + e / 2), cfg.pad_px, self.polarity)
                   for r, p, e in zip(regions, positions, extents, strict=True)
                   if math.isfinite(p)]
        weights = [v for v in weights if v is not None]
        if not weights:
            return
        self.weights = np.median(weights, axis=0)
        self.weights /= max(float(self.weights.sum()), 1e-12)
        profiles = np.array([self.weights @ r.astype(np.float64) for r in regions])
        columns = np.arange(w)
        outside = np.abs(columns[None, :] - positions[:, None]) > (extents[:, None] / 2 + 8.0)
        outside &= np.isfinite(positions)[:, None]
        masked = np.where(outside, profiles, np.nan)
        with np.errstate(all='ignore'):
            static = np.nanmedian(masked, axis=0)
        if not np.all(np.isfinite(static)) or static.min() < cfg.min_baseline:
            return
        self._half = 0.5 * float(np.nanpercentile(extents, 10))
        f = self.exposure_fraction
        kernels = np.full((positions.size, 2), np.nan)
        for n in range(1, positions.size - 1):
            before, middle, after = positions[n - 1:n + 2]
            kernels[n] = (abs(after - before) / 2 * f, (after - 2 * middle + before) * f * f / 2)
        solver = PlateSolver(profiles, static, 1.0 if self.polarity == 'dark' else -1.0)
        reach = self._half + cfg.pad_px
        rms = solver.learn(positions, kernels, reach + 8.0, ROUNDS)
        if solver.plate is None:
            return
        center = solver.plate.mark_center(reach)
        if not math.isfinite(center):
            return
        longest = float(np.nanmax(solver.kernels[:, 0])) if np.any(
            np.isfinite(solver.kernels[:, 0])) else 0.0
        local = solver.plate.local(center, reach + 8.0 + min(longest, cfg.max_blur_px) + 16.0)
        self.plate = local
        self.static = solver.static
        self._rms = float(np.median(rms)) if len(rms) else 1.0

    def _first_positions(self, regions):
        """Return each frame's first position and extent (ROI columns; NaN: not found).

        The strongest dip of the profile against the median profile over the frames (the
        mark is elsewhere in most of them), its extent where the smoothed deficit exceeds a
        quarter of its peak, and the deficit centroid over that extent and a pad.
        """
        cfg = self.config
        profiles = np.array([r.mean(axis=0, dtype=np.float64) for r in regions])
        static = np.median(profiles, axis=0)
        sign = 1.0 if self.polarity == 'dark' else -1.0
        positions = np.full(len(regions), np.nan)
        extents = np.full(len(regions), np.nan)
        if static.min() < cfg.min_baseline:
            return positions, extents
        for n, profile in enumerate(profiles):
            d = sign * (1.0 - profile / static)
            dip = locate(d, 0.0, 0.25, cfg.smoothing_px)
            first, last = dip.lo - cfg.pad_px, dip.hi + cfg.pad_px
            if first < 1 or last > d.size - 2 or not dip.peak > cfg.min_depth:
                continue
            centroid, _, area = deficit_centroid(d, first, last, 1.0)
            if area > 0:
                positions[n], extents[n] = centroid, float(dip.hi - dip.lo + 1)
        return positions, extents

    def _deficit(self, profile, center=math.nan, extent=0.0):
        """Return the deficit against the static field (gain and offset are fitted later)."""
        return (1.0 if self.polarity == 'dark' else -1.0) * (1.0 - profile / self.static)

    @staticmethod
    def _window(d, column, size):
        """Return the grid window of d centred near ``column``, its valid mask and start."""
        j0 = int(round(column)) - size // 2
        index = np.arange(j0, j0 + size)
        valid = (index >= 0) & (index < d.size)
        window = np.zeros(size)
        window[valid] = d[index[valid]]
        return window, valid, j0

    # -- a frame ---------------------------------------------------------------------------
    def measure(self, frame: np.ndarray) -> MarkMeasurement:
        """Measure the mark in one frame (2-D array in DN) and return a MarkMeasurement."""
        if self.plate is None:
            return self._fallback.measure(frame)
        cfg = self.config
        w = self.roi[2]
        region = roi_region(frame, self.roi, self.name)
        profile = self.weights @ region.astype(np.float64)
        if not np.all(np.isfinite(profile)):
            return self._invalid('non-finite pixels')
        saturation = (cfg.saturation_level if cfg.saturation_level is not None
                      else default_saturation(region.dtype))
        if saturation is not None and profile.max() >= saturation:
            return self._invalid('saturated')
        prediction = self._predictor.predict()
        f = self.exposure_fraction
        kernel = None
        if prediction is not None and math.isfinite(prediction.before):
            kernel = (abs(prediction.following - prediction.previous) / 2.0 * f,
                      (prediction.following - 2 * prediction.column + prediction.previous)
                      * f * f / 2.0)
        gated = prediction is not None and math.isfinite(prediction.spread)
        reach = self._half + cfg.pad_px
        if gated:
            blur = kernel[0] if kernel is not None else 0.0
            d = self._deficit(profile, prediction.column, 2 * reach + blur + 8.0)
        else:
            d = self._deficit(profile, math.nan, 0.0)
        if d is None:
            return self._invalid('too dark')
        found = self._search(d, prediction if gated else None, kernel)
        if found is None:
            return self._invalid('mark at the ROI edge')
        start, blur, curve = found
        if not gated:
            d = self._deficit(profile, start, 2 * reach + blur + 8.0)
            if d is None:
                return self._invalid('too dark')
        size = self.plate.size
        window, valid, j0 = self._window(d, start, size)
        fit = self.plate.fit(window, valid, start - j0 - self.plate.center, blur, curve,
                             reach + 8.0)
        if fit is None:
            return self._invalid('no match')
        delta, blur, curve, gain, _, rms, sigma = fit
        position = delta + j0 + self.plate.center
        extent = reach + 0.5 * blur + 0.25 * abs(curve)
        peak = gain * float(self.plate.values.max())
        if abs(position - start) > 4.0 or not math.isfinite(position):
            return self._invalid('no match', contrast=peak)
        if position - extent < 1 or position + extent > w - 2:
            return self._invalid('mark at the ROI edge', contrast=peak)
        reference = float(np.median(self._gains)) if len(self._gains) >= 3 else 1.0
        self._gains.append(gain)
        q_gain = math.exp(-0.5 * ((gain / reference - 1.0) / cfg.area_tolerance) ** 2)
        excess = max(rms / self._rms - cfg.match_tolerance, 0.0)
        q_match = math.exp(-0.5 * (excess / 0.5) ** 2)
        snr = peak * math.sqrt(cfg.smoothing_px) / max(rms, 1e-12)
        q_snr = 1.0 - math.exp(-(snr / cfg.snr_scale) ** 2)
        quality = q_snr * q_gain * q_match
        if quality < cfg.min_quality or snr < cfg.min_snr:
            reason = 'mark area changed' if min(q_gain, q_match) < q_snr else 'low contrast'
            return self._invalid(reason, quality, contrast=peak)
        self._predictor.add(position)
        return MarkMeasurement(position + self.roi[0], quality, sigma_px=sigma, contrast=peak,
                               extent_px=2.0 * extent)

    def _search(self, d, prediction, kernel):
        """Return (column, blur, curve): the best match of the smeared plate, or None.

        Gated around the prediction (one kernel, the predicted one) when there is one, else
        over the whole ROI with a bank of blurs. Score: correlation over the model's norm.
        """
        plate = self.plate
        c = plate.center
        reach = self._half + self.config.pad_px
        if prediction is not None:
            gate = 6.0 * prediction.spread + 3.0
            lo = int(math.floor(prediction.column - gate))
            hi = int(math.ceil(prediction.column + gate)) + 1
            kernels = [kernel if kernel is not None else (0.0, 0.0)]
        else:
            lo, hi = 0, d.size
            kernels = [(b, 0.0) for b in SEARCH_BLURS]
            if kernel is not None:
                kernels.append(kernel)
        lo, hi = max(lo, 0), min(hi, d.size)
        if hi <= lo:
            return None
        best = None
        for blur, curve in kernels:
            core = min(int(math.ceil(reach + 0.5 * blur + 0.25 * abs(curve))) + 2, c - 1)
            template = plate.model(0.0, blur, curve)[c - core:c + core + 1]
            norm = math.sqrt(float(template @ template))
            if norm <= 0:
                continue
            padded = np.zeros(hi - lo + 2 * core)
            a, b = lo - core, hi + core
            padded[max(a, 0) - a:min(b, d.size) - a] = d[max(a, 0):min(b, d.size)]
            score = np.correlate(padded, template, mode='valid') / norm
            k = int(np.argmax(score))
            if best is None or score[k] > best[0]:
                offset = 0.0
                if 0 < k < score.size - 1:
                    left, mid, right = score[k - 1], score[k], score[k + 1]
                    den = left - 2 * mid + right
                    if den < 0:
                        offset = float(np.clip(0.5 * (left - right) / den, -0.5, 0.5))
                best = (float(score[k]), lo + k + offset, blur, curve)
        return None if best is None else best[1:]

    def _invalid(self, reason, quality=0.0, contrast=math.nan):
        self._predictor.add(math.nan)
        return MarkMeasurement(math.nan, quality, contrast=contrast, reason=reason)
