"""smear.BlurScale: the predicted kernel's blur scaled to what the fits find.

A kernel through three positions a frame apart has the chord's velocity, ``sin(w) / w`` of a
sinusoid's; the scale learned from fitted blurs brings the prediction back to the true blur.
"""

import math

import numpy as np

from microball_ros.core.tracking.smear import (
    SCALE_FROM,
    SCALE_LEAST,
    SCALE_RANGE,
    BlurScale,
    quadratic_kernel,
)


def test_the_scale_recovers_a_sinusoids_blur_from_the_chord():
    omega, amplitude, fraction = 0.62, 200.0, 0.5
    scale = BlurScale()
    errors = []
    for n in range(40):
        x = [amplitude * math.sin(omega * (n + j)) for j in (-1, 0, 1)]
        predicted, _ = quadratic_kernel(*x, fraction)
        true = abs(amplitude * omega * math.cos(omega * n)) * fraction
        if predicted >= SCALE_LEAST:
            errors.append((predicted * scale.scale - true) / true)
        scale.add(predicted, true)
    assert math.isclose(scale.scale, omega / math.sin(omega), rel_tol=1e-9)
    # Unscaled the chord is 6.5 % short; scaled from the SCALE_FROM-th frame on, exact
    assert min(errors[:SCALE_FROM]) < -0.06
    assert np.allclose(errors[SCALE_FROM:], 0.0, atol=1e-9)


def test_the_scale_ignores_short_and_failed_frames_and_is_bounded():
    scale = BlurScale()
    for _ in range(20):
        scale.add(0.5 * SCALE_LEAST, 10.0)  # too short to say
        scale.add(10.0, math.nan)  # no fit
    assert scale.scale == 1.0
    for _ in range(SCALE_FROM):
        scale.add(10.0, 30.0)  # a fit three times the prediction: bounded
    assert scale.scale == SCALE_RANGE[1]
    scale.reset()
    assert scale.scale == 1.0
    for _ in range(SCALE_FROM - 1):
        scale.add(10.0, 11.0)
        assert scale.scale == 1.0  # not before SCALE_FROM frames
    scale.add(10.0, 11.0)
    assert math.isclose(scale.scale, 1.1)
