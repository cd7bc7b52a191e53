"""What PlateMarkTracker knows, and how it learns it from the priming frames.

The base of core.tracking.plate.PlateMarkTracker, which measures each frame with what is
learned here; the method as a whole is in that module's docstring. Here: the tracker's state;
``prime``, which chooses per ROI between the centroid, a still or slowly moving mark and a
learned plate (plain or textured, a long smear's); learning the plate twice
(core.tracking.plate_learn) and the offsets and standard-error scale it is calibrated with.
Priming tracks its own frames with ``measure`` (the subclass's) to judge and calibrate a plate.
"""

from collections import deque
import math

import numpy as np

from microball_ros.core.tracking.area_centre import area_offset
from microball_ros.core.tracking.background import StaticBackground
from microball_ros.core.tracking.centroid import CentroidMarkTracker
from microball_ros.core.tracking.config import TrackerConfig
from microball_ros.core.tracking.gains import MarkGains
from microball_ros.core.tracking.image import Roi, check_roi, roi_region
from microball_ros.core.tracking.plate_learn import LearnedPlate, learn_plate
from microball_ros.core.tracking.plate_model import PlateModel
from microball_ros.core.tracking.plate_rows import edge_offset
from microball_ros.core.tracking.predict import MotionPredictor
from microball_ros.core.tracking.priming import (
    TEXTURE_SCORE,
    plain_verdict,
    pulled,
    row_flat_field,
    scatter_scale,
    texture_score,
    unexplained,
)
from microball_ros.core.tracking.profile import glint_columns
from microball_ros.core.tracking.results import MarkMeasurement, with_centre
from microball_ros.core.tracking.rows_guard import ROW_FRACTION, ROW_MARGIN, RowsGuard
from microball_ros.core.tracking.shade import ShadowNote
from microball_ros.core.tracking.small import SmallMotion, moves_little
from microball_ros.core.tracking.smear import (
    BlurScale,
    PeriodicMotion,
    fit_motion,
    least_smeared,
    smear_start,
    smear_verdict,
)
from microball_ros.core.tracking.still import StillMark, is_still

# A plain plate's plate is kept if it reports every frame the centroid does over priming and
# is priming.steadier than it by this margin.
PLAIN_MARGIN = 0.95
# A textured plate that finds its mark in fewer priming frames is dropped (its centre was put
# 142 px off the mark, and it found none: stop 40)
FOUND_LEAST = 8
# The light expected at the mark is the median of its light in this many last frames found
LIGHT_MEMORY = 5
# A plate's kernels are the paths of the sinusoid fitted to the priming track
# (template.path_knots) if it turns this far (rad) over an exposure or more, else quadratic
# paths. In a 1-D model of a textured plate moving +-200 px (stop 41) a quadratic path put the
# position up to 0.001 px off at 0.31 rad (30 fps, half the period exposed), 0.016 at 0.5,
# 0.053 at 0.62 (the whole period), 0.30 at 0.87 (15 fps, 0.7 of the period)
PATH_TURN = 0.5


