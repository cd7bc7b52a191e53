"""Frames from a gamma-encoding camera decoded to linear light (``TrackerConfig.gamma``).

The tracker's model of a moving mark is linear in the light: a smeared mark is the still mark
convolved with its motion during the exposure, so the mark's integrated deficit is the same
at any speed. Machine-vision cameras (mono8, mono16, raw Bayer) give linear values; consumer
cameras, webcams and most video encode ``v = full (light / full) ** (1 / gamma)`` (about 2.2
for sRGB and BT.709). A still mark is unharmed (the power keeps the plate and the mark's
product a product), but a smeared one is not: on a disc smeared up to 75 px (the sixth blind
set's p03, 15 frames/s, whole-period exposure) encoded with 2.2, 10-20 % of the frames were
refused as 'mark area changed' and the RMS went from 0.04-0.05 to 0.10-0.13 px.

``GammaDecoder`` undoes it before anything else sees the frame: ``full (v / full) ** gamma``,
``full`` the pixel type's largest value (255, 65535; 1.0 for float frames up to 1, else 255),
by a look-up table for 8- and 16-bit frames. A full-scale pixel stays full scale, so
saturation is still seen where it was (``saturation_level``).
"""

import math

import cv2
import numpy as np

GAMMA_RANGE = (0.2, 5.0)  # TrackerConfig.gamma's accepted range


def full_scale(frame: np.ndarray) -> float:
    """Return the largest value of ``frame``'s pixel type (float: 1.0 if it stays within 1)."""
    if frame.dtype == np.uint8:
        return 255.0
    if frame.dtype == np.uint16:
        return 65535.0
    if np.issubdtype(frame.dtype, np.integer):
        return float(np.iinfo(frame.dtype).max)
    return 1.0 if float(np.nanmax(frame)) <= 1.0 else 255.0


class GammaDecoder:
    """Decode frames to linear light: ``full (v / full) ** gamma`` (gamma 1: as they are)."""

    def __init__(self, gamma: float = 1.0) -> None:
        """Create a decoder for a camera that encodes with ``gamma``."""
        self.gamma = float(gamma)
        self._tables: dict[np.dtype, np.ndarray] = {}
        self._float_full: float | None = None  # float frames: fixed by the first one

    @property
    def active(self) -> bool:
        """Return True if the decoder changes frames (gamma is not 1)."""
        return self.gamma != 1.0

    def __call__(self, frame: np.ndarray) -> np.ndarray:
        """Return ``frame`` (2-D) in linear light: float32 for 8- and 16-bit, else float64."""
        if not self.active:
            return frame
        if frame.dtype in (np.uint8, np.uint16):
            table = self._tables.get(frame.dtype)
            if table is None:
                full = full_scale(frame)
                values = np.arange(int(full) + 1, dtype=np.float64)
                table = (full * (values / full) ** self.gamma).astype(np.float32)
                self._tables[frame.dtype] = table
            if frame.dtype == np.uint8:
                return cv2.LUT(frame, table)
            return np.take(table, frame)
        if self._float_full is None:
            self._float_full = full_scale(frame)
        full = self._float_full
        values = np.clip(np.asarray(frame, dtype=np.float64), 0.0, None)
        return full * (values / full) ** self.gamma


def check_gamma(gamma: float) -> bool:
    """Return True if ``gamma`` is a camera gamma the tracker accepts (``GAMMA_RANGE``)."""
    return math.isfinite(gamma) and GAMMA_RANGE[0] <= gamma <= GAMMA_RANGE[1]
