"""Several marks through a sequence of frames: time stamps, streaming and batch tracking.

Owns the frame-level API. ``Tracker`` holds one MarkTracker per named ROI, the image scale and
the frame timing (frame n is stamped at its mid-exposure, ``start_time + n / fps +
exposure / 2``, unless the caller gives the stamp, for example a received image's header) and
processes one frame at a time, for a node; after priming, a mark's ROI that a shadow passes
over is divided by the shadow's light first (core.tracking.shade). ``track`` runs a Tracker
over a whole sequence of array frames and returns a TrackResult. Both check the ROIs, the
scale and the rate before any tracking. Output depends only on the ordered frames and the
parameters.
"""

from collections.abc import Callable, Iterable, Mapping
import dataclasses
import itertools
import math
from typing import Any

import numpy as np
import numpy.typing as npt

from microball_ros.core.errors import InputError
from microball_ros.core.tracking.config import TrackerConfig
from microball_ros.core.tracking.gamma import (
    AUTO,
    GammaDecoder,
    adopted_gamma,
    full_scale,
    smear_evidence,
)
from microball_ros.core.tracking.image import (
    Roi,
    check_distinct_rois,
    check_roi,
    check_scale,
    gray_frames,
    roi_region,
    to_gray,
)
from microball_ros.core.tracking.mark import MarkTracker
from microball_ros.core.tracking.mosaic import is_mosaic, unmosaic
from microball_ros.core.tracking.profile import saturation_level
from microball_ros.core.tracking.results import MarkMeasurement, TrackedFrame, TrackResult
from microball_ros.core.tracking.shade import BlackLevel, Shade, ShadowNote, gain_slack

# A frame divided by a passing shadow's light: its standard errors times this. Measured on
# rendered scenes (test_tracking_shade.py, three seeds): such frames' errors were 1.2-1.3 times
# their standard errors, the others' 0.84-1.05.
SHADED_SIGMA = 1.4


