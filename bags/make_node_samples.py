"""Record the node sample bags of microball_ros.testing with the real nodes.

    .venv/bin/python bags/make_node_samples.py bags

writes three bags, each a node's input topics and the outputs the real node (its console
script, as a process) published for them, replayed lock-step by microball_ros.testing.replay:

- ``camera_tracker/``: FRAMES synthetic camera frames of the paper scenario (a small
  WIDTH x HEIGHT camera, so the bag stays small) -> /tracking/positions (the node primed on
  those FRAMES frames: tracker_parameters)
- ``three_stage_estimator/``: the positions camera_tracker publishes for POSITION_FRAMES
  such frames -> /estimation/derivatives (one message a window)
- ``friction_identifier/``: those derivatives -> /friction/model (one refit a window)

Each bag's custom_data keeps the node's parameters (``microball.<node>``), which topics are its
inputs and outputs (``microball.testing``) and this platform's fingerprint: the bags reproduce
byte for byte on the platform that made them, within relative 1e-9 elsewhere (docs/design.md
section 4). Re-run on the machine the tests run on most (CI) to get byte identity there.
"""

import argparse
import os
import shutil
import sys
import tempfile

from microball_ros.app.isolation import claim_domain
from microball_ros.app.play import use_lockstep_profile

FRAMES = 12
POSITION_FRAMES = 300
WIDTH, HEIGHT = 320, 96
SCENARIO = 'paper'
T0_NS = 1_700_000_000_000_000_000  # bag time of the first frame's exposure start
IMAGES = '/camera/image_raw'
POSITIONS = '/tracking/positions'
DERIVATIVES = '/estimation/derivatives'
MODELS = '/friction/model'
TYPES = {IMAGES: 'sensor_msgs/msg/Image', POSITIONS: 'microball_msgs/msg/TrackedPositions',
         DERIVATIVES: 'microball_msgs/msg/DerivativeEstimate',
         MODELS: 'microball_msgs/msg/FrictionModel'}


def camera():
    """Return the scenario and the small camera the frames are rendered with."""
    from microball_ros.core import bench, camera, rig

    scenario = bench.get_scenario(SCENARIO)
    return scenario, rig.camera_for(scenario, camera.CameraConfig(width=WIDTH, height=HEIGHT))


def tracker_parameters():
    """Return camera_tracker's parameters for the small camera.

    ``prime_frames`` is FRAMES: the tracker sample's node learns the marks from exactly its
    FRAMES frames, when the last one arrives, and then publishes them, so no replay of it
    waits for the node's prime_timeout (a wall-clock pause; the default 60 frames would need
    one in every replay). The estimator's POSITION_FRAMES positions are tracked with the same
    parameters, so their first FRAMES are the tracker sample's outputs.
    """
    from microball_ros.core import rig

    scenario, config = camera()
    rois = rig.suggested_rois(scenario, config)
    return {'slider_roi': list(rois['slider']), 'stator_roi': list(rois['stator']),
            'meters_per_pixel': config.meters_per_pixel, 'prime_frames': FRAMES}


def write_frames(path, count):
    """Write a bag of ``count`` rendered frames on /camera/image_raw (the tracker's input)."""
    from rclpy.serialization import serialize_message
    import yaml

    from microball_ros.core import rig
    from microball_ros.io import conversions
    from microball_ros.io.bags.schema import qos_profiles_yaml
    from microball_ros.io.bags.writer import BagWriter
    from microball_ros.nodes.common import DATA_QOS

    scenario, config = camera()
    stepper = rig.RigStepper(scenario, config)
    stepper.command(scenario.angular_frequency)
    custom = {'microball.camera_tracker': yaml.safe_dump(tracker_parameters())}
    with BagWriter(path, custom_data=custom) as writer:
        writer.add_topic(IMAGES, TYPES[IMAGES], qos_profiles_yaml([DATA_QOS]))
        for _ in range(count):
            frame = stepper.next_frame()
            stamp_ns = T0_NS + round(frame.stamp * 1e9)
            message = conversions.image_message(frame.image, stamp_ns * 1e-9)
            message.header.stamp = conversions.nanoseconds_to_stamp(stamp_ns)
            writer.write(IMAGES, serialize_message(message), stamp_ns, stamp_ns)
    return path


