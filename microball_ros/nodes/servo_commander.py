"""servo_commander: commands the crank-slider servo and publishes /servo/command.

Frequency (Hz) with smooth ramps between speeds, start/stop services, and a sweep program (a
list of frequencies with a dwell time) so one run covers a range of relative velocities. The
hardware sits behind a small driver seam (core.servo.ServoDriver, registered in DRIVERS): the
default 'simulated' driver leaves the motion to bench_simulator, which listens to the same
topic; 'dynamixel' drives a Dynamixel X-series servo in velocity control (io.dynamixel), with
the ramp done here in steps of 1/RAMP_RATE s and the measured crank speed published on
servo/state (sensor_msgs/JointState, joint 'crank', velocity in rad/s) at the heartbeat rate.
On ~/stop, on shutdown (SIGINT, SIGTERM) and on any error the motor is stopped. Its health is
on /diagnostics: commands sent, and the driver's fault as the last error.
"""

import sys

from microball_msgs.msg import ServoCommand
from rcl_interfaces.msg import SetParametersResult
from rclpy.node import Node
from rclpy.qos import QoSProfile
from sensor_msgs.msg import JointState
from std_srvs.srv import Trigger

from microball_ros.core.errors import InputError
from microball_ros.core.servo import Ramp, ServoDriver, Sweep
from microball_ros.io.dynamixel import DynamixelDriver
from microball_ros.nodes.common import (
    LATCHED_QOS,
    NodeDiagnostics,
    Param,
    create_publisher,
    declare_parameters,
    run,
)

TWO_PI = 6.283185307179586
RAMP_RATE = 20.0            # goal updates per second while a hardware driver ramps, Hz


class SimulatedServoDriver(ServoDriver):
    """The simulated rig: bench_simulator subscribes to /servo/command, nothing else to do."""

    def __init__(self, values=None, log=None):
        pass


DRIVERS = {'simulated': SimulatedServoDriver, 'dynamixel': DynamixelDriver}

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
    'port': Param('', 'serial port of the servo (driver dynamixel), e.g. /dev/ttyUSB0',
                  read_only=True),
    'baudrate': Param(57600, 'serial baud rate of the servo (driver dynamixel)', 9600, 4500000,
                      read_only=True),
    'servo_id': Param(1, 'Dynamixel ID of the servo (driver dynamixel)', 0, 252,
                      read_only=True),
    'gear_ratio': Param(1.0, 'crank turns per motor turn (driver dynamixel)', 1e-3, 1e3,
                        read_only=True),
}


def _sweep(values):
    return Sweep(tuple(f for f in values['sweep_frequencies'] if f != 0.0), values['sweep_dwell'])


def check_parameters(values):
    """Return None if the parameter values are consistent, else a one-line reason."""
    if values['driver'] not in DRIVERS:
        return f"unknown driver {values['driver']!r}; known: {', '.join(DRIVERS)}"
    if values['driver'] == 'dynamixel' and not values['port']:
        return 'driver dynamixel needs the port parameter (e.g. port:=/dev/ttyUSB0)'
    return _sweep(values).check()


def reach_problem(values, max_frequency):
    """Return None if every frequency asked for is within the driver's reach, else a reason."""
    if max_frequency is None:
        return None
    asked = [values['frequency'], *values['sweep_frequencies']]
    if max(asked) > max_frequency:
        return (f"{max(asked):g} Hz is beyond the servo's reach ({max_frequency:.4g} Hz at "
                'its Velocity Limit and this gear_ratio)')
    return None


