"""The image side of tracking: gray frames, regions of interest, the scale, automatic ROIs.

Owns everything that is about pixels rather than one mark's profile: converting an array frame
to gray (``to_gray``), walking a sequence of array frames and checking they share one size
(``gray_frames``), validating the user's ROIs and image scale (``parse_roi``, ``check_roi``,
``check_scale``, with one-line InputErrors) and finding one ROI per mark when none is given
(``detect_rois``). Frames are arrays here; opening video files and image folders is
microball_ros.io.video's job (its FrameSource is an iterable of such arrays).
"""

from collections.abc import Iterable, Iterator
import itertools
import math
import os
from typing import Any

import cv2
import numpy as np
import numpy.typing as npt

from microball_ros.core.errors import InputError

Roi = tuple[int, int, int, int]


def parse_roi(text: str) -> Roi:
    """Parse 'X,Y,W,H' (integers, px) into a tuple; InputError with a one-line message."""
    parts = str(text).split(',')
    try:
        values = tuple(int(p.strip()) for p in parts)
    except ValueError:
        values = ()
    if len(values) != 4:
        raise InputError(f'ROI {text!r} must be four integers X,Y,W,H')
    return (values[0], values[1], values[2], values[3])


def check_roi(roi: Any, frame_size: tuple[int, int] | None = None, name: str = 'mark') -> Roi:
    """Validate an ROI (x, y, w, h) against a frame size (width, height); return it as ints.

    Raises InputError with a one-line message if the ROI is malformed, too small to track in
    (w < 16 or h < 1) or extends outside the frame.
    """
    try:
        x, y, w, h = (int(v) for v in roi)
        if any(int(v) != v for v in roi):
            raise ValueError
    except (TypeError, ValueError):
        raise InputError(f'{name} ROI {roi!r} must be four integers (x, y, w, h)') from None
    if w < 16 or h < 1:
        raise InputError(f'{name} ROI {x},{y},{w},{h} is too small (need w >= 16, h >= 1)')
    if x < 0 or y < 0:
        raise InputError(f'{name} ROI {x},{y},{w},{h} starts outside the frame')
    if frame_size is not None:
        width, height = frame_size
        if x + w > width or y + h > height:
            raise InputError(f'{name} ROI {x},{y},{w},{h} extends outside the '
                             f'{width}x{height} frame')
    return (x, y, w, h)


def roi_region(frame: np.ndarray, roi: Roi, name: str = 'mark') -> np.ndarray:
    """Return the ROI's pixels of a 2-D frame; InputError (one line) if it lies outside."""
    x, y, w, h = roi
    if frame.ndim != 2 or x + w > frame.shape[1] or y + h > frame.shape[0]:
        raise InputError(f'{name} ROI {x},{y},{w},{h} extends outside the '
                         f'{frame.shape[1] if frame.ndim > 1 else 0}x{frame.shape[0]} frame')
    return frame[y:y + h, x:x + w]


def check_distinct_rois(rois: dict[str, Roi]) -> None:
    """Refuse two ROIs that frame the same mark (overlapping by more than half the smaller).

    The slider's and the stator's marks sit on different plates; ROIs that largely overlap
    are a copy-paste mistake, and tracking both would report one mark twice.
    """
    items = list(rois.items())
    for i, (name_a, (xa, ya, wa, ha)) in enumerate(items):
        for name_b, (xb, yb, wb, hb) in items[i + 1:]:
            overlap = (max(0, min(xa + wa, xb + wb) - max(xa, xb))
                       * max(0, min(ya + ha, yb + hb) - max(ya, yb)))
            smaller = min(wa * ha, wb * hb)
            if smaller and overlap > 0.5 * smaller:
                raise InputError(f'the {name_a} and {name_b} ROIs overlap by '
                                 f'{100 * overlap / smaller:.0f} %: each must frame its own '
                                 "mark (the slider's and the stator's are on different plates)")


def check_scale(meters_per_pixel: Any) -> float:
    """Validate the image scale (m per px): positive and finite; return it as float."""
    try:
        value = float(meters_per_pixel)
    except (TypeError, ValueError):
        raise InputError(f'meters per pixel {meters_per_pixel!r} is not a number') from None
    if not (math.isfinite(value) and value > 0):
        raise InputError(f'meters per pixel must be positive and finite, got {value!r}')
    return value


def to_gray(frame: npt.ArrayLike) -> np.ndarray:
    """Return a frame as a 2-D array: gray as is, H x W x 1, BGR or BGRA converted by OpenCV.

    Raises InputError (one line) for any other shape.
    """
    array = np.asarray(frame)
    if array.ndim == 3 and array.shape[2] == 1:
        array = array[:, :, 0]
    elif array.ndim == 3 and array.shape[2] in (3, 4):
        code = cv2.COLOR_BGR2GRAY if array.shape[2] == 3 else cv2.COLOR_BGRA2GRAY
        array = cv2.cvtColor(array, code)
    if array.ndim != 2:
        raise InputError(f'a frame must be a 2-D (gray) or H x W x 3 array, got shape '
                         f'{array.shape}')
    return array


