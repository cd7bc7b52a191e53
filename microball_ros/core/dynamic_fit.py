"""Dynamic friction models, identified when the loop test finds memory (issue 13, item 8).

Output-error fits: each candidate's state is integrated along the MEASURED relative motion (the
pipeline's v_rel for the fit and the relative positions, on the uniform grid, split into pieces
at gaps) and the a_slid it predicts is compared with the measured one; least squares over
bounded log parameters (scipy.optimize.least_squares). Nothing differentiates the noisy a_slid
(the equation-error fit a + tau da/dt + L(v) = 0 this replaces used the estimated jerk: errors
in variables; on bench/independent lag-40ms seed 0 it gave a lagged viscous law with tau 42.5
[42.3, 42.7] ms for 40 ms; this fit: lagged Langevin, 40.01 [39.88, 40.14] ms).

Between samples the relative position is a cubic Hermite curve through the measured positions
with the v_rel estimates as slopes, evaluated SUBSTEPS times finer; along it the states advance
exactly for the input linear over a sub-step:

* a first-order lag of a static law, tau dF/dt = L(v) - F, a = -F: a linear filter of
  L(v(t)), exact for L(v) linear over a sub-step (first-order hold; scipy.signal.lfilter).
  Candidates ``lagged_langevin`` (A, alpha, tau) and ``lagged_viscous`` (c, tau);
* Dahl (shape exponent 1), dF/dt = sigma0 (v - |v| F / Fc), a = -F: rate independent, F relaxes
  towards sign(dx) Fc exponentially in the distance slid, Fc / sigma0 the length (``relax``);
  ``dahl`` (Fc, sigma0);
* LuGre (Canudas de Wit et al. 1995), dz/dt = v - sigma0 |v| z / g(v), g the Stribeck curve,
  L = sigma0 z + sigma1 dz/dt + sigma2 v: z relaxes like Dahl's F with g(v) for Fc. ``lugre``
  fits all six: sigma1 cannot be fixed (at the true other five, sigma1 = 0 instead of 40 raises
  the rms residual from 0.017 to 0.075 m/s^2 on bench/independent lugre seed 0), but at 30 fps
  the six are not separately identifiable: the fit is precise (small spread over seeds) and
  biased (Fs 0.03 for 0.25, sigma0 3400 for 2000), a description of the loop, not parameters.

The measured a_slid is what the three-stage algorithm makes of the positions: the model's a_slid
is seen through the same camera (Track.seen), which matters for Dahl and LuGre, whose corners at
the reversals have harmonics far beyond Nyquist. The initial state of a piece: the state the
model reaches after its first stator period (the motion is periodic); every sample is fitted, so
the AIC compares with the static laws' on the same samples.

Intervals: 95 %, Wald in the log parameters with the covariance the larger of the
independent-noise one and the batch-means sandwich over the pipeline's blocks of whole periods
(the residuals are coloured), Student t with blocks - 1 degrees of freedom, as the static laws'
(core.pipeline_fit). Choice: the lowest AIC among the dynamic candidates; ``delta_aic`` against
the best static law on the same samples says whether memory is worth its parameters.

Measured on bench/independent, 6 seeds each (true value, mean estimate, coverage of the 95 %
intervals): lag-10ms tau 10 ms, 10.01 ms, 6/6 (A 5/6, alpha 5/6); lag-40ms tau 40 ms, 40.00
ms, 6/6 (A 6/6, alpha 6/6). Dahl: Fc 0.25, 0.2495, 4/6; sigma0 2000, 2073, 0/6: at 30 fps
the presliding length Fc / sigma0 = 125 um is slid within about one frame at each reversal and
the cubic path between frames misses it (+3.9 % noise-free), so LuGre, which nests Dahl, wins
by AIC in 5 of 6 seeds. Long records: the candidates are fitted to the first SEARCH_SAMPLES,
compared on the whole record at those parameters, and the chosen one refitted to all of it
(a 10-min lag-40ms record: 3.6 s for the dynamic part on the shared 2-core machine).
"""

