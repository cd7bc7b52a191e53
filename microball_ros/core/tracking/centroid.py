"""One mark in one ROI by its deficit profile (the default method): stages, checks, quality.

Owns CentroidMarkTracker (its state and priming: core.tracking.centroid_priming). Per frame
it removes the static background learned on the priming frames (core.tracking.background, if
any), builds the profile and baseline
(core.tracking.profile; the plate's columns that something else darkens, such as a particle
passing, left out of the baseline: ``disturbed``), locates the dip (core.tracking.search: the
strongest one within the mark's reach, ``Reach``, and when it fails a check the next one
there), checks it (signal-to-noise, the mark clear of the ROI edges, no saturation, row
weights like the mark's own, an integrated deficit consistent with recent frames) and fits its
position (core.tracking.subpixel). A failed check gives NaN and a quality below
``min_quality``: positions are never invented. Its state, all from earlier frames in order:
the previous position (to tell a still mark from a moving one), where it was last found and
how far it moved per frame (its reach), the recent integrated deficits (to recognise a partly
hidden mark) and, after the first ``ROW_FRAMES`` frames the mark was found in, its rows and
row weights (the plates move along x only, so they do not change; a frame whose rows depart
from them shows a mark partly hidden or something dark beside it). Rows learned over the
priming frames are kept from the first frame on (``reset`` keeps them): until they are known,
every row of the ROI counts, and a glint or a dark patch above or below the mark can join its
dip.

A smear longer than ``LONG_SMEAR`` of the ROI (15 fps at a whole-frame exposure) leaves too
little plate in its own frame for a baseline: it is measured against the plain plate learned
while priming (core.tracking.background.StaticPlate) times the frame's gain, its window runs
to the noise, and a window that cuts the smear rejects the frame. That plate is learned only
when the priming frames, each with its own baseline, show long smears or lose frames
(``_smears_long``), and in the second case kept only if it loses fewer of them.
"""

from collections import deque
import functools
import math

import numpy as np

from microball_ros.core.tracking.centroid_priming import (
    LONG_SMEAR,
    ROW_FRAMES,
    CentroidPriming,
)
from microball_ros.core.tracking.image import roi_region
from microball_ros.core.tracking.profile import (
    column_profile,
    deficit_noise,
    disturbed,
    plate_row_weights,
    polarity_of,
    polarity_of_pixels,
    relative_deficit,
    row_weights,
    saturation_level,
    smooth,
)
from microball_ros.core.tracking.results import MarkMeasurement
from microball_ros.core.tracking.rows_guard import mark_rows
from microball_ros.core.tracking.search import Dip, locate, locate_within
from microball_ros.core.tracking.subpixel import deficit_centroid, refine_position

# A long smear's window runs to SMEAR_THRESHOLD of the peak (or the noise), and a deficit
# outside it over CUT_FRACTION of the area inside rejects the frame (centroid_priming.LONG_SMEAR).
SMEAR_THRESHOLD = 0.01
SHORT_FIRST = 0.6
CUT_FRACTION = 0.05


def cut_smear(deficit: np.ndarray, lo: int, hi: int, pad: int, noise: float) -> bool:
    """Return True if a deficit against the plate lies outside columns lo - pad..hi + pad.

    Against the plate the deficit is the mark's alone (and noise): outside the window it
    sums to more than ``CUT_FRACTION`` of the area inside plus three times its noise only
    when the window cuts the smear (or something else dark is in the ROI).
    """
    inside = float(deficit[max(lo - pad, 0):hi + pad + 1].sum())
    outside = float(deficit.sum()) - inside
    return abs(outside) > CUT_FRACTION * max(inside, 0.0) + 3.0 * noise * math.sqrt(
        deficit.size)



