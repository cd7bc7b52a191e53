"""What CentroidMarkTracker knows, and how it learns it from the priming frames.

The base of core.tracking.centroid.CentroidMarkTracker, which measures each frame with what
is learned here (the method is in that module's docstring). Here: the tracker's state and
``reset``; ``prime``, which learns the polarity, the static background
(core.tracking.background; refused when it takes the mark away), the plain plate for smears
too long for a baseline of the frame's own, and the mark's rows. Priming measures its own
frames with ``measure`` (the subclass's).
"""

from collections import deque
import functools
import math

import numpy as np

from microball_ros.core.tracking.background import StaticBackground, StaticPlate
from microball_ros.core.tracking.config import TrackerConfig
from microball_ros.core.tracking.image import Roi, check_roi, roi_region
from microball_ros.core.tracking.profile import (
    Baseline,
    column_profile,
    polarity_of,
    polarity_of_pixels,
)
from microball_ros.core.tracking.reach import Reach
from microball_ros.core.tracking.results import MarkMeasurement

VOTES, VOTE_SHARE = 3, 0.8  # voted_polarity: clear guesses needed, and the share agreeing
MIDDLE_FROM = 9  # voted_polarity: ROI rows from which its middle third votes first
ROW_FRAMES = 20  # frames the mark is found in before its rows are fixed (rows_guard)
# A smear whose extent (against the learned plate) exceeds LONG_SMEAR of the ROI's width is
# measured against the plate (core.tracking.centroid).
LONG_SMEAR = 0.25
LOST_FRACTION = 0.2  # priming frames lost with their own baseline: smears may be long
SMEAR_GROWTH = 2.0  # a long smear's extent (90th percentile) over its shortest (10th)


