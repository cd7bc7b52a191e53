"""Tracker settings: the one frozen TrackerConfig every stage of the tracker reads.

Owns the tuning of the mark model (polarity, baseline degree), the search (smoothing,
threshold, pad), the checks that reject a frame (signal-to-noise, depth, saturation, area
history) and the sub-pixel fit (method, the motion below which a mark counts as still). It
validates itself on construction with a one-line InputError; the stages never re-check it.
``quality`` is the measurement quality every tracker reports, from these settings.
"""

from dataclasses import dataclass
import math

from microball_ros.core.errors import InputError
from microball_ros.core.tracking.gamma import GAMMA_RANGE, check_gamma

METHODS = ('auto', 'centroid', 'symmetric', 'template')
POLARITIES = ('auto', 'dark', 'bright')


@dataclass(frozen=True)
class TrackerConfig:
    """Tracker tuning; the defaults suit any mark that stands out from its plate.

    ``method``: 'auto' (centroid, or symmetry when the mark is nearly still), 'centroid' (exact
    for any mark shape, noisier), 'symmetric' (marks symmetric along x, still or uniformly
    moving only) or 'template' (a template of any shape learned from the video, fitted with
    the motion blur, gated by a motion prediction, a static background removed: for textured
    plates; experimental, slower). Lengths in px; ``threshold`` is the fraction of the peak
    deficit that
    delimits the mark; ``still_motion_px`` is the frame-to-frame motion below which 'auto' uses
    symmetry (blending to the centroid at three times that) in the first detection.
    ``polarity``: 'auto' (learned from the first frame the mark is found in), 'dark' or
    'bright'. ``max_blur_px``: the longest motion smear expected (sizes the template grid);
    ``template_forget``: per-frame forgetting of the learned template; ``background_rate``:
    the rate of the static-background running mean; ``match_tolerance``: the fit residual,
    in units of the plate's noise, above which a frame does not show the learned mark.
    ``merge_gap_px``: parts of a mark above the threshold this close are one mark (bars).
    ``black_level``: the camera's dark offset (DN, the value of a pixel that gets no light;
    0: none): a passing shadow's light (core.tracking.shade) scales the pixels above it.
    ``gamma``: the camera's encoding gamma (1: linear, as machine-vision cameras are; about
    2.2 for sRGB video): frames are decoded to linear light before anything else
    (core.tracking.gamma); ``black_level`` is then in linear units. 0 (the default): found
    from the priming frames (the marks' deficits shrink with their smear if encoded), else 1.
    ``static_background``: the default methods learn a pattern fixed in the image (a window,
    dust, scratches) from the priming frames and divide it out, when it stands out from the
    noise (core.tracking.background).
    """

    method: str = 'auto'
    polarity: str = 'auto'
    baseline_degree: int = 3
    smoothing_px: int = 5
    threshold: float = 0.05
    merge_gap_px: int = 16
    pad_px: int = 4
    weight_rows: bool = True
    min_snr: float = 8.0
    snr_scale: float = 12.0
    min_depth: float = 0.005
    min_baseline: float = 4.0
    saturation_level: float | None = None
    black_level: float = 0.0
    gamma: float = 0.0
    max_saturated_fraction: float = 0.002
    area_tolerance: float = 0.12
    area_history: int = 9
    still_motion_px: float = 1.0
    min_quality: float = 0.5
    max_blur_px: float = 96.0
    warmup_frames: int = 8
    prime_frames: int = 60
    template_forget: float = 0.98
    background_rate: float = 1.0 / 32.0
    match_tolerance: float = 2.0
    static_background: bool = True

    def __post_init__(self) -> None:
        """Reject inconsistent settings with a one-line message."""
        if self.method not in METHODS:
            raise InputError(f'tracker method must be one of {", ".join(METHODS)}, '
                             f'got {self.method!r}')
        if self.polarity not in POLARITIES:
            raise InputError(f'tracker polarity must be one of {", ".join(POLARITIES)}, '
                             f'got {self.polarity!r}')
        if not (math.isfinite(self.black_level) and self.black_level >= 0):
            raise InputError(f'black level must be a finite number >= 0 DN, '
                             f'got {self.black_level!r}')
        try:
            gamma = float(self.gamma)
        except (TypeError, ValueError):
            gamma = math.nan
        if not check_gamma(gamma):
            raise InputError(f'gamma must be in {GAMMA_RANGE[0]:g} .. {GAMMA_RANGE[1]:g} (1: a '
                             f'linear camera; 0: find it), got {self.gamma!r}')
        if not 0 <= int(self.baseline_degree) <= 5:
            raise InputError('tracker baseline_degree must be in 0..5')
        if (int(self.smoothing_px) < 1 or int(self.pad_px) < 0 or int(self.area_history) < 1
                or int(self.merge_gap_px) < 0):
            raise InputError('tracker smoothing_px, area_history must be >= 1, pad_px and '
                             'merge_gap_px >= 0')
        if not (self.max_blur_px >= 0 and 0 < self.template_forget <= 1
                and 0 < self.background_rate <= 1 and self.match_tolerance > 0):
            raise InputError('tracker max_blur_px must be >= 0, template_forget and '
                             'background_rate in (0, 1], match_tolerance > 0')
        if not 0 < self.threshold < 1 or not 0 <= self.min_quality <= 1:
            raise InputError('tracker threshold must be in (0, 1), min_quality in [0, 1]')

    def quality(self, snr: float, ratio: float, tolerance: float,
                misfit: float | None = None) -> tuple[float, str]:
        """Return a measurement's quality in [0, 1] and why it would be refused.

        Quality = (1 - exp(-(snr / snr_scale)^2)) * exp(-(ratio - 1)^2 / (2 tolerance^2))
        * exp(-(max(misfit - match_tolerance, 0) / 0.5)^2 / 2): the signal-to-noise, the
        mark's area or gain against the recent frames' (``ratio``), and the fit's residual in
        units of the plate's noise (``misfit``, none: 1). The reason: the poorest part, 'mark
        area changed', 'poor fit' (the residual: something over the mark, or a smear that is
        no quadratic path, as a slider breaking away mid-exposure) or 'low contrast'.
        """
        q_snr = 1.0 - math.exp(-(snr / self.snr_scale) ** 2)
        q_ratio = math.exp(-0.5 * ((ratio - 1.0) / tolerance) ** 2)
        q_match = 1.0
        if misfit is not None:
            q_match = math.exp(-0.5 * (max(misfit - self.match_tolerance, 0.0) / 0.5) ** 2)
        reason = 'low contrast'
        if min(q_ratio, q_match) < q_snr:
            reason = 'poor fit' if q_match < q_ratio else 'mark area changed'
        return q_snr * q_ratio * q_match, reason
