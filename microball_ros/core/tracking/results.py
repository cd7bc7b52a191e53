"""What the tracker reports: one mark in one frame, one frame, and a whole sequence.

Plain frozen records, no computation beyond unit conversion: MarkMeasurement (image columns,
quality, noise, and why a sample is invalid), TrackedFrame (the marks of one frame and its
mid-exposure stamp) and TrackResult (arrays per mark, and the position-CSV columns of
docs/design.md section 5). An invalid sample is NaN with a low quality, never an invented position.
"""

from dataclasses import dataclass, field
import math

import numpy as np

from microball_ros.core.errors import InputError


def with_centre(noise: float, centre: float) -> float:
    """Return a position's standard error: its noise's and its centre's, in quadrature.

    ``centre``: the standard error of where the mark's centre lies, the same in every frame
    (core.tracking.plate_rows); NaN (not estimated) leaves the noise's alone.
    """
    return math.hypot(noise, centre) if math.isfinite(centre) else noise


@dataclass(frozen=True)
class MarkMeasurement:
    """One mark in one frame.

    ``position_px``: image column of the mark centre averaged over the exposure (NaN when
    invalid); ``quality`` in [0, 1] (valid iff >= the configured ``min_quality``);
    ``sigma_px``: the position's standard error (its noise, and on a textured plate the error
    of where the mark's centre lies, the same in every frame); ``contrast``: peak relative
    deficit; ``extent_px``: length of the (blurred) mark; ``reason``: why the sample is
    invalid, or ''.
    """

    position_px: float
    quality: float
    sigma_px: float = float('nan')
    contrast: float = float('nan')
    extent_px: float = float('nan')
    reason: str = ''

    @property
    def valid(self) -> bool:
        """Return True if the position was measured."""
        return not math.isnan(self.position_px)


@dataclass(frozen=True)
class TrackedFrame:
    """The result of one frame: index, mid-exposure time (s), measurement per mark name."""

    index: int
    time: float
    marks: dict[str, MarkMeasurement]
    meters_per_pixel: float

    def position(self, name: str) -> float:
        """Return the position of mark ``name`` in m (NaN when invalid)."""
        return self.marks[name].position_px * self.meters_per_pixel

    def quality(self, name: str) -> float:
        """Return the quality of mark ``name``."""
        return self.marks[name].quality


@dataclass(frozen=True)
class TrackResult:
    """Tracked positions of a sequence: arrays per mark name, all of the length of ``time``.

    ``position`` in m, ``position_px`` in image columns, ``quality`` in [0, 1], ``sigma_px``
    the position's standard error; invalid samples are NaN with a low quality; ``polarity``
    the learned polarity per mark ('dark' or 'bright'; absent if the mark was never found);
    ``centre_sigma_px`` the part of ``sigma_px`` that is one error in every frame: where the
    mark's centre lies on a textured plate (px; 0 on a plain plate, NaN if not estimated);
    ``mosaic`` whether the frames were a raw colour mosaic, smoothed (core.tracking.mosaic);
    ``shaded`` per mark, the frames a passing shadow was divided out of (core.tracking.shade);
    ``black_level`` the camera's black level (DN) estimated from the shadows and its standard
    error (NaN, NaN when given, or when no shadow told it); ``gamma`` the gamma the frames
    were decoded with (1: as read; core.tracking.gamma) and ``gamma_found`` whether priming
    found it (gamma 0 in the config).
    """

    time: np.ndarray
    position: dict[str, np.ndarray]
    position_px: dict[str, np.ndarray]
    quality: dict[str, np.ndarray]
    sigma_px: dict[str, np.ndarray]
    reason: dict[str, list[str]]
    meters_per_pixel: float
    fps: float
    exposure: float
    names: tuple[str, ...] = field(default=())
    polarity: dict[str, str] = field(default_factory=dict)
    centre_sigma_px: dict[str, float] = field(default_factory=dict)
    mosaic: bool = False
    shaded: dict[str, int] = field(default_factory=dict)
    black_level: tuple[float, float] = (math.nan, math.nan)
    gamma: float = 1.0
    gamma_found: bool = False

    def to_columns(self) -> dict[str, np.ndarray]:
        """Return the position-CSV columns (docs/design.md section 5) as an ordered dict.

        ``time,stator_position,slider_position,slider_quality,stator_quality,slider_sigma,
        stator_sigma`` (sigma: the position's standard error, m); needs marks named 'slider'
        and 'stator'; NaN marks an empty cell (a lost mark has neither position nor sigma).
        """
        for name in ('slider', 'stator'):
            if name not in self.position:
                raise InputError(f'no mark named {name!r} was tracked')
        return {'time': self.time, 'stator_position': self.position['stator'],
                'slider_position': self.position['slider'],
                'slider_quality': self.quality['slider'],
                'stator_quality': self.quality['stator'],
                'slider_sigma': self._sigma_m('slider'), 'stator_sigma': self._sigma_m('stator')}

    def _sigma_m(self, name: str) -> np.ndarray:
        sigma = np.asarray(self.sigma_px[name], dtype=float) * self.meters_per_pixel
        return np.where(np.isfinite(self.position[name]), sigma, np.nan)
