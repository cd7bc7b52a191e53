"""The learned mark: a 1-D template of any shape and polarity, smeared by the exposure's motion.

Owns the mark model every frame is fitted to. A frame's relative profile ``r(x)`` near the mark
is modelled as ``c + g (T * K)(x - s)``: ``T`` the learned template (signed: negative for a
dark mark, positive for a bright one, with whatever pattern the plate carries around the mark),
``K`` the motion kernel of the exposure, ``s`` the mark position averaged over the exposure,
``g`` the contrast (1 for the learned mark; a covered mark drops it) and ``c`` an offset
(flicker). The kernel is the distribution of the positions along a quadratic path
``L u + Q (u^2 - 1/12)``, ``u`` uniform in [-1/2, 1/2] (``L`` = speed x exposure, ``Q`` =
acceleration x exposure^2 / 2, px), or a known sinusoid's own path (``path_knots``), split into
straight segments, so its spectrum is exact per segment and its mean is zero: the fitted ``s``
is the exposure average for any such motion.

Everything is on one periodic grid of ``size`` columns with the template's origin at the
centre (``MarkTemplate``): the model and its derivative are one inverse real FFT each. The
template is learned by least squares over frames (a multi-frame Wiener deconvolution: each
frame's window, aligned by its fitted position and deblurred by its kernel, is accumulated in
the Fourier domain with a slow forgetting factor), so a sharp template emerges from blurred
frames. ``fit`` is Levenberg-Marquardt on (s, L, Q) with (c, g) solved linearly, and returns
the position's standard error from the residuals.
"""

import functools
import math
from typing import NamedTuple

import numpy as np

SEGMENTS = 6


class Fit(NamedTuple):
    """A fitted frame: position (grid units), its sigma, blur, contrast, offset, residual."""

    shift: float
    sigma: float
    blur: float
    curve: float
    gain: float
    offset: float
    rms: float
    samples: int


_U = np.linspace(-0.5, 0.5, SEGMENTS + 1)
_U2 = _U * _U - 1.0 / 12.0


