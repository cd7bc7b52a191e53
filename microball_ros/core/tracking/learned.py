"""One mark by a learned template (method 'template'): detect, learn, predict, search, fit.

Owns LearnedMarkTracker, the stateful tracking of one mark by its learned model. The first
frame in which the
mark is found (core.tracking.detect, both polarities when 'auto') fixes its polarity, the row
weights (a matched filter across rows) and a first template (core.tracking.template). From then
on, per frame:

1. the ROI is reduced to a row-weighted profile along x and divided by the learned static
   background (texture fixed in the image: a running mean per column, updated only outside
   the mark's footprint), then by a polynomial fitted outside the predicted footprint (uneven
   illumination and flicker); what is left is the relative profile ``r``;
2. the search is gated around the position predicted from the mark's recent track
   (core.tracking.predict) and matches the template smeared by the predicted motion; with no
   prediction (the start, after a loss) the whole ROI is searched, so a mark is re-acquired;
3. the fit (core.tracking.template) gives the exposure-averaged position, its standard error,
   the blur and the contrast;
4. the checks: signal-to-noise, the mark clear of the ROI edges, a contrast and a residual
   consistent with the learned mark (a covered or partly covered mark fails them), no
   saturation. A failed check gives NaN with a quality below ``min_quality``: positions are
   never invented;
5. learning: the template from this frame (deblurred by the kernel of its motion, known one
   frame later), the static background outside the footprint.
"""

from collections import deque
import math

import numpy as np

from microball_ros.core.tracking.config import TrackerConfig
from microball_ros.core.tracking.detect import Detection, detect
from microball_ros.core.tracking.image import Roi, check_roi, roi_region
from microball_ros.core.tracking.predict import MotionPredictor
from microball_ros.core.tracking.profile import (
    Baseline,
    column_profile,
    deficit_noise,
    polarity_of,
    saturation_level,
)
from microball_ros.core.tracking.results import MarkMeasurement
from microball_ros.core.tracking.search import peak_offset
from microball_ros.core.tracking.template import MarkTemplate