from dataclasses import dataclass, fields
import math
from typing import ClassVar

import numpy as np
from scipy import fft, optimize, signal, stats
from scipy.interpolate import CubicHermiteSpline, CubicSpline

from microball_ros.core import friction

SUBSTEPS = 8  # fine steps per sample along which the states are integrated
PAD = 2  # samples of v_rel extrapolated at each end of a piece, under the camera's kernel
WARMUP_PERIODS = 1.0  # the periodic initial state: the state after this many periods
MAX_RELAXATION = 700.0  # exp(-x) of a chunk of the time-varying recurrence stays in float64
SEARCH_SAMPLES = 3600  # longer records: candidates fitted on the first this many samples
REFIT_EVALUATIONS = 30  # then the chosen one refitted to the whole record from there
LOG_SPAN = math.log(1e4)  # bounds: each parameter within 1e4 of its start either way


@dataclass(frozen=True)
class Dahl:
    """Dahl friction (shape exponent 1), per unit mass: dF/dt = sigma0 (v - |v| F / Fc), a = -F.

    Fc (m/s^2): the level F approaches in steady sliding; sigma0 (1/s^2): the stiffness at a
    reversal, dF/dx = sigma0; Fc / sigma0 is the distance over which the friction builds up. The
    state interface of friction.LaggedFriction and friction.LuGre, so friction.validate runs it.
    """

    sigma0: float = 2000.0
    Fc: float = 0.25
    name: ClassVar[str] = 'dahl'
    n_states: ClassVar[int] = 1

    @property
    def params(self) -> dict[str, float]:
        """Return the parameters as a dict, field name -> value."""
        return {f.name: getattr(self, f.name) for f in fields(self)}

    def force(self, v_rel):
        """Return the steady-sliding friction Fc sign(v_rel), m/s^2."""
        return self.Fc * np.sign(v_rel)

    def acceleration(self, v_rel):
        """Return the steady-sliding slider acceleration -force(v_rel), m/s^2."""
        return -self.force(v_rel)

    def initial_state(self) -> np.ndarray:
        """Return the initial friction [F] = [0]."""
        return np.zeros(1)

    def state_derivative(self, state: np.ndarray, v_rel: float) -> np.ndarray:
        """Return [dF/dt]."""
        return np.array([self.sigma0 * (v_rel - abs(v_rel) * state[0] / self.Fc)])

    def acceleration_from_state(self, state: np.ndarray, v_rel: float) -> float:
        """Return the slider acceleration -F, m/s^2."""
        return -float(state[0])


@dataclass
class _Piece:
    """A contiguous stretch of samples: [start, stop) into the fitted arrays, v_rel fine.

    ``fine`` spans PAD samples before the first to PAD after the last (the camera's kernel
    needs them), SUBSTEPS points per sample: sample n of the piece is fine[(n + PAD) m].
    """

    start: int
    stop: int
    fine: np.ndarray
    step: np.ndarray  # the relative displacement over each fine step, m
    period: int  # fine steps in one stator period (the warm-up)


