"""The recent gains of a mark's fits, and the guard against a frame whose gain jumps.

A fit of the learned plate (core.tracking.plate) returns the mark's gain against the plate:
about 1, steady from frame to frame whatever the light (the light is divided out). Something
over the plate beside the mark (a passing ball) changes it while the fit's residual stays
small and its position moves by pixels. ``MarkGains`` keeps the recent gains (their median is
the reference), learns their scatter over the priming frames, and refuses a frame further
than ``SPREADS`` scatters (and ``FLOOR``) from the reference; a refused gain is not kept, so
the frames after it are judged against the mark's own. A change that lasts ``LASTING`` frames
in a row is taken up as the new gain (it is the mark's, not something passing).
"""

from collections import deque
import math
import statistics

import numpy as np

SPREADS = 6.0  # clear frames stay within 3-4 scatters (0.003-0.008 each) on our textures
FLOOR = 0.03
LASTING = 30  # frames in a row (1 s at 30 fps)


class MarkGains:
    """Recent gains of a mark (``history`` of them), their reference and the jump guard."""

    def __init__(self, history: int) -> None:
        """Keep up to ``history`` recent gains; no scatter learned yet (no guard)."""
        self._recent: deque[float] = deque(maxlen=int(history))
        self._off: list[float] = []
        self.spread = math.inf
        self._log: list[float] | None = None

    def reset(self) -> None:
        """Forget the recent gains (the learned scatter is kept)."""
        self._recent.clear()
        self._off = []

    def start_log(self) -> None:
        """Log each judged frame's relative gain (priming) until ``learn_spread``."""
        self._log = []

    def learn_spread(self) -> None:
        """Set the scatter from the log (8 frames at least, else no guard); stop logging."""
        log, self._log = self._log, None
        self.spread = (1.4826 * float(np.median(np.abs(log))) if log is not None
                       and len(log) >= 8 else math.inf)

    def stop_log(self) -> None:
        """Stop logging (the learned scatter is kept)."""
        self._log = None

    def forget_spread(self) -> None:
        """Drop the learned scatter (no guard) and stop logging."""
        self.spread, self._log = math.inf, None

    def judge(self, gain: float, slack: float = 0.0) -> float | None:
        """Return the reference to judge ``gain`` against, or None if the guard refuses it.

        A gain kept (not refused) joins the recent ones. The reference is 1 until 3 are known.
        ``slack``: how far this frame's gain may be off for a known cause (relative, added to
        the guard's tolerance): a shadow's light over a camera's black level not given
        (core.tracking.shade.gain_slack).
        """
        if len(self._recent) < 3:
            self._recent.append(gain)
            return 1.0
        reference = statistics.median(self._recent)  # as np.median, faster
        if self._log is not None:
            self._log.append(gain / reference - 1.0)
        if abs(gain / reference - 1.0) > max(SPREADS * self.spread, FLOOR) + slack:
            self._off.append(gain)
            if len(self._off) < LASTING:
                return None
            self._recent.clear()
            self._recent.extend(self._off[-3:])
            reference = statistics.median(self._recent)  # as np.median, faster
        self._off = []
        self._recent.append(gain)
        return reference
