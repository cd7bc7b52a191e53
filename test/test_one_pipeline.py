"""One analysis for nodes and files: the identifier over DDS and `microball analyze` agree.

The same positions go through three_stage_estimator + friction_identifier (real nodes, real
topics) and, written to a CSV, through `microball analyze`; the model, its intervals, the
memory verdict and the warnings must be the same numbers (same platform, same code: equal to
the last bits, within a relative 1e-12 for safety).
"""

import json
import math

from microball_msgs.msg import DerivativeEstimate, FrictionModel, TrackedPositions
import numpy as np
import pytest
from rclpy.parameter import Parameter

from microball_ros import cli
from microball_ros.core import bench, rig
from microball_ros.io import conversions
from microball_ros.io.positions_csv import write_positions_csv
from microball_ros.nodes.common import DATA_QOS
from microball_ros.nodes.friction_identifier import FrictionIdentifier
from microball_ros.nodes.three_stage_estimator import ThreeStageEstimator
from microball_ros.testing import Harness

pytestmark = pytest.mark.ros


def test_identifier_and_analyze_give_the_same_model_for_the_same_positions(ros_context,
                                                                         tmp_path):
    scenario = bench.get_scenario('paper')
    exposure = rig.camera_for(scenario).exposure
    record = bench.simulate(scenario, 30.0)
    estimator = ThreeStageEstimator(context=ros_context, parameter_overrides=[
        Parameter('exposure', value=exposure)])
    identifier = FrictionIdentifier(context=ros_context, parameter_overrides=[
        Parameter('exposure', value=exposure)])
    harness = Harness(ros_context, estimator, identifier)
    windows, models = [], []
    try:
        harness.probe.create_subscription(DerivativeEstimate, 'estimation/derivatives',
                                          windows.append, DATA_QOS)
        harness.probe.create_subscription(FrictionModel, 'friction/model', models.append,
                                          DATA_QOS)
        publisher = harness.probe.create_publisher(TrackedPositions, 'tracking/positions',
                                                   DATA_QOS)
        harness.wait_for_subscribers(publisher)
        for k, t in enumerate(record.time):
            publisher.publish(conversions.tracked_positions(
                t, k, record.slider_position[k], record.stator_position[k], 1.0, 1.0))
        harness.spin_until(lambda: len(windows) >= 5 and len(models) == len(windows),
                           timeout=120.0, message='a model for every window')
        # Let the estimator finish: no window may be left without its model.
        harness.spin_until(lambda: len(models) == len(windows), timeout=60.0,
                           message='the last model')
    finally:
        harness.close()
    model = models[-1]
    # The samples the node saw: the union of its windows' positions, by stamp.
    arrays = [conversions.estimate_arrays(msg) for msg in windows]
    time = np.concatenate([a[0] for a in arrays])
    _, first = np.unique(np.round(time * 1e9).astype(np.int64), return_index=True)
    stator = np.concatenate([a[3] for a in arrays])[first]
    slider = np.concatenate([a[4] for a in arrays])[first]
    csv_path, json_path = tmp_path / 'union.csv', tmp_path / 'union.json'
    write_positions_csv(str(csv_path), {'time': time[first], 'stator_position': stator,
                                        'slider_position': slider})
    assert cli.main(['analyze', str(csv_path), '--exposure', repr(exposure),
                     '--json', str(json_path)]) == 0
    result = json.loads(json_path.read_text())

    assert model.name == result['model']['name'] == 'langevin'
    for ours, theirs in ((model.a, result['model']['A']),
                         (model.alpha, result['model']['alpha']),
                         (model.rmse, result['model']['rmse']),
                         *zip(model.a_ci95, result['model']['A_ci95'], strict=True),
                         *zip(model.alpha_ci95, result['model']['alpha_ci95'], strict=True)):
        assert math.isclose(ours, theirs, rel_tol=1e-12), (ours, theirs)
    assert model.sample_count == result['samples_used']
    assert model.memory_verdict == result['memory_verdict'] == 'memoryless'
    assert sorted(model.warnings) == sorted(f"{w['code']}: {w['message']}"
                                            for w in result['warnings'])
    # ... and the answer is right: the truth inside both intervals.
    assert model.a_ci95[0] <= 1.2 <= model.a_ci95[1]
    assert model.alpha_ci95[0] <= 110.0 <= model.alpha_ci95[1]