class Track:
    """The measured v_rel and a_slid the dynamic models are fitted to, split at gaps.

    ``velocity``, ``acceleration``: the samples (m/s, m/s^2); ``index``: their grid indices
    (consecutive within a piece); ``dt`` (s) the grid step; ``frequency`` (Hz) the stator's;
    ``exposure`` (s) the camera's; ``position`` (m): the relative positions at the samples, the
    path between samples then a cubic Hermite curve (None: a cubic spline of v_rel). Pieces
    shorter than the warm-up plus two samples are left out (``kept``: the samples fitted).

    ``camera`` True: a model's a_slid is compared with the measured one as the three-stage
    algorithm sees it. Its a_slid at a sample is the center second difference of positions
    averaged over the exposure, i.e. the true a_slid convolved with a triangle of half-width
    dt (and a box of the exposure), compensated bin by bin by 1 / (sinc^2(f dt) sinc(f T)).
    Below Nyquist that is the identity; a harmonic above Nyquist comes out attenuated by
    (f_alias / f)^2 instead of aliased at full amplitude. Dahl and LuGre have sharp corners at
    the reversals whose harmonics reach far beyond Nyquist at 30 fps: on bench/independent dahl
    seed 0 the rms residual at the true parameters is 0.014 m/s^2 with the point values and
    0.0085 with the camera's view (noise alone 0.008).
    """

    def __init__(self, velocity, acceleration, index, dt, frequency, exposure=0.0,
                 substeps=SUBSTEPS, camera=True, position=None):
        """Split the samples at gaps of the grid index and interpolate v_rel in each piece."""
        self.velocity = np.asarray(velocity, dtype=float)
        self.acceleration = np.asarray(acceleration, dtype=float)
        index = np.asarray(index)
        self.dt, self.frequency, self.substeps = float(dt), float(frequency), int(substeps)
        self.h = self.dt / self.substeps
        self.camera = camera
        m = self.substeps
        hat = 1.0 - np.abs(np.arange(-m, m + 1)) / m
        reach = exposure / (2 * self.h)  # the exposure's box, centred, fractional ends
        steps = np.arange(-math.ceil(reach), math.ceil(reach) + 1)
        box = np.clip(reach + 0.5 - np.abs(steps), 0.0, 1.0)
        kernel = np.convolve(hat, box)
        self.kernel = kernel / kernel.sum()
        self.exposure = float(exposure)
        period = max(1, int(round(WARMUP_PERIODS / (self.frequency * self.h))))
        breaks = np.flatnonzero(np.diff(index) != 1) + 1
        self.pieces = []
        self.kept = np.zeros(len(index), dtype=bool)
        for start, stop in zip([0, *breaks], [*breaks, len(index)], strict=True):
            if (stop - start - 1) * m < period + 2 * m:
                continue
            coarse = np.arange(stop - start) * self.dt
            fine = np.arange(-PAD * m, (stop - start - 1 + PAD) * m + 1) * self.h
            if position is None:
                spline = CubicSpline(coarse, self.velocity[start:stop])
                v = spline(fine)
                step = 0.5 * self.h * (v[:-1] + v[1:])
            else:
                path = CubicHermiteSpline(coarse, position[start:stop],
                                          self.velocity[start:stop])
                v, step = path(fine, 1), np.diff(path(fine))
            self.pieces.append(_Piece(start, stop, v, step, period))
            self.kept[start:stop] = True
        self.scale = float(np.sqrt(np.mean(self.acceleration[self.kept] ** 2))) \
            if self.kept.any() else 1.0

    def seen(self, fine_acceleration, piece):
        """Return the a_slid at the piece's samples as the camera sees it, from the fine grid."""
        m = self.substeps
        count = piece.stop - piece.start
        if not self.camera:
            return fine_acceleration[PAD * m:(PAD + count) * m:m]
        half = len(self.kernel) // 2
        windows = np.lib.stride_tricks.sliding_window_view(fine_acceleration, len(self.kernel))
        first = PAD * m - half
        crude = windows[first:first + count * m:m] @ self.kernel
        # Compensated over the even extension: the periodic FFT sees no jump at the ends.
        mirrored = np.concatenate([crude, crude[::-1]])
        frequencies = fft.rfftfreq(2 * count, self.dt)
        gain = 1.0 / (np.sinc(frequencies * self.dt) ** 2 * np.sinc(frequencies * self.exposure))
        return fft.irfft(fft.rfft(mirrored) * gain, 2 * count)[:count]

    def predict(self, model, params):
        """Return the a_slid the model with params predicts at the kept samples."""
        return np.concatenate([self.seen(model.predict(params, piece, self), piece)
                               for piece in self.pieces])

    @property
    def measured(self):
        """Return the measured a_slid at the kept samples."""
        return self.acceleration[self.kept]


def _first_order_hold(tau, h):
    """Return (b, a) of tau dF/dt + F = u, exact for u linear over each step h."""
    phi = math.exp(-h / tau)
    gain = -math.expm1(-h / tau)  # 1 - phi, accurate for h << tau
    b1 = 1.0 - tau / h * gain if h / tau > 1e-3 else h / (2 * tau)
    return np.array([b1, gain - b1]), np.array([1.0, -phi])


