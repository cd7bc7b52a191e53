"""Servo programs, the motor model, and the servo_commander node."""

import math

from microball_msgs.msg import ServoCommand
import pytest
from rclpy.parameter import Parameter
from std_srvs.srv import Trigger

from microball_ros.core.servo import MotorModel, Sweep
from microball_ros.nodes.common import LATCHED_QOS
from microball_ros.nodes.servo_commander import ServoCommander
from microball_ros.testing import Harness


def test_sweep_program_steps_through_its_frequencies_then_ends():
    sweep = Sweep((1.0, 2.0, 3.0), dwell=5.0)
    assert sweep.check() is None
    assert [sweep.frequency_at(t) for t in (0, 4.99, 5.0, 12, 14.99, 15.0)] == \
        [1.0, 1.0, 2.0, 3.0, 3.0, None]
    assert sweep.duration == 15.0
    assert Sweep((0.0,), 1.0).check() is not None
    assert Sweep((1.0,), 0.0).check() is not None


def test_motor_ramps_linearly_and_lags_exponentially():
    motor = MotorModel(lag=0.0)
    motor.command(0.0, 10.0, ramp_time=2.0)
    assert motor.target(1.0) == pytest.approx(5.0)
    assert motor.advance(0.0, 1.0) == pytest.approx(2.5)  # mid-step target
    motor = MotorModel(lag=0.1)
    motor.command(0.0, 10.0, ramp_time=0.0)
    omega = [motor.advance(0.001 * k, 0.001) for k in range(100)]
    assert omega[-1] == pytest.approx(10.0 * (1 - math.exp(-1.0)), rel=1e-9)


def test_commander_publishes_starts_stops_and_sweeps(ros_context):
    node = ServoCommander(context=ros_context, parameter_overrides=[
        Parameter('sweep_frequencies', value=[2.0, 3.5]),
        Parameter('sweep_dwell', value=0.5), Parameter('heartbeat', value=20.0)])
    harness = Harness(ros_context, node)
    try:
        commands = []
        harness.probe.create_subscription(ServoCommand, 'servo/command', commands.append,
                                          LATCHED_QOS)
        harness.spin_until(lambda: commands, message='the latched command')
        first = commands[-1]
        assert first.enabled and first.frequency == pytest.approx(2.95)
        assert first.angular_velocity == pytest.approx(2 * math.pi * 2.95)
        assert first.amplitude == pytest.approx(1.2e-3)

        def call(name):
            client = harness.probe.create_client(Trigger, f'/servo_commander/{name}')
            harness.spin_until(lambda: client.service_is_ready(), message=f'{name} service')
            future = client.call_async(Trigger.Request())
            harness.spin_until(future.done, message=f'{name} response')
            return future.result()

        assert call('stop').success
        harness.spin_until(lambda: not commands[-1].enabled, message='a stop command')
        assert call('start_sweep').success
        harness.spin_until(lambda: commands[-1].frequency == 3.5, message='the second step')
        seen = [c.frequency for c in commands if c.enabled]
        assert seen.index(2.0) < seen.index(3.5)
        harness.spin_until(lambda: commands[-1].frequency == pytest.approx(2.95),
                           message='the end of the sweep')
        result = node.set_parameters([Parameter('sweep_frequencies', value=[50.0])])[0]
        assert not result.successful and 'sweep frequencies' in result.reason
    finally:
        harness.close()
