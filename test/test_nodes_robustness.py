"""Robustness: a node waits quietly; a killed estimator restarts cleanly; bad input is dropped.

Bad input (NaN, stamps or frame indices going backwards, a foreign publisher) is dropped and
counted on /diagnostics, and the good messages after it give the normal output.
"""

import copy
import math
import os
import signal
import subprocess
import sys

from microball_msgs.msg import DerivativeEstimate, FrictionModel, TrackedPositions
import numpy as np
import pytest
from std_msgs.msg import Header

from microball_ros.core import bench, memory
from microball_ros.core.windowing import PositionWindower, Skip, WindowSettings
from microball_ros.io import conversions
from microball_ros.nodes.common import DATA_QOS
from microball_ros.nodes.friction_identifier import FrictionIdentifier
from microball_ros.testing import Harness, killable_env


def _start_estimator(directory):
    # Killed with SIGKILL, then restarted: without Fast DDS shared memory, or the restart
    # would delete ports this process has mapped (killable_env).
    return subprocess.Popen([sys.executable, '-m', 'microball_ros.nodes.three_stage_estimator'],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            env=killable_env(directory))


def _shared_memory_ports(pid):
    """Return the Fast DDS shared-memory ports process ``pid`` has mapped."""
    with open(f'/proc/{pid}/maps') as maps:
        return {line.split()[5] for line in maps if '/dev/shm/fastdds_port' in line}


def _deleted_mappings(pid):
    """Return the shared-memory files process ``pid`` still maps that have been deleted."""
    with open(f'/proc/{pid}/maps') as maps:
        return {line.split()[-2] for line in maps if line.rstrip().endswith('(deleted)')
                and '/dev/shm/' in line}


def _subscription_ids(node, topic):
    return {bytes(info.endpoint_gid) for info in node.get_subscriptions_info_by_topic(topic)}


def test_killed_estimator_restarts_and_the_pipeline_resumes(ros_context, tmp_path):
    record = bench.simulate(bench.get_scenario('paper'), 40.0)
    identifier = FrictionIdentifier(context=ros_context)
    harness = Harness(ros_context, identifier)
    estimator = _start_estimator(tmp_path)
    try:
        probe = harness.probe
        models, windows = [], []
        probe.create_subscription(FrictionModel, 'friction/model', models.append, DATA_QOS)
        probe.create_subscription(DerivativeEstimate, 'estimation/derivatives', windows.append,
                                  DATA_QOS)
        positions = probe.create_publisher(TrackedPositions, 'tracking/positions', DATA_QOS)
        # Started before anything publishes positions, the estimator waits quietly.
        harness.wait_for_subscribers(positions)
        harness.wait_for_output_subscribers('three_stage_estimator', 'estimation/derivatives', 2)
        assert estimator.poll() is None and windows == []
        assert _shared_memory_ports(estimator.pid) == set()  # it leaves none behind

        def publish(frames):
            for k in frames:
                positions.publish(conversions.tracked_positions(
                    record.time[k], k, record.slider_position[k], record.stator_position[k],
                    1.0, 1.0))

        publish(range(0, 450))  # 15 s
        harness.spin_until(lambda: len(models) >= 6, timeout=60, message='6 models')
        old_subscriptions = _subscription_ids(probe, 'tracking/positions')
        os.kill(estimator.pid, signal.SIGKILL)
        estimator.wait(timeout=10)
        before = len(windows)

        estimator = _start_estimator(tmp_path)
        harness.spin_until(
            lambda: _subscription_ids(probe, 'tracking/positions') - old_subscriptions,
            timeout=30, message='the restarted estimator')
        harness.wait_for_subscribers(positions)
        harness.diagnostics().pop('three_stage_estimator', None)  # the killed one's status
        harness.wait_for_output_subscribers('three_stage_estimator', 'estimation/derivatives', 2)
        assert _deleted_mappings(os.getpid()) == set()  # no port of this process deleted
        publish(range(600, 1200))  # 20 s more, after a gap of 5 s
        harness.spin_until(lambda: len(windows) >= before + 8, timeout=60,
                           message='windows from the restarted estimator')
        harness.spin_until(lambda: len(models) == len(windows), timeout=60,
                           message='a model for every window')
        resumed = windows[before:]
        assert min(conversions.stamp_to_seconds(w.header.stamp) for w in resumed) >= \
            record.time[600]
        model = models[-1]
        assert model.window_count == len(windows)
        assert model.a * model.alpha / 3 == pytest.approx(1.2 * 110 / 3, rel=0.05)
        assert all(w.memoryless for w in windows)
    finally:
        estimator.kill()
        estimator.wait(timeout=10)
        harness.close()


