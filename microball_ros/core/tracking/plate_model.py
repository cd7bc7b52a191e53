"""The learned plate of core.tracking.plate: motion kernels, the plate model, its solver.

``kernel_derivatives`` / ``kernel_spectra``: the exposure's motion kernel (a quadratic path,
blur ``L`` and curvature ``Q``, as core.tracking.template) and its derivatives, in frequency;
``PlateModel``: the plate's relative deficit ``D(u)`` in plate coordinates, smeared and
placed per frame (learned by core.tracking.plate_solver).
"""

import math

import numpy as np

from microball_ros.core.tracking.small_linalg import solve
from microball_ros.core.tracking.template import SEGMENTS, kernel_spectrum, tukey

UPSAMPLE = 8  # the plate model's grid: 1/8 px
ASYMMETRY_MOVE = 1.0  # px: PlateModel.mark_center's edges that far from the centre of symmetry
ASYMMETRY_GAIN = 3.0  # ... and D that much less symmetric about them: the symmetry wins
# PlateModel.fit_clear: columns off the fit by CLIP noise are left out, in at most
# CLEAR_ROUNDS rounds, while those left keep CLEAR_INFORMATION of the position's information
CLIP, CLEAR_ROUNDS, CLEAR_INFORMATION = 4.0, 3, 0.5
SMEARED_KEPT = 64  # PlateModel.smeared: kernels kept (a search's bank is 6-19)

_U = np.linspace(-0.5, 0.5, SEGMENTS + 1)
_U2 = _U * _U - 1.0 / 12.0
_MID_L = (_U[1:] + _U[:-1]) / 2.0 - float(np.mean((_U[1:] + _U[:-1]) / 2.0))
_MID_Q = (_U2[1:] + _U2[:-1]) / 2.0 - float(np.mean((_U2[1:] + _U2[:-1]) / 2.0))
_WIDTH_L = np.diff(_U)
_WIDTH_Q = np.diff(_U2)


# The segments' ends, as the mids (both less the mean mid): the kernel is zero-mean
_ENDS = np.array([_U - float(np.mean((_U[1:] + _U[:-1]) / 2.0)),
                  _U2 - float(np.mean((_U2[1:] + _U2[:-1]) / 2.0))])
_WIDTHS = np.array([_WIDTH_L, _WIDTH_Q])
ENDS_FROM = 1e-3  # _by_ends: its rounding error over the spectrum, at most 1e-16 / this


_PHASE_WEIGHTS = np.array([np.full(SEGMENTS, 1.0), _MID_L, _MID_Q]) / SEGMENTS
_SINC_WEIGHTS = np.array([0.5 * _WIDTH_L, 0.5 * _WIDTH_Q]) / SEGMENTS
_TINY = 1e-100  # stands for 0 in a segment's half-width or at k = 0: sin(z) / z is then 1
_RANGE = np.arange(4096, dtype=float)  # _turns' fine and coarse steps (k.size up to 16 M)
TURNS_FROM = 256  # _turns: from this many frequencies, as coarse times fine turns
SERIES_BELOW = 1e-3  # _sinc_parts: z this small by the Taylor series


_IDENTITY = np.eye(5)


