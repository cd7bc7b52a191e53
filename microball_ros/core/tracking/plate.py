"""One mark on a plate whose texture moves with it: the learned plate, registered per frame.

Owns PlateMarkTracker (same interface as CentroidMarkTracker); what priming measures to choose
is core.tracking.priming. Priming decides per ROI whether the plate is textured: pixel noise is
independent between the even and the odd rows while a texture on the plate is common to both,
so the correlation of their profiles outside the mark (after a cubic detrend) is about 0 on a
plain plate and 0.5-1 on a textured one (``texture_score``; a static background the centroid
tracker learned is divided out first). On a plain plate the centroid tracker
(core.tracking.centroid) tracks the priming frames first. Its window weighs every column in
it alike, the mark's flat middle and the noise beside it, so its variance is 1.5-3 times the
bound's for a box and far more for thin strokes (a cross, bars): the plate is learned as below
and kept only if, over the priming frames, it reports every frame the centroid does and it is
``steadier`` (its jitter about a smooth periodic motion under ``PLAIN_MARGIN`` times the
centroid's, or its standard errors when the motion is not periodic, and the two tracks agreeing
as their standard errors allow), on the frames where the two do not disagree grossly
(``agreeing``: a particle passing pulls one); its positions are offset by the mean difference
of the two tracks there (the centroid is exact on average). Kept, it alone measures every
frame, and a frame whose rows depart from the mark's own (core.tracking.rows_guard) is 'mark
partly hidden'. Else every frame is the centroid's.

On a textured plate the texture moves with the mark, so near the mark the plate's relative
deficit ``D(u)`` (mark and texture, plate coordinates) is the same in every frame, smeared by
the exposure's motion kernel ``K`` (core.tracking.template: a quadratic path, blur ``L``,
curvature ``Q``). A frame's deficit is ``d(x) = c + g (D * K)(x - s)`` with ``s`` the position
averaged over the exposure. The tracker

1. learns from the priming frames (core.tracking.plate_learn) the row weights, the static
   field and ``D`` with each frame's position and kernel, twice (the second time from the
   positions the first plate measures, on a row flat field if there is one; kept if it fits
   better); a texture moves the mark's edges by 0.1-0.3 px, so the positions are then offset
   to where its edges, row by row, are most nearly mirror-symmetric
   (core.tracking.plate_rows.edge_offset), with that centre's standard error (one error in
   every frame, in each position's standard error: ``centre_sigma_px``);
2. per frame divides the row-weighted profile by the static field and by the frame's light: a
   straight line fitted on ``LIGHT_FLANK`` px either side of the mark (robustly, so that a
   particle over a flank does not tilt it: profile.light_level), to the profile over the whole
   learned plate placed at the predicted position, so the texture is not mistaken for light and
   the mark's contrast is relative to the plate next to it in the same frame (flicker does not
   look like a covered mark); then searches the mark by a matched filter of ``D`` smeared by
   the predicted motion (a sinusoid of the priming track's frequency), gated around the
   predicted position (``MotionPredictor``; from the seventh frame on, by the priming track's
   frequency until its recurrence has the frames it needs) so texture dips never win; after a
   loss over the whole ROI (plate_search.search_kernels), where a first fit poorer than
   priming's is refused and the ``plate_search.CANDIDATES`` best matches are tried in turn (a
   particle near the mark matches better than the mark). A match ``RELIGHT`` px or more from
   where it was predicted (or without a prediction) has the light fitted again beside it;
3. fits ``s``, ``L`` and ``Q`` (Gauss-Newton, ``c`` and ``g`` solved linearly, with fallbacks
   for a poor fit: ``PlateModel.fit_frame``): the texture, common to data and model, is signal;
4. checks the mark's path clear of the ROI edges, its contrast ``g`` against recent frames
   (a covered mark loses contrast; a jump of it, something passing beside the mark, is refused:
   core.tracking.gains) and the fit's residual against the residuals while priming: a failed
   check gives NaN with a quality below ``min_quality``; positions are never invented.

Long smears (core.tracking.smear: a path over ``LONG_BLUR`` of the ROI) start step 1 from a
periodic motion fitted to the smears, and search a bank of its kernels; the plate is kept only
if its priming track passes ``smear_verdict``, else every frame is NaN. A mark still over the
priming frames learns no plate: the centroid measures it, or core.tracking.still on a texture;
one moving less than its own width neither (core.tracking.small). Once such a mark moves, the
next ``prime_frames`` frames are gathered and it is learned again from them (``_gather``).
On a plain plate an asymmetric mark (an L, a triangle) is placed at its contrast centroid
(core.tracking.area_centre: an offset measured over the priming frames; none for a symmetric
mark).
"""

