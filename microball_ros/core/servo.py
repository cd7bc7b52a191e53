"""Servo programs and the motor's response to them (servo_commander, bench_simulator)."""

from dataclasses import dataclass
import math


@dataclass(frozen=True)
class Sweep:
    """A sweep program: dwell ``dwell`` seconds at each of ``frequencies`` (Hz), in order."""

    frequencies: tuple
    dwell: float

    def check(self):
        """Return None if the program is usable, else a one-line reason."""
        if any(not (0 < f <= 20) for f in self.frequencies):
            return 'sweep frequencies must be in (0, 20] Hz'
        if self.frequencies and not self.dwell > 0:
            return 'sweep dwell must be positive'
        return None

    def frequency_at(self, elapsed):
        """Return the commanded frequency elapsed seconds into the sweep, or None when done."""
        if elapsed < 0 or not self.frequencies:
            return None
        step = int(elapsed // self.dwell)
        return self.frequencies[step] if step < len(self.frequencies) else None

    @property
    def duration(self):
        """Return the whole program's duration, s."""
        return self.dwell * len(self.frequencies)


class MotorModel:
    """Crank speed of a servo following its commands: a linear ramp, then a first-order lag.

    A command sets a target angular velocity reached by a linear ramp over ``ramp_time``
    seconds from the current target; the shaft follows the ramped target through a
    first-order lag of time constant ``lag`` (the motor's mechanical response), integrated
    exactly for piecewise-constant inputs on the caller's steps.
    """

    def __init__(self, lag=0.05):
        if not lag >= 0:
            raise ValueError(f'motor lag must be >= 0, got {lag!r}')
        self.lag = lag
        self.omega = 0.0
        self._ramp_from = 0.0
        self._ramp_to = 0.0
        self._ramp_start = 0.0
        self._ramp_time = 0.0

    def command(self, time, omega, ramp_time):
        """Ask for angular velocity omega (rad/s) from time on, ramping over ramp_time s."""
        self._ramp_from = self.target(time)
        self._ramp_to = float(omega)
        self._ramp_start = float(time)
        self._ramp_time = max(0.0, float(ramp_time))

    def target(self, time):
        """Return the ramped target angular velocity at time, rad/s."""
        if self._ramp_time == 0 or time >= self._ramp_start + self._ramp_time:
            return self._ramp_to
        fraction = max(0.0, (time - self._ramp_start) / self._ramp_time)
        return self._ramp_from + fraction * (self._ramp_to - self._ramp_from)

    def advance(self, time, step):
        """Advance the shaft speed over [time, time + step] and return it, rad/s."""
        goal = self.target(time + 0.5 * step)
        if self.lag == 0:
            self.omega = goal
        else:
            self.omega = goal + (self.omega - goal) * math.exp(-step / self.lag)
        return self.omega
