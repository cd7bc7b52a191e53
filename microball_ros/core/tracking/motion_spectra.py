"""The exposure's motion kernel in frequency, for core.tracking.plate_model's fits.

A quadratic path (blur ``L``, curvature ``Q``, as core.tracking.template), or a known
sinusoid's (``kappa``: its turn over the exposure, template.path_knots), as ``SEGMENTS``
straight segments of equal duration: ``kernel_spectra`` (several kernels, shifted),
``kernel_derivatives`` (the spectrum and its d/dblur, d/dcurve), and the private parts the
plate fit calls every frame (``kernel_parts``, ``smears``), kept fast: phases as coarse
times fine turns (``_turns``), one exponential per segment end (``_by_ends``).
"""

import functools
import math
from typing import NamedTuple

import numpy as np

from microball_ros.core.tracking.template import SEGMENTS, path_knots


class _Basis(NamedTuple):
    """A path's segments, per unit blur (``_l``) and curvature (``_q``): mids, widths, ends."""

    mid_l: np.ndarray
    mid_q: np.ndarray
    width_l: np.ndarray
    width_q: np.ndarray
    ends: np.ndarray  # the segments' ends, as the mids (both less the mean mid): zero-mean
    widths: np.ndarray
    phase_weights: np.ndarray
    sinc_weights: np.ndarray


def _make_basis(u: np.ndarray, u2: np.ndarray) -> _Basis:
    """Return the segments of the path ``blur u + curve u2`` (``u``, ``u2`` at their ends)."""
    mid_l = (u[1:] + u[:-1]) / 2.0 - float(np.mean((u[1:] + u[:-1]) / 2.0))
    mid_q = (u2[1:] + u2[:-1]) / 2.0 - float(np.mean((u2[1:] + u2[:-1]) / 2.0))
    width_l, width_q = np.diff(u), np.diff(u2)
    ends = np.array([u - float(np.mean((u[1:] + u[:-1]) / 2.0)),
                     u2 - float(np.mean((u2[1:] + u2[:-1]) / 2.0))])
    return _Basis(mid_l, mid_q, width_l, width_q, ends, np.array([width_l, width_q]),
                  np.array([np.full(SEGMENTS, 1.0), mid_l, mid_q]) / SEGMENTS,
                  np.array([0.5 * width_l, 0.5 * width_q]) / SEGMENTS)


_QUADRATIC = _make_basis(*path_knots(0.0))
_ENDS = _QUADRATIC.ends  # the quadratic path's segment ends (blur, curvature rows)


@functools.lru_cache(maxsize=32)
def _sinusoid_basis(kappa: float) -> _Basis:
    """Return ``_basis`` of a sinusoid's path (kept: a tracker has one or two)."""
    return _make_basis(*path_knots(kappa))


def _basis(kappa: float) -> _Basis:
    """Return the segments of the path for ``kappa`` (template.path_knots; 0: quadratic)."""
    return _QUADRATIC if kappa == 0.0 else _sinusoid_basis(float(kappa))


ENDS_FROM = 1e-3  # _by_ends: its rounding error over the spectrum, at most 1e-16 / this


_TINY = 1e-100  # stands for 0 in a segment's half-width or at k = 0: sin(z) / z is then 1
_RANGE = np.arange(4096, dtype=float)  # _turns' fine and coarse steps (k.size up to 16 M)
TURNS_FROM = 256  # _turns: from this many frequencies, as coarse times fine turns
SERIES_BELOW = 1e-3  # _sinc_parts: z this small by the Taylor series