def voted_polarity(regions) -> str | None:
    """Return the polarity most of the ROIs' clear guesses give, None if they do not agree.

    Each ROI's guess as ``CentroidMarkTracker.measure`` makes it (``polarity_of`` its column
    profile, else ``polarity_of_pixels``); at least ``VOTES`` clear guesses, ``VOTE_SHARE`` of
    them one way. The first frame the mark was found in decided alone before: on a textured
    rectangle at 15 frames/s smeared over 0.7 of the period, 31 of the 60 priming frames guessed
    dark and none bright, but a frame guessing nothing was measured both ways against the
    static background, whose median the smears had darkened, and taken for a bright mark.

    An ROI is drawn about the mark's path, so the mark fills its middle rows and a texture
    may fill the rest: the middle third of the rows (ROIs of ``MIDDLE_FROM`` rows or more)
    votes first, the whole ROI when those rows give no verdict (a mark off the ROI's middle).
    A cross 13 % deep on a 5 px grain of 4.7 % gave 1 clear guess in 60 frames over the whole
    ROI, and was taken for a bright mark; in its middle rows 56 of 60 guessed dark.
    """
    regions = list(regions)
    if regions and len(regions[0]) >= MIDDLE_FROM:
        height = len(regions[0])
        middle = _vote([region[height // 3:height - height // 3] for region in regions])
        if middle is not None:
            return middle
    return _vote(regions)


def _vote(regions) -> str | None:
    """Return ``voted_polarity``'s verdict on ``regions`` as they are (None: no verdict)."""
    guesses = [polarity_of(column_profile(region)) or polarity_of_pixels(region)
               for region in regions]
    dark, bright = guesses.count('dark'), guesses.count('bright')
    if dark + bright < VOTES or max(dark, bright) < VOTE_SHARE * (dark + bright):
        return None
    return 'dark' if dark > bright else 'bright'


class CentroidPriming:
    """The state of a CentroidMarkTracker and its learning (see the module); measures nothing.

    State (all from earlier frames, in order): the previous position, to tell a still mark from
    a moving one, and the recent integrated deficits, to recognise a partly hidden mark.
    """

    def __init__(self, roi: Roi, config: TrackerConfig | None = None, name: str = 'mark',
                 exposure_fraction: float = 0.5):
        """Create a tracker for the mark in ``roi`` (x, y, w, h, px).

        With polarity 'auto' the first frame the mark is found in (as dark or as bright,
        whichever stands out more) fixes the polarity. ``exposure_fraction`` is unused here.
        """
        self.roi = check_roi(roi, name=name)
        self.config = TrackerConfig() if config is None else config
        self.name = name
        self._baseline = Baseline(self.roi[2], self.config.baseline_degree)
        self._areas: deque[float] = deque(maxlen=int(self.config.area_history))
        self._previous: float | None = None
        self._background = StaticBackground()
        self._plate = StaticPlate()
        self._plate_rows: slice | None = None
        self._plate_mean: np.ndarray | None = None
        self._rows: slice | None = None
        self._row_weights: np.ndarray | None = None
        self._row_tolerance = math.inf
        self._weights: np.ndarray | None = None
        self._row_samples: list[np.ndarray] = []
        # (rows, weights, tolerance) learned over the priming frames; None: learned while tracking
        self._primed_rows: tuple | None = None
        self.keep_rows = True  # False: ``reset`` forgets them too (rows learned while tracking)
        self._reach = Reach()
        self._gate: tuple[float, float] | None = None
        self._taken: tuple[int, int] | None = None  # the dip measured (columns)
        self._exclude: tuple[int, int] | None = None  # a dip found not to be the mark
        self.polarity: str | None = None if self.config.polarity == 'auto' else (
            self.config.polarity)

    def reset(self) -> None:
        """Forget the history (for a new, unrelated sequence)."""
        self._areas.clear()
        self._previous = None
        self._reach = Reach()
        self._rows = self._row_weights = None
        self._row_tolerance = math.inf
        if self._primed_rows is not None and self.keep_rows:
            self._rows, self._row_weights, self._row_tolerance = self._primed_rows
        self._row_samples.clear()
        if self.config.polarity == 'auto':
            self.polarity = None

    def prime(self, frames) -> None:
        """Learn the polarity, the mark's rows and the static background, then reset.

        The background (core.tracking.background) is learned when ``static_background`` is
        set: a first one from the plain temporal median locates the mark in every priming
        frame, then the frames are averaged per pixel outside the mark's footprint. The mark's
        rows are learned last, from the first ``ROW_FRAMES`` priming frames it is found in, and
        kept by ``reset``.
        """
        frames = list(frames)
        polarity = self.polarity  # a polarity found before is kept (priming again: still.py)
        self._primed_rows = None
        self.reset()  # no rows of an earlier priming while this one measures
        self.polarity = polarity
        self._background.clear()
        self._plate.clear()
        self._plate_rows = self._plate_mean = None
        x, y, w, h = self.roi

        @functools.cache
        def vote():  # on the raw frames ``measure`` would guess on: once, however often asked
            return voted_polarity([frame[y:y + h, x:x + w] for frame in frames if frame.ndim == 2
                                   and x + w <= frame.shape[1] and y + h <= frame.shape[0]])

        regions = None
        if self.config.static_background:
            regions = np.stack([roi_region(frame, self.roi, self.name) for frame in frames]
                               ) if frames else None
            if regions is not None:
                self._background.inverse = StaticBackground.provisional(
                    regions.astype(np.float32))
                if self._background.inverse is not None and not self._keeps_mark(frames):
                    self._background.clear()
                if self._background.inverse is None:
                    regions = None
        self._find_polarity(frames, vote)
        if regions is not None:
            polarity = self.polarity
            first = self._background.inverse
            self._background.learn(regions, self._footprints(frames), first)
            self.reset()
            self.polarity = polarity
            if self._background.inverse is not None and not self._keeps_mark(frames):
                self._background.clear()
                if self.config.polarity == 'auto':
                    self.polarity = None  # found again, on the frames as they are
                self._find_polarity(frames, vote)
            if self.polarity is None:  # the background took the mark away (a still mark)
                self._background.clear()
                self._find_polarity(frames, vote)
        if self.polarity is not None and len(frames) > 0:
            long, lost = self._smears_long(frames)
            if long or lost:
                self._plate.learn(np.stack([self._background.apply(roi_region(
                    frame, self.roi, self.name)) for frame in frames]), self.polarity,
                    int(self.config.smoothing_px), int(self.config.merge_gap_px))
            if lost and not long and np.count_nonzero(np.isnan(self._extents(frames))) >= lost:
                # Frames lost for another reason than long smears (a particle passing): the
                # plate does not find them either, and would measure the others worse.
                self._plate.clear()
            self._learn_primed_rows(frames)

    def _learn_primed_rows(self, frames) -> None:
        """Learn the mark's rows from the priming frames, kept by ``reset``.

        As tracking would, from the first ``ROW_FRAMES`` frames the mark is found in; if it is
        found in fewer, none are kept (they are learned while tracking, as before: on a
        textured plate smeared at 15 fps, rows from 14 poor detections lost 109 of 120 frames).
        """
        if not self.config.weight_rows or self.roi[3] < 2:
            return
        polarity = self.polarity
        for frame in frames:
            if self._rows is not None:
                break
            self.measure(frame)
        if self._rows is not None:
            self._primed_rows = (self._rows, self._row_weights, self._row_tolerance)
        self.reset()
        self.polarity = polarity

    def _smears_long(self, frames) -> tuple[bool, int]:
        """Return whether the priming frames may hold smears too long for a baseline; reset.

        Measured with each frame's own baseline: (long, lost). ``long``: the 90th percentile
        of the mark's extent (smear and all) at least ``LONG_SMEAR`` of the ROI's width (the
        extent measured against the plate) and ``SMEAR_GROWTH`` times its 10th percentile (a
        wide mark that hardly moves in a narrow ROI is no smear: 26 px in a 99 px ROI lost 22
        of 90 frames against the plate). ``lost``: the frames lost, if more than
        ``LOST_FRACTION`` of them (else 0); the plate is then kept only if it loses fewer. Only
        then is the plain plate learned and tried on every frame: a short mark under a drifting
        illumination gradient would look long against it (times one gain; a pair of bars
        smeared over 0.18 of a narrow ROI lost 100 of 120 frames so), and it costs time.
        """
        extents = self._extents(frames)
        count = int(np.count_nonzero(np.isnan(extents)))
        lost = count if count > LOST_FRACTION * len(frames) else 0
        extents = extents[np.isfinite(extents)]
        if not extents.size:
            return False, lost
        longest, shortest = (float(v) for v in np.percentile(extents, [90, 10]))
        return longest >= LONG_SMEAR * self.roi[2] and longest >= SMEAR_GROWTH * shortest, lost

    def _extents(self, frames) -> np.ndarray:
        """Return the mark's extent in each of ``frames`` (px; NaN: lost); reset."""
        polarity = self.polarity
        found = [self.measure(frame) for frame in frames]
        self.reset()
        self.polarity = polarity
        return np.array([m.extent_px if m.valid else math.nan for m in found], dtype=float)

    def _find_polarity(self, frames, vote) -> None:
        """Learn the polarity (if not known); reset.

        ``vote()``: the frames' own guesses (``voted_polarity``), used when they agree; else
        the first frame the mark is found in (both polarities tried where its guess is
        unclear).
        """
        if self.polarity is None:
            self.polarity = vote()
        for frame in frames:
            if self.polarity is not None:
                break
            self.measure(frame)
        polarity = self.polarity
        self.reset()
        self.polarity = polarity

    def _contrast(self, frames) -> float:
        """Return the mark's median contrast over ``frames`` (0 where not found); reset."""
        polarity = self.polarity
        found = [self.measure(frame) for frame in frames]
        self.reset()
        self.polarity = polarity
        return float(np.median([m.contrast if m.valid and m.contrast > 0 else 0.0
                                for m in found]))

    def _keeps_mark(self, frames) -> bool:
        """Return False if the background takes the mark away (a mark that hardly moves).

        A mark that stays over the same pixels in most priming frames is in their median,
        and so in a background learned from it: divided by it, the frames lose the mark (or
        show it with the wrong polarity). True if the mark keeps at least half its contrast
        over the priming frames against the frames as they are (polarity found afresh).
        """
        learned = (self._background.inverse, self._background.added,
                   self._background.reference, self._background.gain, self._background.opaque)
        sample = frames[::max(len(frames) // 20, 1)]
        polarity = self.polarity
        with_background = self._contrast(sample)
        self._background.clear()
        if self.config.polarity == 'auto':
            self.polarity = None
        without = self._contrast(sample)
        (self._background.inverse, self._background.added, self._background.reference,
         self._background.gain, self._background.opaque) = learned
        self.polarity = polarity
        return with_background >= 0.5 * without

    def _footprints(self, frames) -> np.ndarray:
        """Return the columns the mark covers in each frame (all of them where not found)."""
        x, _, w, _ = self.roi
        covered = np.ones((len(frames), w), dtype=bool)
        guard = int(self.config.pad_px) + int(self.config.smoothing_px) + 2
        for i, frame in enumerate(frames):
            found = self.measure(frame)
            if found.valid and math.isfinite(found.extent_px):
                center = found.position_px - x
                half = found.extent_px / 2.0 + guard
                covered[i] = False
                covered[i, max(int(center - half), 0):max(int(math.ceil(center + half)) + 1,
                                                           0)] = True
        return covered

    @property
    def background(self) -> StaticBackground:
        """Return the static background (its ``inverse`` None when none was learned)."""
        return self._background

    @property
    def mark_rows(self) -> tuple[int, int] | None:
        """Return the ROI rows (first, stop) the mark occupies, learned while priming; or None."""
        rows = None if self._primed_rows is None else self._primed_rows[0]
        if rows is None or rows.start is None or rows.stop is None:
            return None
        return int(rows.start), int(rows.stop)

    @property
    def centre_sigma_px(self) -> float:
        """Return the standard error of the mark's centre common to every frame: 0 (px).

        The deficit's centroid is the mark's exposure-averaged centre, exact on average on a
        plain plate. (On a textured plate the texture pulls it: method 'auto' learns the
        plate there, and says what its centre's error is.)
        """
        return 0.0

    @property
    def learned(self) -> dict:
        """Return what was learned: the polarity, the static background, the mark's rows."""
        learned: dict = {'polarity': self.polarity} if self.polarity else {}
        if self._row_weights is not None and self._rows is not None:
            learned['rows'] = (self._rows.start, self._rows.stop)
        if self._background.inverse is not None:
            learned['static_background'] = self._background.kind
            learned['static_background_gain'] = self._background.gain
        return learned

    def measure(self, frame: np.ndarray) -> MarkMeasurement:
        """Measure the mark in one frame (CentroidMarkTracker.measure)."""
        raise NotImplementedError
