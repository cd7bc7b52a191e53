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


def check_time_base(time, source='record', tolerance=None):
    """Refuse only time stamps no analysis can use: too few, not finite, or running backwards.

    Gaps, dropped frames, duplicated stamps and jitter are analysed (core.timebase puts the
    samples on their frame grid and says what it repaired), so they pass here. ``tolerance``
    is accepted for compatibility and ignored.
    """
    time = np.asarray(time, dtype=float)
    if len(time) < 3:
        raise RecordError(f'{source}: only {len(time)} samples')
    if not np.all(np.isfinite(time)):
        k = int(np.flatnonzero(~np.isfinite(time))[0])
        raise RecordError(f'{source}: time stamp {k + 1} is not a finite number')
    steps = np.diff(time)
    if np.any(steps < 0):
        k = int(np.flatnonzero(steps < 0)[0])
        raise RecordError(f'{source}: decreasing time stamp {time[k + 1]:.6g} after '
                          f'{time[k]:.6g}: not one record in time order')
    if not np.any(steps > 0):
        raise RecordError(f'{source}: every time stamp is {time[0]:.6g}')


# What a MEMS microball bearing rig can plausibly produce (for unit checks with a hint).
MAX_TRAVEL = 0.1  # m: strokes are millimetres (with drift, centimetres); mm values exceed this
SAMPLE_PERIOD_RANGE = (1e-5, 1.0)  # s: cameras from 1 to 100,000 frames per second


def check_units(record, source='record'):
    """Refuse a record whose units are evidently not seconds and metres, saying what they are.

    The time step of a camera lies between 10 us and 1 s; a bearing moves millimetres. A time
    column in milliseconds or nanoseconds, or positions in millimetres or micrometres, fail
    these checks by orders of magnitude, and the message says which unit the numbers look
    like.
    """
    steps = np.diff(record.time)
    period = float(np.median(steps)) if steps.size else 0.0
    low, high = SAMPLE_PERIOD_RANGE
    if period > high:
        unit = 'nanoseconds' if period > 1e5 else 'microseconds' if period > 1e2 \
            else 'milliseconds'
        raise RecordError(f'{source}: time steps of {period:.6g} look like {unit}: the time '
                          'column must be in seconds')
    if 0 < period < low:
        raise RecordError(f'{source}: time steps of {period:.3g} s ({1 / period:.3g} frames '
                          "per second) are not a camera's: the time column must be in seconds")
    for name in ('stator_position', 'slider_position'):
        values = getattr(record, name)
        finite = values[np.isfinite(values)]
        if finite.size == 0:
            continue
        travel = float(np.ptp(finite))
        if travel > MAX_TRAVEL:
            unit = 'micrometres' if travel > 20 else 'millimetres'
            raise RecordError(f'{source}: {name} spans {travel:.4g}, which looks like {unit}: '
                              'positions must be in metres (a bearing moves millimetres)')
