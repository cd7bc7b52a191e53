"""A raw colour mosaic read as a grey image: ``is_mosaic`` finds it, ``unmosaic`` removes it.

A colour camera's sensor sees each pixel through one of four filters in a 2 x 2 pattern
(Bayer). Frames saved raw (not demosaiced) and read as grey carry that pattern: the four
phases of the 2 x 2 grid differ by the channels' gains (0.8 / 1 / 0.7 is typical before white
balance), a checkerboard fixed in the image that no lens makes (optics blur a scene's own
detail at a 2 px period to a few per cent at most). On such frames a mark is measured through
its colour's pattern: an independent set's disc on a textured plate was 0.27 px off. A Bayer
image message is demosaiced (io.video.image_to_gray); a video file or a mono8 message holding a
raw mosaic is found here, from the priming frames' mean, and smoothed with the [1 2 1] / 4
filter in x and in y: its response at the 2 px period is zero and, symmetric, it moves nothing.
"""

import cv2
import numpy as np

MOSAIC_SPREAD = 0.03  # the four phases' means this far apart (relative): a mosaic
_KERNEL = np.array([0.25, 0.5, 0.25], dtype=np.float32)


def phase_spread(frames) -> float:
    """Return how far apart the means of the four 2 x 2 phases of the frames' mean are.

    (largest - smallest) / their mean, over the frames' whole area (an even number of rows
    and columns); 0 for frames smaller than 2 x 2 or not bright.
    """
    total = None
    for frame in frames:  # summed one by one: 60 frames of 1280 x 720 in float64 are 440 MB
        array = np.asarray(frame, dtype=np.float64)
        total = array if total is None else total + array
    if total is None:
        return 0.0
    height, width = (total.shape[0] // 2) * 2, (total.shape[1] // 2) * 2
    if height == 0 or width == 0:
        return 0.0
    total = total[:height, :width]
    phases = [float(total[i::2, j::2].mean()) for i in (0, 1) for j in (0, 1)]
    level = float(np.mean(phases))
    return (max(phases) - min(phases)) / level if level > 0 else 0.0


def is_mosaic(frames) -> bool:
    """Return True if the (grey) frames carry a raw colour mosaic (``MOSAIC_SPREAD``)."""
    frames = list(frames)
    return bool(frames) and phase_spread(frames) > MOSAIC_SPREAD


def unmosaic(frame: np.ndarray) -> np.ndarray:
    """Return ``frame`` smoothed by [1 2 1] / 4 in x and y, in its own pixel type (rounded)."""
    smoothed = cv2.sepFilter2D(np.asarray(frame, dtype=np.float32), -1, _KERNEL, _KERNEL,
                               borderType=cv2.BORDER_REFLECT)
    if np.issubdtype(frame.dtype, np.integer):
        limits = np.iinfo(frame.dtype)
        return np.clip(np.rint(smoothed), limits.min, limits.max).astype(frame.dtype)
    return smoothed.astype(frame.dtype, copy=False)
