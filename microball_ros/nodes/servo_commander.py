"""servo_commander: commands the crank-slider servo and publishes /servo/command.

Frequency (Hz) with smooth ramps between speeds, start/stop services, and a sweep program (a
list of frequencies with a dwell time) so one run covers a range of relative velocities. The
hardware sits behind a small driver seam (ServoDriver): the default 'simulated' driver leaves
the motion to bench_simulator, which listens to the same topic; a serial driver for a real
servo implements ServoDriver.apply and registers in DRIVERS, and the node does not change.
"""

import sys

from microball_msgs.msg import ServoCommand
from rclpy.node import Node
from std_srvs.srv import Trigger

from microball_ros.core.servo import Sweep
from microball_ros.nodes.common import LATCHED_QOS, Param, declare_parameters, run

TWO_PI = 6.283185307179586


class ServoDriver:
    """The hardware seam: apply a ServoCommand to a motor."""

    def apply(self, command):
        """Send the command to the hardware."""
        raise NotImplementedError

    def close(self):
        """Release the hardware (stop the motor)."""


class SimulatedServoDriver(ServoDriver):
    """The simulated rig: bench_simulator subscribes to /servo/command, nothing else to do."""

    def apply(self, command):
        """Do nothing: the published command is the simulated motor's input."""


DRIVERS = {'simulated': SimulatedServoDriver}

PARAMS = {
    'frequency': Param(2.95, 'crank frequency, Hz', 0.05, 20.0),
    'amplitude': Param(1.2e-3, 'stator amplitude = crank radius, m (mechanical, fixed)',
                       1e-6, 0.1, read_only=True),
    'ramp_time': Param(1.0, 'time to ramp between speeds, s', 0.0, 60.0),
    'autostart': Param(True, 'start the motor when the node starts'),
    'sweep_frequencies': Param([0.0], 'sweep program: frequencies in Hz, run by the '
                                      '~/start_sweep service (an empty program is [0.0])'),
    'sweep_dwell': Param(10.0, 'sweep program: seconds at each frequency', 0.1, 3600.0),
    'heartbeat': Param(1.0, 'republish the current command at this rate, Hz', 0.1, 100.0),
    'driver': Param('simulated', 'servo driver: ' + ', '.join(DRIVERS), read_only=True),
}


def _sweep(values):
    return Sweep(tuple(f for f in values['sweep_frequencies'] if f != 0.0), values['sweep_dwell'])


def check_parameters(values):
    """Return None if the parameter values are consistent, else a one-line reason."""
    if values['driver'] not in DRIVERS:
        return f"unknown driver {values['driver']!r}; known: {', '.join(DRIVERS)}"
    return _sweep(values).check()


class ServoCommander(Node):
    """Publish the servo command; start, stop and sweep on request."""

    def __init__(self, **kwargs):
        super().__init__('servo_commander', **kwargs)
        self._values = declare_parameters(self, PARAMS, check_parameters)
        self.add_post_set_parameters_callback(self._on_parameters_set)
        self._driver = DRIVERS[self._values['driver']]()
        self._publisher = self.create_publisher(ServoCommand, 'servo/command', LATCHED_QOS)
        self._enabled = bool(self._values['autostart'])
        self._frequency = self._values['frequency']
        self._sweep_start = None
        self.create_service(Trigger, '~/start', self._on_start)
        self.create_service(Trigger, '~/stop', self._on_stop)
        self.create_service(Trigger, '~/start_sweep', self._on_start_sweep)
        self._heartbeat = self.create_timer(1.0 / self._values['heartbeat'], self._on_heartbeat)
        self._send()

    def _on_parameters_set(self, parameters):
        self._values.update({p.name: p.value for p in parameters if p.name in PARAMS})
        if any(p.name == 'frequency' for p in parameters) and self._sweep_start is None:
            self._frequency = self._values['frequency']
            self._send()

    def _command(self):
        msg = ServoCommand()
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.enabled = self._enabled
        msg.frequency = float(self._frequency)
        msg.angular_velocity = TWO_PI * msg.frequency
        msg.amplitude = float(self._values['amplitude'])
        msg.ramp_time = float(self._values['ramp_time'])
        return msg

    def _send(self):
        msg = self._command()
        self._driver.apply(msg)
        self._publisher.publish(msg)

    def _on_heartbeat(self):
        if self._sweep_start is not None:
            elapsed = (self.get_clock().now() - self._sweep_start).nanoseconds * 1e-9
            frequency = _sweep(self._values).frequency_at(elapsed)
            if frequency is None:
                self.get_logger().info('sweep finished')
                self._sweep_start = None
                self._frequency = self._values['frequency']
            elif frequency != self._frequency:
                self.get_logger().info(f'sweep: {frequency:g} Hz')
                self._frequency = frequency
        self._send()

    def _on_start(self, request, response):
        self._enabled = True
        self._send()
        response.success, response.message = True, f'running at {self._frequency:g} Hz'
        return response

    def _on_stop(self, request, response):
        self._enabled, self._sweep_start = False, None
        self._send()
        response.success, response.message = True, 'stopped'
        return response

    def _on_start_sweep(self, request, response):
        sweep = _sweep(self._values)
        if not sweep.frequencies:
            response.success, response.message = False, 'no sweep program (sweep_frequencies)'
            return response
        self._enabled, self._sweep_start = True, self.get_clock().now()
        self._frequency = sweep.frequencies[0]
        self._send()
        response.success = True
        response.message = f'sweeping {len(sweep.frequencies)} frequencies, {sweep.duration:g} s'
        return response

    def destroy_node(self):
        """Stop the motor through the driver, then destroy the node."""
        self._driver.close()
        super().destroy_node()


def main(args=None):
    """Run the node (console script servo_commander)."""
    return run(ServoCommander, args)


if __name__ == '__main__':
    sys.exit(main())