class Tracker:
    """Track several marks (for example 'slider' and 'stator') frame by frame.

    ``rois`` maps mark names to ROIs (x, y, w, h, px); ``exposure`` (s) only sets the time
    stamps (mid-exposure); None assumes half the frame period, like the paper's camera
    (1/60 s at 30 fps). Output depends only on the ordered frames and the parameters.
    """

    def __init__(self, rois: Mapping[str, Any], meters_per_pixel: Any, fps: Any = 30.0,
                 exposure: float | None = None, start_time: float = 0.0,
                 config: TrackerConfig | None = None,
                 frame_size: tuple[int, int] | None = None):
        """Validate the parameters (InputError, one line) and create a MarkTracker per ROI."""
        if not rois:
            raise InputError('need at least one mark ROI')
        self.meters_per_pixel = check_scale(meters_per_pixel)
        try:
            self.fps = float(fps)
        except (TypeError, ValueError):
            raise InputError(f'fps {fps!r} is not a number') from None
        if not (math.isfinite(self.fps) and self.fps > 0):
            raise InputError(f'fps must be positive and finite, got {fps!r}')
        self.exposure = 0.5 / self.fps if exposure is None else float(exposure)
        if not (0 <= self.exposure <= 1.0 / self.fps):
            raise InputError(f'exposure must be in [0, 1/fps], got {exposure!r}')
        self.start_time = float(start_time)
        self.config = TrackerConfig() if config is None else config
        checked = {name: check_roi(roi, frame_size, name) for name, roi in rois.items()}
        check_distinct_rois(checked)
        self.marks = {name: MarkTracker(roi, self.config, name, self.exposure * self.fps)
                      for name, roi in checked.items()}
        self.index = 0
        self.mosaic = False  # the frames are a raw colour mosaic (core.tracking.mosaic)
        self.shades: dict[str, Shade] = {}  # per mark, a passing shadow's light (priming)
        self.shaded = dict.fromkeys(self.marks, 0)  # per mark, frames a shadow was divided out of
        self.black = BlackLevel()  # the camera's, from the shadows (unless config gives it)
        # To linear light (core.tracking.gamma); with gamma 0, priming may find one
        self.decoder = GammaDecoder(1.0 if self.config.gamma == AUTO else self.config.gamma)
        self.gamma_found = math.nan  # priming's verdict with gamma 0 (1.0: linear)

    def frame_time(self, index: int) -> float:
        """Return the mid-exposure time (s) of frame ``index``."""
        return self.start_time + index / self.fps + self.exposure / 2.0

    def prime(self, frames: Iterable[npt.ArrayLike]) -> None:
        """Learn every mark from ``frames``, then restart at frame 0 with what was learned.

        Batch tracking primes on the first ``config.prime_frames`` frames and then tracks
        them again, so the first frames get the learned mark too. Frames that are a raw
        colour mosaic are smoothed from now on (``mosaic``). With ``config.gamma`` 0, the
        marks' deficits against their smear tell whether the frames are gamma-encoded
        (core.tracking.gamma): if so, the marks are primed again on the frames decoded.
        """
        read = [to_gray(frame) for frame in frames]
        grey = self._prime(read)
        if self.config.gamma == AUTO and not self.decoder.active:
            evidence = [self._smear_evidence(name, mark, grey)
                        for name, mark in self.marks.items()]
            found = adopted_gamma(evidence)
            if found != 1.0:
                self.decoder = GammaDecoder(found)
                self._prime(read)
            self.gamma_found = found

    def _prime(self, read: list[np.ndarray]) -> list[np.ndarray]:
        """Prime every mark and shade on the frames ``read`` (grey); return them as primed."""
        grey = [self._linear(frame) for frame in read]
        self.mosaic = is_mosaic(grey)
        if self.mosaic:
            grey = [unmosaic(frame) for frame in grey]
        self.shades = {}
        for name, mark in self.marks.items():
            mark.prime(grey)
            rows = getattr(mark, 'mark_rows', None)
            if rows is not None:
                shade = Shade(mark.roi[3], mark.roi[2], rows)
                shade.prime([roi_region(frame, mark.roi, name) for frame in grey])
                if shade.enabled:
                    self.shades[name] = shade
        return grey

    def _smear_evidence(self, name: str, mark: Any, grey: list[np.ndarray]):
        """Return a plain plate's mark's evidence of an encoding gamma (None: none)."""
        track, rows = getattr(mark, 'priming_track', None), getattr(mark, 'mark_rows', None)
        if track is None or rows is None or mark.polarity is None or getattr(
                mark, 'on_texture', False):
            return None
        saturation = saturation_level(grey[0].dtype, self.config.saturation_level)
        regions = [roi_region(frame, mark.roi, name)[rows[0]:rows[1]] for frame in grey]
        return smear_evidence(regions, track[0], track[1], mark.polarity, saturation)

    def process(self, frame: npt.ArrayLike, time: float | None = None) -> TrackedFrame:
        """Track all marks in the next frame and return a TrackedFrame.

        ``time`` (s, mid-exposure) overrides the stamp computed from the frame index (for
        example the header stamp of a received image).
        """
        frame = self._linear(to_gray(frame))
        if self.mosaic:
            frame = unmosaic(frame)
        result = TrackedFrame(
            index=self.index, time=self.frame_time(self.index) if time is None else float(time),
            marks={name: self._measure(name, mark, frame) for name, mark in self.marks.items()},
            meters_per_pixel=self.meters_per_pixel)
        self.index += 1
        return result

    def _linear(self, frame: np.ndarray) -> np.ndarray:
        """Return ``frame`` in linear light (``config.gamma``; 1: the frame itself).

        Decoded frames are floats, whose pixel type tells no saturation level: before the
        first one, the config's (if not given) becomes the pixel type's full scale, which
        decoding keeps, and the marks' trackers start again with it.
        """
        if not self.decoder.active:
            return frame
        if (self.config.saturation_level is None
                and np.issubdtype(frame.dtype, np.integer)):
            self.config = dataclasses.replace(self.config,
                                              saturation_level=full_scale(frame))
            self.marks = {name: MarkTracker(mark.roi, self.config, name,
                                            self.exposure * self.fps)
                          for name, mark in self.marks.items()}
        return self.decoder(frame)

    def _measure(self, name: str, mark: Any, frame: np.ndarray) -> MarkMeasurement:
        """Return mark ``name``'s measurement in ``frame``, with a passing shadow divided out.

        The light taken from beside the mark adds its own noise: a frame it was divided by
        has its standard error times ``SHADED_SIGMA``, and the mark's tracker is told of the
        shadow (``shadow``, a ShadowNote: its fit is judged with the light's error). The
        mark's contrast in and out of the shadows gives the camera's black level
        (``black``, core.tracking.shade.BlackLevel) when the config does not.
        """
        shaded, light, black = self._shaded(name, frame)
        note = None
        if light is not None:
            first, stop = self.shades[name].rows
            known = self.config.black_level > 0.0 or self.black.value is not None
            note = ShadowNote(gain_slack(float(light[first:stop].min()), known),
                              self.shades[name].error)
        if hasattr(mark, 'shadow'):
            mark.shadow = note
        found = mark.measure(shaded)
        if light is None:
            if found.valid:
                self.black.lit(name, found.contrast)
            return found
        self.shaded[name] += 1
        if not found.valid:
            return found
        self._black_sample(name, found, light, black)
        return dataclasses.replace(found, sigma_px=found.sigma_px * SHADED_SIGMA)

    def _black_sample(self, name: str, found: MarkMeasurement, light: np.ndarray,
                      black: float) -> None:
        """Give ``black`` the mark's contrast under a shadow's ``light`` (ROI, as read)."""
        if self.config.black_level > 0.0 or not math.isfinite(found.extent_px):
            return
        shade = self.shades[name]
        first, stop = shade.rows
        centre = found.position_px - self.marks[name].roi[0]
        lo = int(math.floor(centre - found.extent_px / 2.0))
        hi = int(math.ceil(centre + found.extent_px / 2.0)) + 1
        if lo < 0 or hi > light.shape[1]:
            return
        self.black.shaded(name, found.contrast, light[first:stop, lo:hi], shade.level(lo, hi),
                          black)

    def _shaded(self, name: str,
                frame: np.ndarray) -> tuple[np.ndarray, np.ndarray | None, float]:
        """Return ``frame`` with mark ``name``'s ROI divided by a passing shadow's light.

        Also the light as read (None when not divided) and the black level the light was
        taken above: ``config.black_level``, else ``black``'s estimate, else 0. The frame
        itself when no shadow is on the ROI (core.tracking.shade), or when a column of the
        mark's rows is saturated there (the mark's tracker refuses that frame itself).
        """
        black = self.config.black_level
        if black == 0.0:
            black = self.black.value or 0.0
        shade = self.shades.get(name)
        if shade is None:
            return frame, None, black
        roi = self.marks[name].roi
        region = roi_region(frame, roi, name)
        read = shade.light(region)
        if read is None:
            return frame, None, black
        saturation = saturation_level(frame.dtype, self.config.saturation_level)
        first, stop = shade.rows
        if saturation is not None and float(
                region[first:stop].mean(axis=0).max()) >= saturation:
            return frame, None, black
        light = shade.above_black(read, black)
        if light.min() <= 0.0:
            return frame, None, black  # darker than the black level: that is wrong, as is
        shaded = frame.astype(np.float64)
        x, y, w, h = roi
        shaded[y:y + h, x:x + w] = (region - black) / light + black
        return shaded, read, black


