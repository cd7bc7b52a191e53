"""What ``microball track`` says after tracking a video: the lines beside the written CSV.

Each line states something about the numbers' uncertainty that the CSV's columns alone do not:
where the marks' centres lie on textured plates (one error common to every frame), the caveat
on a lossy video's standard errors, the frames a passing shadow was divided out of
(core.tracking.shade), a raw colour mosaic smoothed before tracking, and frames decoded
with a gamma found from them (core.tracking.gamma).
"""

import math

from microball_ros.core.tracking import TrackResult
from microball_ros.core.tracking.tracker import SHADED_SIGMA
from microball_ros.io.video import FrameSource

NAMES = ('slider', 'stator')


def summary_lines(result: TrackResult, source: FrameSource, black_level: float) -> list[str]:
    """Return the lines to print after ``result`` was tracked from ``source``."""
    lines = []
    centres = centre_errors(result.centre_sigma_px)
    if centres:
        lines.append(centres)
        if source.lossy:
            lines.append(f'lossy video ({source.codec or "JPEG images"}): on MPEG-4 and MJPEG '
                         "videos a textured mark's centre was up to 5 times further off than "
                         'said (2 of 4 marks tested; README)')
    if any(result.shaded.values()):
        line = (f"a shadow was divided out of {result.shaded.get('slider', 0)} / "
                f"{result.shaded.get('stator', 0)} frames (slider / stator; its light taken "
                f'beside each mark, their standard errors times {SHADED_SIGMA:g})')
        black, sigma = result.black_level
        if black_level == 0 and math.isfinite(black):
            line += (f"; the camera's dark offset, from the shadow: {black:.1f} +- {sigma:.1f} "
                     'DN (if known, give it: --black-level DN)')
        elif black_level == 0:
            line += ': if the camera has a dark offset, give it (--black-level DN)'
        lines.append(line)
    if result.mosaic:
        lines.append('the frames are a raw colour mosaic (Bayer, not demosaiced): tracked '
                     'smoothed [1 2 1] / 4 in x and y')
    if result.gamma_found and result.gamma != 1.0:
        lines.append(f"the frames look gamma-encoded (the marks' deficits shrank with their "
                     f'smear): decoded with gamma {result.gamma:.2f} found from the first '
                     'frames (give --gamma G if known, --gamma 1 to track them as read)')
    return lines


def centre_errors(sigmas: dict[str, float]) -> str:
    """Return a line on where the marks' centres lie on their plates, or '' if exactly."""
    if all(sigmas.get(name) == 0.0 for name in NAMES):
        return ''
    parts = []
    for name in NAMES:
        sigma = sigmas.get(name, math.nan)
        parts.append(f'{name} not estimated' if math.isnan(sigma) else f'{name} +-{sigma:.3f} px')
    return (f"marks' centres on their plates: {', '.join(parts)} (one error common to "
            'every frame, in the sigma columns; it cancels in velocities and accelerations)')
