"""The learned plate's rows guard on a plain plate: a frame whose rows depart from the mark's.

As the centroid tracker's (core.tracking.centroid): something over some of the mark's rows (a
ball, a shadow) changes its depth there, so the mark's row weights (``row_weights``: its
depth per ROI row against the plate on both flanks) depart from its own. Those are learned
from the frames of a priming pass (``centroid.mark_rows``: the rows it occupies, its weights
there and how far a clear frame's depart). Something beside the mark (a passing particle)
spoils one flank only: the weights against the other flank are then the mark's own.
"""

import math

import numpy as np

from microball_ros.core.tracking.centroid import mark_rows
from microball_ros.core.tracking.profile import row_weights


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

    def hidden(self, region: np.ndarray, first: float, last: float, polarity: str) -> bool:
        """Return True if the rows of the whole mark (columns first..last) depart from its own."""
        if self.log is None and self._band is None:
            return False
        own = row_weights(region, int(first), int(last), self.pad, polarity)
        if self.log is not None:
            if own is not None:
                self.log.append(own)
            return False
        if self._rows is None or self._band is None:
            return own is None
        # Something beside the mark (a passing particle) spoils one flank: the other will do
        for sides in ((True, False), (False, True)) if self._departs(own) else ():
            own = row_weights(region, int(first), int(last), self.pad, polarity, sides)
            if not self._departs(own):
                return False
        return self._departs(own)

    def _departs(self, own: np.ndarray | None) -> bool:
        """Return True if the rows ``own`` (row_weights, None: none) are not the mark's own."""
        if own is None or self._rows is None or self._band is None:
            return True
        part = own[self._rows]
        part = part / max(float(part.sum()), 1e-12)
        return float(np.abs(part - self._band).sum()) > self._tolerance
