"""MotionPredictor: where the gated search looks, against a known motion.

The track is a crank-slider-like motion (a fundamental and a second harmonic 15 % of it) with
pixel noise; the truth is the next frame's position.
"""

import math

import numpy as np
import pytest

from microball_ros.core.tracking.predict import WARM_LEAST, MotionPredictor


def crank(frames, omega, amplitude=120.0, harmonic=0.15, noise=0.05, seed=0, third=0.0):
    """Return a crank-slider-like track (px) at ``frames`` with Gaussian noise."""
    t = np.asarray(frames, dtype=float)
    x = 300.0 - amplitude * (np.cos(omega * t) + harmonic * np.cos(2.0 * omega * t + 0.7)
                             + third * np.cos(3.0 * omega * t + 0.3))
    return x + np.random.default_rng(seed).normal(0.0, noise, t.size)


def gate(prediction):
    """Return the search's gate half-width (core.tracking.plate_search.search_plate)."""
    return 6.0 * prediction.spread + 3.0


@pytest.mark.parametrize('omega', [2 * math.pi * 2.95 / 30, 2 * math.pi * 2.95 / 15,
                                   2 * math.pi * 1.0 / 60])
def test_a_known_frequency_gates_the_first_frames(omega):
    """From ``WARM_LEAST`` positions on, the next frame is within the gate, and near."""
    track = crank(np.arange(40), omega)
    known, unknown = MotionPredictor(), MotionPredictor()
    known.use_frequency(omega, 0.05)
    for n in range(len(track) - 1):
        known.add(track[n])
        unknown.add(track[n])
        prediction = known.predict()
        if n + 1 < WARM_LEAST:
            assert not math.isfinite(prediction.spread)  # the whole ROI is searched
            continue
        error = abs(prediction.column - track[n + 1])
        assert math.isfinite(prediction.spread)
        assert error <= 0.5 * gate(prediction)
        if n + 1 < 3 * (known.order + 1) + known.order:  # the recurrence needs more
            assert not math.isfinite(unknown.predict().spread)
        else:  # the recurrence's, the same with or without the frequency
            assert unknown.predict() == prediction


def test_the_gate_widens_where_the_model_misses_the_motion():
    """A third harmonic (not in the model) widens the spread, so the gate holds."""
    omega = 2 * math.pi * 2.95 / 30
    track = crank(np.arange(18), omega, third=0.3)
    predictor = MotionPredictor()
    predictor.use_frequency(omega, 0.05)
    spreads = []
    for n in range(len(track) - 1):
        predictor.add(track[n])
        prediction = predictor.predict()
        if math.isfinite(prediction.spread):
            assert abs(prediction.column - track[n + 1]) <= gate(prediction)
            spreads.append(prediction.spread)
    assert len(spreads) == len(track) - WARM_LEAST
    assert min(spreads) > 1.0  # px: far over the noise (0.05) and the floor


def test_after_a_loss_the_known_frequency_gates_again_once_found_again():
    omega = 2 * math.pi * 2.95 / 30
    track = crank(np.arange(60), omega)
    track[30:38] = np.nan  # covered
    predictor = MotionPredictor()
    predictor.use_frequency(omega, 0.05)
    for n in range(38):
        predictor.add(track[n])
    assert predictor.predict() is None  # lost in the last frame: searched everywhere
    for n in range(38, 45):
        predictor.add(track[n])
        prediction = predictor.predict()
        assert math.isfinite(prediction.spread)  # five of the last 19 found
        assert abs(prediction.column - track[n + 1]) <= 0.5 * gate(prediction)
    predictor.use_frequency(math.nan, 0.0)  # forgotten (a plate dropped)
    predictor.reset()
    for n in range(50, 54):
        predictor.add(track[n])
    assert not math.isfinite(predictor.predict().spread)
