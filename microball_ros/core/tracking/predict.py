"""Motion prediction for the gated search: where the mark will be in the next frames.

Owns the mark's recent track (image columns, frame by frame, NaN when lost) and a linear
predictor fitted to it by least squares: a nearly periodic motion (a sinusoid and its
harmonics, slow drift) obeys a short linear recurrence ``x[n] = sum a_i x[n - i] + b``, so a
few coefficients fitted over the last periods predict the next frame to a fraction of a pixel
without knowing the frequency. With too little history for it (the first frames, or after a
loss), a mark whose motion's frequency is known from priming (``use_frequency``) is predicted
by a sinusoid of that frequency and its second harmonic fitted to the last ``WARM_LEAST`` or
more positions; else it falls back to constant velocity, then to the last position.
``Prediction.spread`` says how far to trust the prediction (infinite: not at all, the whole
ROI is searched).
"""

from collections import deque
import functools
import math
from typing import NamedTuple

import numpy as np

from microball_ros.core.tracking.small_linalg import lstsq

WARM_LEAST = 7  # positions to predict from with a known frequency (5 coefficients)
WARM_FLOOR = 0.25  # px: its spread at least (a gate of 6 spreads + 3 px: 4.5 px at least)


class Prediction(NamedTuple):
    """Predicted column of this frame and the next, one-step spread (px); previous column."""

    column: float
    following: float
    previous: float
    before: float
    spread: float


@functools.lru_cache(maxsize=8)
def _windows(size: int, length: int) -> np.ndarray:
    """Return the indices of every run of ``length`` in ``size`` values (one per row)."""
    index = np.arange(size - length + 1)[:, None] + np.arange(length)
    index.flags.writeable = False
    return index


class MotionPredictor:
    """Linear prediction of a mark's column from its recent valid positions."""

    def __init__(self, order: int = 4, history: int = 60):
        """Keep ``history`` frames and fit a recurrence of ``order`` past values."""
        self.order = int(order)
        self._track: deque[float] = deque(maxlen=int(history))
        self._omega = math.nan  # rad/frame, ``use_frequency``
        self._scatter = 0.0

    def use_frequency(self, omega: float, scatter: float) -> None:
        """Predict the first frames by a sinusoid of ``omega`` (rad/frame) (``_warm``).

        ``scatter`` (px): the positions' scatter about the motion while priming.
        """
        self._omega, self._scatter = float(omega), float(scatter)

    def reset(self) -> None:
        """Forget the track."""
        self._track.clear()

    def add(self, column: float) -> None:
        """Append this frame's column (NaN when the mark was lost)."""
        self._track.append(float(column))

    def lost(self) -> bool:
        """Return True if the mark was lost in the last frame (after at least one frame)."""
        return bool(self._track) and not math.isfinite(self._track[-1])

    def _recurrence(self, track):
        p = self.order
        if track.size <= p:
            return None
        windows = track[_windows(track.size, p + 1)]  # as sliding_window_view, faster
        windows = windows[np.isfinite(windows).all(axis=1)]
        if len(windows) < 3 * (p + 1):
            return None
        design = np.empty((len(windows), p + 1))
        design[:, :p] = windows[:, -2::-1]
        design[:, p] = 1.0
        goal = windows[:, -1]
        coef = lstsq(design, goal)
        residual = goal - design @ coef
        spread = math.sqrt(float(residual @ residual) / max(len(goal) - p - 1, 1))
        return coef, spread

    def predict(self) -> Prediction | None:
        """Return the prediction for the next frame, or None without any recent position."""
        track = np.array(self._track)
        if track.size == 0 or not np.isfinite(track[-1]):
            return None
        previous = track[-1]
        before = track[-2] if track.size >= 2 else math.nan
        p = self.order
        fitted = self._recurrence(track) if np.all(np.isfinite(track[-p:])) else None
        if fitted is not None:
            coef, spread = fitted
            recent = list(track[-p:][::-1])
            column = float(np.dot(coef[:-1], recent) + coef[-1])
            following = float(np.dot(coef[:-1], [column] + recent[:-1]) + coef[-1])
            return Prediction(column, following, previous, before, max(spread, 0.05))
        warm = self._warm(track) if math.isfinite(self._omega) else None
        if warm is not None:
            return Prediction(warm[0], warm[1], previous, before, warm[2])
        if math.isfinite(before):
            velocity = previous - before
            return Prediction(previous + velocity, previous + 2 * velocity, previous, before,
                              math.inf)
        return Prediction(previous, previous, previous, before, math.inf)

    def _warm(self, track):
        """Return (column, following, spread) from a sinusoid of the known frequency, or None.

        Fitted (offset, cosine and sine of the fundamental and the second harmonic) to the
        positions found among the last ``3 (order + 1) + order`` frames (what the recurrence
        needs), at least ``WARM_LEAST``; the spread is the fit's residual per degree of freedom
        widened by the extrapolation (over 170 rendered tracks the next frame was at most 0.65
        of the gate away), at least the priming scatter and ``WARM_FLOOR``.
        """
        recent = track[-(3 * (self.order + 1) + self.order):]
        frames = np.flatnonzero(np.isfinite(recent)).astype(float)
        if frames.size < WARM_LEAST:
            return None
        frames -= recent.size  # the next frame is at 0

        def design(t):
            angle = self._omega * np.asarray(t, dtype=float)
            columns = [np.ones_like(angle)]
            for k in (1, 2):  # and the second harmonic, a crank's
                columns += [np.cos(k * angle), np.sin(k * angle)]
            return np.column_stack(columns)

        values = recent[np.isfinite(recent)]
        basis = design(frames)
        inverse = np.linalg.pinv(basis)
        coef = inverse @ values
        residual = values - basis @ coef
        ahead = design([0.0, 1.0])
        # The residual per degree of freedom, times what extrapolating to the next frame
        # adds to it (its leverage: 1 + a (B'B)^-1 a', with (B'B)^-1 = pinv(B) pinv(B)')
        leverage = float(np.sum((ahead[0] @ inverse) ** 2))
        spread = math.sqrt(float(residual @ residual) / (frames.size - 5)
                           * (1.0 + leverage))
        column, following = (float(v) for v in ahead @ coef)
        return column, following, max(spread, self._scatter, WARM_FLOOR)
