"""numpy.linalg's solve and lstsq for the small systems of every frame, on LAPACK directly.

The same LAPACK routines numpy calls (gesv, gelsd), with the same cut-off, so the same numbers;
numpy's checks and wrapping cost more than the 5 x 5 and 60 x 5 systems of a frame (the plate
fit's steps, the motion's recurrence, the light's line).
"""

import functools

import numpy as np
from scipy.linalg import lapack

_EPS = float(np.finfo(float).eps)


def solve(a: np.ndarray, b: np.ndarray) -> np.ndarray | None:
    """Return ``np.linalg.solve(a, b)`` for float64 ``a``, or None if ``a`` is singular."""
    _, _, x, info = lapack.dgesv(a, b)
    return None if info != 0 else x


@functools.lru_cache(maxsize=64)
def _workspace(rows: int, columns: int) -> tuple[int, int]:
    """Return gelsd's work sizes for a ``rows`` x ``columns`` system with one right side."""
    work, iwork, info = lapack.dgelsd_lwork(rows, columns, 1, -1)
    if info != 0:
        raise ValueError(f'gelsd workspace query failed ({info})')
    return int(work), int(iwork)


def lstsq(a: np.ndarray, b: np.ndarray, rcond: float | None = None) -> np.ndarray:
    """Return ``np.linalg.lstsq(a, b, rcond)[0]`` for a float64 matrix and one right side.

    ``rcond`` None: numpy's default, the machine epsilon times the larger dimension. Raises
    ``np.linalg.LinAlgError`` if the SVD does not converge, as numpy does.
    """
    rows, columns = a.shape
    if rows < columns:  # under-determined: gelsd would need ``b`` padded; none in a frame
        return np.linalg.lstsq(a, b, rcond=rcond)[0]
    cut = _EPS * max(rows, columns) if rcond is None else float(rcond)
    work, iwork = _workspace(rows, columns)
    x, _, _, info = lapack.dgelsd(a, b, lwork=work, size_iwork=iwork, cond=cut)
    if info != 0:
        raise np.linalg.LinAlgError('SVD did not converge in linear least squares')
    return x[:columns]