def _start(node):
    return subprocess.Popen([sys.executable, '-m', f'microball_ros.nodes.{node}'],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)


def _stop(*processes):
    outputs = []
    for process in processes:
        if process.poll() is None:
            process.send_signal(signal.SIGINT)
        try:
            outputs.append(process.communicate(timeout=20)[0])
        except subprocess.TimeoutExpired:
            process.kill()
            outputs.append(process.communicate()[0])
    return outputs


def _clean_windows(record, frames):
    """Return the window start stamps a clean estimator makes of these frames (defaults)."""
    windower = PositionWindower(WindowSettings())  # the node defaults
    starts = []
    for k in frames:
        for event in windower.push(record.time[k], k, record.stator_position[k],
                                   record.slider_position[k], True):
            if not isinstance(event, Skip):
                starts.append(conversions.seconds_to_stamp(event.time[0]))
    return starts


def test_bad_positions_are_dropped_counted_and_the_good_ones_analysed(ros_context):
    record = bench.simulate(bench.get_scenario('paper'), 20.0)
    harness = Harness(ros_context)
    estimator, identifier = _start('three_stage_estimator'), _start('friction_identifier')
    try:
        probe = harness.probe
        windows, models = [], []
        probe.create_subscription(DerivativeEstimate, 'estimation/derivatives', windows.append,
                                  DATA_QOS)
        probe.create_subscription(FrictionModel, 'friction/model', models.append, DATA_QOS)
        status = harness.diagnostics()
        positions = probe.create_publisher(TrackedPositions, 'tracking/positions', DATA_QOS)
        harness.wait_for_subscribers(positions)
        # Both writers' sides, or the first outputs may go before they match (this probe and
        # the identifier on the estimates, this probe on the models).
        harness.wait_for_output_subscribers('three_stage_estimator', 'estimation/derivatives', 2)
        harness.wait_for_output_subscribers('friction_identifier', 'friction/model')

        def good(k):
            return conversions.tracked_positions(record.time[k], k, record.slider_position[k],
                                                 record.stator_position[k], 1.0, 1.0)

        for k in range(0, 100):
            positions.publish(good(k))
        nan = good(100)
        nan.slider_position, nan.slider_valid = math.nan, True
        backwards = good(100)
        backwards.header.stamp = good(50).header.stamp
        duplicate = good(100)
        duplicate.header.stamp = good(99).header.stamp
        index_backwards = good(100)
        index_backwards.frame_index = 50
        for msg in (nan, backwards, duplicate, index_backwards):
            positions.publish(msg)
        # Another rig on this domain: a second publisher, sending a plausible sample.
        foreign = probe.create_publisher(TrackedPositions, 'tracking/positions', DATA_QOS)
        harness.wait_for_subscribers(foreign)
        foreign.publish(good(100))
        foreign.publish(good(101))
        good_frames = range(0, len(record.time))
        for k in good_frames[100:]:
            positions.publish(good(k))
        expected = _clean_windows(record, good_frames)
        assert len(expected) >= 10
        harness.spin_until(lambda: len(windows) >= len(expected) and
                           len(models) >= len(expected), 90, 'every window and model')
        assert [w.header.stamp for w in windows] == expected
        assert all(w.memoryless and w.phase_difference == pytest.approx(math.pi, abs=0.1)
                   for w in windows)
        assert models[-1].window_count == len(expected)
        assert models[-1].a * models[-1].alpha / 3 == pytest.approx(1.2 * 110 / 3, rel=0.05)
        total = str(len(good_frames))
        harness.spin_until(lambda: status.get('three_stage_estimator', {}).get('received')
                           == total, 30, 'the estimator diagnostics')
        values = status['three_stage_estimator']
        assert values['dropped'] == '6'
        for kind, count in (('NaN position', 1), ('stamp going backwards', 1),
                            ('duplicated stamp', 1), ('frame index going backwards', 1),
                            ('foreign publisher', 2)):
            assert values[f'dropped: {kind}'] == str(count), (kind, values)
        harness.spin_until(lambda: status.get('friction_identifier', {}).get('received')
                           == str(len(expected)), 30, 'the identifier diagnostics')
        assert status['friction_identifier']['dropped'] == '0'
    finally:
        outputs = _stop(estimator, identifier)
        print(*outputs, sep='\n')  # shown when the test fails
        harness.close()
    # Each kind is logged once, however often it happens.
    assert outputs[0].count('dropped foreign publisher') == 1, outputs[0]


