"""Cut a stream of tracked positions into analysis windows of whole stator periods.

Used by the three_stage_estimator node, pure and deterministic: the windows depend only on the
ordered samples pushed in, never on arrival times. A window never contains an invalid sample
(lost mark) or a frame gap: such stretches are skipped with a reason, not filled in.
"""

from dataclasses import dataclass

import numpy as np

from microball_ros.core.errors import InputError
from microball_ros.core.harmonics import fundamental_frequency


@dataclass(frozen=True)
class Window:
    """A run of consecutive valid samples spanning ``periods`` stator periods."""

    time: np.ndarray
    stator_position: np.ndarray
    slider_position: np.ndarray
    frame_index: np.ndarray
    frequency: float
    periods: float


@dataclass(frozen=True)
class Skip:
    """Samples dropped without analysis, and why."""

    count: int
    reason: str


@dataclass(frozen=True)
class WindowSettings:
    """How windows are cut; see PositionWindower."""

    window_periods: float = 8.0
    hop_periods: float = 4.0
    min_frequency: float = 0.5
    min_amplitude: float = 1e-5
    frequency_tolerance: float = 0.02
    stamp_tolerance: float = 0.05

    def check(self) -> str | None:
        """Return None if the settings are usable, else a one-line reason."""
        if not self.window_periods >= 4:
            return 'window_periods must be at least 4 (the memory test needs 4 periods)'
        if not 0 < self.hop_periods <= self.window_periods:
            return 'hop_periods must be in (0, window_periods]'
        if not self.min_frequency > 0:
            return 'min_frequency must be positive'
        if not self.min_amplitude >= 0:
            return 'min_amplitude must be >= 0'
        if not 0 < self.frequency_tolerance < 1:
            return 'frequency_tolerance must be in (0, 1)'
        if not 0 < self.stamp_tolerance < 0.5:
            return 'stamp_tolerance must be in (0, 0.5)'
        return None


def _frequency_or_none(stator, dt):
    try:
        return fundamental_frequency(stator, dt)
    except ValueError:
        return None


def _frequency_or_nan(stator, dt):
    frequency = _frequency_or_none(stator, dt)
    return float('nan') if frequency is None else frequency


class PositionWindower:
    """Accumulate samples and emit Window or Skip events.

    * A frame-index gap, a non-uniform stamp step (off the running period by more than
      ``stamp_tolerance``) or an invalid sample ends the current run: the samples before it
      are skipped (too short to analyse) and a new run starts after it.
    * Once a run spans ``window_periods`` periods of its stator fundamental (re-estimated with
      every new sample once the run covers two periods), its first ``window_periods`` periods
      are emitted as a Window, and the run advances by ``hop_periods`` periods.
    * If the fundamental of any two-period segment of the window differs from the first
      segment's by more than ``frequency_tolerance`` (a servo speed change, a sweep step),
      the samples before that segment are skipped instead: the new frequency starts a new
      window.
    * A stator that does not oscillate (amplitude below ``min_amplitude``, m) is skipped.
    """

    def __init__(self, settings: WindowSettings | None = None):
        self.settings = settings or WindowSettings()
        reason = self.settings.check()
        if reason:
            raise InputError(reason)
        self._rows: list[tuple[float, int, float, float]] = []  # stamp, index, stator, slider

    @property
    def pending(self) -> int:
        """Return how many samples wait for a window."""
        return len(self._rows)

    def push(self, stamp: float, frame_index: int, stator: float, slider: float,
             valid: bool = True) -> list[Window | Skip]:
        """Add one sample; return the list of Window and Skip events it completes."""
        events = []
        if not (valid and np.isfinite(stator) and np.isfinite(slider)):
            events += self._drop(len(self._rows) + 1, 'invalid sample (lost mark)')
            return events
        if self._rows and not self._continues(stamp, frame_index):
            events += self._drop(len(self._rows), 'frame gap or irregular time stamps')
        self._rows.append((float(stamp), int(frame_index), float(stator), float(slider)))
        events += self._emit()
        return events

    def _continues(self, stamp, frame_index):
        last_stamp, last_index = self._rows[-1][:2]
        if frame_index != last_index + 1 or stamp <= last_stamp:
            return False
        if len(self._rows) < 2:
            return True
        period = (last_stamp - self._rows[0][0]) / (len(self._rows) - 1)
        return abs((stamp - last_stamp) - period) <= self.settings.stamp_tolerance * period

    def _drop(self, count, reason):
        """Forget the first count samples (count may include one never stored)."""
        del self._rows[:count]
        return [Skip(count=count, reason=reason)] if count else []

    def _emit(self):
        settings = self.settings
        rows = self._rows
        if len(rows) < 16:
            return []
        data = np.array(rows)
        dt = (data[-1, 0] - data[0, 0]) / (len(rows) - 1)
        duration = len(rows) * dt
        stator = data[:, 2]
        # Wait up to window_periods periods of the slowest frequency for an oscillation.
        waited = duration * settings.min_frequency >= settings.window_periods
        frequency = None
        if np.ptp(stator) / 2 >= settings.min_amplitude:
            frequency = _frequency_or_none(stator, dt)
        if frequency is None:
            return self._drop(len(rows), 'stator not oscillating') if waited else []
        needed = int(round(settings.window_periods / (frequency * dt)))
        if duration * frequency < 2 or len(rows) < needed:
            return []
        window = data[:needed]
        # Stationary? Compare the fundamental of consecutive two-period segments.
        segments = max(2, int(settings.window_periods // 2))
        bounds = np.linspace(0, needed, segments + 1).astype(int)
        local = [_frequency_or_nan(window[a:b, 2], dt)
                 for a, b in zip(bounds[:-1], bounds[1:], strict=True)]
        for k in range(1, segments):
            change = abs(local[k] - local[0]) / max(local[k], local[0])
            if not change <= settings.frequency_tolerance:  # NaN too: a segment at rest
                return self._drop(int(bounds[k]), f'frequency changed ({local[0]:.3f} -> '
                                                  f'{local[k]:.3f} Hz)')
        frequency = fundamental_frequency(window[:, 2], dt)
        hop = max(1, int(round(settings.hop_periods / (frequency * dt))))
        del self._rows[:hop]
        return [Window(time=window[:, 0], stator_position=window[:, 2],
                       slider_position=window[:, 3], frame_index=window[:, 1].astype(np.int64),
                       frequency=float(frequency), periods=needed * dt * frequency)]