def expected_windows(bag, parameters):
    """Return how many windows three_stage_estimator publishes for the bag's positions."""
    from microball_msgs.msg import TrackedPositions
    from rclpy.serialization import deserialize_message

    from microball_ros.app.reprocess import expected_windows as count

    samples = []
    for message in bag.messages([POSITIONS]):
        msg = deserialize_message(message.data, TrackedPositions)
        samples.append((msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec,
                        msg.frame_index, msg.stator_position, msg.slider_position,
                        msg.slider_valid and msg.stator_valid))
    return count(samples, parameters)


def record(source, node, inputs, output, expected, out, parameters=None):
    """Replay ``source`` through the node's process; write inputs + its outputs to ``out``."""
    from microball_ros.testing.replay import replay

    result = replay(source, node, inputs=inputs, outputs={output: TYPES[output]},
                    expected={output: expected}, parameters=parameters, timeout=120.0)
    counts = {t: result.received.count(t) for t in result.outputs}
    if result.timed_out or counts[output] != expected:
        sys.exit(f'{node}: expected {expected} messages on {output}, got {counts}; '
                 f'log: {result.process.log_path}')
    result.write_bag(out)
    print(f'{out}: {result.published} on {", ".join(inputs)} -> {counts[output]} on {output} '
          f'({sum(os.path.getsize(os.path.join(out, f)) for f in os.listdir(out))} bytes)')
    return out


def main():
    """Render the frames and record the three bags into the output folder."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('output', help='folder for the bags (bags/ of the repository)')
    args = parser.parse_args()
    use_lockstep_profile()  # before anything initialises rclpy
    claim = claim_domain()
    os.environ.update(claim.environment())
    from microball_ros.io.bags.reader import open_bag

    work = tempfile.mkdtemp(prefix='microball-samples-')
    try:
        targets = {name: os.path.join(args.output, name) for name in
                   ('camera_tracker', 'three_stage_estimator', 'friction_identifier')}
        for target in targets.values():
            shutil.rmtree(target, ignore_errors=True)
        # camera_tracker: a few frames, one position each.
        frames = write_frames(os.path.join(work, 'frames'), FRAMES)
        record(frames, 'camera_tracker', [IMAGES], POSITIONS, FRAMES, targets['camera_tracker'])
        # three_stage_estimator: the tracker's positions for more frames.
        many = write_frames(os.path.join(work, 'many_frames'), POSITION_FRAMES)
        positions = record(many, 'camera_tracker', [IMAGES], POSITIONS, POSITION_FRAMES,
                           os.path.join(work, 'positions'))
        estimator = {'exposure': camera()[1].exposure}
        cut = os.path.join(work, 'positions_only')
        _copy_topics(open_bag(positions), cut, [POSITIONS])
        windows = expected_windows(open_bag(cut), estimator)
        record(cut, 'three_stage_estimator', [POSITIONS], DERIVATIVES, windows,
               targets['three_stage_estimator'], estimator)
        # friction_identifier: the estimator's windows, one refit each.
        derivatives = os.path.join(work, 'derivatives_only')
        _copy_topics(open_bag(targets['three_stage_estimator']), derivatives, [DERIVATIVES])
        record(derivatives, 'friction_identifier', [DERIVATIVES], MODELS, windows,
               targets['friction_identifier'])
    finally:
        shutil.rmtree(work, ignore_errors=True)
        claim.release()


def _copy_topics(bag, out, topics):
    """Copy some topics of a bag (bytes, times, QoS) with its custom_data but no test spec."""
    from microball_ros.io.bags.writer import BagWriter
    from microball_ros.io.fingerprint import CUSTOM_DATA_KEY
    from microball_ros.testing.replay import SPEC_KEY

    custom = {k: v for k, v in bag.custom_data.items()
              if k.startswith('microball.') and k not in (SPEC_KEY, CUSTOM_DATA_KEY)}
    with BagWriter(out, custom_data=custom) as writer:
        for topic in topics:
            writer.add_topic(topic, bag.topics[topic].type, bag.topics[topic].qos_profiles_yaml)
        for message in bag.messages(topics):
            writer.write(message.topic, message.data, message.log_time_ns,
                         message.publish_time_ns)
    return out


if __name__ == '__main__':
    main()