class PlatePriming:
    """The state of a PlateMarkTracker and its learning (see the module); measures nothing."""

    def __init__(self, roi: Roi, config: TrackerConfig | None = None, name: str = 'mark',
                 exposure_fraction: float = 0.5):
        """Create a tracker for the mark in ``roi`` (x, y, w, h, px)."""
        self.roi = check_roi(roi, name=name)
        self.config = TrackerConfig() if config is None else config
        self.name = name
        self.exposure_fraction = float(exposure_fraction)
        self._fallback = CentroidMarkTracker(self.roi, self.config, name, exposure_fraction)
        self.plate: PlateModel | None = None
        self.texture = 0.0
        self._pulled = False  # a texture too faint to score pulls the centroid: ``on_texture``
        # The centroid's priming track: ROI columns and smeared lengths (NaN: not found)
        self.priming_track: tuple[np.ndarray, np.ndarray] | None = None
        self.weights: np.ndarray | None = None
        self.static: np.ndarray | None = None
        self.flat: np.ndarray | None = None
        self._background: StaticBackground | None = None
        self._half = self._outer = self._whole = 8.0  # px: its half-width, its reach in D
        self._full: PlateModel | None = None
        self._shift, self._rms = 0.0, 1.0  # D's origin in the whole plate; priming's residual
        self._misfit = math.inf  # the plate's LearnedPlate.misfit, to compare another with
        self._kernel: tuple[float, float] | None = None  # the last measured (blur, curve)
        self.priming = False  # the priming frames are being tracked (``_track_priming``)
        self._predictor = MotionPredictor()
        self._blur_scale = BlurScale()  # the predicted kernels' blur against the fits'
        self._predicted_blur = math.nan  # this frame's, unscaled
        self._gains = MarkGains(int(self.config.area_history))  # and the jump guard
        # The light at the mark in the last frames it was found in (plate._deficit's)
        self._lights: deque[float] = deque(maxlen=LIGHT_MEMORY)
        self._light = math.nan  # ... in the frame being measured
        self._motion: PeriodicMotion | None = None  # a long smear's motion, from priming
        # The shadow this frame was divided by (core.tracking.tracker sets it), or None
        self.shadow: ShadowNote | None = None
        self._periodic: PeriodicMotion | None = None  # from a textured plate's priming track
        self._refused = False  # a long smear whose plate could not be learned: all NaN
        self._path_omega = 0.0  # rad/frame: the sinusoid whose paths the plate's kernels are
        self._clipped: np.ndarray | None = None  # this frame's glint columns
        self._saturates = False  # the plate's own pixels saturated while priming
        self._offset, self._asymmetry = 0.0, math.nan  # px added to positions; plate_rows
        self._offset_sigma = 0.0  # px: the offset's standard error (NaN: not measured)
        # A still mark, or one moving less than its width, on a textured plate
        self._still: StillMark | SmallMotion | None = None
        self._moved = False  # ... that moved since ``reset``
        self._still_at: float | None = None  # a still mark's centroid on a plain plate (ROI px)
        self._gathered: list | None = None  # frames since it moved, to learn it again from
        self.revised: list[MarkMeasurement] = []  # ``_gather``'s frames measured again
        self._sigma_scale = 1.0  # the standard errors times this (``scatter_scale``)
        self._unexplained = 0.0  # px added to them in quadrature (``_prime_plain``)
        # An asymmetric mark on a plain plate: px to its contrast centroid, standard error
        self._area: tuple[float, float] = (0.0, 0.0)
        self._guard = RowsGuard(int(self.config.pad_px))  # plain plate: the mark's rows
        self.jitter: tuple[float, float] | None = None  # plain plate: centroid's, plate's

    @property
    def polarity(self) -> str | None:
        """Return the mark's polarity ('dark' or 'bright'), None until it is known."""
        return self._fallback.polarity

    @polarity.setter
    def polarity(self, value: str | None) -> None:
        self._fallback.polarity = value

    @property
    def textured(self) -> bool:
        """Return True once priming found a textured plate and learned it."""
        return self.plate is not None and self.on_texture

    @property
    def on_texture(self) -> bool:
        """Return True if the plate is taken as textured.

        By its ``texture`` score, or because a texture too faint to score pulls the centroid
        (``_prime_plain``).
        """
        return self.texture >= TEXTURE_SCORE or self._pulled

    @property
    def learned(self) -> dict:
        """Return what was learned: the centroid tracker's, and the plate near the mark if any."""
        learned = dict(self._fallback.learned)
        if self.plate is not None:
            learned.update(polarity=self.polarity, half_width=self._half, texture=self.texture,
                           template=self.plate.values.copy(), center=self.plate.center,
                           offset=self._offset, sigma_scale=self._sigma_scale,
                           edge_asymmetry=self._asymmetry, offset_sigma=self._offset_sigma)
        if self._area[0] != 0.0:  # an asymmetric mark: to its contrast centroid (px, sigma)
            learned.update(area_offset=self._area[0], area_offset_sigma=self._area[1])
        return learned

    @property
    def mark_rows(self) -> tuple[int, int] | None:
        """Return the ROI rows (first, stop) the mark occupies; None if unknown.

        Its learned plate's row weights over ``rows_guard.ROW_FRACTION`` of the largest,
        widened by ``ROW_MARGIN`` (as the centroid's rows); the centroid's when no plate was
        learned.
        """
        if self.weights is None:
            return self._fallback.mark_rows
        deep = np.flatnonzero(self.weights > ROW_FRACTION * float(self.weights.max()))
        if deep.size == 0:
            return None
        return (max(int(deep[0]) - ROW_MARGIN, 0),
                min(int(deep[-1]) + ROW_MARGIN + 1, self.weights.size))

    @property
    def centre_sigma_px(self) -> float:
        """Return the standard error of where the mark's centre is put (px; NaN: unknown).

        One error, the same in every frame (a texture under the mark moves with it), in each
        position's ``sigma_px`` too; velocities and accelerations are free of it. 0 for the
        centroid on a plain plate (exact on average); NaN for the centroid on a textured
        plate whose plate could not be learned (its texture pulls the centroid by an amount
        not measured).
        """
        if self._still is not None and not self._moved:
            return self._still.centre_sigma
        if self.plate is not None and self.weights is not None:
            return with_centre(self._offset_sigma, self._area[1])
        return math.nan if self.on_texture else self._area[1]

    def reset(self) -> None:
        """Forget the track (what was learned is kept)."""
        self._predictor.reset()
        self._blur_scale.reset()
        self._gains.reset()
        self._lights.clear()
        self._moved = False
        self._gathered = None
        polarity = self._fallback.polarity
        self._fallback.reset()
        self._fallback.polarity = polarity

    def _region(self, frame):
        """Return the ROI of ``frame``, without the static background if one was learned."""
        region = roi_region(frame, self.roi, self.name)
        return region if self._background is None else self._background.apply(region)

    # -- learning --------------------------------------------------------------------------
    def prime(self, frames) -> None:
        """Learn the polarity, whether the plate is textured, and if so the plate; restart."""
        frames = list(frames)
        self._forget()
        self.texture, self.jitter, self._area = 0.0, None, (0.0, 0.0)
        self._pulled = False
        self.priming_track = None
        self._fallback.prime(frames)
        # The centroid's rows learned while priming serve it when it measures the frames; the
        # choices and the learning below see it as they always did (rows learned as it tracks)
        self._fallback.keep_rows = False
        self.reset()
        try:
            self._prime(frames)
        finally:
            self._fallback.keep_rows = True
            self.reset()

    def _prime(self, frames) -> None:
        """``prime`` once the centroid is primed."""
        if self.polarity is None or len(frames) < 12:
            return
        # A pattern fixed in the image (the centroid tracker's) first: the plate's own next.
        self._background = (self._fallback.background
                            if 'static_background' in self._fallback.learned else None)
        regions = [self._region(frame) for frame in frames]
        x = self.roi[0]
        sample, marks = least_smeared(self._fallback.measure, frames, regions, x,
                                      self.polarity)
        self.reset()
        if sample is None:
            return
        self.texture = texture_score(sample, marks)
        # A still mark (a stuck slider) learns no plate: the centroid's, or core.tracking.still's
        centroid = self._track_priming(frames, self._fallback.measure)
        self.priming_track = (centroid[0], np.array(
            [m.extent_px if m.valid else math.nan for m in centroid[1]]))
        still = is_still(centroid[1], x)
        self._path_omega = _path_frequency(centroid[0], self.exposure_fraction)
        # Without the pattern fixed in the image (a dot of dust deeper than the mark in their
        # mean was taken for a still mark); a mark still over the priming frames is in that
        # pattern, which the centroid then does not keep
        self._still = StillMark.learn(regions, self.polarity, int(self.config.pad_px), still)
        # A mark moving less than its width is in the median the plate's learning starts from
        small = self._still is None and not still and moves_little(centroid[1], x)
        if small:
            self._still = SmallMotion.learn(regions, self.polarity, int(self.config.pad_px))
            # The centroid's extents can mislead it (a long smear on a coarse texture, its
            # window over most of the ROI): a mark the frames do not register still moves
            small = self._still is not None
        self._still_at = float(np.nanmedian(centroid[0])) if (
            still and self._still is None) else None
        if self._still is None and not still and not small:
            if self.texture < TEXTURE_SCORE:
                self._prime_plain(regions, frames, centroid)  # calibrates a plate it keeps
            else:
                self._prime_textured(regions, frames, self.polarity)
        if self.plate is None and self._still is None and not self._refused:
            # The centroid measures every frame: its standard errors scaled as a plate's (a
            # pattern fixed in the image that the background leaves scatters it too)
            self._sigma_scale = scatter_scale(centroid[0], centroid[1])
        self._gains.stop_log()
        # A plate whose own pixels saturate (a bright speckle) has no glints to tell apart
        self._saturates = self.weights is not None and any(
            glint_columns(roi_region(frame, self.roi, self.name), self.weights > 0,
                          self.config.saturation_level) is not None for frame in frames)
        if not self.on_texture and self._still is None and not self._refused:
            # core.tracking.area_centre (a still mark's own module puts it: on a texture)
            self._area = area_offset(regions, centroid[0], np.array(
                [m.extent_px for m in centroid[1]]), self.polarity, int(self.config.pad_px))
        self.reset()

    def _prime_textured(self, regions, frames, polarity: str) -> None:
        """On a textured plate, learn the plate (a long smear's, or relearned) and calibrate."""
        start = smear_start(regions, polarity, self.exposure_fraction)
        self._motion = None if start is None else start[4]  # a long smear (smear.py)
        if start is not None:  # its plate's kernels: the sinusoid's paths (path_knots)
            kernels = start[4].kernels(np.arange(len(regions)), start[4].turn)[1]
            start = (start[0], kernels, *start[2:])
        self._offset_sigma = math.nan  # until the edges measure it (a long smear's: never)
        self._learn(regions, start)
        if self._motion is not None:
            self._check_smear(frames)
        elif self.plate is not None:
            self._relearn(regions, frames)
            tracked = self._track_priming(frames, self.measure)
            if np.count_nonzero(np.isfinite(tracked[0])) < FOUND_LEAST:
                self._forget()  # a plate that does not find its own mark: the centroid's
                return
            self._offset, self._asymmetry, self._offset_sigma = edge_offset(
                regions if self.flat is None else [r / self.flat for r in regions],
                self.weights, tracked[0], tracked[2], self._outer,
                1.0 if polarity == 'dark' else -1.0, kappa=self.plate.kappa)
            self._calibrate(tracked)

    def _calibrate(self, tracked) -> None:
        """Scale the fit's standard errors to the scatter of the track over the priming frames.

        ``tracked``: the priming frames' ``_track_priming`` with this plate; the scale is
        ``scatter_scale``'s.
        """
        positions, found, _ = tracked
        self._gains.learn_spread()  # from the plate's last pass over the priming frames
        if self.on_texture and self._motion is None:  # its kernels, from now
            self._periodic = fit_motion(positions, self.exposure_fraction)
        motion = self._motion or self._periodic
        if motion is not None:  # the first frames' search gated too (core.tracking.predict)
            self._predictor.use_frequency(motion.omega, motion.spread)
        # At five frames per period a third harmonic takes up a long smear's scatter (15 fps,
        # 0.7 of the period exposed: 0.23 px about it, 0.29 about two, the error's spread 0.32)
        self._sigma_scale = (scatter_scale(positions, found) if self._motion is None
                             else scatter_scale(positions, found, 2))

    def _check_smear(self, frames) -> None:
        """Keep a long smear's plate if ``smear_verdict`` trusts it; else refuse every frame."""
        tracked = self._track_priming(frames, self.measure) if self.plate is not None else None

        def centroid(n: int) -> float:
            """Return the centroid's position of frame n (ROI column), measured on its own."""
            self.reset()  # its area guard compares a frame with the last ones
            found = self._fallback.measure(frames[n])
            self.reset()
            return found.position_px - self.roi[0] if found.valid else math.nan

        if tracked is None or self._motion is None or not smear_verdict(
                tracked[0], centroid, self._motion):
            self._forget()
            self._refused = True
            return
        self._calibrate(tracked)

    def _track_priming(self, frames, measure):
        """Return the positions (ROI columns, NaN: none), measurements and kernels (NaN: none)."""
        self.reset()
        x = self.roi[0]
        self._gains.start_log()
        found, kernels = [], []
        self.priming = True
        try:
            for frame in frames:
                found.append(measure(frame))
                known = found[-1].valid and self._kernel is not None and measure == self.measure
                kernels.append(self._kernel if known else (math.nan, math.nan))
        finally:
            self.priming = False
        self.reset()
        return (np.array([m.position_px - x if m.valid else math.nan for m in found]), found,
                np.array(kernels, dtype=float))

    def _prime_plain(self, regions, frames, tracked) -> None:
        """On a plain plate, learn the plate and keep it if it tracks better than the centroid.

        ``tracked``: the centroid's ``_track_priming``. The plate tracks the priming frames
        too, and is kept and offset as ``priming.plain_verdict`` says (``PLAIN_MARGIN``). The
        mark's rows and row weights are learned from the plate's track (``mark_rows``). When
        the centroid is ``priming.pulled`` and the plate is not, the plate is learned again
        as a textured one (``on_texture``). A plate refused though steadier leaves the
        centroid the part of the two tracks' difference their standard errors do not explain
        (``priming.unexplained``), added to its standard errors.
        """
        centroid, reference, _ = tracked
        self._learn(regions, found=centroid)
        if self.plate is not None:
            self._relearn(regions, frames)
        if self.plate is None:
            return self._forget()
        self._guard.start_log()
        tracked = self._track_priming(frames, self.measure)
        self._guard.learn(self.roi[3])
        keep, jitters, offset = plain_verdict(centroid, reference, tracked[0], tracked[1],
                                              PLAIN_MARGIN)
        self.jitter = jitters
        polarity = self.polarity
        sigmas = [np.array([m.sigma_px if m.valid else math.nan for m in found])
                  for found in (reference, tracked[1])]
        if polarity is not None and pulled(jitters, sigmas):
            # A texture too faint to score pulls the centroid (2.3 px off at a whole-frame
            # exposure, the plate's jitter a sixth of its): learned as a textured plate
            self._forget()
            self._pulled = True
            self._prime_textured(regions, frames, polarity)
            return
        if not keep:
            # Refused though steadier: the two disagree by more than their errors allow, and
            # the centroid that measures every frame carries what they leave out
            spread = (unexplained([centroid, tracked[0]], sigmas)
                      if jitters[1] < PLAIN_MARGIN * jitters[0] else 0.0)
            self._forget()
            self._unexplained = spread
            return
        self._offset, self._offset_sigma = offset
        self._calibrate(tracked)

    def _forget(self) -> None:
        """Drop a learned plate: every frame is measured by the centroid tracker again."""
        self.plate = self._full = self._motion = self._periodic = None
        self.weights = self.static = self.flat = None
        self._half = self._outer = self._whole = 8.0
        self._shift, self._rms, self._sigma_scale = 0.0, 1.0, 1.0
        self._misfit, self._unexplained = math.inf, 0.0
        self._offset, self._asymmetry, self._still = 0.0, math.nan, None
        self._offset_sigma = 0.0
        self._still_at = None
        self._gains.forget_spread()
        self._guard.forget()
        self._predictor.use_frequency(math.nan, 0.0)
        self._refused = False
        self._path_omega = 0.0
        self.reset()

    def _relearn(self, regions, frames) -> None:
        """Learn the plate again from the positions and kernels the learned plate measures.

        The first positions (dip centroids) can be pixels off on a texture; the rounds of the
        solver then stop short of the plate. Measured with the first plate (search and full
        fit), the positions start within a fraction of a pixel, so the second plate is sharp.
        Kept only if it fits the frames better (``LearnedPlate.misfit``: the median residual
        per pixel). Where the centroid found too few priming frames for their motion (a
        texture), the first plate's track gives the sinusoid whose paths the kernels are
        (``_omega``).
        """
        positions, _, kernels = self._track_priming(frames, self.measure)
        positions[np.isnan(kernels[:, 0])] = np.nan
        if np.count_nonzero(np.isfinite(positions)) < 8 or self.polarity is None:
            return
        omega = self._omega
        if omega == 0.0:
            omega = _path_frequency(positions, self.exposure_fraction)
        spans = np.array([self._span(kernel[0], kernel) for kernel in kernels])  # NaN: none
        flat = row_flat_field(regions, self.weights, positions, spans)
        learned = learn_plate(regions if flat is None else [r / flat for r in regions],
                              self.polarity, self.config, self.exposure_fraction,
                              self._motion is not None, (positions, kernels), omega=omega)
        if learned is not None and learned.misfit <= self._misfit:
            learned.flat = flat
            self._use(learned)
            if self._motion is None:
                self._path_omega = omega

    def _learn(self, regions, start=None, found=None) -> None:
        """Learn the plate (core.tracking.plate_learn); leave ``plate`` None on failure.

        ``start``: (positions, kernels) per frame to start the solver from (NaN: unknown),
        instead of the dip centroids and kernels from neighbouring frames; ``found``: the
        centroid's positions, frames whose dip centroid is far off them left out.
        """
        if self.polarity is None:
            return
        learned = learn_plate(regions, self.polarity, self.config, self.exposure_fraction,
                              self._motion is not None, start, found, self._omega)
        if learned is None:
            self.plate = None
        else:
            self._use(learned)

    @property
    def _omega(self) -> float:
        """Return the frequency (rad/frame) whose sinusoid's paths the plate's kernels are.

        A long smear's motion's, else the centroid's priming track's if it turns over
        ``PATH_TURN`` in an exposure; 0: quadratic paths. Learned and fitted with the
        sinusoid's own paths (template.path_knots): a quadratic path put a long smear's
        positions 0.25 px RMS off, noise-free, at 15 fps with 0.7 of the period exposed.
        """
        return self._path_omega if self._motion is None else self._motion.omega

    def _use(self, learned: LearnedPlate) -> None:
        """Measure with the plate ``learned`` from now on."""
        self.plate, self._full, self._shift = learned.plate, learned.full, learned.shift
        self._half, self._outer, self._whole = learned.half, learned.outer, learned.whole
        self.weights, self.static, self.flat = learned.weights, learned.static, learned.flat
        self._rms, self._misfit = learned.rms, learned.misfit

    def _span(self, blur, kernel):
        """Return the width (px) the smeared mark can cover: the light is fitted outside it."""
        curve = abs(kernel[1]) if kernel is not None else 0.0
        return 2.0 * (self._outer + 0.5 * abs(blur) + 0.25 * curve) + 8.0

    def measure(self, frame: np.ndarray) -> MarkMeasurement:
        """Measure the mark in one frame (PlateMarkTracker.measure)."""
        raise NotImplementedError


def _path_frequency(positions: np.ndarray, fraction: float) -> float:
    """Return the frequency (rad/frame) of the sinusoid fitted to ``positions``.

    0 (quadratic paths) unless one fits (smear.fit_motion) and turns ``PATH_TURN`` rad or
    more over an exposure of ``fraction`` of the frame period.
    """
    periodic = fit_motion(positions, fraction)
    return periodic.omega if periodic is not None and periodic.turn >= PATH_TURN else 0.0
