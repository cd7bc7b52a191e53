"""``microball reprocess``: replay a bag's tracked positions through fresh nodes, lock-step.

A fresh three_stage_estimator and friction_identifier are started as processes with the
parameters the run recorded (bag metadata, custom_data 'microball.<node>'), the bag's
/tracking/positions are published lock-step (each after the estimator acknowledged the
previous one), and an in-process recorder writes the replayed positions and the nodes' fresh
/estimation/derivatives and /friction/model to the output bag. The nodes' outputs depend only
on their ordered input, so the new messages equal the recorded ones byte for byte on the
platform that recorded them (and within relative 1e-9 on another: docs/design.md section 4).

A bag with only /camera/image_raw goes through a fresh camera_tracker first (parameters as in
frames.tracker_parameters); a frame is published only while fewer than the tracker's
``prime_frames`` are without a recorded position (it holds that many while it learns the
marks), so no frame can be dropped however slow the tracker.

The output bag keeps the parameters the nodes were given and this platform's fingerprint in its
custom_data, so it can itself be reprocessed. ``check()`` compares the reproduced topics with the
recorded ones (microball_ros.io.compare) and names both platforms.
"""

import shutil
import tempfile
import time
from typing import NamedTuple

from diagnostic_msgs.msg import DiagnosticArray
import rclpy
from rclpy.executors import SingleThreadedExecutor
import yaml

from microball_ros.app.experiment import (
    WRITERS,
    NodeCrashed,
    NodeProcesses,
    flatten_parameters,
)
from microball_ros.app.play import Player, use_lockstep_profile
from microball_ros.core.windowing import PositionWindower, Window, WindowSettings
from microball_ros.io import fingerprint
from microball_ros.io.bags.reader import IMAGES_TOPIC, BagError, open_bag, recorded_parameters
from microball_ros.io.compare import BYTE_IDENTICAL, NOT_COMPARED, compare_bags
from microball_ros.io.frames import TRACKER, tracked_frames, tracker_parameters
from microball_ros.nodes.camera_tracker import reliable_images
from microball_ros.nodes.common import diagnostic_values, subscribers_key
from microball_ros.nodes.recorder import Recorder
from microball_ros.nodes.three_stage_estimator import PARAMS as ESTIMATOR_PARAMS

POSITIONS = '/tracking/positions'
OUTPUTS = ('/estimation/derivatives', '/friction/model')
REPROCESSED_NODES = ('three_stage_estimator', 'friction_identifier')
# The subscriptions each node's writer must have matched before the replay starts (the
# recorder's, and the next node's).
READERS = {POSITIONS: 2, '/estimation/derivatives': 2, '/friction/model': 1}


def expected_windows(samples, estimator_parameters):
    """Return how many windows the estimator will publish for these positions.

    ``samples`` are (stamp_ns, frame_index, stator, slider, valid) in publishing order; they
    go through the same core windower, with the same settings, as in the estimator node.
    """
    values = {name: p.default for name, p in ESTIMATOR_PARAMS.items()}
    values.update(estimator_parameters)
    windower = PositionWindower(WindowSettings(
        window_periods=values['window_periods'], hop_periods=values['hop_periods'],
        min_amplitude=values['min_amplitude'],
        frequency_tolerance=values['frequency_tolerance']))
    count = 0
    for stamp_ns, frame_index, stator, slider, valid in samples:
        # The node's stamp_to_seconds(header.stamp), to the last bit.
        stamp = stamp_ns // 1_000_000_000 + (stamp_ns % 1_000_000_000) * 1e-9
        events = windower.push(stamp, frame_index, stator, slider, valid)
        count += sum(isinstance(e, Window) for e in events)
    return count


def _recorded_samples(bag):
    """Yield the bag's TrackedPositions as expected_windows samples."""
    from microball_msgs.msg import TrackedPositions
    from rclpy.serialization import deserialize_message

    for message in bag.messages([POSITIONS]):
        msg = deserialize_message(message.data, TrackedPositions)
        yield (msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec,
               msg.frame_index, msg.stator_position, msg.slider_position,
               msg.slider_valid and msg.stator_valid)


def _tracked_samples(bag, tracker_parameters):
    """Yield what a camera_tracker with these parameters will publish, as samples."""
    for stamp_ns, index, stator, slider, _, _ in tracked_frames(bag, tracker_parameters):
        yield stamp_ns, index, stator, slider, stator == stator and slider == slider