def _lag(u, tau, h, period):
    """Return F along u for the lag, starting from the state a period of u leads to."""
    b, a = _first_order_hold(tau, h)
    warm, _ = signal.lfilter(b, a, u[:period + 1], zi=[u[0] * (1 - b[0])])
    out, _ = signal.lfilter(b, a, u, zi=[warm[-1] - b[0] * u[0]])
    return out


def relax(rate, target, y0):
    """Return y[0] = y0, y[k+1] = phi[k] y[k] + (1 - phi[k]) target[k], phi = exp(-rate).

    Vectorised: the recurrence is solved in chunks over which the summed rate (>= 0) stays
    below MAX_RELAXATION, so the products of phi are formed in float64 without underflow.
    """
    rate = np.minimum(np.asarray(rate, dtype=float), 50.0)
    target = np.asarray(target, dtype=float)
    y = np.empty(len(rate) + 1)
    y[0] = y0
    total = np.cumsum(rate)
    chunk = np.floor(total / (MAX_RELAXATION - 50.0)).astype(int)
    edges = np.flatnonzero(np.diff(chunk)) + 1
    start_value = y0
    for lo, hi in zip([0, *edges], [*edges, len(rate)], strict=True):
        decay = np.cumsum(rate[lo:hi])  # D_j: summed rate through step j of the chunk
        weights = -np.expm1(-rate[lo:hi]) * target[lo:hi] * np.exp(decay)
        # y[k+1] = exp(-D_k) (y_lo + sum_{j<=k} (1 - phi_j) target_j exp(D_j))
        y[lo + 1:hi + 1] = np.exp(-decay) * (start_value + np.cumsum(weights))
        start_value = y[hi]
    return y


def _bristle(piece, sigma0, level):
    """Return the bristle state z along fine v_rel (LuGre; Dahl with level Fc), periodic start.

    Over a sub-step with v_rel of one sign z relaxes towards sign(v) g / sigma0 by
    exp(-sigma0 |dx| / g), dx the distance slid (trapezoid of v_rel), g at the mid velocity.
    """
    period, step = piece.period, piece.step
    g = level(0.5 * (piece.fine[:-1] + piece.fine[1:]))
    rate = sigma0 * np.abs(step) / g
    target = np.sign(step) * g / sigma0
    warm = relax(rate[:period], target[:period], target[0])
    return relax(rate, target, warm[-1])


@dataclass(frozen=True)
class _Candidate:
    """A dynamic model the fit can try: parameter names and how it predicts a_slid."""

    name: str
    names: tuple
    kind: str  # 'lag' (of base), 'dahl', 'lugre'
    base: str | None = None
    fixed: tuple = ()  # (name, value) pairs of parameters held fixed

    def predict(self, params, piece, track):
        """Return the a_slid the model predicts on the piece's fine grid."""
        h = track.h
        if self.kind == 'lag':
            if self.base == 'langevin':
                u = friction.langevin(piece.fine, params['A'], params['alpha'])
            else:
                u = params['c'] * piece.fine
            return -_lag(u, params['tau'], h, piece.period)
        if self.kind == 'dahl':
            fc = params['Fc']
            z = _bristle(piece, params['sigma0'], lambda v: np.full_like(v, fc))
            return -params['sigma0'] * z
        p = {**dict(self.fixed), **params}
        fc, fs, vs = p['Fc'], p['Fs'], p['vs']

        def level(v):
            return fc + (fs - fc) * np.exp(-(v / vs) ** 2)

        z = _bristle(piece, p['sigma0'], level)
        v = piece.fine
        rate = v - p['sigma0'] * np.abs(v) * z / level(v)
        return -(p['sigma0'] * z + p['sigma1'] * rate + p['sigma2'] * v)

    def law(self, params):
        """Return the fitted law for friction.validate (the state interface)."""
        if self.kind == 'lag':
            base = (friction.Langevin(params['A'], params['alpha']) if self.base == 'langevin'
                    else friction.Viscous(params['c']))
            return friction.LaggedFriction(base, params['tau'])
        if self.kind == 'dahl':
            return Dahl(params['sigma0'], params['Fc'])
        p = {**dict(self.fixed), **params}
        return friction.LuGre(sigma0=p['sigma0'], sigma1=p['sigma1'], sigma2=p['sigma2'],
                              Fc=p['Fc'], Fs=p['Fs'], vs=p['vs'])


