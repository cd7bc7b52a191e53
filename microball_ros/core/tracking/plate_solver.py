"""The joint learning of core.tracking.plate's plate: ``PlateSolver``.

``PlateSolver`` learns, by alternating least squares, the plate's deficit ``D``
(core.tracking.plate_model.PlateModel), the static field and the frames' light, positions
and kernels; ``motion_kernels`` / ``motion_curvatures``: a frame's kernel from the positions
of it and its neighbours.
"""

import math

import numpy as np
from scipy.ndimage import binary_dilation, binary_opening

from microball_ros.core.tracking.motion_spectra import kernel_spectra
from microball_ros.core.tracking.plate_model import PlateModel, fft_size, grid_window


def motion_kernels(positions: np.ndarray, fraction: float) -> np.ndarray:
    """Return each frame's kernel (blur, curvature; px; rows) from it and its neighbours.

    The quadratic through three frames, over an exposure of ``fraction`` of the frame period:
    blur ``|p[n+1] - p[n-1]| / 2 fraction``, curvature as ``motion_curvatures``; NaN at the
    ends.
    """
    positions = np.asarray(positions, dtype=float)
    kernels = np.full((positions.size, 2), np.nan)
    kernels[1:-1, 0] = np.abs(positions[2:] - positions[:-2]) / 2 * fraction
    kernels[:, 1] = motion_curvatures(positions, kernels[:, 1], fraction)
    return kernels


def motion_curvatures(positions: np.ndarray, fallback: np.ndarray,
                      fraction: float, omega: float = 0.0) -> np.ndarray:
    """Return each frame's kernel curvature from the positions of it and its neighbours.

    ``(p[n+1] - 2 p[n] + p[n-1]) fraction^2 / 2`` (px): the quadratic through three frames,
    over an exposure of ``fraction`` of the frame period; ``fallback`` where a neighbour is
    unknown (NaN). With a sinusoid's ``omega`` (rad/frame; its path's kernels:
    template.path_knots), the sinusoid's own: the second difference of exposure averages is
    ``2 (1 - cos omega) sinc(omega fraction / 2)`` times the acceleration over ``omega^2``
    (0.85 at five frames per period and 0.7 of the period exposed).
    """
    curvatures = np.array(fallback, dtype=float)
    second = (positions[2:] - 2 * positions[1:-1] + positions[:-2]) * fraction * fraction / 2
    if omega > 0.0:
        half = 0.5 * omega * fraction
        second *= omega * omega / (2.0 * (1.0 - math.cos(omega)) * (math.sin(half) / half))
    known = np.isfinite(second)
    curvatures[1:-1][known] = second[known]
    return curvatures


# A robust solver leaves out of the next round the columns of a frame whose residual is over
# OUTLIER_SPREADS robust spreads (1.4826 MAD over all frames' residuals) in runs of at least
# OUTLIER_RUN columns, widened by OUTLIER_WIDEN: something that is neither plate nor light in
# that frame (a particle passing).
OUTLIER_SPREADS, OUTLIER_RUN, OUTLIER_WIDEN = 6.0, 4, 2


def outlier_columns(residual: np.ndarray) -> np.ndarray:
    """Return the columns (frames x columns, True: out) of ``residual`` that are outliers.

    Runs of at least ``OUTLIER_RUN`` columns over ``OUTLIER_SPREADS`` robust spreads of all
    the residuals, widened by ``OUTLIER_WIDEN`` columns either side.
    """
    spread = 1.4826 * float(np.median(np.abs(residual - np.median(residual))))
    if not spread > 0:
        return np.zeros(residual.shape, dtype=bool)
    far = np.abs(residual) > OUTLIER_SPREADS * spread
    far = binary_opening(far, structure=np.ones((1, OUTLIER_RUN), dtype=bool))
    return binary_dilation(far, structure=np.ones((1, 2 * OUTLIER_WIDEN + 1), dtype=bool))


