"""``microball reprocess``: replay a bag's tracked positions through fresh nodes, lock-step.

A fresh three_stage_estimator and friction_identifier are started as processes with the
parameters the run recorded (bag metadata, custom_data 'microball.<node>'), the bag's
/tracking/positions are published lock-step (each after the estimator acknowledged the
previous one), and an in-process recorder writes the replayed positions and the nodes' fresh
/estimation/derivatives and /friction/model to the output bag. The nodes' outputs depend only
on their ordered input, so the new messages equal the recorded ones byte for byte.
"""

import tempfile
import time

import rclpy
from rclpy.executors import SingleThreadedExecutor
import yaml

from microball_ros.bags.reader import BagError, open_bag
from microball_ros.core.windowing import PositionWindower, Window, WindowSettings
from microball_ros.experiment import NodeCrashed, _Processes
from microball_ros.nodes.recorder import Recorder
from microball_ros.nodes.three_stage_estimator import PARAMS as ESTIMATOR_PARAMS
from microball_ros.player import Player, use_lockstep_profile

POSITIONS = '/tracking/positions'
OUTPUTS = ('/estimation/derivatives', '/friction/model')
REPROCESSED_NODES = ('three_stage_estimator', 'friction_identifier')


def recorded_parameters(bag):
    """Return node name -> parameters stored in the bag's metadata (empty if none)."""
    parameters = {}
    custom_data = (bag.metadata or {}).get('custom_data') or {}
    for node in REPROCESSED_NODES:
        text = custom_data.get(f'microball.{node}')
        parameters[node] = yaml.safe_load(text) if text else {}
    return parameters


def expected_windows(bag, estimator_parameters):
    """Return how many windows the estimator will publish for the bag's positions.

    The bag's TrackedPositions go through the same core windower, with the same settings, as
    in the estimator node.
    """
    from microball_msgs.msg import TrackedPositions
    from rclpy.serialization import deserialize_message

    from microball_ros import conversions

    values = {name: p.default for name, p in ESTIMATOR_PARAMS.items()}
    values.update(estimator_parameters)
    windower = PositionWindower(WindowSettings(
        window_periods=values['window_periods'], hop_periods=values['hop_periods'],
        min_amplitude=values['min_amplitude'],
        frequency_tolerance=values['frequency_tolerance']))
    count = 0
    for message in bag.messages([POSITIONS]):
        msg = deserialize_message(message.data, TrackedPositions)
        events = windower.push(conversions.stamp_to_seconds(msg.header.stamp), msg.frame_index,
                               msg.stator_position, msg.slider_position,
                               msg.slider_valid and msg.stator_valid)
        count += sum(isinstance(e, Window) for e in events)
    return count


def reprocess(bag_path, output, progress=print, timeout=600.0):
    """Reprocess bag_path into the bag directory output; return per-topic counts."""
    use_lockstep_profile()
    bag = open_bag(bag_path)
    if POSITIONS not in bag.topics:
        raise BagError(f'{bag_path}: no {POSITIONS} to reprocess (it has: '
                       f'{", ".join(sorted(bag.topics))})')
    parameters = recorded_parameters(bag)
    windows = expected_windows(bag, parameters['three_stage_estimator'])
    progress(f'{bag.topics[POSITIONS].count} positions -> {windows} windows expected')
    context = rclpy.Context()
    rclpy.init(context=context)
    executor = SingleThreadedExecutor(context=context)
    log_dir = tempfile.mkdtemp(prefix='microball-reprocess-')
    processes = _Processes({name: parameters[name] for name in REPROCESSED_NODES}, log_dir)
    recorder = Recorder(context=context, parameter_overrides=[
        rclpy.parameter.Parameter('output', value=output),
        rclpy.parameter.Parameter('topics', value=[POSITIONS, *OUTPUTS])])
    player = Player(bag, topics=[POSITIONS], context=context)
    for node in (recorder, player):
        executor.add_node(node)
    deadline = time.monotonic() + timeout

    def spin_until(condition, what):
        while not condition():
            executor.spin_once(timeout_sec=0.05)
            processes.check()
            if time.monotonic() > deadline:
                raise NodeCrashed(f'timed out waiting for {what}; node logs in {log_dir}')

    try:
        for name in REPROCESSED_NODES:
            processes.start(name)
        positions = player.publishers_by_topic[POSITIONS]
        spin_until(lambda: positions.get_subscription_count() >= 2,  # estimator + recorder
                   'the estimator to subscribe')
        spin_until(lambda: all(recorder.matched.get(t, 0) >= 1 for t in OUTPUTS),
                   'the recorder to connect to the outputs')
        player.play(executor, lockstep=True,
                    progress=lambda n, t: progress(f'replayed {n} positions ({t:.1f} s)'))
        replayed = player.published
        spin_until(lambda: all(recorder.counts.get(t, 0) >= windows for t in OUTPUTS)
                   and recorder.counts.get(POSITIONS, 0) >= replayed,
                   f'{windows} estimates and models')
    finally:
        processes.stop()
        executor.shutdown()
        counts = recorder.close()
        player.destroy_node()
        rclpy.shutdown(context=context)
    return counts