def path_knots(kappa: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Return the path's two shapes at the segments' ends (``u`` from -1/2 to 1/2).

    A quadratic path: ``u`` and ``u^2 - 1/12`` (blur ``L`` and curvature ``Q`` their
    weights). A motion that turns ``kappa`` rad of a sinusoid over the exposure (its angular
    frequency times the exposure) traces ``sin(kappa u) / kappa`` and ``2 (1 - cos(kappa u))
    / kappa^2`` less its mean instead, ``L`` and ``Q`` keeping their meaning (the mid-exposure
    velocity times the exposure, half its acceleration times its square): the same to second
    order in ``u``, exact for the sinusoid. The quadratic put positions
    0.3 px off on a textured plate at 15 fps, 0.7 of the period exposed (kappa 0.87; a 1-D
    model of it, noise-free: 0.000 with these; stop 41).
    """
    if kappa == 0.0:
        return _U, _U2
    return _sinusoid_knots(float(kappa))


@functools.lru_cache(maxsize=32)
def _sinusoid_knots(kappa: float) -> tuple[np.ndarray, np.ndarray]:
    """Return ``path_knots`` of a sinusoid (kept: a tracker has one or two)."""
    return sinusoid_shapes(_U, kappa)


def sinusoid_shapes(u: np.ndarray, kappa: float) -> tuple[np.ndarray, np.ndarray]:
    """Return a sinusoid's two path shapes (``path_knots``) at ``u``.

    Each has mean 0 over the exposure, as ``u`` and ``u^2 - 1/12``: the blur and the
    curvature leave the mean position alone.
    """
    half = 0.5 * kappa * np.asarray(u, dtype=float)
    h = 0.5 * kappa  # the mean: 2 (1 - sin(h) / h) / kappa^2, by its series for a small h
    h2 = h * h
    lack = (h2 / 6.0 * (1.0 - h2 / 20.0 * (1.0 - h2 / 42.0 * (1.0 - h2 / 72.0))) if h < 0.1
            else 1.0 - math.sin(h) / h)
    curve = 4.0 * np.sin(half) ** 2 / (kappa * kappa) - 2.0 * lack / (kappa * kappa)
    return np.sin(2.0 * half) / kappa, curve


def kernel_spectrum(k: np.ndarray, blur: float, curve: float,
                    kappa: float = 0.0) -> np.ndarray:
    """Return the spectrum of the zero-mean motion kernel (blur L, curvature Q, px) at ``k``.

    ``kappa``: a sinusoidal path's turn over the exposure (``path_knots``; 0: quadratic).
    """
    u, u2 = path_knots(kappa)
    d = blur * u + curve * u2
    mid, width = (d[1:] + d[:-1]) / 2.0, d[1:] - d[:-1]
    mid = mid - mid.mean()
    half = np.outer(width / 2.0, k)
    safe = np.where(half == 0.0, 1.0, half)
    sinc = np.where(half == 0.0, 1.0, np.sin(safe) / safe)
    return (np.exp(-1j * np.outer(mid, k)) * sinc).mean(axis=0)


def tukey(size: int, center: float, half: float, ramp: float) -> np.ndarray:
    """Return a window that is 1 within ``half`` of ``center`` and falls to 0 over ``ramp``."""
    distance = np.abs(np.arange(size) - center) - half
    return np.where(distance <= 0, 1.0, 0.5 + 0.5 * np.cos(np.pi * np.clip(
        distance / max(ramp, 1e-9), 0.0, 1.0)))


class MarkTemplate:
    """A learned template on a periodic grid of ``size`` columns, origin at ``size // 2``.

    ``support``: half-width (px) around the origin where the template is learned and trusted.
    """

    def __init__(self, size: int, support: float, forget: float = 0.98,
                 regularisation: float = 1e-3):
        """Create an empty template (``ready`` is False until the first frame is added)."""
        self.size = int(size)
        self.center = self.size // 2
        self.support = float(support)
        self.k = 2 * np.pi * np.fft.rfftfreq(self.size)
        self.forget = float(forget)
        self.regularisation = float(regularisation)
        self._num = np.zeros(self.k.size, complex)
        self._den = np.zeros(self.k.size)
        self._shape = tukey(self.size, self.center, self.support, 8.0)
        self.spectrum = np.zeros(self.k.size, complex)
        self.values = np.zeros(self.size)
        self.frames = 0

    @property
    def ready(self) -> bool:
        """Return True once the template has learned at least one frame."""
        return self.frames > 0

    def add(self, window: np.ndarray, valid: np.ndarray, delta: float, blur: float,
            curve: float, gain: float, offset: float, half: float) -> None:
        """Learn from one frame's window (grid-aligned data, ``delta`` = s - origin column).

        ``valid`` marks the grid columns that hold data; ``half`` is the half-width around
        the mark that is used (the rest is tapered off).
        """
        taper = tukey(self.size, self.center + delta, half, 12.0) * valid
        data = np.fft.rfft((window - offset) * taper)
        h = gain * kernel_spectrum(self.k, blur, curve) * np.exp(-1j * self.k * delta)
        self._num = self.forget * self._num + np.conj(h) * data
        self._den = self.forget * self._den + np.abs(h) ** 2
        self.frames += 1
        floor = self.regularisation * float(self._den.max())
        values = np.fft.irfft(self._num / (self._den + floor), self.size) * self._shape
        self.values = values
        self.spectrum = np.fft.rfft(values)

    def _lobe(self, fraction):
        magnitude = np.convolve(np.abs(self.values), np.full(5, 0.2), mode='same')
        reach = int(self.support)
        near = magnitude[self.center - reach:self.center + reach + 1]
        peak_index = self.center - reach + int(np.argmax(near))
        threshold = fraction * magnitude[peak_index]
        below = magnitude <= threshold
        left = np.flatnonzero(below[:peak_index])
        right = np.flatnonzero(below[peak_index + 1:])
        lo = int(left[-1]) + 1 if left.size else 0
        hi = peak_index + int(right[0]) if right.size else self.size - 1
        return lo, hi

    def recenter(self, sign: float, fraction: float = 0.05) -> float:
        """Move the origin to the centroid of the signed main lobe; return the shift (px).

        The mark's position is then the centroid of its contrast (its centre for a symmetric
        mark), whatever frames the template was learned from.
        """
        lo, hi = self._lobe(fraction)
        lo, hi = max(lo - 2, 0), min(hi + 2, self.size - 1)
        weight = np.clip(sign * self.values[lo:hi + 1], 0.0, None)
        if weight.sum() <= 0:
            return 0.0
        shift = float(weight @ np.arange(lo, hi + 1)) / float(weight.sum()) - self.center
        phase = np.exp(1j * self.k * shift)
        self._num = self._num * phase
        self.spectrum = self.spectrum * phase
        self.values = np.fft.irfft(self.spectrum, self.size)
        return shift

    def half_width(self, fraction: float) -> float:
        """Return the half-width (px) of the template's main lobe, above fraction x its peak.

        The lobe is the contiguous run around the strongest value near the origin where the
        smoothed magnitude exceeds ``fraction`` of that value.
        """
        lo, hi = self._lobe(fraction)
        return float(max(self.center - lo, hi - self.center))

    def model(self, delta: float, blur: float, curve: float) -> tuple[np.ndarray, np.ndarray]:
        """Return the smeared template at grid columns shifted by ``delta``, and d/d(delta)."""
        spectrum = self.spectrum * kernel_spectrum(self.k, blur, curve) * np.exp(
            -1j * self.k * delta)
        return (np.fft.irfft(spectrum, self.size),
                np.fft.irfft(-1j * self.k * spectrum, self.size))

    def smeared(self, blur: float, curve: float) -> np.ndarray:
        """Return the template smeared by a kernel, centred (for the matched-filter search)."""
        return self.model(0.0, blur, curve)[0]

    def _cost(self, window, used, state):
        m = self.model(*state)[0][used]
        y = window[used]
        basis = np.column_stack([np.ones(m.size), m])
        coef, *_ = np.linalg.lstsq(basis, y, rcond=None)
        residual = y - basis @ coef
        return float(residual @ residual)

    def _evaluate(self, window, used, state):
        delta, blur, curve = state
        model, slope = self.model(delta, blur, curve)
        m = model[used]
        y = window[used]
        basis = np.column_stack([np.ones(m.size), m])
        (offset, gain), *_ = np.linalg.lstsq(basis, y, rcond=None)
        residual = y - offset - gain * m
        step = 0.25
        model_l = self.model(delta, blur + step, curve)[0][used]
        model_q = self.model(delta, blur, curve + step)[0][used]
        jacobian = np.column_stack([np.ones(m.size), m, gain * slope[used],
                                    gain * (model_l - m) / step, gain * (model_q - m) / step])
        return float(residual @ residual), jacobian, residual, float(gain), float(offset)

    def fit(self, window: np.ndarray, valid: np.ndarray, delta: float, blur: float,
            curve: float, half: float, iterations: int = 10) -> Fit | None:
        """Fit shift, blur and curvature to a grid-aligned window; None if it fails.

        The fit uses the valid columns within ``half`` + the blur of the mark; ``delta`` is
        the starting shift, ``blur`` and ``curve`` the starting kernel (Levenberg-Marquardt).
        """
        grid = np.arange(self.size) - self.center
        if curve:  # the predicted curvature, or none: the better start
            reach = half + 0.5 * abs(blur) + abs(curve) / 6.0
            wide = valid & (np.abs(grid - delta) <= reach)
            if np.count_nonzero(wide) >= 12 and self._cost(
                    window, wide, (delta, blur, 0.0)) < self._cost(window, wide,
                                                                   (delta, blur, curve)):
                curve = 0.0
        for _ in range(2):
            reach = half + 0.5 * abs(blur) + abs(curve) / 6.0
            used = valid & (np.abs(grid - delta) <= reach)
            if np.count_nonzero(used) < 12:
                return None
            state = (delta, abs(blur), curve)
            best = self._evaluate(window, used, state)
            damping = 1e-3
            for _ in range(iterations):
                cost, jacobian, residual = best[:3]
                normal = jacobian.T @ jacobian
                try:
                    step = np.linalg.solve(normal + damping * np.diag(np.diag(normal) + 1e-12),
                                           jacobian.T @ residual)
                except np.linalg.LinAlgError:
                    return None
                candidate = (state[0] + step[2], abs(state[1] + step[3]), state[2] + step[4])
                trial = self._evaluate(window, used, candidate)
                if trial[0] <= cost:
                    state, best = candidate, trial
                    damping = max(damping / 10.0, 1e-7)
                    if abs(step[2]) < 2e-4 and abs(step[3]) < 0.02 and abs(step[4]) < 0.05:
                        break
                else:
                    damping *= 10.0
                    if damping > 1e4:
                        break
            moved_kernel = abs(state[1] - abs(blur)) + abs(state[2] - curve) / 6.0
            delta, blur, curve = state
            if moved_kernel < 4.0:
                break
        cost, jacobian, _, gain, offset = best
        count = jacobian.shape[0]
        variance = cost / max(count - 5, 1)
        covariance = np.linalg.pinv(jacobian.T @ jacobian, rcond=1e-12)
        sigma = math.sqrt(max(float(covariance[2, 2]) * variance, 0.0))
        if not math.isfinite(sigma):
            return None
        return Fit(float(delta), sigma, float(blur), float(curve), gain, offset,
                   math.sqrt(variance), count)
