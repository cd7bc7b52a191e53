"""The picture of a tracking set-up: ROIs, the learned marks and the track on a frame.

Owns ``draw_tracking``, the one drawing both ``microball track --preview`` and camera_tracker's
debug image show (pure: an array in, a BGR array out). Each ROI is a blue box with its name and
learned polarity; the track so far is a trail of dots along the ROI's middle row (green when
measured); the current position is a green line the mark's height, or a red cross-hatch on the
ROI when the mark is lost.
"""

from collections.abc import Mapping, Sequence
import math

import cv2
import numpy as np

from microball_ros.core.tracking.image import Roi

ROI_COLOUR = (255, 128, 0)
MARK_COLOUR = (0, 220, 0)
LOST_COLOUR = (0, 0, 255)


def _to_bgr8(frame: np.ndarray) -> np.ndarray:
    frame = np.asarray(frame)
    if frame.dtype != np.uint8:
        top = float(frame.max()) if frame.size else 1.0
        frame = np.clip(frame.astype(np.float64) * (255.0 / max(top, 1.0)), 0, 255).astype(
            np.uint8)
    if frame.ndim == 2:
        return cv2.cvtColor(frame, cv2.COLOR_GRAY2BGR)
    return frame.copy()


def draw_tracking(frame: np.ndarray, rois: Mapping[str, Roi], positions_px: Mapping[str, float],
                  tracks_px: Mapping[str, Sequence[float]] | None = None,
                  labels: Mapping[str, str] | None = None) -> np.ndarray:
    """Return a BGR uint8 copy of ``frame`` with ROIs, marks and tracks drawn.

    ``positions_px``: each mark's current image column (NaN when lost); ``tracks_px``: its
    earlier columns (NaN allowed), drawn as dots; ``labels``: text per mark (for example the
    learned polarity), written above its ROI.
    """
    image = _to_bgr8(frame)
    for name, (x, y, w, h) in rois.items():
        cv2.rectangle(image, (x, y), (x + w - 1, y + h - 1), ROI_COLOUR, 1)
        text = name + (f' ({labels[name]})' if labels and labels.get(name) else '')
        cv2.putText(image, text, (x + 2, max(y - 4, 10)), cv2.FONT_HERSHEY_SIMPLEX, 0.4,
                    ROI_COLOUR, 1, cv2.LINE_AA)
        middle = y + h // 2
        for column in (tracks_px or {}).get(name, ()):
            if math.isfinite(column):
                cv2.circle(image, (int(round(column)), middle), 1, MARK_COLOUR, -1)
        column = positions_px.get(name, math.nan)
        if math.isfinite(column):
            cv2.line(image, (int(round(column)), y), (int(round(column)), y + h - 1),
                     MARK_COLOUR, 1)
        else:
            cv2.line(image, (x, y), (x + w - 1, y + h - 1), LOST_COLOUR, 1)
            cv2.line(image, (x, y + h - 1), (x + w - 1, y), LOST_COLOUR, 1)
    return image