import copy
import dataclasses
import math

import numpy as np

from microball_ros.core.tracking.area_centre import area_offset
from microball_ros.core.tracking.background import StaticBackground
from microball_ros.core.tracking.centroid import CentroidMarkTracker
from microball_ros.core.tracking.config import TrackerConfig
from microball_ros.core.tracking.gains import MarkGains
from microball_ros.core.tracking.image import Roi, check_roi, roi_region
from microball_ros.core.tracking.plate_learn import LearnedPlate, learn_plate
from microball_ros.core.tracking.plate_model import PlateModel, grid_window
from microball_ros.core.tracking.plate_rows import edge_offset
from microball_ros.core.tracking.plate_search import plate_level, search_plate
from microball_ros.core.tracking.predict import MotionPredictor
from microball_ros.core.tracking.priming import (
    TEXTURE_SCORE,
    plain_verdict,
    row_flat_field,
    scatter_scale,
    texture_score,
)
from microball_ros.core.tracking.profile import (
    LIGHT_FLANK,
    default_saturation,
    glint_columns,
    light_level,
)
from microball_ros.core.tracking.results import MarkMeasurement, with_centre
from microball_ros.core.tracking.rows_guard import RowsGuard
from microball_ros.core.tracking.small import SmallMotion, moves_little
from microball_ros.core.tracking.smear import (
    PeriodicMotion,
    fit_motion,
    least_smeared,
    path_range,
    predicted_kernel,
    smear_start,
    smear_verdict,
)
from microball_ros.core.tracking.still import REACH, StillMark, is_still

EDGE_PX = 1.0  # px beyond the mark's half-width (quarter depth) that must be in the ROI
GATHER_BYTES = 2 ** 28  # a still mark that moved is learned again if its frames fit in this
RESTART_BLURS = (0.0, 2.0, 4.0, 8.0)  # fits restarted from these blurs when one fails
# A plain plate's plate is kept if it reports every frame the centroid does over priming and
# is priming.steadier than it by this margin.
PLAIN_MARGIN = 0.95
SMEAR_MOVE = 0.25  # a long smear's fit may move this much of the blur from the search's start
REACQUIRE_MATCH = 1.4  # after a loss, a poorer fit may be false (a shadow leaving: 2.7 px off)
RELIGHT = 8.0  # px: a match this far from the prediction has the light fitted again beside it


