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


class ServoDriver:
    """The hardware seam of servo_commander: one motor turning the crank.

    A driver is built from the node's parameter values and a logger (``driver(values, log)``)
    and registered in servo_commander's ``DRIVERS``. The node calls ``open`` once, ``drive``
    whenever the (ramped) crank frequency changes, ``stop`` on ~/stop, ``crank_velocity`` at
    the heartbeat rate and ``close`` on shutdown. A problem the user can fix (no port, no
    answer) raises ``InputError``; a fault the motor reports sets ``fault`` after the driver
    stopped the motor.
    """

    fault = None              # None, or a one-line reason once the motor stopped on a fault
    max_frequency = None      # the highest crank frequency the motor can be asked for, Hz

    def open(self):
        """Connect to the motor and prepare it (torque stays off until ``drive``)."""

    def drive(self, frequency):
        """Turn the crank at frequency (Hz), enabling the motor first if needed."""

    def stop(self):
        """Stop the motor and release its torque."""

    def crank_velocity(self):
        """Return the measured crank angular velocity (rad/s), or None if not measured."""
        return None

    def close(self):
        """Stop the motor (best effort) and release the hardware; never raises."""


@dataclass(frozen=True)
class Ramp:
    """A linear ramp from ``origin`` at ``start`` to ``goal`` ``duration`` seconds later."""

    start: float = 0.0
    origin: float = 0.0
    goal: float = 0.0
    duration: float = 0.0

    def value(self, time):
        """Return the ramp's value at time (origin before start, goal after the end)."""
        if self.duration <= 0 or time >= self.start + self.duration:
            return self.goal
        fraction = max(0.0, (time - self.start) / self.duration)
        return self.origin + fraction * (self.goal - self.origin)

    def done(self, time):
        """Return True once the ramp has reached its goal."""
        return self.duration <= 0 or time >= self.start + self.duration

    def to(self, time, goal, duration):
        """Return a new ramp from this one's value at time to goal over duration seconds."""
        return Ramp(float(time), self.value(time), float(goal), max(0.0, float(duration)))


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
        self._ramp = Ramp()

    def command(self, time, omega, ramp_time):
        """Ask for angular velocity omega (rad/s) from time on, ramping over ramp_time s."""
        self._ramp = self._ramp.to(time, omega, ramp_time)

    def target(self, time):
        """Return the ramped target angular velocity at time, rad/s."""
        return self._ramp.value(time)

    def advance(self, time, step):
        """Advance the shaft speed over [time, time + step] and return it, rad/s."""
        goal = self.target(time + 0.5 * step)
        if self.lag == 0:
            self.omega = goal
        else:
            self.omega = goal + (self.omega - goal) * math.exp(-step / self.lag)
        return self.omega
