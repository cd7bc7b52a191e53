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
partly hidden'. Else every frame is the centroid's, unless the centroid scatters about the
motion far over its standard errors while the plate does not (``priming.pulled``: a texture
too faint to score pulls it, up to 2.3 px): the plate is then learned as a textured one.
A plate refused though steadier than the centroid leaves it, in its standard errors, what
the two tracks' difference holds beyond theirs (``priming.unexplained``: a pull that follows
the motion, which the scatter about it does not show).

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
   look like a covered mark; a flank whose light is far from the light at the mark in the
   last frames, under a tool held beside it, gives way to the other); then searches the mark
   by a matched filter of ``D`` smeared by the predicted motion (a sinusoid of the priming
   track's frequency), gated around the predicted position (``MotionPredictor``; from the
   seventh frame on, by the priming track's frequency until its recurrence has the frames it
   needs) so texture dips never win; after a loss over the whole ROI
   (plate_search.search_kernels), where a first fit poorer than priming's is refused and the
   ``plate_search.CANDIDATES`` best matches are tried in turn (a particle near the mark
   matches better than the mark; after priming, those shaped most like the mark first: a
   tool beside its path matches better at several places). A match ``RELIGHT`` px or more
   from where it was predicted (or without a prediction) has the light fitted again beside it;
3. fits ``s``, ``L`` and ``Q`` (Gauss-Newton, ``c`` and ``g`` solved linearly, with fallbacks
   for a poor fit: ``PlateModel.fit_frame``): the texture, common to data and model, is signal;
   columns of the other polarity or deeper than the mark (a tool beside it) are left out,
   and the mark is partly hidden if they reach its core;
4. checks the mark's path clear of the ROI edges, its contrast ``g`` against recent frames
   (a covered mark loses contrast; a jump of it, something passing beside the mark, is refused:
   core.tracking.gains) and the fit's residual against the residuals while priming: a failed
   check gives NaN with a quality below ``min_quality``; positions are never invented. A frame
   refused for its residual or its gain while its residual is poor (a slider breaking away
   mid-exposure traces no quadratic path) is fitted again with a kernel of any shape
   (core.tracking.free_kernel) and judged again by it, if that puts the mark near where the
   quadratic fit did; the next frame is then predicted as after a loss.