CANDIDATES = (
    _Candidate('lagged_langevin', ('A', 'alpha', 'tau'), 'lag', 'langevin'),
    _Candidate('lagged_viscous', ('c', 'tau'), 'lag', 'viscous'),
    _Candidate('dahl', ('Fc', 'sigma0'), 'dahl'),
    _Candidate('lugre', ('Fc', 'Fs', 'vs', 'sigma0', 'sigma1', 'sigma2'), 'lugre'),
)


def _scan(candidate, track, grid, linear=None):
    """Return the parameters of ``grid`` (a list of dicts) that fit best.

    ``linear``: the name of a parameter the prediction is proportional to; its best value is
    solved for at each point of the grid (the value in the grid is the one it scales).
    """
    best, best_rss = grid[0], math.inf
    measured = track.measured
    for trial in grid:
        with np.errstate(all='ignore'):
            predicted = track.predict(candidate, trial)
            if linear is not None:
                factor = float(predicted @ measured) / float(predicted @ predicted)
                if not factor > 0:
                    continue
                trial = {**trial, linear: trial[linear] * factor}
                predicted = predicted * factor
            residual = predicted - measured
        rss = float(residual @ residual)
        if rss < best_rss:
            best, best_rss = trial, rss
    return best


def starts(track, fit, comparison, fitted):
    """Return {candidate name: (grid of starting parameters, linear parameter or None)}.

    ``fitted``: the candidates fitted so far (LuGre starts from Dahl's fit).
    """
    kept = track.kept
    v, a = track.velocity[kept], track.acceleration[kept]
    v_top = float(np.percentile(np.abs(v), 99)) or 1e-3
    a_top = float(np.percentile(np.abs(a), 99)) or 1e-3
    w = 2 * math.pi * track.frequency
    taus = np.geomspace(0.03, 3.0, 9) / w
    alphas = np.geomspace(0.3, 10.0, 7) / v_top
    if fit is not None:
        alphas = np.append(alphas, fit.params['alpha'])
    viscous = next((e.params['c'] for e in comparison if e.ok and e.name == 'viscous'),
                   a_top / v_top)
    lengths = np.geomspace(0.003, 1.0, 9) * v_top / w  # Fc / sigma0, against the stroke
    out: dict[str, tuple[list[dict], str | None]] = {
        'lagged_langevin': ([{'A': a_top, 'alpha': alpha, 'tau': tau}
                             for alpha in alphas for tau in taus], 'A'),
        'lagged_viscous': ([{'c': viscous, 'tau': tau} for tau in taus], 'c'),
        'dahl': ([{'Fc': a_top, 'sigma0': a_top / length} for length in lengths], 'Fc'),
    }
    dahl = fitted.get('dahl')
    dahl = dahl['params'] if dahl else {'Fc': a_top, 'sigma0': a_top * w / v_top * 10}
    root = math.sqrt(dahl['sigma0'])
    out['lugre'] = ([{'Fc': 0.8 * dahl['Fc'], 'Fs': 1.2 * dahl['Fc'], 'vs': vs * v_top,
                      'sigma0': dahl['sigma0'], 'sigma1': damping * root,
                      'sigma2': 0.1 * a_top / v_top}
                     for damping in (0.1, 0.3, 1.0, 2.0) for vs in (0.05, 0.15, 0.4)], None)
    return out


