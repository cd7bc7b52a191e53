"""small_linalg: numpy's solve and lstsq on LAPACK directly, the same numbers bit for bit.

The frame's small systems (the plate fit's steps and covariance, the motion's recurrence,
the light's line) go to LAPACK without numpy's wrapping; what they return must be what
numpy returns, rank-deficient systems included, and the inputs must be left as they were.
"""

import numpy as np
import pytest

from microball_ros.core.tracking.small_linalg import lstsq, solve


def test_solve_is_numpys_solve_and_inverse_bit_for_bit():
    rng = np.random.default_rng(11)
    for _ in range(50):
        jacobian = rng.normal(size=(5, 80))
        normal = jacobian @ jacobian.T
        right = rng.normal(size=5)
        kept = normal.copy(), right.copy()
        assert np.array_equal(solve(normal, right), np.linalg.solve(normal, right))
        assert np.array_equal(solve(normal, np.eye(5)), np.linalg.inv(normal))
        assert np.array_equal(normal, kept[0]) and np.array_equal(right, kept[1])


def test_solve_returns_none_for_a_singular_matrix():
    assert solve(np.ones((5, 5)), np.ones(5)) is None
    assert solve(np.zeros((3, 3)), np.eye(3)) is None


@pytest.mark.parametrize('rcond', [None, 1e-12])
def test_lstsq_is_numpys_lstsq_bit_for_bit_even_rank_deficient(rcond):
    """A sinusoid's recurrence design (5 lags and 1) is rank-deficient: the minimum norm."""
    rng = np.random.default_rng(12)
    t = np.arange(60.0)
    for trial in range(40):
        x = 150.0 + 100.0 * np.sin(0.6 * t + trial) + 10.0 * np.sin(1.2 * t)
        if trial % 2:
            x = x + rng.normal(0.0, 0.02, t.size)
        windows = x[np.arange(55)[:, None] + np.arange(6)]
        design = np.column_stack([windows[:, -2::-1], np.ones(55)])
        goal = windows[:, -1].copy()
        kept = design.copy()
        expected = np.linalg.lstsq(design, goal, rcond=rcond)[0]
        assert np.array_equal(lstsq(design, goal, rcond), expected)
        assert np.array_equal(design, kept)


def test_lstsq_of_an_underdetermined_system_is_numpys():
    rng = np.random.default_rng(13)
    design, goal = rng.normal(size=(3, 5)), rng.normal(size=3)
    assert np.array_equal(lstsq(design, goal), np.linalg.lstsq(design, goal, rcond=None)[0])