Long smears (core.tracking.smear: a path over ``LONG_BLUR`` of the ROI) start step 1 from a
periodic motion fitted to the smears, and search a bank of its kernels; the plate is kept only
if its priming track passes ``smear_verdict``, else every frame is NaN. Their kernels are the
motion's own paths, a sinusoid's (template.path_knots), not quadratic ones, and so are those
of any plate whose priming motion turns over ``plate_priming.PATH_TURN`` in an exposure. A
mark still over the priming frames learns no plate: the centroid measures it, or
core.tracking.still on a texture; one moving less than its own width neither
(core.tracking.small). Once such a mark moves, the next ``prime_frames`` frames are gathered
and it is learned again from them (``_gather``). On a plain plate an asymmetric mark (an L,
a triangle) is placed at its contrast centroid (core.tracking.area_centre: an offset measured
over the priming frames; none for a symmetric mark).
"""

import copy
import dataclasses
import math
import statistics

import numpy as np

from microball_ros.core.tracking.free_kernel import fit_free_kernel
from microball_ros.core.tracking.image import roi_region
from microball_ros.core.tracking.plate_model import grid_window
from microball_ros.core.tracking.plate_priming import PlatePriming
from microball_ros.core.tracking.plate_search import plate_level, search_plate
from microball_ros.core.tracking.profile import (
    LIGHT_FLANK,
    glint_columns,
    light_level,
    saturation_level,
)
from microball_ros.core.tracking.results import MarkMeasurement, with_centre
from microball_ros.core.tracking.smear import path_range, predicted_kernel
from microball_ros.core.tracking.still import REACH

EDGE_PX = 1.0  # px beyond the mark's half-width (quarter depth) that must be in the ROI
GATHER_BYTES = 2 ** 28  # a still mark that moved is learned again if its frames fit in this
RESTART_BLURS = (0.0, 2.0, 4.0, 8.0)  # fits restarted from these blurs when one fails
SMEAR_MOVE = 0.25  # a long smear's fit may move this much of the blur from the search's start
REACQUIRE_MATCH = 1.4  # after a loss, a poorer fit may be false (a shadow leaving: 2.7 px off)
RELIGHT = 8.0  # px: a match this far from the prediction has the light fitted again beside it
# A free kernel's mean within this many standard errors of the quadratic fit's position, and
# FREE_SLACK of its path's length, at most FREE_SLACK_MOST px (a quadratic path misplaces a
# breakaway: 0.4-0.5 px of 7-8; a long smear's would allow pixels)
FREE_AGREE = 3.0
FREE_SLACK = 0.1
FREE_SLACK_MOST = 1.0
# Columns whose deficit is under OPPOSITE times the plate's least (or 0), or over DEEPER
# times its most, by OPPOSITE_NOISE times priming's residual, at least OPPOSITE_RUN of them, are
# something else: left out of the fit with OPPOSITE_GUARD columns beside them; over the
# model's CORE, the mark is hidden
OPPOSITE, DEEPER, OPPOSITE_NOISE, OPPOSITE_RUN, OPPOSITE_GUARD, CORE = 3.0, 1.3, 6.0, 3, 2, 0.25


class PlateMarkTracker(PlatePriming):
    """Track one mark, with the plate's texture learned when it has one (see the module).

    Same interface as CentroidMarkTracker; until ``prime`` has found a textured plate (and
    on plain plates) it measures exactly like it. Its state and ``prime`` are
    core.tracking.plate_priming's; here each frame is measured.
    """

    # -- a frame ---------------------------------------------------------------------------

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
        expected = statistics.median(self._lights) if self._lights else None
        level = light_level(plate, self.polarity, center, extent,
                            flank=LIGHT_FLANK if math.isfinite(center) else None,
                            noise=self._rms, expected=expected, both=not self.priming)
        if level is None:
            return None
        if math.isfinite(center):
            self._light = float(level[int(np.clip(round(center), 0, w - 1))])
        return sign * (1.0 - ratio / level)


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
            if found.valid and (self._sigma_scale != 1.0 or self._unexplained):
                found = dataclasses.replace(found, sigma_px=math.hypot(
                    found.sigma_px * self._sigma_scale, self._unexplained))
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
        saturation = saturation_level(region.dtype, cfg.saturation_level)
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
                                  self.exposure_fraction,
                                  0.0 if self.plate is None else self.plate.kappa)
        gated = prediction if prediction is not None and math.isfinite(prediction.spread) \
            else None
        self._predicted_blur = math.nan
        if kernel is not None and gated is not None:  # its blur as the fits have had it
            self._predicted_blur = kernel[0]
            kernel = (kernel[0] * self._blur_scale.scale, kernel[1])
        if gated is not None:
            blur = kernel[0] if kernel is not None else 0.0
            d = self._deficit(profile, gated.column, self._span(blur, kernel), kernel)
        else:
            d = self._deficit(profile, math.nan, 0.0)
        if d is None:
            return self._invalid('too dark')
        failure = None
        # After priming, a loss's candidates are ordered by their shape too (plate_search): a
        # tool beside the mark's path matches better than the mark at several places. While
        # priming, by their match alone (t18 and t20 of an independent set: 0.22 -> 0.26 and
        # 0.021 -> 0.036 px RMS for one slider, with the plate learned from other frames).
        for match in search_plate(plate, d, gated, kernel, self._motion or self._periodic,
                                  self._motion is not None, self._half + cfg.pad_px,
                                  shaped=not self.priming):
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
        # Something beside the mark of the other polarity (a dark tool beside a bright mark:
        # far below the plate's least deficit) or deeper than the mark anywhere (a dark tool
        # beside a dark mark) is no part of it: left out, unless it reaches the mark's core
        # (then the mark is partly hidden)
        margin = OPPOSITE_NOISE * self._rms
        other = valid & ((window < OPPOSITE * min(float(plate.values.min()), 0.0) - margin)
                         | (window > DEEPER * float(plate.values.max()) + margin))
        if np.count_nonzero(other) >= OPPOSITE_RUN:
            model = plate.model(start - j0 - plate.center, blur, curve)
            if np.any(other & (model > CORE * float(model.max()))):
                return ('mark partly hidden', 0.0, math.nan)
            valid &= ~(np.convolve(other, np.ones(2 * OPPOSITE_GUARD + 1), 'same') > 0)
            window[~valid] = 0.0
        tolerance = REACQUIRE_MATCH if lost else cfg.match_tolerance + 0.5
        noise = self._noise()
        # Restarted from short kernels if poor; then, on a plain plate only, fitted without
        # what passes beside the mark (a whole-frame smear on a speckle often fits that poorly:
        # speckle_full's stator went 0.099 -> 0.106 px RMS).
        fit = plate.fit_frame(window, valid, start - j0 - plate.center, blur, curve, reach + 8.0,
                              tolerance * noise,
                              RESTART_BLURS if restart else RESTART_BLURS[:1],
                              None if self.on_texture else self._rms)
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
                                                     and not self.on_texture)
        moved = 4.0 + SMEAR_MOVE * max(blur, found[1]) if smeared else 4.0
        if abs(position - start) > moved or not math.isfinite(position):
            return ('no match', 0.0, peak)
        if lost and rms > REACQUIRE_MATCH * noise:  # after a loss: maybe a false match
            return ('no match', 0.0, peak)
        if first < 1 or last > w - 2:
            return ('mark at the ROI edge', 0.0, peak)
        if self._background is not None and self._background.hides(first, last):
            return ('mark partly hidden', 0.0, peak)
        around = path_range(blur, curve, self._whole)
        core = path_range(blur, curve, self._half)
        if self._guard.hidden(region, position + around[0], position + around[1],
                              self.polarity or 'dark', (position + core[0], position + core[1])):
            return ('mark partly hidden', 0.0, peak)
        # A fit no quadratic path explains (a slider breaking away mid-exposure) that would be
        # refused, for its residual or its gain, gets a kernel of any shape (core.tracking.
        # free_kernel), kept if it puts the mark near where the quadratic fit did. Not while
        # priming: what is learned from the priming frames stays as it was (one frame of
        # textured_fps15's priming so kept moved its stator's RMS 0.106 -> 0.110 px).
        poor = rms > cfg.match_tolerance * noise and not self.priming
        gains = copy.deepcopy(self._gains) if poor else None  # as before this frame's judging
        judged = self._judge(gain, rms, sigma_gain, peak)
        kernel: tuple[float, float] | None = (blur, curve)
        if gains is not None and (judged is None or (judged[0] < cfg.min_quality
                                                     and judged[1] == 'poor fit')):
            path = path_range(blur, curve)
            free = fit_free_kernel(plate, window, valid, delta, reach, path)
            slack = min(FREE_SLACK * (path[1] - path[0]), FREE_SLACK_MOST)
            if free is not None and abs(free.delta - delta) <= FREE_AGREE * math.hypot(
                    free.sigma, sigma) + slack:
                self._gains = gains
                judged = self._judge(free.gain, free.rms, sigma_gain, peak)
                position += free.delta - delta
                sigma = free.sigma
                kernel = None  # no quadratic path: priming would learn nothing from it
        if judged is None:
            return ('mark area changed', 0.0, peak)
        quality, reason, snr = judged
        if quality < cfg.min_quality or snr < cfg.min_snr:
            return (reason, quality, peak)
        # A frame no quadratic path fits is no guide to the next: predicted as after a loss
        self._predictor.add(position if kernel is not None else math.nan)
        if kernel is not None:
            self._blur_scale.add(self._predicted_blur, blur)
        if math.isfinite(self._light):
            self._lights.append(self._light)
        self._kernel = kernel
        return MarkMeasurement(position + self.roi[0] + self._offset, quality,
                               sigma_px=with_centre(sigma * self._sigma_scale,
                                                    self._offset_sigma),
                               contrast=peak, extent_px=last - first)

    def _judge(self, gain, rms, sigma_gain, peak):
        """Return a fit's (quality, reason, snr), or None if its gain jumped (core.tracking.gains).

        The gain's own noise (``sigma_gain``) widens the tolerance (a faint mark's is noisy).
        """
        cfg = self.config
        reference = self._gains.judge(gain, 0.0 if self.shadow is None else
                                      self.shadow.gain_slack)
        if reference is None:
            return None
        snr = peak * math.sqrt(cfg.smoothing_px) / max(rms, 1e-12)
        tolerance = math.hypot(cfg.area_tolerance, 3.0 * sigma_gain / reference)
        quality, reason = cfg.quality(snr, gain / reference, tolerance, rms / self._noise())
        return quality, reason, snr

    def _noise(self) -> float:
        """Return the residual a fit of this frame may have from noise alone.

        Priming's residual; in a frame divided by a passing shadow's light (``shadow``, set
        by core.tracking.tracker), with that light's own error added (p12's stator, 0.0035
        and 0.0033: its fits of 0.0061 were refused after a loss, 1.4 times priming's at most).
        """
        if self.shadow is None:
            return self._rms
        return math.hypot(self._rms, self.shadow.error)

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
