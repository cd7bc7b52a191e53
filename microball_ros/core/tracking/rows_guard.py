"""The learned plate's rows guard on a plain plate: a frame whose rows depart from the mark's.

As the centroid tracker's (core.tracking.centroid): something over some of the mark's rows (a
ball, a shadow) changes its depth there, so the mark's row weights (``row_weights``: its
depth per ROI row against the plate on both flanks) depart from its own. Those are learned
from the frames of a priming pass (``mark_rows``, the centroid tracker's too: the rows it
occupies, its weights there and how far a clear frame's depart). Something beside the mark (a
passing particle) spoils one flank only: the weights against the other flank are then the
mark's own.
"""

import math

import numpy as np

from microball_ros.core.tracking.profile import row_weights

MIN_ROW_FRAMES = 5
ROW_FRACTION = 0.03
ROW_MARGIN = 3
ROW_TOLERANCE = 0.06
ROW_SPREADS = 5.0
CORE_PAD = 2  # px beside the mark's core in the guard's last window (RowsGuard.hidden)


def mark_rows(weights: list[np.ndarray],
              height: int) -> tuple[slice | None, np.ndarray | None, float]:
    """Return the ROI rows the mark occupies and its row weights there, from several frames.

    The weight of a row is proportional to the mark's integrated deficit in it, which motion
    along x does not change: the median over the frames is the mark's own, less noisy than
    one frame's. The rows run from the first to the last whose median weight exceeds
    ``ROW_FRACTION`` of the largest, widened by ``ROW_MARGIN``. Third, the largest L1
    distance of one frame's row weights from these that a clear mark shows: ``ROW_TOLERANCE``
    plus ``ROW_SPREADS`` times the median distance in the frames given. (None, None, inf)
    with fewer than ``MIN_ROW_FRAMES`` frames or when that leaves fewer than 2 rows.
    """
    weights = [w for w in weights if w.size == height]
    if len(weights) < MIN_ROW_FRAMES:
        return None, None, math.inf
    stack = np.array(weights)
    median = np.median(stack, axis=0)
    above = np.flatnonzero(median > ROW_FRACTION * float(median.max()))
    if above.size == 0:
        return None, None, math.inf
    first, last = max(int(above[0]) - ROW_MARGIN, 0), min(int(above[-1]) + ROW_MARGIN + 1,
                                                           height)
    if last - first < 2:
        return None, None, math.inf
    band = median[first:last] / float(median[first:last].sum())
    own = stack[:, first:last] / np.maximum(stack[:, first:last].sum(axis=1, keepdims=True),
                                            1e-12)
    spread = float(np.median(np.abs(own - band).sum(axis=1)))
    return slice(first, last), band, ROW_TOLERANCE + ROW_SPREADS * spread


class RowsGuard:
    """The mark's own rows and row weights, learned from logged frames, and the guard."""

    def __init__(self, pad: int) -> None:
        """Create a guard that guards nothing; ``pad``: px of the mark's flanks (row_weights)."""
        self.pad = int(pad)
        self.log: list[np.ndarray] | None = None  # the row weights of a priming pass
        self.forget()

    def forget(self) -> None:
        """Guard nothing."""
        self._rows: slice | None = None
        self._band: np.ndarray | None = None
        self._tolerance = math.inf

    def start_log(self) -> None:
        """Log the row weights of the frames ``hidden`` is asked about, and refuse none."""
        self.log = []

    def learn(self, height: int) -> None:
        """Learn the mark's rows from the logged frames (ROI ``height`` rows); stop logging."""
        self._rows, self._band, self._tolerance = mark_rows(self.log or [], height)
        self.log = None

    def hidden(self, region: np.ndarray, first: float, last: float, polarity: str,
               core: tuple[float, float] | None = None) -> bool:
        """Return True if the rows of the whole mark (columns first..last) depart from its own.

        ``core``: the columns of the mark's core (its extent at the tracker's threshold, no
        faint tails); what departs in the whole mark's window but not there, with ``CORE_PAD``
        px beside it, is something dark beside the mark reaching into the window (a tool's
        edge 1-3 px from a mark wholly in view), not over it.
        """
        if self.log is None and self._band is None:
            return False
        own = row_weights(region, int(first), int(last), self.pad, polarity)
        if self.log is not None:
            if own is not None:
                self.log.append(own)
            return False
        if self._rows is None or self._band is None:
            return own is None
        if not self._departs(own):
            return False
        # Something beside the mark (a passing particle) spoils one flank: the other will do
        windows = [(first, last, self.pad)] + ([] if core is None else [(*core, CORE_PAD)])
        for n, (lo, hi, pad) in enumerate(windows):
            for sides in ((True, False), (False, True)) + (((True, True),) if n else ()):
                if not self._departs(row_weights(region, int(lo), int(hi), pad, polarity,
                                                 sides)):
                    return False
        return True

    def _departs(self, own: np.ndarray | None) -> bool:
        """Return True if the rows ``own`` (row_weights, None: none) are not the mark's own."""
        if own is None or self._rows is None or self._band is None:
            return True
        part = own[self._rows]
        part = part / max(float(part.sum()), 1e-12)
        return float(np.abs(part - self._band).sum()) > self._tolerance