class ServoCommander(Node):
    """Publish the servo command, drive the motor; start, stop and sweep on request."""

    def __init__(self, **kwargs):
        super().__init__('servo_commander', **kwargs)
        self._driver = None
        self._values = declare_parameters(self, PARAMS, check_parameters)
        driver = DRIVERS[self._values['driver']](dict(self._values), self.get_logger())
        driver.open()
        self._driver = driver
        try:
            self._start()
        except BaseException:
            self._close_driver()            # the motor never runs without a node to stop it
            raise

    def _start(self):
        problem = reach_problem(self._values, self._driver.max_frequency)
        if problem:
            raise InputError(f'{self.get_name()}: bad parameters: {problem}')
        self.add_on_set_parameters_callback(self._check_reach)
        self.add_post_set_parameters_callback(self._on_parameters_set)
        self._publisher = create_publisher(self, ServoCommand, 'servo/command', LATCHED_QOS)
        self._state_publisher = create_publisher(self, JointState, 'servo/state',
                                                 QoSProfile(depth=10))
        self.diagnostics = NodeDiagnostics(self, hardware_id=self._values['port'])
        self._enabled = bool(self._values['autostart'])
        self._frequency = self._values['frequency']
        self._sweep_start = None
        self._ramp = Ramp()
        self._driven = None               # the frequency last given to the driver, Hz
        self.create_service(Trigger, '~/start', self._on_start)
        self.create_service(Trigger, '~/stop', self._on_stop)
        self.create_service(Trigger, '~/start_sweep', self._on_start_sweep)
        self._heartbeat = self.create_timer(1.0 / self._values['heartbeat'], self._on_heartbeat)
        self._ramp_timer = self.create_timer(1.0 / RAMP_RATE, self._drive)
        self._send()

    def _check_reach(self, parameters):
        proposed = dict(self._values)
        proposed.update({p.name: p.value for p in parameters if p.name in PARAMS})
        problem = reach_problem(proposed, self._driver.max_frequency)
        return SetParametersResult(successful=problem is None, reason=problem or '')

    def _on_parameters_set(self, parameters):
        self._values.update({p.name: p.value for p in parameters if p.name in PARAMS})
        if any(p.name == 'frequency' for p in parameters) and self._sweep_start is None:
            self._frequency = self._values['frequency']
            self._send()

    def _now(self):
        return self.get_clock().now().nanoseconds * 1e-9

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
        """Publish the current command and bring the motor to it (ramped)."""
        msg = self._command()
        if not msg.enabled:
            self._ramp = Ramp()
            if self._driven is not None:
                self._driven = None
                self._driver.stop()
        elif msg.frequency != self._ramp.goal or self._driven is None:
            self._ramp = self._ramp.to(self._now(), msg.frequency, msg.ramp_time)
            self._ramp_timer.reset()
            self._drive()               # the ramp timer takes the later steps
        self._publisher.publish(msg)
        self.diagnostics.count('commands sent')

    def _drive(self):
        """Give the driver the ramped frequency when it changed (ramp timer and _send)."""
        if not self._enabled or self._driver.fault is not None:
            self._ramp_timer.cancel()
            return
        now = self._now()
        frequency = self._ramp.value(now)
        if frequency != self._driven:
            self._driven = frequency
            self._driver.drive(frequency)
            self._check_fault()
        if self._ramp.done(now):
            self._ramp_timer.cancel()       # no wake-ups while the speed holds

    def _check_fault(self):
        """After a motor fault (the driver stopped the motor): disable and say so."""
        if self._driver.fault is None or not self._enabled:
            return
        self._enabled, self._sweep_start, self._driven = False, None, None
        self._ramp = Ramp()
        self.diagnostics.error(f'servo stopped: {self._driver.fault}', log=False)  # logged
        self._publisher.publish(self._command())
        self.diagnostics.count('commands sent')

    def _publish_state(self):
        velocity = self._driver.crank_velocity()
        self._check_fault()
        if velocity is None:
            return
        msg = JointState()
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.name = ['crank']
        msg.velocity = [float(velocity)]
        self._state_publisher.publish(msg)

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
        self._publish_state()

    def _on_start(self, request, response):
        if self._driver.fault is not None:
            response.success, response.message = False, self._driver.fault
            return response
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
        if self._driver.fault is not None:
            response.success, response.message = False, self._driver.fault
            return response
        self._enabled, self._sweep_start = True, self.get_clock().now()
        self._frequency = sweep.frequencies[0]
        self._send()
        response.success = True
        response.message = f'sweeping {len(sweep.frequencies)} frequencies, {sweep.duration:g} s'
        return response

    def _close_driver(self):
        driver, self._driver = self._driver, None
        if driver is not None:
            driver.close()

    def destroy_node(self):
        """Stop the motor through the driver, then destroy the node."""
        self._close_driver()
        super().destroy_node()


def main(args=None):
    """Run the node (console script servo_commander)."""
    return run(ServoCommander, args)


if __name__ == '__main__':
    sys.exit(main())