def _intervals(jacobian, residual, blocks, k):
    """Return the 95 % half-widths of the log parameters (batch means or iid, the larger)."""
    n = len(residual)
    hessian = jacobian.T @ jacobian
    inverse = np.linalg.pinv(hessian)
    rss = float(residual @ residual)
    iid = np.diag(inverse) * rss / max(n - k, 1)
    _, block = np.unique(blocks, return_inverse=True)
    count = int(block.max()) + 1
    per_block = np.zeros((count, k))
    np.add.at(per_block, block, jacobian * residual[:, None])
    per_block -= per_block.mean(axis=0)
    sandwich = np.diag(inverse @ (per_block.T @ per_block) @ inverse) * count / max(count - 1, 1)
    return stats.t.ppf(0.975, max(count - 1, 1)) * np.sqrt(np.maximum(iid, sandwich))


def fit_candidate(candidate, track, start, blocks, max_nfev=None):
    """Fit one dynamic model by output error; return its entry (a dict), 'error' if it failed.

    ``start``: the parameters to start from (a dict), or (grid, linear): the best of grid
    (_scan). ``blocks``: the batch-means block of every kept sample.
    """
    params = start if isinstance(start, dict) else _scan(candidate, track, *start)
    names = candidate.names
    scales = np.array([params[name] for name in names], dtype=float)
    measured, k = track.measured, len(names)

    def residual(theta):
        values = dict(zip(names, scales * np.exp(theta), strict=True))
        with np.errstate(all='ignore'):
            out = (track.predict(candidate, values) - measured) / track.scale
        return np.where(np.isfinite(out), out, 1e3)

    try:
        solution = optimize.least_squares(residual, np.zeros(k), bounds=(-LOG_SPAN, LOG_SPAN),
                                          method='trf', x_scale=1.0, max_nfev=max_nfev)
    except (ValueError, ArithmeticError, np.linalg.LinAlgError) as error:
        return {'name': candidate.name, 'ok': False, 'error': friction.one_line(error)}
    values = scales * np.exp(solution.x)
    rss = float(solution.fun @ solution.fun) * track.scale ** 2
    n = len(measured)
    if not (solution.status >= (0 if max_nfev else 1) and math.isfinite(rss) and rss > 0):
        return {'name': candidate.name, 'ok': False,
                'error': f'{candidate.name}: the fit did not converge ({solution.message})'}
    half = _intervals(solution.jac, solution.fun, blocks, k)
    at_bound = [name for name, x in zip(names, solution.x, strict=True)
                if abs(x) > LOG_SPAN - 1e-3]
    params = {name: float(value) for name, value in zip(names, values, strict=True)}
    ci95 = {name: (float(value * math.exp(-h)), float(value * math.exp(h)))
            if h < 700 else (0.0, math.inf)
            for name, value, h in zip(names, values, half, strict=True)}
    return {'name': candidate.name, 'ok': True, 'error': None, 'params': params,
            'ci95': ci95, 'fixed': dict(candidate.fixed), 'at_bound': at_bound,
            'aic': n * math.log(rss / n) + 2 * (k + 1), 'rmse': math.sqrt(rss / n), 'n': n,
            'candidate': candidate}


def _static_aic(entry, track):
    """Return a static law's AIC on the kept samples (its comparison AIC if all are kept)."""
    if track.kept.all():
        return entry.aic
    v, a = track.velocity[track.kept], track.acceleration[track.kept]
    residual = entry.law.acceleration(v) - a
    n, k = len(a), len(entry.params)
    return n * math.log(float(residual @ residual) / n) + 2 * (k + 1)


def _determined(ci95, span=1e3):
    """Return True if every 95 % interval is finite, above zero and within ``span``-fold."""
    return all(0 < lo and math.isfinite(hi) and hi < span * lo for lo, hi in ci95.values())