class LearnedMarkTracker:
    """Track one mark inside one ROI, frame by frame.

    ``exposure_fraction``: exposure time x frame rate (how much of the motion between frames
    smears a frame), used to learn a sharp template from blurred frames.
    """

    def __init__(self, roi: Roi, config: TrackerConfig | None = None, name: str = 'mark',
                 exposure_fraction: float = 0.5):
        """Create a tracker for the mark in ``roi`` (x, y, w, h, px)."""
        self.roi = check_roi(roi, name=name)
        self.config = TrackerConfig() if config is None else config
        self.name = name
        self.exposure_fraction = float(exposure_fraction)
        self._baseline = Baseline(self.roi[2], self.config.baseline_degree)
        self.reset()

    def reset(self) -> None:
        """Forget everything learned (for a new, unrelated sequence)."""
        width = self.roi[2]
        self.polarity: str | None = None
        self.template: MarkTemplate | None = None
        self._weights: np.ndarray | None = None
        self._half = 0.0
        self._texture = np.zeros(width)
        self._texture_count = np.zeros(width)
        self._gains: deque[float] = deque(maxlen=int(self.config.area_history))
        self._predictor = MotionPredictor()
        self._pending: list = []
        self._blur = 0.0

    def prime(self, frames) -> None:
        """Learn the mark from ``frames`` (2-D arrays), then start the sequence afresh.

        Keeps what was learned (polarity, row weights, template, static background) and
        forgets the track, so the same frames can be tracked again from the first one with
        the learned mark.
        """
        for frame in frames:
            self.measure(frame)
        if self.template is not None and self.template.ready:
            self.template.recenter(-1.0 if self.polarity == 'dark' else 1.0)
        self._gains.clear()
        self._predictor.reset()
        self._pending = []
        self._blur = 0.0

    @property
    def centre_sigma_px(self) -> float:
        """Return NaN: where the template's centre lies on the mark is not estimated."""
        return math.nan

    @property
    def learned(self) -> dict:
        """Return what was learned: polarity, half-width (px) and template (or empty)."""
        if self.template is None:
            return {}
        return {'polarity': self.polarity, 'half_width': self._half,
                'template': self.template.values.copy(), 'center': self.template.center}

    def _invalid(self, reason, quality=0.0, contrast=math.nan):
        self._predictor.add(math.nan)
        self._pending = self._pending[-1:] + [None]
        return MarkMeasurement(math.nan, quality, contrast=contrast, reason=reason)

    def measure(self, frame: np.ndarray) -> MarkMeasurement:
        """Measure the mark in one frame (2-D array) and return a MarkMeasurement."""
        cfg = self.config
        region = roi_region(frame, self.roi, self.name)
        profile = column_profile(region)
        if not np.all(np.isfinite(profile)):
            return self._invalid('non-finite pixels')
        saturation = saturation_level(region.dtype, cfg.saturation_level)
        if saturation is not None and profile.max() >= saturation:
            return self._invalid('saturated')
        if self.template is None:
            return self._initialise(region, profile, saturation)
        if self.template.frames < cfg.warmup_frames:
            return self._warmup(region, None, saturation)
        return self._track(region, saturation)

    # -- the first lock --------------------------------------------------------------------
    def _initialise(self, region, profile, saturation):
        cfg = self.config
        polarities = ('dark', 'bright') if cfg.polarity == 'auto' else (cfg.polarity,)
        guess = polarity_of(profile) if cfg.polarity == 'auto' else None
        if guess is not None:
            polarities = (guess,)
        found = [detect(region, profile, self._baseline, cfg, p) for p in polarities]
        best: Detection = max(found, key=lambda d: (d.found, d.snr))
        if not best.found:
            return self._invalid(best.reason, contrast=best.peak)
        polarity = polarities[found.index(best)]
        if self._saturated(region, best.position, best.hi - best.lo, saturation, polarity):
            return self._invalid('saturated', contrast=best.peak)
        self.polarity = polarity
        self._weights = best.weights
        self._half = (best.hi - best.lo) / 2.0 + cfg.pad_px
        support = self._half + 16.0
        size = 64
        while size < 2 * (support + cfg.max_blur_px / 2.0 + 32):
            size *= 2
        self.template = MarkTemplate(size, support, cfg.template_forget)
        return self._warmup(region, best, saturation)

    def _warmup(self, region, found, saturation):
        """Report a single-frame detection while the template learns its first frames."""
        cfg = self.config
        if found is None:
            polarity = self.polarity or 'dark'  # _initialise set it before any warm-up frame
            found = detect(region, column_profile(region), self._baseline, cfg, polarity)
        if not found.found:
            return self._invalid(found.reason, contrast=found.peak)
        extent = (found.hi - found.lo) / 2.0 + cfg.pad_px
        if self._saturated(region, found.position, 2 * extent, saturation, self.polarity):
            return self._invalid('saturated', contrast=found.peak)
        r, keep = self._relative(region, found.position, extent + cfg.pad_px)
        if r is None:
            return self._invalid('too dark')
        window, valid, j0 = self._window(r, found.position)
        self._learn(window, valid, j0, found.position, 1.0, 0.0, extent)
        self._predictor.add(found.position)
        quality = 1.0 - math.exp(-(found.snr / cfg.snr_scale) ** 2)
        return MarkMeasurement(found.position + self.roi[0], quality, sigma_px=found.sigma,
                               contrast=found.peak, extent_px=float(found.hi - found.lo + 1))

    # -- helpers ---------------------------------------------------------------------------
    def _saturated(self, region, column, extent, saturation, polarity):
        cfg = self.config
        if saturation is None or polarity != 'dark' or not math.isfinite(column):
            return False
        reach = int(extent / 2 + cfg.pad_px + cfg.smoothing_px + 4)
        c = int(round(column))
        window = region[:, max(c - reach, 0):c + reach + 1]
        return np.count_nonzero(window >= saturation) > cfg.max_saturated_fraction * window.size

    def _relative(self, region, center, half):
        """Return r = profile / (texture x baseline) - 1 and the plain-plate mask."""
        weights = self._weights
        if weights is None:
            profile = column_profile(region)
        else:
            profile = weights @ region.astype(np.float64)
        self._raw = profile
        flat = profile / (1.0 + self._texture)
        w = profile.size
        keep = np.ones(w, dtype=bool)
        if math.isfinite(center):
            keep[max(int(center - half), 0):min(int(center + half) + 1, w)] = False
        if np.count_nonzero(keep) < 12:
            keep[:] = True
        base = self._baseline.fit(flat, keep)
        self._base = base
        if base.min() < self.config.min_baseline:
            return None, keep
        return flat / base - 1.0, keep

    @property
    def _learned(self) -> MarkTemplate:
        """The template, which exists once the first frames were seen (after _warmup)."""
        if self.template is None:
            raise RuntimeError('the mark template is used before it was created')
        return self.template

    def _window(self, r, column):
        """Return the grid window of r centred near ``column``, its valid mask and start."""
        size = self._learned.size
        j0 = int(round(column)) - self._learned.center
        index = np.arange(j0, j0 + size)
        valid = (index >= 0) & (index < r.size)
        window = np.zeros(size)
        window[valid] = r[index[valid]]
        return window, valid, j0

    def _search(self, r, prediction, blur, curve):
        """Return (column, blur) of the best match of the template smeared by a bank of blurs.

        The score is the correlation with the smeared template over its norm (a matched
        filter per blur); gated around the prediction when there is one.
        """
        template = self._learned
        best = None
        for length in sorted({round(blur), 0, 12, 32, 64}):
            core = int(math.ceil(self._half + length / 2.0)) + 2
            core = min(core, template.center - 1, (r.size - 1) // 2)
            smeared = template.smeared(float(length), 0.0)[
                template.center - core:template.center + core + 1]
            norm = float(np.sqrt(smeared @ smeared))
            if norm <= 0:
                continue
            score = np.convolve(r, smeared[::-1], mode='same') / norm
            lo, hi = core // 2, r.size - core // 2
            if prediction is not None:
                gate = 6.0 * prediction.spread + 3.0
                lo = max(lo, int(math.floor(prediction.column - gate)))
                hi = min(hi, int(math.ceil(prediction.column + gate)) + 1)
            if hi - lo < 1:
                continue
            k = lo + int(np.argmax(score[lo:hi]))
            if best is None or score[k] > best[0]:
                best = (float(score[k]), k + peak_offset(score, k), float(length))
        return None if best is None else best[1:]

    # -- a frame with a learned mark -------------------------------------------------------
    def _track(self, region, saturation):
        cfg = self.config
        prediction = self._predictor.predict()
        fraction = self.exposure_fraction
        blur, curve = self._blur, 0.0
        if prediction is not None and math.isfinite(prediction.before):
            blur = abs(prediction.following - prediction.previous) / 2.0 * fraction
            curve = (prediction.following - 2 * prediction.column + prediction.previous) * (
                fraction ** 2) / 2.0
        blur = max(blur, 2.0)
        gated = prediction is not None and math.isfinite(prediction.spread)
        if prediction is not None and gated:
            reach = self._half + blur / 2 + 6.0 * prediction.spread + cfg.smoothing_px + 6
            r, keep = self._relative(region, prediction.column, reach)
        else:
            r, keep = self._relative(region, math.nan, 0.0)
        if r is None:
            return self._invalid('too dark')
        found = self._search(r, prediction if gated else None, blur, curve)
        if found is None:
            return self._invalid('mark at the ROI edge')
        column, searched = found
        if not gated or abs(searched - blur) > 0.5 * max(blur, searched):
            blur, curve = max(searched, 2.0), 0.0
        if not gated:  # refit the plate without the found mark
            r, keep = self._relative(region, column, self._half + blur / 2 + cfg.pad_px + 6)
            if r is None:
                return self._invalid('too dark')
        noise = deficit_noise(r, keep)
        window, valid, j0 = self._window(r, column)
        template = self._learned
        fit = template.fit(window, valid, column - j0 - template.center, blur, curve,
                           self._half + 4.0)
        if fit is None:
            return self._invalid('low contrast')
        position = j0 + template.center + fit.shift
        smeared = template.smeared(fit.blur, fit.curve)
        peak = abs(fit.gain) * float(np.max(np.abs(smeared)))
        snr = peak * math.sqrt(cfg.smoothing_px) / noise
        reference = float(np.median(self._gains)) if self._gains else 1.0
        ratio = fit.gain / reference
        extent = self._half + fit.blur / 2.0 + abs(fit.curve) / 6.0
        if snr < cfg.min_snr or fit.gain <= 0:
            return self._invalid('low contrast', contrast=peak)
        if position - extent < 1 or position + extent > r.size - 2:
            return self._invalid('mark at the ROI edge', contrast=peak)
        if self._saturated(region, position, 2 * extent, saturation, self.polarity):
            return self._invalid('saturated', contrast=peak)
        quality, reason = cfg.quality(snr, ratio, cfg.area_tolerance, fit.rms / noise)
        self._gains.append(fit.gain)
        if quality < cfg.min_quality:
            return self._invalid(reason, quality, contrast=peak)
        self._blur = fit.blur
        self._learn(window, valid, j0, position, fit.gain, fit.offset, extent)
        self._predictor.add(position)
        return MarkMeasurement(position + self.roi[0], quality, sigma_px=fit.sigma,
                               contrast=peak, extent_px=2 * extent)

    def _learn(self, window, valid, j0, position, gain, offset, extent):
        """Learn the static background outside the mark and the template (one frame late)."""
        cfg = self.config
        outside = np.ones(self._texture.size, dtype=bool)
        outside[max(int(position - extent - cfg.pad_px - 4), 0):
                int(position + extent + cfg.pad_px + 5)] = False
        ratio = self._raw / self._base - 1.0
        self._texture_count[outside] += 1
        rate = np.maximum(1.0 / self._texture_count[outside], cfg.background_rate)
        self._texture[outside] += rate * (ratio[outside] - self._texture[outside])
        self._pending.append((window, valid, j0, position, gain, offset))
        track = self._pending[-3:]
        if len(track) == 3 and all(item is not None for item in track):
            before, middle, after = (item[3] for item in track)
            window, valid, j0, position, gain, offset = track[1]
            fraction = self.exposure_fraction
            blur = abs(after - before) / 2.0 * fraction
            curve = (after - 2 * middle + before) * fraction ** 2 / 2.0
            self._learned.add(window, valid, position - j0 - self._learned.center, blur,
                              curve, gain, offset, self._half + blur / 2 + abs(curve) / 6 + 8.0)
            self._half = self._learned.half_width(self.config.threshold) + self.config.pad_px
        del self._pending[:-2]