def frequencies(k: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
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


def kernel_parts(k, mik, k_safe, blur, curve, shift=0.0, kappa=0.0):
    """Return rows: the kernel's spectrum, its d/dx, d/dblur, d/dcurve (``kernel_derivatives``).

    ``mik``, ``k_safe``: from ``frequencies(k)``; ``shift``: the kernel moved that far (px);
    ``kappa``: a sinusoidal path's turn over the exposure (template.path_knots; 0: quadratic).
    """
    basis = _basis(kappa)
    if blur == 0.0:
        return _shifted(_kernel_parts_at_rest(k, mik, curve, basis), mik, shift)
    ends = blur * basis.ends[0] + curve * basis.ends[1]
    widths = ends[1:] - ends[:-1]
    if _by_ends(k, widths):
        return _kernel_parts_by_ends(k, mik, k_safe, ends + shift, widths, basis)
    return _shifted(_kernel_parts_by_segments(k, mik, k_safe, blur, curve, basis), mik, shift)


def _shifted(parts, mik, shift):
    """Return ``parts`` of a kernel moved by ``shift`` px (in place)."""
    if shift != 0.0:
        parts *= np.exp(mik * shift)
    return parts


def _kernel_parts_by_segments(k, mik, k_safe, blur, curve, basis=_QUADRATIC):
    """Return ``kernel_parts`` from the segments' mids and half-widths (no ``_by_ends``)."""
    mid = blur * basis.mid_l + curve * basis.mid_q
    half = 0.5 * (blur * basis.width_l + curve * basis.width_q)
    half[np.abs(half) < _TINY] = _TINY
    sinc, slope = _sinc_parts(half, k, k_safe)
    rotor = _turns(-mid, k)
    common = rotor * sinc
    slope = rotor * slope
    parts = np.empty((4, k.size), complex)
    # The spectrum, and its parts moved by the segments' mids and changed by their widths.
    np.matmul(basis.phase_weights, common, out=parts[1:])
    width = basis.sinc_weights @ slope
    width *= k
    parts[2:] *= mik
    parts[2:] += width
    parts[0] = parts[1]
    parts[1] *= mik
    return parts


def _kernel_parts_by_ends(k, mik, k_safe, ends, widths, basis=_QUADRATIC):
    """Return ``kernel_parts`` from the segments' ``ends`` and ``widths`` (``_by_ends``).

    With ``T_s = (e_s - e_s+1) / (i k w_s)`` (``e_j = exp(-i k x_j)``), the spectrum is the
    mean of ``T_s``; ``dT_s/dx_s = (T_s - e_s) / w_s``, ``dT_s/dx_s+1 = (e_s+1 - T_s) / w_s``,
    and ``dx_j/dblur``, ``dx_j/dcurve`` are the ends' rows of ``basis.ends``. Every part is then a
    sum over the ends' exponentials, some over ``i k``: two small matrix products (of 3 and 2
    rows: BLAS's gemm; one row would be its gemv, which OpenBLAS runs on a second thread from
    about 4096 elements, spinning through every frame: see ``smears``).
    """
    inv = 1.0 / widths
    over = np.zeros((3, SEGMENTS + 1))  # times e, over i k: the spectrum and the T_s parts
    over[0, :-1] = inv
    over[0, 1:] -= inv
    scaled = basis.widths * (inv * inv)
    over[1:, :-1] -= scaled
    over[1:, 1:] += scaled
    direct = np.zeros((2, SEGMENTS + 1))  # times e: the e_j parts
    direct[:, 1:] = inv
    direct[:, :-1] -= inv
    direct *= basis.ends / SEGMENTS
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


def kernels_parts(k, mik, k_safe, blurs, curves, kappa=0.0):
    """Return ``kernel_parts`` of several kernels (frames x 4 x k), none with blur 0."""
    basis = _basis(kappa)
    mid = np.outer(blurs, basis.mid_l)
    mid += np.outer(curves, basis.mid_q)
    half = np.outer(blurs, 0.5 * basis.width_l)
    half += np.outer(curves, 0.5 * basis.width_q)
    half[np.abs(half) < _TINY] = _TINY
    sinc, slope = _sinc_parts(half, k, k_safe)
    rotor = _turns(-mid, k)
    common = rotor * sinc
    slope = rotor * slope
    parts = np.empty((len(mid), 4, k.size), complex)
    np.matmul(basis.phase_weights, common, out=parts[:, 1:])
    width = basis.sinc_weights @ slope
    width *= k
    parts[:, 2:] *= mik
    parts[:, 2:] += width
    parts[:, 0] = parts[:, 1]
    parts[:, 1] *= mik
    return parts


def _kernel_parts_at_rest(k, mik, curve, basis=_QUADRATIC):
    """Return ``kernel_parts`` for blur 0, rounded exactly as the fits have always had it.

    d/dblur is 0 there (the kernel is even in the blur), so what a Gauss-Newton step from
    blur 0 does is decided by the rounding of that 0; kept as it was, the fits are too.
    """
    mid = curve * basis.mid_q
    z = np.outer(0.5 * (curve * basis.width_q), k)
    rotor = np.exp(np.outer(mid, mik))
    sinc = np.sinc(z * (1.0 / np.pi))
    d_sinc = rotor * ((np.cos(z) - sinc) / np.where(np.abs(z) < 1e-12, 1.0, z)) * k
    common = rotor * sinc
    parts = np.empty((4, k.size), complex)
    parts[0] = common.mean(axis=0)
    parts[1] = parts[0] * mik
    parts[2] = (common * (basis.mid_l[:, None] * mik)
                + d_sinc * (0.5 * basis.width_l)[:, None]).mean(axis=0)
    parts[3] = (common * (basis.mid_q[:, None] * mik)
                + d_sinc * (0.5 * basis.width_q)[:, None]).mean(axis=0)
    return parts


def kernel_derivatives(k: np.ndarray, blur: float, curve: float, kappa: float = 0.0):
    """Return the motion kernel's spectrum (as template.kernel_spectrum) and d/dblur, d/dcurve.

    The kernel is the distribution of ``blur u + curve (u^2 - 1/12)``, ``u`` uniform in
    [-1/2, 1/2] (or with ``kappa``, a sinusoid's path: template.path_knots), as ``SEGMENTS``
    straight segments of equal duration.
    """
    spectrum, _, d_blur, d_curve = kernel_parts(k, *frequencies(k), blur, curve, 0.0, kappa)
    return spectrum, d_blur, d_curve


def smears(k, mik, k_safe, blurs, curves, shifts, kappa=0.0) -> np.ndarray:
    """Return the spectra of kernels (rows, as ``kernel_spectra``); ``frequencies(k)``."""
    basis = _basis(kappa)
    ends = np.outer(blurs, basis.ends[0])
    ends += np.outer(curves, basis.ends[1])
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
    mid = np.outer(blurs, basis.mid_l)
    mid += np.outer(curves, basis.mid_q)
    mid += np.asarray(shifts, dtype=float)[:, None]
    half = np.outer(blurs, 0.5 * basis.width_l)
    half += np.outer(curves, 0.5 * basis.width_q)
    half[np.abs(half) < _TINY] = _TINY
    rotor = _turns(-mid, k)
    rotor *= _sinc_parts(half, k, k_safe, slope=False)[0]
    return rotor.sum(axis=1) / SEGMENTS


def kernel_spectra(k: np.ndarray, blurs: np.ndarray, curves: np.ndarray,
                   shifts: np.ndarray, kappa: float = 0.0) -> np.ndarray:
    """Return the spectra of several kernels (rows), each shifted by ``shifts`` (px).

    ``kappa``: a sinusoidal path's turn over the exposure (template.path_knots; 0: quadratic).
    """
    return smears(k, *frequencies(k), blurs, curves, shifts, kappa)