def identify_dynamic(result, blocks):
    """Return the dynamic model of a PipelineResult with memory, a dict, or None.

    ``result``: the pipeline's result with its static ``fit`` and ``comparison`` set;
    ``blocks``: the batch-means block of every estimated sample (core.pipeline_fit). Every
    candidate is fitted; the one of lowest AIC among those whose intervals are all bounded
    (else among all) is returned as {name, params, ci95, aic, rmse, law (for
    friction.validate), fixed, at_bound, candidates [{name, kind, ok, error, aic, rmse,
    determined}] (the static laws too, on the same samples), static_best, delta_aic (chosen
    minus best static; negative: the memory is worth its parameters), samples}. None if no
    candidate could be fitted or the record has no piece longer than the warm-up.
    """
    est, grid = result.estimate, result.grid
    position = grid.slider[est.index] - grid.stator[est.index]

    def track_of(stop):
        return Track(result.velocity_for_fit[:stop], result.fit_acceleration[:stop],
                     est.index[:stop], result.sample_period, result.frequency,
                     exposure=result.options.exposure, position=position[:stop])

    blocks = np.asarray(blocks)
    track = track_of(len(est.index))
    if not track.kept.any():
        return None
    # A long record: the candidates are fitted on its first SEARCH_SAMPLES, compared on all of
    # it at those parameters, and the chosen one refitted to all of it from there.
    search = track if len(est.index) <= SEARCH_SAMPLES else track_of(SEARCH_SAMPLES)
    if not search.kept.any():
        search = track
    fitted: dict[str, dict | None] = {}
    errors = {}
    for candidate in CANDIDATES:  # dahl before lugre: its fit starts LuGre's
        start = starts(search, result.fit, result.comparison, fitted)[candidate.name]
        entry = fit_candidate(candidate, search, start,
                              blocks[:len(search.kept)][search.kept])
        fitted[candidate.name] = entry if entry['ok'] else None
        errors[candidate.name] = entry['error']
    if search is not track:
        for entry in fitted.values():
            if entry is not None:
                residual = track.predict(entry['candidate'], entry['params']) - track.measured
                n, k = len(residual), len(entry['params'])
                rss = float(residual @ residual)
                entry.update(aic=n * math.log(rss / n) + 2 * (k + 1), rmse=math.sqrt(rss / n))
    dynamic = [entry for entry in fitted.values() if entry is not None]
    if not dynamic:
        return None
    # A model whose every interval is bounded is preferred to a better-scoring one with a
    # parameter the data leave open (Dahl against LuGre, which nests it, on a Dahl record).
    determined = [entry for entry in dynamic if _determined(entry['ci95'])]
    chosen = min(determined or dynamic, key=lambda entry: entry['aic'])
    if search is not track:
        refit = fit_candidate(chosen['candidate'], track, chosen['params'],
                              blocks[track.kept], max_nfev=REFIT_EVALUATIONS)
        if refit['ok']:
            fitted[chosen['name']] = chosen = refit
    statics = [{'name': e.name, 'kind': 'static', 'ok': True, 'error': None,
                'aic': float(_static_aic(e, track)), 'rmse': e.rmse}
               for e in result.comparison if e.ok]
    candidates = []
    for name, entry in fitted.items():
        candidates.append({'name': name, 'kind': 'dynamic', 'ok': entry is not None,
                           'error': errors[name], 'aic': entry and entry['aic'],
                           'rmse': entry and entry['rmse'],
                           'determined': entry is not None and _determined(entry['ci95'])})
    best_static = min(statics, key=lambda entry: entry['aic'], default=None)
    try:  # RK4 at 1 ms (friction.validate) cannot follow a lag much shorter than its step
        law = (chosen['candidate'].law(chosen['params'])
               if chosen['params'].get('tau', 1.0) >= 1e-3 else None)
    except (ValueError, ArithmeticError):
        law = None
    return {'name': chosen['name'], 'params': chosen['params'], 'ci95': chosen['ci95'],
            'aic': chosen['aic'], 'rmse': chosen['rmse'], 'law': law, 'fixed': chosen['fixed'],
            'at_bound': chosen['at_bound'],
            'candidates': sorted(candidates + statics,
                                 key=lambda e: math.inf if e['aic'] is None else e['aic']),
            'static_best': None if best_static is None else best_static['name'],
            'delta_aic': None if best_static is None else chosen['aic'] - best_static['aic'],
            'samples': chosen['n']}
