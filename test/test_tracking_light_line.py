"""profile._fitted: the light's line across the mark in closed form, as polyfit has it."""

import numpy as np

from microball_ros.core.tracking.profile import _fitted, polyfit


def test_the_closed_form_line_and_constant_are_polyfits_to_rounding():
    rng = np.random.default_rng(21)
    for _ in range(200):
        size = int(rng.integers(24, 500))
        u = np.linspace(-1.0, 1.0, size)
        y = 1.0 + 0.2 * u + rng.normal(0.0, 0.01, size)
        keep = rng.random(size) < 0.3
        keep[:4] = True
        for order in (0, 1, 2):
            expected = np.polyval(polyfit(u[keep], y[keep], order), u)
            assert np.allclose(_fitted(u, y, keep, order), expected, rtol=0, atol=1e-13)


def test_a_line_through_columns_all_at_one_place_is_polyfits():
    u = np.linspace(-1.0, 1.0, 30)
    keep = np.zeros(30, dtype=bool)
    keep[7] = True
    expected = np.polyval(polyfit(u[keep], (2.0 * u + 1.0)[keep], 1), u)
    assert np.array_equal(_fitted(u, 2.0 * u + 1.0, keep, 1), expected)
