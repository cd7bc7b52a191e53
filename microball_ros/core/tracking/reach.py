"""Where the centroid's mark can be in a frame, from the frames it was found in: ``Reach``.

Owned by core.tracking.centroid: the mark's last position and its steps per frame, and what
it looked like when found (peak, extent, whether its window clipped).
"""

from collections import deque
import math

import numpy as np

# Reach: after MIN_STEPS steps between consecutive frames the mark was found in, it is at most
# REACH_MARGIN times the largest of the last STEP_HISTORY steps (plus 1 px) per frame from
# where it was last found; a dip there NEAR_PEAK as deep as the mark wins over a deeper one
# outside.
MIN_STEPS, STEP_HISTORY, REACH_MARGIN, NEAR_PEAK = 5, 300, 1.5, 0.5
MIN_UNCLIPPED = 10  # a bright mark found this often, never saturated: saturation is a glint
# Reach.widest: parts of a dip are joined up to JOIN_GROWTH times the largest recent extent
# plus JOIN_PAD px (a faster smear); more is something else beside the mark
JOIN_GROWTH, JOIN_PAD = 1.5, 8.0


class Reach:
    """Where the mark can be in this frame: how far it moved per frame, from where it was found.

    A particle passing over the plate, deeper than the mark, is the strongest dip of the ROI:
    taken for the mark, it is tens of pixels off. The mark moves a bounded step per frame, so
    a dip beyond what it can have moved since it was last found is something else when
    another, nearly as deep as the mark (``NEAR_PEAK``), lies within reach. Without that,
    the strongest dip stands (a mark that jumped is found again).
    """

    def __init__(self):
        self.last: float | None = None
        self.since = 0
        self.steps: deque[float] = deque(maxlen=STEP_HISTORY)
        self.peaks: deque[float] = deque(maxlen=STEP_HISTORY)
        self.extents: deque[float] = deque(maxlen=STEP_HISTORY)
        self.clipped: deque[bool] = deque(maxlen=STEP_HISTORY)  # saturated pixels in the window

    def copy(self) -> 'Reach':
        """Return an independent copy (a trial measurement must not change this one)."""
        other = Reach()
        other.last, other.since = self.last, self.since
        other.steps.extend(self.steps)
        other.peaks.extend(self.peaks)
        other.extents.extend(self.extents)
        other.clipped.extend(self.clipped)
        return other

    def found(self, position: float, peak: float, extent: float,
              clipped: bool = False) -> None:
        """Record the mark found at ``position`` (px) with this ``peak`` and ``extent``.

        ``clipped``: saturated pixels in its window.
        """
        if self.last is not None and self.since == 1:
            self.steps.append(abs(position - self.last))
        self.last, self.since = position, 0
        self.peaks.append(peak)
        self.extents.append(extent)
        self.clipped.append(clipped)

    def never_clipped(self) -> bool:
        """Return True if the mark was found ``MIN_UNCLIPPED`` times and never saturated."""
        return len(self.clipped) >= MIN_UNCLIPPED and not any(self.clipped)

    def window(self, x: int) -> tuple[float, float] | None:
        """Return the ROI columns the mark's dip can peak in; None: any.

        ``x``: the ROI's first image column. Within the largest recent extent's half (the
        dip's peak is within it of the mark's centre) of the reach.
        """
        if self.last is None or len(self.steps) < MIN_STEPS:
            return None
        reach = self.since * (REACH_MARGIN * max(self.steps) + 1.0) + 0.5 * max(self.extents)
        center = self.last - x
        return center - reach, center + reach

    def widest(self) -> float:
        """Return the widest dip (px) the mark's parts make (inf until ``MIN_STEPS`` found).

        A particle beside a mark made of parts (two bars, a ring's walls) is joined to it
        as a part: a particle 18 px beside a bar made a dip 46 px wide of a mark 11 px wide.
        """
        if len(self.extents) < MIN_STEPS:
            return math.inf
        return JOIN_GROWTH * max(self.extents) + JOIN_PAD

    def least(self) -> float:
        """Return the least peak of a dip taken for the mark in place of a deeper one (inf)."""
        return NEAR_PEAK * float(np.median(self.peaks)) if self.peaks else math.inf