class CentroidMarkTracker(CentroidPriming):
    """Track one mark inside one ROI, frame by frame (its state and ``prime``: the base's)."""

    def _invalid(self, reason, contrast=float('nan')):
        self._previous = None
        return MarkMeasurement(float('nan'), 0.0, contrast=contrast, reason=reason)

    def _deficit(self, profile, keep, polarity):
        """Return the deficit against a baseline fitted on ``keep``, or None if too dark."""
        baseline = self._baseline.fit(profile, keep)
        if baseline.min() < self.config.min_baseline:
            return None
        return relative_deficit(profile, baseline, polarity)

    def measure(self, frame: np.ndarray) -> MarkMeasurement:
        """Measure the mark in one frame (2-D array in DN) and return a MarkMeasurement.

        Before the polarity is known ('auto') it is guessed from the column profile, else
        from the ROI's pixels; when neither is clear, both are tried and the better is kept.
        """
        self._reach.since += 1
        self._gate = self._reach.window(self.roi[0])
        if self.polarity is not None:
            return self._measure(frame, self.polarity)
        x, y, w, h = self.roi
        if frame.ndim == 2 and x + w <= frame.shape[1] and y + h <= frame.shape[0]:
            region = frame[y:y + h, x:x + w]
            guess = polarity_of(column_profile(region)) or polarity_of_pixels(region)
            if guess is not None:
                measurement = self._measure(frame, guess)
                if measurement.valid:
                    self.polarity = guess
                return measurement
        state = (deque(self._areas, maxlen=self._areas.maxlen), self._previous, self._reach)
        results = {}
        for polarity in ('dark', 'bright'):
            self._areas, self._previous = deque(state[0], maxlen=state[0].maxlen), state[1]
            self._reach = state[2].copy()
            results[polarity] = (self._measure(frame, polarity), self._areas, self._previous,
                                 self._reach)
        polarity = max(results, key=lambda p: (results[p][0].valid, results[p][0].quality,
                                               results[p][0].contrast
                                               if math.isfinite(results[p][0].contrast) else 0))
        measurement, self._areas, self._previous, self._reach = results[polarity]
        if measurement.valid:
            self.polarity = polarity
        return measurement

    def _measure(self, frame: np.ndarray, polarity: str) -> MarkMeasurement:
        """Measure the mark in one frame (2-D array in DN) and return a MarkMeasurement.

        When the dip taken fails a check (something else dark, deeper than the mark: its rows
        or its area are not the mark's), the strongest other dip within reach at least
        ``Reach.least`` deep is measured instead, if there is one.
        """
        self._exclude = self._taken = None
        areas = deque(self._areas, maxlen=self._areas.maxlen)
        found = self._measure_dip(frame, polarity)
        if found.valid or self._taken is None or not self._reach.peaks:
            return found
        first = self._areas
        guard = int(self.config.pad_px) + int(self.config.smoothing_px)
        self._exclude = (self._taken[0] - guard, self._taken[1] + guard)
        self._areas = areas
        other = self._measure_dip(frame, polarity)
        self._exclude = None
        if other.valid:
            return other
        self._areas = first  # as if only the first dip had been measured
        return found

    def _measure_dip(self, frame: np.ndarray, polarity: str) -> MarkMeasurement:
        """Measure the mark in one frame (2-D array in DN) and return a MarkMeasurement.

        Quality = (1 - exp(-(snr / snr_scale)^2)) * exp(-(area ratio - 1)^2 / (2 tol^2)) (tol:
        area_tolerance and 3 sigma of the area's noise in quadrature), 0 after
        a failed check (too dark, saturated, mark at the ROI edge, no mark); the position is NaN
        whenever the quality is below ``min_quality``.
        """
        cfg = self.config
        x, y, w, h = self.roi
        full = roi_region(frame, self.roi, self.name)
        rows = slice(None) if self._rows is None else self._rows
        region = full[rows]
        profile = column_profile(region)
        if not np.all(np.isfinite(profile)):
            return self._invalid('non-finite pixels')
        saturation = saturation_level(region.dtype, cfg.saturation_level)
        if saturation is not None and profile.max() >= saturation:
            return self._invalid('saturated')
        raw = region
        if self._background.inverse is not None:
            region = self._background.apply(full)[rows]
            profile = column_profile(region)
        pad = int(cfg.pad_px)
        guard = pad + int(cfg.smoothing_px)
        if self._plate.image is not None:
            smear = self._against_plate(profile, None, polarity, shortest=LONG_SMEAR * w)
            if (smear is not None and (smear[3] - smear[2] + 1 > LONG_SMEAR * w or smear[5])
                    and self._plate.seen(smear[2], smear[3])):
                # A smear too long for a baseline from the frame's own columns, or one the
                # located dip holds only part of (the rest hidden, or something else dark).
                deficit, keep, lo, hi, gain, _ = smear
                return self._finish(region, raw, deficit, keep, lo, hi, polarity, saturation,
                                    gain)
        # Columns far beyond the plate on the other side (a dark tool in a bright mark's ROI)
        # are no plate: the baseline is not fitted to them
        middle = float(np.median(profile))
        beyond = profile < 0.5 * middle if polarity == 'bright' else profile > 2.0 * middle
        far = beyond if np.count_nonzero(beyond) else None
        baseline = self._baseline.envelope(profile, polarity, far)
        if baseline.min() < cfg.min_baseline:
            return self._invalid('too dark')
        deficit = relative_deficit(profile, baseline, polarity)
        dip = self._locate(deficit, 0.0, 0.25, 0)
        if dip is None:
            return self._invalid('no other dip')
        _, _, lo, hi = dip
        margin = guard + (hi - lo) // 4
        # Columns something else darkens (``disturbed``: a dip beside the mark) stay out
        off = np.ones(w, dtype=bool)
        off[max(lo - margin, 0):hi + margin + 1] = False
        refit = functools.partial(self._deficit, profile, polarity=polarity)  # on given columns
        off = disturbed(deficit, off, refit)
        if far is not None:
            off |= far
        for attempt in range(3):
            # Plain plate = everything outside the mark and a guard band; refit on it twice.
            keep = ~off
            keep[max(lo - margin, 0):hi + margin + 1] = False
            if np.count_nonzero(keep) < 12:
                flat = float(np.max(np.abs(deficit))) < cfg.min_depth
                return self._invalid('low contrast' if flat else 'mark fills the ROI (widen it)')
            if attempt == 2:
                break
            deficit = self._deficit(profile, keep, polarity)
            if deficit is None:
                return self._invalid('too dark')
            if attempt == 0:  # against the fitted baseline, what the envelope hid
                off |= disturbed(deficit, keep, refit)
            dip = self._locate(deficit, 0.0, cfg.threshold, cfg.merge_gap_px)
            if dip is None:
                return self._invalid('no other dip')
            _, _, lo, hi = dip
            margin = guard
        return self._finish(region, raw, deficit, keep, lo, hi, polarity, saturation, None)

    def _locate(self, deficit, noise, fraction, gap) -> Dip | None:
        """Return the mark's dip: the strongest one, within reach and not excluded (``Reach``).

        A deeper dip out of reach gives way to one within it at least ``Reach.least`` deep; an
        excluded dip (``_exclude``) to any such other one, else None.
        """
        smoothing = int(self.config.smoothing_px)
        widest = self._reach.widest()
        dip = locate(deficit, noise, fraction, smoothing, gap, widest)
        gate, exclude = self._gate, self._exclude
        if (gate is None or gate[0] <= dip.column <= gate[1]) and (
                exclude is None or not exclude[0] <= dip.column <= exclude[1]):
            return dip
        columns = np.arange(deficit.size)
        allowed = np.ones(deficit.size, dtype=bool)
        if exclude is not None:
            allowed &= (columns < exclude[0]) | (columns > exclude[1])
        if gate is not None:
            allowed &= (columns >= gate[0]) & (columns <= gate[1])
        near = locate_within(deficit, noise, fraction, smoothing, gap, allowed, widest)
        if near is not None and near.peak >= self._reach.least():
            return near
        return None if exclude is not None else dip

    def _against_plate(self, profile, weights, polarity, keep=None, shortest=0.0):
        """Return (deficit, keep, lo, hi, gain, cut) against the learned plate times a gain.

        The gain is fitted on ``keep`` (the columns away from the mark), or found with them:
        from all columns, then (twice) from those outside the located smear and a guard. The
        smear's extent is where the smoothed deficit exceeds three times its noise (the
        plate is the frame's own, less the noise: nothing else is left). None if too dark,
        or if the first extent is shorter than ``SHORT_FIRST`` times ``shortest`` columns (a
        mark for the frame's own baseline: no time spent here). ``cut``: the located smear
        does not hold all the deficit (``cut_smear``).
        """
        cfg = self.config
        rows = slice(None) if self._rows is None else self._rows
        if weights is None:
            if self._plate_rows != rows:
                self._plate_rows, self._plate_mean = rows, self._plate.profile(None, rows)
            plate = self._plate_mean
        else:
            plate = self._plate.profile(weights, rows)
        if plate is None:
            return None
        ratio = profile / plate
        sign = 1.0 if polarity == 'dark' else -1.0
        guard = int(cfg.pad_px) + int(cfg.smoothing_px)
        fixed = keep is not None
        cut = False
        free = keep if fixed else np.ones(profile.size, dtype=bool)
        for _ in range(1 if fixed else 3):
            gain = float(np.mean(ratio[free])) if fixed else float(np.median(ratio[free]))
            if not gain * float(plate.min()) >= cfg.min_baseline:
                return None
            deficit = sign * (1.0 - ratio / gain)
            noise = deficit_noise(deficit, free)
            _, peak, lo, hi = locate(deficit, noise, SMEAR_THRESHOLD, cfg.smoothing_px,
                                     cfg.merge_gap_px)
            if not fixed and hi - lo + 1 <= SHORT_FIRST * shortest:
                if not cut_smear(deficit, lo, hi, int(cfg.pad_px), noise):
                    return None
                cut = True
            shortest = 0.0
            if not fixed:
                # The gain from the plate outside every dip that stands out (a part of the
                # smear beyond a gap, too), and a guard.
                level = max(SMEAR_THRESHOLD * peak, 3.0 * noise / math.sqrt(cfg.smoothing_px))
                above = (smooth(deficit, int(cfg.smoothing_px)) > level).astype(float)
                free = np.convolve(above, np.ones(2 * guard + 1), mode='same') == 0
                free[max(lo - guard, 0):hi + guard + 1] = False
                if np.count_nonzero(free) < 12:
                    return None
        if not fixed and not cut and shortest == 0.0:
            cut = cut_smear(deficit, lo, hi, int(cfg.pad_px), noise)
        return deficit, free, lo, hi, gain, cut

    def _finish(self, region, raw, deficit, keep, lo, hi, polarity, saturation, gain):
        """Return the measurement from a located mark: row weights, checks, position.

        ``gain``: not None when the deficit is against the learned plate times this gain (a
        long smear), not a baseline fitted to this frame; the row weights are then measured
        against the plate, the window runs to the noise and must hold the whole deficit the
        ROI shows.
        """
        smear = gain is not None
        if not smear:
            self._taken = (lo, hi)
        cfg = self.config
        x, _, w, _ = self.roi
        pad = int(cfg.pad_px)
        guard = pad + int(cfg.smoothing_px)
        if cfg.weight_rows and region.shape[0] > 1:
            if smear:
                plate = self._plate.image
                rows = slice(None) if self._rows is None else self._rows
                own = None if plate is None else plate_row_weights(
                    region, gain * plate[rows], lo, hi, pad, polarity)
            else:
                own = row_weights(region, lo, hi, pad, polarity)
            if self._row_weights is not None and own is not None and float(
                    np.abs(own - self._row_weights).sum()) > self._row_tolerance:
                # Rows darker or lighter than the mark's own: partly hidden, or something
                # dark beside it (a ball passing) that would pull the centroid.
                return self._invalid('mark partly hidden')
            weights = own if self._row_weights is None else self._row_weights
            weighted = None if weights is None else weights @ region.astype(np.float64)
            if weights is not None and self._rows is None:
                self._weights = weights
            else:
                self._weights = None
            if weighted is not None:
                if smear:
                    found = self._against_plate(weighted, weights, polarity, keep)
                    deficit = None if found is None else found[0]
                else:
                    deficit = self._deficit(weighted, keep, polarity)
                if deficit is None:
                    return self._invalid('too dark')
        noise = deficit_noise(deficit, keep)
        dip = self._locate(deficit, noise, SMEAR_THRESHOLD if smear else cfg.threshold,
                           cfg.merge_gap_px)
        if dip is None:
            return self._invalid('no other dip')
        _, peak, lo, hi = dip
        snr = peak * math.sqrt(cfg.smoothing_px) / noise
        if snr < cfg.min_snr or peak < cfg.min_depth:
            return self._invalid('low contrast', contrast=peak)
        first, last = lo - pad, hi + pad
        if first < 1 or last > w - 2:
            return self._invalid('mark at the ROI edge', contrast=peak)
        if self._background.hides(first, last):
            return self._invalid('mark partly hidden', contrast=peak)
        clipped = False
        if saturation is not None:
            window = raw[:, max(first - guard, 0):last + guard + 1]
            clipped = bool(np.count_nonzero(window >= saturation)
                           > cfg.max_saturated_fraction * window.size)
            # A bright mark may clip; one that never did has something else beside it (a glint)
            if clipped and (polarity == 'dark' or self._reach.never_clipped()):
                return self._invalid('saturated', contrast=peak)
        centroid, sigma_centroid, area = deficit_centroid(deficit, first, last, noise)
        if area <= 0:
            return self._invalid('low contrast', contrast=peak)
        if smear and cut_smear(deficit, lo, hi, pad, noise):
            # Against the plate the deficit is the mark's alone: a window that cuts the smear
            # leaves part of it outside (or something else dark is in the ROI).
            return self._invalid('smear cut by the window', contrast=peak)
        # The integrated deficit does not change with blur: a jump means a partly hidden mark.
        # The area's own noise widens the tolerance (a faint mark's area is noisy).
        area_noise = 3.0 * noise * math.sqrt(last - first + 1) / area
        tolerance = math.hypot(cfg.area_tolerance, area_noise)
        # Rejected frames enter the history too, so a lasting change is accepted after a while.
        ratio = area / float(np.median(self._areas)) if len(self._areas) >= 3 else 1.0
        self._areas.append(area)
        position, sigma = refine_position(deficit, first, last, centroid, sigma_centroid, noise,
                                          x, cfg, self._previous)
        quality, reason = cfg.quality(snr, ratio, tolerance)
        extent = float(hi - lo + 1)
        if quality < cfg.min_quality or not math.isfinite(position):
            self._previous = None
            return MarkMeasurement(float('nan'), quality, contrast=peak, extent_px=extent,
                                   reason=reason)
        self._previous = position
        self._reach.found(position, peak, extent, clipped)
        self._learn_rows()
        return MarkMeasurement(position, quality, sigma_px=sigma, contrast=peak,
                               extent_px=extent)

    def _learn_rows(self) -> None:
        """Fix the mark's rows and row weights after ``ROW_FRAMES`` frames it was found in."""
        if self._rows is not None or self._weights is None:
            return
        self._row_samples.append(self._weights)
        self._weights = None
        if len(self._row_samples) >= ROW_FRAMES:
            self._rows, self._row_weights, self._row_tolerance = mark_rows(
                self._row_samples, self.roi[3])
            self._row_samples.clear()
            if self._rows is None:
                self._rows = slice(None)