def output_custom_data(bag, parameters):
    """Return the output bag's custom_data (YAML text): parameters and this platform.

    The source bag's 'microball.<node>' entries, those of the nodes that ran here replaced by
    the values they were given, and this platform's fingerprint (never the recorded one).
    """
    kept = {key: value for key, value in
            ((bag.metadata or {}).get('custom_data') or {}).items()
            if key.startswith('microball.') and key != fingerprint.CUSTOM_DATA_KEY}
    for name, values in parameters.items():
        kept[f'microball.{name}'] = yaml.safe_dump(
            {k: v for k, v in values.items() if k != 'wait_for_subscribers'})
    kept.update(fingerprint.to_custom_data())
    return yaml.safe_dump(kept)


def reprocess(bag_path, output, progress=print, timeout=60.0, tracking=None):
    """Reprocess bag_path into the bag directory output; return per-topic counts.

    ``tracking``: camera_tracker values given by the user (slider_roi, stator_roi,
    meters_per_pixel; None entries are taken from the recording), for a bag with only frames.
    ``timeout``: seconds any wait may go without progress before giving up.
    """
    use_lockstep_profile()
    bag = open_bag(bag_path)
    parameters = {name: recorded_parameters(bag, name) for name in REPROCESSED_NODES}
    if POSITIONS in bag.topics:
        source, nodes, recorded = POSITIONS, REPROCESSED_NODES, [POSITIONS, *OUTPUTS]
        samples = _recorded_samples(bag)
    elif IMAGES_TOPIC in bag.topics:
        source, nodes, recorded = IMAGES_TOPIC, (TRACKER, *REPROCESSED_NODES), [POSITIONS,
                                                                               *OUTPUTS]
        # The tracker listens only once the estimator and the recorder receive its positions.
        parameters[TRACKER] = {**tracker_parameters(bag, **(tracking or {})),
                               'wait_for_subscribers': 2,
                               **flatten_parameters(
                                   {'qos_overrides': reliable_images('subscription')})}
        values = parameters[TRACKER]
        progress(f"{bag_path} has only camera frames: tracking them through camera_tracker "
                 f"(slider ROI {values['slider_roi']}, stator ROI {values['stator_roi']}, "
                 f"{values['meters_per_pixel']:.6g} m/px)")
        samples = _tracked_samples(bag, parameters[TRACKER])
    else:
        raise BagError(f'{bag_path}: nothing to reprocess: no {POSITIONS} and no '
                       f'{IMAGES_TOPIC} (it has: {", ".join(sorted(bag.topics))})')
    windows = expected_windows(samples, parameters['three_stage_estimator'])
    progress(f'{bag.topics[source].count} messages on {source} -> {windows} windows expected')
    context = rclpy.Context()
    rclpy.init(context=context)
    executor = SingleThreadedExecutor(context=context)
    log_dir = tempfile.mkdtemp(prefix='microball-reprocess-')
    processes = NodeProcesses({name: parameters[name] for name in nodes}, log_dir)
    recorder = Recorder(context=context, parameter_overrides=[
        rclpy.parameter.Parameter('output', value=output),
        rclpy.parameter.Parameter('topics', value=recorded),
        rclpy.parameter.Parameter('custom_data', value=output_custom_data(bag, parameters))])
    player = Player(bag, topics=[source], context=context)
    # The nodes' writers report on /diagnostics how many subscriptions they have matched: the
    # graph shows a subscription before the writer has matched it, and what it publishes
    # before that is lost (volatile QoS; a rare timeout of the estimates before this).
    monitor = rclpy.create_node('microball_reprocess_monitor', context=context)
    statuses: dict = {}
    monitor.create_subscription(DiagnosticArray, '/diagnostics',
                                lambda msg: statuses.update(diagnostic_values(msg)), 10)
    writers = {name: '/' + topic for topic, name in WRITERS.items() if name in nodes}
    for node in (recorder, player, monitor):
        executor.add_node(node)

    def spin_until(condition, what, progress_of=lambda: None):
        deadline, seen = time.monotonic() + timeout, progress_of()
        while not condition():
            executor.spin_once(timeout_sec=0.05)
            processes.check()
            if progress_of() != seen:
                deadline, seen = time.monotonic() + timeout, progress_of()
            if time.monotonic() > deadline:
                raise NodeCrashed(f'timed out waiting for {what}; node logs in {log_dir}')

    def positions_recorded():
        return recorder.counts.get(POSITIONS, 0)

    completed = False
    try:
        for name in nodes:
            processes.start(name)
        published = player.publishers_by_topic[source]
        subscribers = 1 if source == IMAGES_TOPIC else 2  # tracker; estimator + recorder
        spin_until(lambda: published.get_subscription_count() >= subscribers,
                   f'the {nodes[0]} to subscribe')
        spin_until(lambda: all(recorder.matched.get(t, 0) >= 1 for t in recorded
                               if t != source),
                   'the recorder to connect to the outputs')
        spin_until(lambda: all(int(statuses.get(name, {}).get(subscribers_key(topic), 0))
                               >= READERS[topic] for name, topic in writers.items()),
                   "the nodes' writers to match their subscriptions")
        ready = None
        if source == IMAGES_TOPIC:
            # The tracker holds its first prime_frames frames (it learns the marks from
            # them), then publishes one position a frame: frame n + 1 only once at most
            # prime_frames - 1 frames are without a recorded position.
            held = max(int(parameters[TRACKER]['prime_frames']), 1) - 1

            def ready():
                spin_until(lambda: positions_recorded() >= player.published - held,
                           'the position of the last frame')
        player.play(executor, lockstep=True, ready=ready,
                    progress=lambda n, t: progress(f'replayed {n} messages ({t:.1f} s)'))
        replayed = player.published
        spin_until(lambda: all(recorder.counts.get(t, 0) >= windows for t in OUTPUTS)
                   and positions_recorded() >= replayed,
                   f'{windows} estimates and models',
                   lambda: (*(recorder.counts.get(t, 0) for t in OUTPUTS),
                            positions_recorded()))
        completed = True
    finally:
        processes.stop()
        if completed:  # a failed run keeps its node logs: its error names them
            shutil.rmtree(log_dir, ignore_errors=True)
        executor.shutdown()
        counts = recorder.close()
        player.destroy_node()
        monitor.destroy_node()
        rclpy.shutdown(context=context)
    return counts


