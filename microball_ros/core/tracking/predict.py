"""Motion prediction for the gated search: where the mark will be in the next frames.

Owns the mark's recent track (image columns, frame by frame, NaN when lost) and a linear
predictor fitted to it by least squares: a nearly periodic motion (a sinusoid and its
harmonics, slow drift) obeys a short linear recurrence ``x[n] = sum a_i x[n - i] + b``, so a
few coefficients fitted over the last periods predict the next frame to a fraction of a pixel
without knowing the frequency. With too little history it falls back to constant velocity,
then to the last position, and says how far to trust the prediction (``Prediction.spread``).
"""

from collections import deque
import math
from typing import NamedTuple

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view


class Prediction(NamedTuple):
    """Predicted column of this frame and the next, one-step spread (px); previous column."""

    column: float
    following: float
    previous: float
    before: float
    spread: float


class MotionPredictor:
    """Linear prediction of a mark's column from its recent valid positions."""

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

    def lost(self) -> bool:
        """Return True if the mark was lost in the last frame (after at least one frame)."""
        return bool(self._track) and not math.isfinite(self._track[-1])

    def _recurrence(self, track):
        p = self.order
        if track.size <= p:
            return None
        windows = sliding_window_view(track, p + 1)
        windows = windows[np.all(np.isfinite(windows), axis=1)]
        if len(windows) < 3 * (p + 1):
            return None
        design = np.column_stack([windows[:, -2::-1], np.ones(len(windows))])
        goal = windows[:, -1]
        scale = max(float(np.std(goal)), 1.0)
        coef, *_ = np.linalg.lstsq(design, goal, rcond=None)
        residual = goal - design @ coef
        spread = math.sqrt(float(residual @ residual) / max(len(goal) - p - 1, 1))
        return coef, spread, scale

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
            coef, spread, _ = fitted
            recent = list(track[-p:][::-1])
            column = float(np.dot(coef[:-1], recent) + coef[-1])
            following = float(np.dot(coef[:-1], [column] + recent[:-1]) + coef[-1])
            return Prediction(column, following, previous, before, max(spread, 0.05))
        if math.isfinite(before):
            velocity = previous - before
            return Prediction(previous + velocity, previous + 2 * velocity, previous, before,
                              math.inf)
        return Prediction(previous, previous, previous, before, math.inf)
