"""bench_simulator: the rig's stand-in (servo + crank-slider + bearing + camera).

Subscribes to /servo/command; integrates the stator (crank-slider, motor with ramp and lag)
and the slider (the scenario's friction law); renders frames with the synthetic camera and
publishes them on /camera/image_raw (mono8, header.stamp = mid-exposure) with the ground truth
on /bench/ground_truth. Real time by default; with ``speed`` != 1 it runs that much faster
and publishes /clock (the other nodes then set use_sim_time). A real camera driver publishing
sensor_msgs/Image, or a real servo, replaces it without touching the other nodes. A servo
command with a NaN or infinite speed, a negative ramp, a stamp going backwards, or from a
publisher beyond ``expected_publishers`` is dropped and counted on /diagnostics.
"""

import math
import sys

from microball_msgs.msg import BenchState, ServoCommand
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.qos import QoSProfile
from rosgraph_msgs.msg import Clock as ClockMsg
from sensor_msgs.msg import Image

from microball_ros.core import bench
from microball_ros.core.rig import RigStepper
from microball_ros.io import conversions
from microball_ros.nodes.common import (
    DATA_QOS,
    IMAGE_QOS,
    LATCHED_QOS,
    InputGuard,
    NodeDiagnostics,
    Param,
    create_publisher,
    declare_parameters,
    non_finite,
    run,
)

PARAMS = {
    'scenario': Param('paper', 'bench scenario: ' + ', '.join(bench.scenario_names()),
                      read_only=True),
    'seed': Param(-1, "noise seed; -1 takes the scenario's", -1, 2**31 - 1, read_only=True),
    'speed': Param(1.0, 'simulated seconds per wall-clock second', 0.05, 50.0),
    'publish_clock': Param(False, 'publish /clock (simulated time) for use_sim_time nodes'),
    'duration': Param(0.0, 'stop publishing frames after this much simulated time, s '
                           '(0: run until stopped)', 0.0, 1e6),
    'motor_lag': Param(0.05, 'motor speed lag (first-order time constant), s', 0.0, 5.0,
                       read_only=True),
    'frame_id': Param('camera', 'frame_id of the images and ground truth', read_only=True),
    'wait_for_subscribers': Param(0, 'hold the first frame until the images and the ground '
                                     'truth each have this many matched subscribers and a '
                                     'servo command has arrived (a reproducible start); 0 '
                                     'starts at once', 0, 100),
    'expected_publishers': Param(1, 'publishers of servo/command this node accepts commands '
                                    "from (the first ones heard); more are another rig's, "
                                    'dropped; 0 accepts any number', 0, 100, read_only=True),
}


def command_problem(msg):
    """Return None, or (kind, detail) for a ServoCommand no working servo_commander sends."""
    bad = non_finite(msg, ('angular_velocity', 'frequency', 'ramp_time'))
    if bad:
        return ('NaN command', f'{", ".join(bad)} not finite')
    if msg.ramp_time < 0:
        return ('negative ramp time', f'{msg.ramp_time:g} s')
    return None


def check_parameters(values):
    """Return None if the parameter values are consistent, else a one-line reason."""
    if values['scenario'] not in bench.scenario_names():
        return (f"unknown scenario {values['scenario']!r}; "
                f"known: {', '.join(bench.scenario_names())}")
    return None