def _frequencies(k: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Return what the kernel's derivatives need of ``k``: -ik, and k with no zero."""
    return -1j * k, np.where(k == 0.0, _TINY, k)


def _turns(angles: np.ndarray, k: np.ndarray) -> np.ndarray:
    """Return ``exp(i angles k)`` (shape ``angles.shape + k.shape``) on an rfft grid ``k``.

    ``k`` is ``2 pi rfftfreq(size)``: ``k[n] = n k[1]``. Past ``TURNS_FROM`` frequencies
    ``exp(i a n k[1])`` is a coarse turn ``exp(i a B m k[1])`` times a fine one
    ``exp(i a j k[1])`` (``n = B m + j``, ``B`` about the square root of ``k.size``): about
    ``2 sqrt(k.size)`` complex exponentials instead of ``k.size``, the same to a few units in
    the last place (the kernels' spectra are most of a plate fit's time).
    """
    angles = np.asarray(angles, dtype=float)[..., None]
    count = k.size
    if count < TURNS_FROM:
        return np.exp(1j * (angles * k))
    block = math.isqrt(count - 1) + 1
    steps = (count + block - 1) // block
    angles = angles * float(k[1])
    fine = np.exp(1j * (angles * _RANGE[:block]))
    coarse = np.exp(1j * ((angles * block) * _RANGE[:steps]))
    turns = coarse[..., :, None] * fine[..., None, :]
    return turns.reshape(*turns.shape[:-2], steps * block)[..., :count]


def _sinc_parts(half: np.ndarray, k: np.ndarray, k_safe: np.ndarray, slope: bool = True):
    """Return ``sin(z) / z`` and (``slope``) its d/dz, ``z = half k``; 1 and 0 at k = 0.

    Past ``TURNS_FROM`` frequencies from ``exp(i z)`` (``_turns``). Below ``SERIES_BELOW`` by
    their Taylor series, where ``cos(z) - sin(z) / z`` would be lost in the rounding.
    """
    z = half[..., None] * k_safe
    d_sinc = None
    if k.size < TURNS_FROM:
        sinc = np.sin(z)
        sinc /= z
        if slope:
            d_sinc = np.cos(z)
            d_sinc -= sinc
            d_sinc /= z
    else:
        turns = _turns(half, k)
        sinc = turns.imag / z
        if slope:
            d_sinc = turns.real - sinc
            d_sinc /= z
    sinc[..., 0] = 1.0  # k = 0
    if d_sinc is not None:
        d_sinc[..., 0] = 0.0
    if k.size > 1 and float(np.abs(half).min()) * float(k[1]) < SERIES_BELOW:
        small = np.abs(z) < SERIES_BELOW
        small[..., 0] = False
        z2 = z[small] ** 2
        sinc[small] = 1.0 - z2 / 6.0 * (1.0 - z2 / 20.0)
        if d_sinc is not None:
            d_sinc[small] = -z[small] / 3.0 * (1.0 - z2 / 10.0)
    return sinc, d_sinc


def _by_ends(k, widths) -> bool:
    """Return True if a kernel's spectrum is computed from its segments' ends (``_ENDS``).

    A segment's part of the spectrum is ``(e_s - e_s+1) / (i k w_s)``, ``e_j = exp(-i k
    x_j)`` at its ends ``x_j``, ``w_s`` its length: one complex exponential per end instead of
    a phase and a sine per segment (the search's and light's smears, and the fit's steps, are
    most of a frame's time). It loses ``1e-16 / (k w_s)`` to rounding: a segment shorter than
    ``ENDS_FROM`` over the lowest frequency is computed from its mid and half-width instead.
    """
    return k.size > 1 and float(np.abs(widths).min()) * float(k[1]) >= ENDS_FROM


def _kernel_parts(k, mik, k_safe, blur, curve, shift=0.0):
    """Return rows: the kernel's spectrum, its d/dx, d/dblur, d/dcurve (``kernel_derivatives``).

    ``mik``, ``k_safe``: from ``_frequencies(k)``; ``shift``: the kernel moved that far (px).
    """
    if blur == 0.0:
        return _shifted(_kernel_parts_at_rest(k, mik, curve), mik, shift)
    ends = blur * _ENDS[0] + curve * _ENDS[1]
    widths = ends[1:] - ends[:-1]
    if _by_ends(k, widths):
        return _kernel_parts_by_ends(k, mik, k_safe, ends + shift, widths)
    return _shifted(_kernel_parts_by_segments(k, mik, k_safe, blur, curve), mik, shift)


def _shifted(parts, mik, shift):
    """Return ``parts`` of a kernel moved by ``shift`` px (in place)."""
    if shift != 0.0:
        parts *= np.exp(mik * shift)
    return parts


def _kernel_parts_by_segments(k, mik, k_safe, blur, curve):
    """Return ``_kernel_parts`` from the segments' mids and half-widths (no ``_by_ends``)."""
    mid = blur * _MID_L + curve * _MID_Q
    half = 0.5 * (blur * _WIDTH_L + curve * _WIDTH_Q)
    half[np.abs(half) < _TINY] = _TINY
    sinc, slope = _sinc_parts(half, k, k_safe)
    rotor = _turns(-mid, k)
    common = rotor * sinc
    slope = rotor * slope
    parts = np.empty((4, k.size), complex)
    # The spectrum, and its parts moved by the segments' mids and changed by their widths.
    np.matmul(_PHASE_WEIGHTS, common, out=parts[1:])
    width = _SINC_WEIGHTS @ slope
    width *= k
    parts[2:] *= mik
    parts[2:] += width
    parts[0] = parts[1]
    parts[1] *= mik
    return parts


def _kernel_parts_by_ends(k, mik, k_safe, ends, widths):
    """Return ``_kernel_parts`` from the segments' ``ends`` and ``widths`` (``_by_ends``).

    With ``T_s = (e_s - e_s+1) / (i k w_s)`` (``e_j = exp(-i k x_j)``), the spectrum is the
    mean of ``T_s``; ``dT_s/dx_s = (T_s - e_s) / w_s``, ``dT_s/dx_s+1 = (e_s+1 - T_s) / w_s``,
    and ``dx_j/dblur``, ``dx_j/dcurve`` are the ends' rows of ``_ENDS``. Every part is then a
    sum over the ends' exponentials, some over ``i k``: two small matrix products (of 3 and 2
    rows: BLAS's gemm; one row would be its gemv, which OpenBLAS runs on a second thread from
    about 4096 elements, spinning through every frame: see ``_smears``).
    """
    inv = 1.0 / widths
    over = np.zeros((3, SEGMENTS + 1))  # times e, over i k: the spectrum and the T_s parts
    over[0, :-1] = inv
    over[0, 1:] -= inv
    scaled = _WIDTHS * (inv * inv)
    over[1:, :-1] -= scaled
    over[1:, 1:] += scaled
    direct = np.zeros((2, SEGMENTS + 1))  # times e: the e_j parts
    direct[:, 1:] = inv
    direct[:, :-1] -= inv
    direct *= _ENDS / SEGMENTS
    turns = _turns(-ends, k)
    parts = np.empty((4, k.size), complex)
    np.matmul(over, turns, out=parts[1:])
    parts[1:] /= (1j * SEGMENTS) * k_safe
    parts[2:] += direct @ turns
    parts[0] = parts[1]
    parts[0, 0] = 1.0  # k = 0
    parts[2:, 0] = 0.0
    parts[1] = parts[0] * mik
    return parts


def _kernels_parts(k, mik, k_safe, blurs, curves):
    """Return ``_kernel_parts`` of several kernels (frames x 4 x k), none with blur 0."""
    mid = np.outer(blurs, _MID_L)
    mid += np.outer(curves, _MID_Q)
    half = np.outer(blurs, 0.5 * _WIDTH_L)
    half += np.outer(curves, 0.5 * _WIDTH_Q)
    half[np.abs(half) < _TINY] = _TINY
    sinc, slope = _sinc_parts(half, k, k_safe)
    rotor = _turns(-mid, k)
    common = rotor * sinc
    slope = rotor * slope
    parts = np.empty((len(mid), 4, k.size), complex)
    np.matmul(_PHASE_WEIGHTS, common, out=parts[:, 1:])
    width = _SINC_WEIGHTS @ slope
    width *= k
    parts[:, 2:] *= mik
    parts[:, 2:] += width
    parts[:, 0] = parts[:, 1]
    parts[:, 1] *= mik
    return parts


def _kernel_parts_at_rest(k, mik, curve):
    """Return ``_kernel_parts`` for blur 0, rounded exactly as the fits have always had it.

    d/dblur is 0 there (the kernel is even in the blur), so what a Gauss-Newton step from
    blur 0 does is decided by the rounding of that 0; kept as it was, the fits are too.
    """
    mid = curve * _MID_Q
    z = np.outer(0.5 * (curve * _WIDTH_Q), k)
    rotor = np.exp(np.outer(mid, mik))
    sinc = np.sinc(z * (1.0 / np.pi))
    d_sinc = rotor * ((np.cos(z) - sinc) / np.where(np.abs(z) < 1e-12, 1.0, z)) * k
    common = rotor * sinc
    parts = np.empty((4, k.size), complex)
    parts[0] = common.mean(axis=0)
    parts[1] = parts[0] * mik
    parts[2] = (common * (_MID_L[:, None] * mik)
                + d_sinc * (0.5 * _WIDTH_L)[:, None]).mean(axis=0)
    parts[3] = (common * (_MID_Q[:, None] * mik)
                + d_sinc * (0.5 * _WIDTH_Q)[:, None]).mean(axis=0)
    return parts


def kernel_derivatives(k: np.ndarray, blur: float, curve: float):
    """Return the motion kernel's spectrum (as template.kernel_spectrum) and d/dblur, d/dcurve.

    The kernel is the distribution of ``blur u + curve (u^2 - 1/12)``, ``u`` uniform in
    [-1/2, 1/2], as ``SEGMENTS`` straight segments of equal duration.
    """
    spectrum, _, d_blur, d_curve = _kernel_parts(k, *_frequencies(k), blur, curve)
    return spectrum, d_blur, d_curve


def _smears(k, mik, k_safe, blurs, curves, shifts) -> np.ndarray:
    """Return the spectra of kernels (rows, as ``kernel_spectra``); ``_frequencies(k)``."""
    ends = np.outer(blurs, _ENDS[0])
    ends += np.outer(curves, _ENDS[1])
    ends += np.asarray(shifts, dtype=float)[:, None]
    widths = ends[:, 1:] - ends[:, :-1]
    if _by_ends(k, widths):  # summed as arrays: one weighted row of them would be BLAS's gemv,
        # on two threads from about 4096 elements (the long grids': twice the CPU time)
        turns = _turns(-ends, k)
        spectra = turns[:, :-1] - turns[:, 1:]
        spectra /= widths[:, :, None]
        spectra = spectra.sum(axis=1)
        spectra /= (1j * SEGMENTS) * k_safe
        spectra[:, 0] = 1.0  # k = 0
        return spectra
    mid = np.outer(blurs, _MID_L)
    mid += np.outer(curves, _MID_Q)
    mid += np.asarray(shifts, dtype=float)[:, None]
    half = np.outer(blurs, 0.5 * _WIDTH_L)
    half += np.outer(curves, 0.5 * _WIDTH_Q)
    half[np.abs(half) < _TINY] = _TINY
    rotor = _turns(-mid, k)
    rotor *= _sinc_parts(half, k, k_safe, slope=False)[0]
    return rotor.sum(axis=1) / SEGMENTS


def kernel_spectra(k: np.ndarray, blurs: np.ndarray, curves: np.ndarray,
                   shifts: np.ndarray) -> np.ndarray:
    """Return the spectra of several kernels (rows), each shifted by ``shifts`` (px)."""
    return _smears(k, *_frequencies(k), blurs, curves, shifts)


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
        self._smeared: dict[tuple[float, float], np.ndarray] = {}  # see ``smeared``
        self._smeared_of: np.ndarray | None = None

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
        spectrum = self.spectrum * _smears(self.k, *self._frequencies(), (blur,), (curve,),
                                           (delta,))[0]
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
        mik, k_safe = self._frequencies()
        delta, blur, curve = float(delta), abs(float(blur)), float(curve)
        result = lowest = None
        jacobian = np.empty((5, count))
        jacobian[0] = 1.0
        for _ in range(iterations):
            kernel = _kernel_parts(self.k, mik, k_safe, blur, curve, delta)
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
        mik, k_safe = self._frequencies()
        state = np.array([deltas[batch], blurs[batch], curves[batch]])
        kept: list = [None] * batch.size  # per frame: state, gain, offset, cost, normal
        active = np.arange(batch.size)
        failed = np.zeros(batch.size, dtype=bool)
        for _ in range(iterations):
            if active.size == 0:
                break
            delta, blur, curve = state[:, active]
            parts = _kernels_parts(self.k, mik, k_safe, blur, curve)
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

    def _frequencies(self) -> tuple[np.ndarray, np.ndarray]:
        """Return -ik and k with no zero, for ``_kernel_parts`` (kept: ``k`` never changes)."""
        if getattr(self, '_kept_frequencies', None) is None:
            self._kept_frequencies = _frequencies(self.k)
        return self._kept_frequencies

    def local(self, shift: float, support: float) -> 'PlateModel':
        """Return the part within ``support`` of ``origin + shift`` as a small model there."""
        size = fft_size(max(64, int(math.ceil(2 * support + 32))))
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