class PlateMarkTracker:
    """Track one mark, with the plate's texture learned when it has one (see the module).

    Same interface as CentroidMarkTracker; until ``prime`` has found a textured plate (and
    on plain plates) it measures exactly like it.
    """

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
        self.weights: np.ndarray | None = None
        self.static: np.ndarray | None = None
        self.flat: np.ndarray | None = None
        self._background: StaticBackground | None = None
        self._half = self._outer = self._whole = 8.0  # px: its half-width, its reach in D
        self._full: PlateModel | None = None
        self._shift, self._rms = 0.0, 1.0  # D's origin in the whole plate; priming's residual
        self._kernel: tuple[float, float] | None = None  # the last measured (blur, curve)
        self._predictor = MotionPredictor()
        self._gains = MarkGains(int(self.config.area_history))  # and the jump guard
        self._motion: PeriodicMotion | None = None  # a long smear's motion, from priming
        self._periodic: PeriodicMotion | None = None  # from a textured plate's priming track
        self._refused = False  # a long smear whose plate could not be learned: all NaN
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
        return self.plate is not None and self.texture >= TEXTURE_SCORE

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
        return math.nan if self.texture >= TEXTURE_SCORE else self._area[1]

    def reset(self) -> None:
        """Forget the track (what was learned is kept)."""
        self._predictor.reset()
        self._gains.reset()
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
        self._fallback.prime(frames)
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
        still = is_still(centroid[1], x)
        # Without the pattern fixed in the image (a dot of dust deeper than the mark in their
        # mean was taken for a still mark); a mark still over the priming frames is in that
        # pattern, which the centroid then does not keep
        self._still = StillMark.learn(regions, self.polarity, int(self.config.pad_px), still)
        # A mark moving less than its width is in the median the plate's learning starts from
        small = self._still is None and not still and moves_little(centroid[1], x)
        if small:
            self._still = SmallMotion.learn(regions, self.polarity, int(self.config.pad_px))
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
        if self.texture < TEXTURE_SCORE and self._still is None and not self._refused:
            # core.tracking.area_centre (a still mark's own module puts it: on a texture)
            self._area = area_offset(regions, centroid[0], np.array(
                [m.extent_px for m in centroid[1]]), self.polarity, int(self.config.pad_px))
        self.reset()

    def _prime_textured(self, regions, frames, polarity: str) -> None:
        """On a textured plate, learn the plate (a long smear's, or relearned) and calibrate."""
        start = smear_start(regions, polarity, self.exposure_fraction)
        self._motion = None if start is None else start[4]  # a long smear (smear.py)
        self._offset_sigma = math.nan  # until the edges measure it (a long smear's: never)
        self._learn(regions, start)
        if self._motion is not None:
            self._check_smear(frames)
        elif self.plate is not None:
            self._relearn(regions, frames)
            tracked = self._track_priming(frames, self.measure)
            self._offset, self._asymmetry, self._offset_sigma = edge_offset(
                regions if self.flat is None else [r / self.flat for r in regions],
                self.weights, tracked[0], tracked[2], self._outer,
                1.0 if polarity == 'dark' else -1.0)
            self._calibrate(tracked)

    def _calibrate(self, tracked) -> None:
        """Scale the fit's standard errors to the scatter of the track over the priming frames.

        ``tracked``: the priming frames' ``_track_priming`` with this plate; the scale is
        ``scatter_scale``'s.
        """
        positions, found, _ = tracked
        self._gains.learn_spread()  # from the plate's last pass over the priming frames
        if self.texture >= TEXTURE_SCORE and self._motion is None:  # its kernels, from now
            self._periodic = fit_motion(positions, self.exposure_fraction)
        motion = self._motion or self._periodic
        if motion is not None:  # the first frames' search gated too (core.tracking.predict)
            self._predictor.use_frequency(motion.omega, motion.spread)
        self._sigma_scale = scatter_scale(positions, found)

    def _check_smear(self, frames) -> None:
        """Keep a long smear's plate if ``smear_verdict`` trusts it; else refuse every frame."""
        tracked = self._track_priming(frames, self.measure) if self.plate is not None else None
        centroid = self._track_priming(frames, self._fallback.measure)[0]
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
        for frame in frames:
            found.append(measure(frame))
            known = found[-1].valid and self._kernel is not None and measure == self.measure
            kernels.append(self._kernel if known else (math.nan, math.nan))
        self.reset()
        return (np.array([m.position_px - x if m.valid else math.nan for m in found]), found,
                np.array(kernels, dtype=float))

    def _prime_plain(self, regions, frames, tracked) -> None:
        """On a plain plate, learn the plate and keep it if it tracks better than the centroid.

        ``tracked``: the centroid's ``_track_priming``. The plate tracks the priming frames
        too, and is kept and offset as ``priming.plain_verdict`` says (``PLAIN_MARGIN``). The
        mark's rows and row weights are learned from the plate's track (``mark_rows``).
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
        keep, self.jitter, offset = plain_verdict(centroid, reference, tracked[0], tracked[1],
                                                  PLAIN_MARGIN)
        if not keep:
            self._forget()
            return
        self._offset, self._offset_sigma = offset
        self._calibrate(tracked)

    def _forget(self) -> None:
        """Drop a learned plate: every frame is measured by the centroid tracker again."""
        self.plate = self._full = self._motion = self._periodic = None
        self.weights = self.static = self.flat = None
        self._half = self._outer = self._whole = 8.0
        self._shift, self._rms, self._sigma_scale = 0.0, 1.0, 1.0
        self._offset, self._asymmetry, self._still = 0.0, math.nan, None
        self._offset_sigma = 0.0
        self._still_at = None
        self._gains.forget_spread()
        self._guard.forget()
        self._predictor.use_frequency(math.nan, 0.0)
        self._refused = False
        self.reset()

    def _relearn(self, regions, frames) -> None:
        """Learn the plate again from the positions and kernels the learned plate measures.

        The first positions (dip centroids) can be pixels off on a texture; the rounds of the
        solver then stop short of the plate. Measured with the first plate (search and full
        fit), the positions start within a fraction of a pixel, so the second plate is sharp.
        Kept only if it fits the frames better (median residual).
        """
        positions, _, kernels = self._track_priming(frames, self.measure)
        positions[np.isnan(kernels[:, 0])] = np.nan
        if np.count_nonzero(np.isfinite(positions)) < 8 or self.polarity is None:
            return
        spans = np.array([self._span(kernel[0], kernel) for kernel in kernels])  # NaN: none
        flat = row_flat_field(regions, self.weights, positions, spans)
        learned = learn_plate(regions if flat is None else [r / flat for r in regions],
                              self.polarity, self.config, self.exposure_fraction,
                              self._motion is not None, (positions, kernels))
        if learned is not None and learned.rms <= self._rms:
            learned.flat = flat
            self._use(learned)

    def _learn(self, regions, start=None, found=None) -> None:
        """Learn the plate (core.tracking.plate_learn); leave ``plate`` None on failure.

        ``start``: (positions, kernels) per frame to start the solver from (NaN: unknown),
        instead of the dip centroids and kernels from neighbouring frames; ``found``: the
        centroid's positions, frames whose dip centroid is far off them left out.
        """
        if self.polarity is None:
            return
        learned = learn_plate(regions, self.polarity, self.config, self.exposure_fraction,
                              self._motion is not None, start, found)
        if learned is None:
            self.plate = None
        else:
            self._use(learned)

    def _use(self, learned: LearnedPlate) -> None:
        """Measure with the plate ``learned`` from now on."""
        self.plate, self._full, self._shift = learned.plate, learned.full, learned.shift
        self._half, self._outer, self._whole = learned.half, learned.outer, learned.whole
        self.weights, self.static, self.flat = learned.weights, learned.static, learned.flat
        self._rms = learned.rms

    def _deficit(self, profile, center=math.nan, extent=0.0, kernel=None):
        """Return the deficit against the static field and this frame's light; None if dark.

        With a centre (the mark's column, predicted or found) the light is fitted to the
        profile over the static field and over the whole learned plate placed there (its
        texture is known, so only the light is left), outside ``extent`` around the mark.
        """
        ratio = profile / self.static
        sign = 1.0 if self.polarity == 'dark' else -1.0
        plate, w = ratio, self.roi[2]
        if self._full is not None and math.isfinite(center):  # the learned plate, smeared
            plate = ratio / plate_level(self._full, center - self._shift, sign, kernel, w)
        level = light_level(plate, self.polarity, center, extent,
                            flank=LIGHT_FLANK if math.isfinite(center) else None,
                            noise=self._rms)
        if level is None:
            return None
        return sign * (1.0 - ratio / level)

    def _span(self, blur, kernel):
        """Return the width (px) the smeared mark can cover: the light is fitted outside it."""
        curve = abs(kernel[1]) if kernel is not None else 0.0
        return 2.0 * (self._outer + 0.5 * abs(blur) + 0.25 * curve) + 8.0

    # -- a frame ---------------------------------------------------------------------------
    def measure(self, frame: np.ndarray) -> MarkMeasurement:
        """Measure the mark in one frame (2-D array in DN) and return a MarkMeasurement.

        An asymmetric mark's position is its contrast centroid (core.tracking.area_centre).
        """
        found = self._measure(frame)
        offset, sigma = self._area
        if offset == 0.0 or not found.valid:
            return found
        return dataclasses.replace(found, position_px=found.position_px + offset,
                                   sigma_px=with_centre(found.sigma_px, sigma))

    def _measure(self, frame: np.ndarray) -> MarkMeasurement:
        """Measure the mark in one frame as ``measure`` (before ``area_offset``)."""
        if self._refused:
            return self._invalid('long smear on a textured plate not learned')
        plate = self.plate
        if self._still is not None and not self._moved:
            found = self._still.measure(self._region(frame),
                                        self.roi[0])
            if found.reason != 'moved':
                return found
            self._start_gathering(frame)  # it moves: the centroid measures it until learned
        if self._gathered is not None:
            return self._gather(frame)
        if plate is None or self.weights is None:
            found = self._fallback.measure(frame)
            if found.valid and self._sigma_scale != 1.0:
                found = dataclasses.replace(found, sigma_px=found.sigma_px * self._sigma_scale)
            if self._still_at is not None and not self._moved and found.valid and abs(
                    found.position_px - self.roi[0] - self._still_at) > REACH:
                self._start_gathering(frame)  # a still mark on a plain plate moves
                if self._gathered is not None:
                    self._gathered.append(frame)
            return found
        # The learned plate (see the module).
        cfg = self.config
        region = self._region(frame)
        if self.flat is not None:
            region = region / self.flat
        profile = self.weights @ region.astype(np.float64)
        if not np.all(np.isfinite(profile)):
            return self._invalid('non-finite pixels')
        saturation = (cfg.saturation_level if cfg.saturation_level is not None
                      else default_saturation(region.dtype))
        if saturation is not None and profile.max() >= saturation:
            return self._invalid('saturated')
        # A dark mark never saturates a pixel: on a plate that did not while priming, a
        # saturated one is a glint riding beside it, which the fit leaves out rather than
        # refusing the frame for its residual
        self._clipped = None if (self.polarity != 'dark' or self.weights is None
                                 or self._saturates) else (
            glint_columns(roi_region(frame, self.roi, self.name), self.weights > 0,
                          cfg.saturation_level))
        prediction, lost = self._predictor.predict(), self._predictor.lost()
        kernel = predicted_kernel(prediction, self._motion or self._periodic,
                                  self.exposure_fraction)
        gated = prediction if prediction is not None and math.isfinite(prediction.spread) \
            else None
        if gated is not None:
            blur = kernel[0] if kernel is not None else 0.0
            d = self._deficit(profile, gated.column, self._span(blur, kernel), kernel)
        else:
            d = self._deficit(profile, math.nan, 0.0)
        if d is None:
            return self._invalid('too dark')
        failure = None
        for match in search_plate(plate, d, gated, kernel, self._motion or self._periodic,
                                  self._motion is not None, self._half + cfg.pad_px):
            # A next-best match refused leaves no trace in the guards (the best's does, as ever)
            saved = None if failure is None else (copy.deepcopy(self._gains), len(
                self._guard.log or ()))
            outcome = self._fit_found(profile, region, d, match, gated, lost,
                                      restart=failure is None)
            if isinstance(outcome, MarkMeasurement):
                return outcome
            if saved is None:
                failure = outcome
            else:
                self._gains = saved[0]
                if self._guard.log is not None:
                    del self._guard.log[saved[1]:]
        return self._invalid(*(failure or ('mark at the ROI edge',)))

    def _fit_found(self, profile, region, d, found, gated, lost, restart=True):
        """Fit the plate where the search found it and check the fit (see the module).

        Returns the MarkMeasurement, or why not: (reason, quality, contrast) for ``_invalid``.
        ``restart``: a poor fit is restarted from all ``RESTART_BLURS`` (else from the first).
        """
        cfg, plate, w = self.config, self.plate, self.roi[2]
        assert plate is not None
        reach = self._half + cfg.pad_px
        start, blur, curve = found
        if gated is None or abs(start - gated.column) > RELIGHT:
            # The light fitted beside where the mark is (not where it was predicted)
            d = self._deficit(profile, start, self._span(blur, (blur, curve)),
                              (blur, curve))
            if d is None:
                return ('too dark', 0.0, math.nan)
        size = plate.size
        window, valid, j0 = grid_window(d, start, size, size // 2)
        if self._clipped is not None:  # a glint's columns are no data
            index = np.arange(j0, j0 + size)
            inside = (index >= 0) & (index < w)
            valid[inside] &= ~self._clipped[index[inside]]
            window[~valid] = 0.0
        tolerance = REACQUIRE_MATCH if lost else cfg.match_tolerance + 0.5
        # Restarted from short kernels if poor; then, on a plain plate only, fitted without
        # what passes beside the mark (a whole-frame smear on a speckle often fits that poorly:
        # speckle_full's stator went 0.099 -> 0.106 px RMS).
        fit = plate.fit_frame(window, valid, start - j0 - plate.center, blur, curve, reach + 8.0,
                              tolerance * self._rms,
                              RESTART_BLURS if restart else RESTART_BLURS[:1],
                              self._rms if self.texture < TEXTURE_SCORE else None)
        if fit is None:
            return ('no match', 0.0, math.nan)
        delta, blur, curve, gain, _, rms, sigma, sigma_gain = fit
        position = delta + j0 + plate.center
        peak = gain * float(plate.values.max())
        first, last = (position + end for end in path_range(blur, curve, self._half + EDGE_PX))
        # A smear on a known motion may move further from the search's start; so may one
        # searched without a prediction on a plain plate (nothing else there to match), and
        # one found by a long kernel (its match is as long, wherever the fit ends).
        smeared = self._motion or self._periodic or (gated is None
                                                     and self.texture < TEXTURE_SCORE)
        moved = 4.0 + SMEAR_MOVE * max(blur, found[1]) if smeared else 4.0
        if abs(position - start) > moved or not math.isfinite(position):
            return ('no match', 0.0, peak)
        if lost and rms > REACQUIRE_MATCH * self._rms:  # after a loss: maybe a false match
            return ('no match', 0.0, peak)
        if first < 1 or last > w - 2:
            return ('mark at the ROI edge', 0.0, peak)
        around = path_range(blur, curve, self._whole)
        if self._guard.hidden(region, position + around[0], position + around[1],
                              self.polarity or 'dark'):
            return ('mark partly hidden', 0.0, peak)
        reference = self._gains.judge(gain)  # core.tracking.gains: None if it jumped
        if reference is None:
            return ('mark area changed', 0.0, peak)
        # The gain's own noise widens the tolerance (a faint mark's gain is noisy).
        snr = peak * math.sqrt(cfg.smoothing_px) / max(rms, 1e-12)
        quality, reason = cfg.quality(snr, gain / reference, math.hypot(
            cfg.area_tolerance, 3.0 * sigma_gain / reference), rms / self._rms)
        if quality < cfg.min_quality or snr < cfg.min_snr:
            return (reason, quality, peak)
        self._predictor.add(position)
        self._kernel = (blur, curve)
        return MarkMeasurement(position + self.roi[0] + self._offset, quality,
                               sigma_px=with_centre(sigma * self._sigma_scale,
                                                    self._offset_sigma),
                               contrast=peak, extent_px=last - first)

    def _start_gathering(self, frame) -> None:
        """Note that a still mark moved; gather frames if ``GATHER_BYTES`` holds them."""
        self._moved = True
        fits = frame.nbytes * max(int(self.config.prime_frames), 12) <= GATHER_BYTES
        self._gathered = [] if fits else None

    def _gather(self, frame) -> MarkMeasurement:
        """Measure ``frame`` by the centroid, gathering frames to learn the moving mark from.

        A mark still (or moving little) over the priming frames that then moves (a servo
        started after the camera, a slider that slips) is learned again from the
        ``config.prime_frames`` frames after it moved, which are then measured again with what
        was learned: ``revised`` (their measurements, in order, before this frame's; a batch
        run replaces what it had). A node has published them already.
        """
        assert self._gathered is not None
        self._gathered.append(frame)
        if len(self._gathered) < max(int(self.config.prime_frames), 12):
            return self._fallback.measure(frame)
        frames, self._gathered = self._gathered, None
        self.prime(frames)
        found = [self.measure(each) for each in frames]
        self.revised = found[:-1]
        return found[-1]

    def _invalid(self, reason, quality=0.0, contrast=math.nan):
        self._predictor.add(math.nan)
        self._kernel = None
        return MarkMeasurement(math.nan, quality, contrast=contrast, reason=reason)