class BenchSimulator(Node):
    """Publish camera frames and ground truth of the simulated rig at the camera rate."""

    def __init__(self, **kwargs):
        super().__init__('bench_simulator', **kwargs)
        self._values = declare_parameters(self, PARAMS, check_parameters)
        self.add_post_set_parameters_callback(self._on_parameters_set)
        values = self._values
        scenario = bench.get_scenario(values['scenario'])
        self._rig = RigStepper(scenario, seed=None if values['seed'] < 0 else values['seed'],
                               motor_lag=values['motor_lag'])
        self._law = scenario.law.name
        self._servo = None
        self._images = create_publisher(self, Image, 'camera/image_raw', IMAGE_QOS)
        self._truth = create_publisher(self, BenchState, 'bench/ground_truth', DATA_QOS)
        # Not self._clock: that is the Node's own clock.
        self._clock_publisher = create_publisher(self, ClockMsg, '/clock',
                                                 QoSProfile(depth=10))
        self.diagnostics = NodeDiagnostics(self)
        self.guard = InputGuard(self, self.diagnostics, 'servo/command',
                                expected=values['expected_publishers'],
                                check=command_problem, allow_equal_stamps=True)
        self.guard.subscribe(ServoCommand, self._on_command, LATCHED_QOS)
        self._wall = Clock(clock_type=ClockType.STEADY_TIME)
        self._timer = None
        self._start_timer()

    @property
    def frames_published(self):
        """Return how many frames were published."""
        return self._rig.index

    def _start_timer(self):
        if self._timer is not None:
            self.destroy_timer(self._timer)
        period = 1.0 / (self._rig.config.fps * self._values['speed'])
        self._timer = self.create_timer(period, self._on_frame, clock=self._wall)

    def _on_parameters_set(self, parameters):
        self._values.update({p.name: p.value for p in parameters if p.name in PARAMS})
        if any(p.name == 'speed' for p in parameters):
            self._start_timer()

    def _on_command(self, msg):
        setting = (msg.enabled, msg.angular_velocity, msg.ramp_time)
        if setting == self._servo:
            return  # a heartbeat repeating the current command
        self._servo = setting
        self._rig.command(msg.angular_velocity if msg.enabled else 0.0, msg.ramp_time)
        self.get_logger().info(f'servo: {"on" if msg.enabled else "off"}, '
                               f'{msg.frequency:g} Hz, ramp {msg.ramp_time:g} s')

    def _on_frame(self):
        wanted = self._values['wait_for_subscribers']
        if self._rig.index == 0 and wanted and (
                self._servo is None or self._images.get_subscription_count() < wanted
                or self._truth.get_subscription_count() < wanted):
            return
        duration = self._values['duration']
        if duration and self._rig.index / self._rig.config.fps >= duration:
            self._timer.cancel()
            self.get_logger().info(f'simulated {duration:g} s: done')
            return
        frame = self._rig.next_frame()
        frame_id = self._values['frame_id']
        stamp = conversions.seconds_to_stamp(frame.stamp)
        self._images.publish(conversions.image_message(frame.image, stamp, frame_id))
        self.diagnostics.count('frames published')
        self._truth.publish(self._bench_state(frame, stamp, frame_id))
        if self._values['publish_clock']:
            self._clock_publisher.publish(
                ClockMsg(clock=conversions.seconds_to_stamp(self._rig.time)))

    def _bench_state(self, frame, stamp, frame_id):
        state = frame.state
        msg = BenchState()
        msg.header.stamp, msg.header.frame_id = stamp, frame_id
        msg.frame_index = frame.index
        msg.crank_angle = float(math.remainder(state.crank_angle, 2 * math.pi))
        msg.crank_angular_velocity = float(frame.crank_angular_velocity)
        msg.stator_position = float(state.stator_position)
        msg.stator_velocity = float(state.stator_velocity)
        msg.slider_position = float(state.slider_position)
        msg.slider_velocity = float(state.slider_velocity)
        msg.stator_position_exposure_mean = float(frame.truth.stator_mean)
        msg.slider_position_exposure_mean = float(frame.truth.slider_mean)
        msg.relative_velocity = float(state.relative_velocity)
        msg.slider_acceleration = float(state.slider_acceleration)
        msg.friction_law = self._law
        return msg


def main(args=None):
    """Run the node (console script bench_simulator)."""
    return run(BenchSimulator, args)


if __name__ == '__main__':
    sys.exit(main())