def gray_frames(frames: Iterable[npt.ArrayLike] | np.ndarray) -> tuple[np.ndarray, Iterator]:
    """Return the first frame of a sequence (gray) and an iterator over all its gray frames.

    ``frames``: an N x H x W (x 3) array, a single H x W frame, or any iterable of 2-D (or
    colour) arrays, such as io.video.FrameSource. Every frame must have the first one's size.
    Raises InputError (one line) for an empty sequence, a wrong shape or a change of size.
    """
    if isinstance(frames, (str, bytes, os.PathLike)):
        raise InputError(f'{os.fsdecode(frames)}: a file, not frames (open it with '
                         f'microball_ros.io.video.FrameSource)')
    if isinstance(frames, np.ndarray):
        if frames.ndim == 2:
            frames = frames[None]
        if frames.ndim not in (3, 4) or frames.shape[0] == 0:
            raise InputError(f'frames must be an N x H x W (x 3) array, got shape '
                             f'{frames.shape}')
    try:
        iterator = iter(frames)
    except TypeError:
        raise InputError('frames must be an array or an iterable of arrays') from None
    first = next(iterator, None)
    if first is None:
        raise InputError('no frames')
    first = to_gray(first)
    height, width = first.shape

    def checked(frame: npt.ArrayLike) -> np.ndarray:
        frame = to_gray(frame)
        if frame.shape != (height, width):
            raise InputError(f'frame size {frame.shape[1]}x{frame.shape[0]} differs from the '
                             f'first frame {width}x{height}')
        return frame
    return first, itertools.chain([first], map(checked, iterator))


def detect_rois(frames: Iterable[npt.ArrayLike] | np.ndarray,
                names: tuple[str, ...] = ('slider', 'stator'), margin_px: int = 24,
                max_frames: int = 60, mark_width_px: int = 61,
                polarity: str = 'dark') -> dict[str, Roi]:
    """Find one ROI per mark automatically, for when none is given; return {name: (x,y,w,h)}.

    ``frames``: as for ``gray_frames`` (arrays, or an io.video.FrameSource). Uses up to
    ``max_frames`` frames: a mark shows up as temporal variation along its travel (moving) or
    as a feature narrower than ``mark_width_px`` that is darker (brighter for
    ``polarity='bright'``) than its row (a black/white top-hat of the mean frame, still). The
    ``len(names)`` largest such regions become ROIs, named from top to bottom (the slider is
    the upper plate), widened by ``margin_px`` along x (plain plate for the baseline) and a
    quarter of that along y. Raises InputError if fewer regions are found. Not for infrared
    frames: the rolling balls look like marks there.
    """
    _, iterator = gray_frames(frames)
    stack = np.array([np.asarray(frame, dtype=np.float32)
                      for frame in itertools.islice(iterator, max(int(max_frames), 1))])
    mean = stack.mean(axis=0)
    kernel = cv2.getStructuringElement(cv2.MORPH_RECT, (int(mark_width_px) | 1, 1))
    operation = cv2.MORPH_BLACKHAT if polarity == 'dark' else cv2.MORPH_TOPHAT
    activity = np.maximum(stack.std(axis=0), cv2.morphologyEx(mean, operation, kernel))
    activity = cv2.GaussianBlur(activity, (0, 0), 2.0)
    floor = float(np.median(activity))
    rows = activity.max(axis=1) - floor
    if rows.max() <= 3.0 * max(floor, 1e-6):
        raise InputError('no marks found: give the ROIs')
    active = np.flatnonzero(rows > 0.3 * rows.max())
    bands = np.split(active, np.flatnonzero(np.diff(active) > 1) + 1)
    bands = sorted(bands, key=lambda b: -float(rows[b].sum()))[:len(names)]
    if len(bands) < len(names):
        raise InputError(f'found {len(bands)} mark(s), expected {len(names)}: give the ROIs')
    height, width = stack.shape[1:]
    pad_y = max(int(margin_px) // 4, 2)
    rois = {}
    for name, band in zip(names, sorted(bands, key=lambda b: int(b[0])), strict=True):
        columns = activity[band[0]:band[-1] + 1].max(axis=0) - floor
        span = np.flatnonzero(columns > 0.3 * columns.max())
        x0 = max(int(span[0]) - int(margin_px), 0)
        x1 = min(int(span[-1]) + 1 + int(margin_px), width)
        y0 = max(int(band[0]) - pad_y, 0)
        y1 = min(int(band[-1]) + 1 + pad_y, height)
        rois[name] = (x0, y0, x1 - x0, y1 - y0)
    return rois