def _estimates(record):
    """Return the DerivativeEstimate messages an estimator makes of the record (defaults)."""
    windower = PositionWindower(WindowSettings())  # the node defaults
    messages = []
    for k, t in enumerate(record.time):
        for event in windower.push(t, k, record.stator_position[k], record.slider_position[k],
                                   True):
            if isinstance(event, Skip):
                continue
            est, test = memory.relative_memory_test(
                event.time, event.stator_position, event.slider_position, 'three-stage',
                frequency=event.frequency, k=3.0, margin=0.1, epsilon=0.0, exposure=0.0)
            header = Header(stamp=conversions.seconds_to_stamp(event.time[0]), frame_id='c')
            messages.append(conversions.derivative_estimate(header, event, est, test, 0.0))
    return messages


def test_bad_estimates_are_dropped_counted_and_the_fit_uses_the_good_ones(ros_context):
    record = bench.simulate(bench.get_scenario('paper'), 16.0)
    good = _estimates(record)
    assert len(good) >= 8
    harness = Harness(ros_context)
    identifier = _start('friction_identifier')
    try:
        probe = harness.probe
        models = []
        probe.create_subscription(FrictionModel, 'friction/model', models.append, DATA_QOS)
        status = harness.diagnostics()
        estimates = probe.create_publisher(DerivativeEstimate, 'estimation/derivatives',
                                           DATA_QOS)
        harness.wait_for_subscribers(estimates)
        harness.wait_for_output_subscribers('friction_identifier', 'friction/model')
        estimates.publish(good[0])
        estimates.publish(good[1])
        nan = copy.deepcopy(good[2])
        nan.slider_acceleration = [math.nan] * len(nan.time)
        short = copy.deepcopy(good[2])
        short.relative_velocity = short.relative_velocity[:-1]
        for msg in (nan, short, good[0], good[1]):  # good[0]: backwards, good[1]: duplicated
            estimates.publish(msg)
        for msg in good[2:]:
            estimates.publish(msg)
        harness.spin_until(lambda: len(models) >= len(good), 90, 'a model per good window')
        harness.spin_until(lambda: status.get('friction_identifier', {}).get('received')
                           == str(len(good)), 30, 'the identifier diagnostics')
        values = status['friction_identifier']
        assert values['dropped'] == '4'
        for kind in ('NaN estimate', 'malformed estimate', 'stamp going backwards',
                     'duplicated stamp'):
            assert values[f'dropped: {kind}'] == '1', (kind, values)
        model = models[-1]
        assert len(models) == len(good) and model.window_count == len(good)
        v = np.concatenate([w.relative_velocity for w in good])
        assert model.sample_count < v.size  # overlapping windows: each sample once
        assert model.a * model.alpha / 3 == pytest.approx(1.2 * 110 / 3, rel=0.05)
    finally:
        print(_stop(identifier)[0])  # shown when the test fails
        harness.close()
