"""Position records: stator and slider positions on a time base, and the check of that base.

The in-memory form of a position record (reading and writing CSV files lives in
``microball_ros.io.positions_csv``). NaN marks a sample where a mark was not measured.
"""

from dataclasses import dataclass, field

import numpy as np

from microball_ros.core.errors import InputError

REQUIRED_COLUMNS = ('time', 'stator_position', 'slider_position')


class RecordError(InputError):
    """A position record that cannot be analysed; the message is one line for the user."""


@dataclass(frozen=True)
class PositionRecord:
    """Sampled stator and slider positions on a uniform time base.

    ``valid`` marks the samples where both positions were measured; ``extra`` holds any other
    numeric columns of the source (for example ground truth from ``microball simulate``).
    """

    time: np.ndarray
    stator_position: np.ndarray
    slider_position: np.ndarray
    extra: dict = field(default_factory=dict)

    @property
    def valid(self):
        """Return a boolean mask of the samples where both marks were measured."""
        return np.isfinite(self.stator_position) & np.isfinite(self.slider_position)

    @property
    def sample_period(self):
        """Return the median sample period, s."""
        return float(np.median(np.diff(self.time)))


def check_time_base(time, source='record', tolerance=0.01):
    """Check that time stamps increase uniformly (within tolerance of the median period)."""
    if len(time) < 3:
        raise RecordError(f'{source}: only {len(time)} samples')
    steps = np.diff(time)
    if np.any(steps <= 0):
        k = int(np.flatnonzero(steps <= 0)[0])
        kind = 'duplicated' if steps[k] == 0 else 'decreasing'
        raise RecordError(f'{source}: {kind} time stamp {time[k + 1]:.6g} after {time[k]:.6g}')
    period = np.median(steps)
    worst = int(np.argmax(np.abs(steps - period)))
    if abs(steps[worst] - period) > tolerance * period:
        raise RecordError(f'{source}: non-uniform sampling: step {steps[worst]:.6g} s after '
                          f't = {time[worst]:.6g} s, median step {period:.6g} s')
