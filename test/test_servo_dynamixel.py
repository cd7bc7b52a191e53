"""servo_commander driver:=dynamixel as a process, against the emulated servo on a pty."""

import math
import signal

from microball_msgs.msg import ServoCommand
import pytest
from sensor_msgs.msg import JointState
from std_srvs.srv import Trigger

from microball_ros.nodes.common import LATCHED_QOS
from microball_ros.testing import NodeProcess
from microball_ros.testing.dynamixel_emulator import GOAL_VELOCITY, DynamixelEmulator

UNIT = 0.229 * 2 * math.pi / 60          # rad/s of the motor per Goal/Present Velocity unit


def _commander(*params):
    """Start the servo_commander console script with driver:=dynamixel and -p params.

    Its standard error (the ROS log) is kept apart from standard output (NodeProcess.log).
    """
    ros_args = ['-p', 'driver:=dynamixel']
    for param in params:
        ros_args += ['-p', param]
    return NodeProcess('servo_commander', ros_args=ros_args, merge_output=False).start()


def _finish(process, sig=None):
    """Send sig (or nothing: it is to exit by itself); return (exit code, standard error)."""
    code = process.stop(timeout=30.0, sig=sig)
    assert not process.killed, f'servo_commander did not exit within 30 s:\n{process.log}'
    return code, process.log


def _writes(servo, since=0):
    return [(w.address, w.value) for w in servo.writes[since:]]


def _stops_last(servo, since):
    """Return True once the writes since index since end with Goal Velocity 0, Torque 0."""
    return _writes(servo, since)[-2:] == [(104, 0), (64, 0)]


@pytest.fixture
def harness(ros_harness):
    """Give a probe node on its own executor, with clients for the commander's services."""
    return ros_harness


def _call(harness, name):
    client = harness.probe.create_client(Trigger, f'/servo_commander/{name}')
    harness.spin_until(client.service_is_ready, message=f'the {name} service')
    future = client.call_async(Trigger.Request())
    harness.spin_until(future.done, message=f'the {name} response')
    return future.result()


def test_commander_ramps_reports_stops_and_exits_on_sigint(harness):
    states, commands = [], []
    harness.probe.create_subscription(JointState, 'servo/state', states.append, 10)
    harness.probe.create_subscription(ServoCommand, 'servo/command', commands.append,
                                      LATCHED_QOS)
    with DynamixelEmulator() as servo:
        servo.set_present_velocity(60)          # the motor turns slower than asked
        node = _commander(f'port:={servo.port}', 'frequency:=0.5', 'gear_ratio:=2.0',
                          'ramp_time:=0.3', 'heartbeat:=10.0')
        try:
            # In order: mode 1 with torque off, torque on, a ramp of goals up to
            # round(60 * 0.5 / 2.0 / 0.229) = 66.
            assert servo.wait_for(lambda s: s.get(GOAL_VELOCITY) == 66, 30), _writes(servo)
            writes = _writes(servo)
            assert writes[:3] == [(64, 0), (11, 1), (64, 1)]
            goals = [value for address, value in writes[3:]]
            assert all(address == 104 for address, _ in writes[3:])
            assert goals == sorted(goals) and goals[0] < 33 and goals[-1] == 66
            assert len(set(goals)) >= 3, goals                 # ramped, not stepped
            assert all(w.accepted for w in servo.writes)

            # servo/state: the crank speed from Present Velocity, 60 units through gear 2.
            harness.spin_until(lambda: states, message='servo/state')
            assert states[-1].name == ['crank']
            assert states[-1].velocity[0] == pytest.approx(60 * UNIT * 2.0, rel=1e-12)

            before = len(servo.writes)
            assert _call(harness, 'stop').success
            assert _writes(servo, before) == [(104, 0), (64, 0)]
            harness.spin_until(lambda: commands and not commands[-1].enabled,
                               message='a disabled command')

            before = len(servo.writes)
            assert _call(harness, 'start').success
            assert servo.wait_for(lambda s: s.get(GOAL_VELOCITY) == 66, 30)
            assert _writes(servo, before)[0] == (64, 1)

            before = len(servo.writes)
            code, err = _finish(node, signal.SIGINT)
            assert code == 0, err
            assert _stops_last(servo, before), _writes(servo, before)
        finally:
            node.stop()


def test_commander_stops_the_motor_on_sigterm(harness):
    states = []
    harness.probe.create_subscription(JointState, 'servo/state', states.append, 10)
    with DynamixelEmulator() as servo:
        node = _commander(f'port:={servo.port}', 'frequency:=0.5', 'ramp_time:=0.0',
                          'heartbeat:=10.0')
        try:
            harness.spin_until(lambda: states, message='servo/state')   # the node is up
            assert servo.get(GOAL_VELOCITY) == 131                       # 0.5 Hz, gear 1
            before = len(servo.writes)
            code, err = _finish(node, signal.SIGTERM)
            assert code == 0, err
            assert _writes(servo, before) == [(104, 0), (64, 0)]
        finally:
            node.stop()


def test_commander_stops_the_motor_and_logs_a_hardware_error(harness):
    commands = []
    harness.probe.create_subscription(ServoCommand, 'servo/command', commands.append,
                                      LATCHED_QOS)
    with DynamixelEmulator() as servo:
        node = _commander(f'port:={servo.port}', 'frequency:=1.0', 'ramp_time:=0.0',
                          'heartbeat:=10.0')
        try:
            assert servo.wait_for(lambda s: s.get(GOAL_VELOCITY) == 262, 30)
            before = len(servo.writes)
            servo.inject_hardware_error()
            assert servo.wait_for(lambda s: _stops_last(s, before), 30), _writes(servo, before)
            harness.spin_until(lambda: commands and not commands[-1].enabled,
                               message='a disabled command after the fault')
            refused = _call(harness, 'start')
            assert not refused.success and 'overheating' in refused.message
            assert all(value == 0 for _, value in _writes(servo, before))
            code, err = _finish(node, signal.SIGINT)
            assert code == 0
            errors = [line for line in err.splitlines() if line.startswith('[ERROR]')]
            assert len(errors) == 1 and 'hardware error' in errors[0] \
                and 'overheating' in errors[0], err
        finally:
            node.stop()


@pytest.mark.parametrize('case', ['silent', 'missing', 'no port'])
def test_commander_exits_with_one_line_when_there_is_no_servo(case, tmp_path):
    with DynamixelEmulator() as servo:
        servo.silent = True
        port = {'silent': servo.port, 'missing': str(tmp_path / 'ttyUSB0'), 'no port': None}
        node = _commander(*[f'port:={port[case]}'] if port[case] else [])
        code, err = _finish(node)
        assert servo.writes == []
    expected = {'silent': 'does not answer', 'missing': 'does not exist',
                'no port': 'needs the port parameter'}[case]
    assert code == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1 and expected in lines[0], err