class Check(NamedTuple):
    """What check() found: the verdict, the topics compared and the two platforms.

    ``recorded_platform`` is the bag's fingerprint (None for a bag recorded before bags
    carried one), ``platform`` this process's.
    """

    verdict: object
    topics: tuple
    recorded_platform: dict | None
    platform: dict

    @property
    def same_platform(self):
        """Return True if the bag carries a fingerprint whose numeric key is this platform's."""
        return (self.recorded_platform is not None
                and self.recorded_platform.get('key') == self.platform.get('key'))

    def platform_lines(self):
        """Return lines naming both platforms, and how they differ unless byte-identical."""
        def name(info):
            return f"{info.get('key')} ({info.get('cpu')}, numpy SIMD {info.get('numpy_simd')})"

        recorded = self.recorded_platform
        if recorded is None:
            return ['platform: no fingerprint recorded (the bag predates them); reprocessed on '
                    f'{name(self.platform)}']
        lines = [f'platform: recorded on {name(recorded)}',
                 f'platform: reprocessed on {name(self.platform)}']
        if self.verdict.status not in (BYTE_IDENTICAL, NOT_COMPARED):
            lines += [f'platform differs: {line}'
                      for line in fingerprint.differences(recorded, self.platform)]
            if self.same_platform:
                lines.append('platform: same fingerprint key, so byte identity was expected '
                             '(determinism contract (a))')
        return lines


def reproduced_topics(bag):
    """Return the topics reprocess reproduces from this bag, in causal order."""
    return OUTPUTS if POSITIONS in bag.topics else (POSITIONS, *OUTPUTS)


def check(bag_path, output):
    """Compare the reprocessed bag output with the recorded bag_path; return a Check.

    Only the reproduced topics the recorded bag has are compared (a bag of only frames has
    none: the verdict is then 'not compared').
    """
    recorded, new = open_bag(bag_path), open_bag(output)
    reproduced = reproduced_topics(recorded)
    topics = tuple(t for t in reproduced if t in recorded.topics)
    verdict = compare_bags(recorded, new, topics)
    if not topics:
        verdict = verdict._replace(line=f'{NOT_COMPARED}: {bag_path} has no recorded '
                                        f'{", ".join(reproduced)}')
    custom_data = (recorded.metadata or {}).get('custom_data')
    return Check(verdict, topics, fingerprint.from_custom_data(custom_data),
                 fingerprint.fingerprint())