def track(frames: Iterable[npt.ArrayLike] | np.ndarray, rois: Mapping[str, Roi],
          meters_per_pixel: Any, fps: float | None = None, exposure: float | None = None,
          start_time: float = 0.0, config: TrackerConfig | None = None,
          progress: Callable[[int, int | None], Any] | None = None,
          max_frames: int | None = None, times: npt.ArrayLike | None = None,
          n_frames: int | None = None) -> TrackResult:
    """Track the marks through a sequence of frames and return a TrackResult.

    ``frames``: an N x H x W (x 3) array or any iterable of 2-D (or colour) arrays, all of one
    size (io.video.track_video opens video files and image folders). ``fps``: needed unless
    ``times`` gives it. ``times``: optional per-frame mid-exposure stamps (s) instead of
    ``start_time + n / fps + exposure / 2``. ``progress``: optional callable(frames_done,
    frames_total_or_None), called every 100 frames and at the end; the total is ``n_frames``
    if given, else the sequence's length if it has one. ROIs, scale and rate are checked
    before any tracking; InputError (one line) for anything unusable.
    """
    first, sequence = gray_frames(frames)
    if n_frames is None and hasattr(frames, '__len__'):
        n_frames = 1 if np.ndim(frames) == 2 else len(frames)  # type: ignore[arg-type]
    check_scale(meters_per_pixel)
    times_given = None if times is None else np.asarray(times, dtype=float).ravel()
    if times_given is not None:
        if fps is None and times_given.size > 1:
            fps = 1.0 / float(np.median(np.diff(times_given)))
    if fps is None:
        raise InputError('the frame rate is unknown: give fps')
    tracker = Tracker(rois, meters_per_pixel, fps, exposure, start_time, config,
                      frame_size=(first.shape[1], first.shape[0]))
    names = tuple(tracker.marks)
    head = list(itertools.islice(sequence, max(int(tracker.config.prime_frames), 0)))
    if max_frames is not None:
        head = head[:max(int(max_frames), 1)]
    tracker.prime(head)
    sequence = itertools.chain(head, sequence)
    stamps: list[float] = []
    rows: list[dict[str, MarkMeasurement]] = []
    for frame in sequence:
        if max_frames is not None and len(rows) >= max_frames:
            break
        stamp = None
        if times_given is not None:
            if len(rows) >= times_given.size:
                raise InputError(f'{times_given.size} time stamps for more frames')
            stamp = times_given[len(rows)]
        result = tracker.process(frame, stamp)
        stamps.append(result.time)
        rows.append(result.marks)
        for name, mark in tracker.marks.items():  # frames measured again (plate._gather)
            revised = getattr(mark, 'revised', None)
            if revised:
                begin = len(rows) - 1 - len(revised)
                for back, found in enumerate(revised):
                    if begin + back >= 0:
                        rows[begin + back][name] = found
                revised.clear()
        if progress is not None and len(rows) % 100 == 0:
            progress(len(rows), n_frames)
    if progress is not None:
        progress(len(rows), n_frames)
    if not rows:
        raise InputError('no frames to track')
    px = {n: np.array([r[n].position_px for r in rows]) for n in names}
    return TrackResult(
        time=np.array(stamps), position={n: px[n] * tracker.meters_per_pixel for n in names},
        position_px=px, quality={n: np.array([r[n].quality for r in rows]) for n in names},
        sigma_px={n: np.array([r[n].sigma_px for r in rows]) for n in names},
        reason={n: [r[n].reason for r in rows] for n in names},
        meters_per_pixel=tracker.meters_per_pixel, fps=tracker.fps,
        exposure=tracker.exposure, names=names,
        polarity={n: m.polarity for n, m in tracker.marks.items() if m.polarity},
        centre_sigma_px={n: m.centre_sigma_px for n, m in tracker.marks.items()},
        mosaic=tracker.mosaic, shaded=dict(tracker.shaded),
        black_level=(math.nan, math.nan) if tracker.black.value is None else (
            tracker.black.value, tracker.black.sigma),
        gamma=tracker.decoder.gamma, gamma_found=math.isfinite(tracker.gamma_found))