class PlateSolver:
    """The plate seen through one ROI, learned from frames by alternating least squares.

    Model of frame n's profile: ``light_n(x) * static(x) * (1 - sign * (D * K_n)(x - s_n))``,
    ``D`` the whole plate's relative deficit on one grid (every column any frame saw), ``K_n``
    the exposure's motion kernel. Rounds of: ``D`` given the rest (preconditioned conjugate
    gradients on the normal equations, circular convolutions by FFT, batched over frames);
    ``static`` and the frames' light (a low-order polynomial each) given ``D`` (closed form);
    each frame's position and kernel given both (``PlateModel.fit``). From the second round, a
    frame's columns the model misses grossly (``outlier_columns``) are left out of ``D``, the
    static field and its light (those within its reach of the mark stay).
    """

    def __init__(self, profiles: np.ndarray, static: np.ndarray, sign: float,
                 regularisation: float = 0.05, iterations: int = 60, light_order: int = 2):
        """Keep the frames' profiles (frames x columns) and a first static field.

        Each frame's light is a polynomial of degree ``light_order`` over the columns (a gain,
        flicker, and a gradient of the light that changes), times the static field.
        """
        self.profiles = profiles
        self.keep = np.ones(profiles.shape)  # 0: a column left out of a frame (an outlier)
        self.static = static.copy()
        self.sign = float(sign)
        self.basis = np.vander(np.linspace(-1.0, 1.0, profiles.shape[1]), int(light_order) + 1)
        self.light = np.ones(profiles.shape)
        self.regularisation = float(regularisation)
        self.iterations = int(iterations)
        self.plate: PlateModel | None = None
        self.kernels = np.full((len(profiles), 2), np.nan)
        self.positions = np.full(len(profiles), np.nan)
        self.rounds = 0  # how many rounds ``learn`` ran

    def learn(self, positions, kernels, reach, rounds, settled=0.0,
              fraction=None, omega=0.0) -> list[float]:
        """Learn from first positions and kernels (NaN: unknown); return the fits' residuals.

        At most ``rounds`` rounds; fewer once the fits move the positions by under
        ``settled`` px RMS (the slow mode of alternating least squares: positions and ``D``
        shifting together converge by a factor of about 0.6 a round). With the exposure's
        ``fraction`` of the frame period, each round's kernels take their curvature from the
        positions (``motion_curvatures``), not from the fits: over a short exposure the
        curvature is hardly seen, and a fitted one skews the kernels, which ``D`` then learns
        (constant offsets of 0.1-0.2 px on textured plates). With a sinusoid's ``omega``
        (rad/frame) too, the kernels are its path's (template.path_knots: ``kappa`` omega
        times ``fraction``) and so are the curvatures.
        """
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
        kappa = omega * fraction if omega > 0.0 and fraction is not None else 0.0
        plate = PlateModel(size, float(size), center=center, kappa=kappa)
        values = np.zeros(size)
        rms: list[float] = []
        moved_rms = math.inf
        for round_ in range(rounds):
            self.rounds = round_ + 1
            use = np.flatnonzero(ok)
            if use.size < 8:
                return []
            j0 = np.rint(positions[use]).astype(int) - center
            delta = positions[use] - j0 - center
            spectra = kernel_spectra(plate.k, kernels[use, 0], kernels[use, 1], delta, kappa)
            rows = np.arange(use.size)[:, None]
            cols = np.arange(w)[None, :] - j0[:, None]
            keep = self.keep[use]
            mask = np.zeros((use.size, size))
            mask[rows, cols] = keep
            data = np.zeros((use.size, size))
            ratio = self.profiles[use] / (self.light[use] * self.static[None, :])
            data[rows, cols] = self.sign * (1.0 - ratio) * keep
            values = self._solve(values, spectra, mask, data, w / size)
            plate.values = values
            plate.spectrum = np.fft.rfft(values)
            model = 1.0 - self.sign * np.fft.irfft(plate.spectrum * spectra, size,
                                                   axis=1)[rows, cols]
            measured, light = self.profiles[use], self.light[use]
            kept = np.where(keep.sum(axis=0) > 0, keep, 1.0)  # a column no frame keeps: all
            for _ in range(2):
                static = ((kept * light * measured * model).sum(axis=0)
                          / (kept * light ** 2 * model ** 2).sum(axis=0))
                light = self._light(measured, static * model, keep)
                scale = light.mean(axis=0)  # a light common to all frames is static
                light, static = light / scale, static * scale
            self.static, self.light[use] = static, light
            # Not at the mark: there the positions' fits answer for a misfit
            near = np.abs(np.arange(w)[None, :] - positions[use, None]) <= (
                reach + 8.0 + np.abs(kernels[use, :1]) + np.abs(kernels[use, 1:]))
            self.keep[use] = ~(outlier_columns(measured / (light * static) - model) & ~near)
            if round_ == rounds - 1 or moved_rms < settled:
                break
            rms = []
            longest = float(np.max(np.abs(kernels[use, 0])) + np.max(np.abs(kernels[use, 1])))
            local = plate.local(0.0, reach + 2.0 * longest + 16.0)
            d = self.sign * (1.0 - self.profiles[use] / (self.light[use] * self.static))
            grids = [grid_window(d[i], positions[n], local.size, local.center)
                     for i, n in enumerate(use)]
            starts = np.array([start for _, _, start in grids])
            fits = local.fit_many(np.array([window for window, _, _ in grids]),
                                  np.array([valid for _, valid, _ in grids]),
                                  positions[use] - starts - local.center, kernels[use, 0],
                                  kernels[use, 1], reach, iterations=2)
            moves = []
            for n, start, fit in zip(use, starts, fits, strict=True):
                moved = (math.nan if fit is None
                         else fit[0] + start + local.center - positions[n])
                if not abs(moved) <= 8.0:
                    ok[n] = False
                    continue
                positions[n] += moved
                kernels[n] = fit[1:3]
                rms.append(fit[5])
                moves.append(moved)
            moved_rms = math.sqrt(float(np.mean(np.square(moves)))) if moves else 0.0
            if fraction is not None:
                kernels[:, 1] = motion_curvatures(np.where(ok, positions, np.nan),
                                                  kernels[:, 1], fraction, omega)
        self.plate, self.kernels, self.positions = plate, kernels, positions
        return rms

    def _light(self, measured, expected, keep):
        """Return each frame's light: the polynomial times ``expected`` nearest ``measured``.

        Least squares over the columns ``keep`` (frames x columns, 0 or 1) holds.
        """
        design = expected[:, :, None] * self.basis[None, :, :]
        normal = np.einsum('nwi,nwj,nw->nij', design, design, keep)
        right = np.einsum('nwi,nw->ni', design, measured * keep)
        coefficients = np.linalg.solve(normal, right[:, :, None])[:, :, 0]
        return coefficients @ self.basis.T

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
