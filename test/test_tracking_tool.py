"""A tool held still beside the mark's path: the clear frames measured, the covered ones not.

A probe or tweezers brought over the plate after priming (an independent set's p10 and b24)
sits at one end of the mark's stroke: the mark comes within a few px of it, passes partly
under it and comes back, every period. Measured on these scenes before this test existed
(dark tool, 8 DN, 90 px wide, on a 170 DN plate with a dark mark or a 90 DN one with a bright
mark; 240 frames, 140-150 of them clear; upright / tilted): 18 and 11 clear frames lost for a
plain dark mark (the light's flank on the tool: 'too dark'), 130 and 110 for a bright one
(once lost, a bright mark was never found again: the light over the whole ROI went through
the tool and every candidate after a loss was on it). Held from the first frame it was
learned as a static pattern and divided out:
``test_a_tool_held_from_the_first_frame_is_not_divided_away_from_a_mark_under_it``.
"""

import math
import os
import sys

import numpy as np
import pytest

sys.path.insert(0, os.path.dirname(__file__))
from tracking_scenes import PlateSpec, SceneSpec, render  # noqa: E402

from microball_ros.core.tracking import track  # noqa: E402

FRAMES, TOOL_FROM = 180, 70
TOOL_LEFT, TOOL_WIDTH, TOOL_LEVEL = 555.0, 90.0, 8.0


def _scene(polarity, texture, tilt, seed=0, tool_from=TOOL_FROM):
    """Render the scene: a stator mark moving 200 px at 1 Hz, the tool from ``tool_from``."""
    stator = PlateSpec(band=(290.0, 460.0), phase=1.0, frequency=1.0, amplitude=200.0,
                       contrast=-100.0 if polarity == 'dark' else 60.0,
                       level=170.0 if polarity == 'dark' else 90.0, texture=texture)
    spec = SceneSpec(plates={'slider': PlateSpec(band=(20.0, 190.0), frequency=1.0,
                                                 amplitude=200.0),
                             'stator': stator})
    tool = ('stator', tool_from, FRAMES, TOOL_LEFT, TOOL_LEFT + TOOL_WIDTH, TOOL_LEVEL, tilt)
    return render(spec, FRAMES, seed=seed, tools=[tool]), spec


def _reach(spec, tilt, tool_from=TOOL_FROM):
    """Return per frame how far (px) the mark's smeared right edge reaches into the tool.

    The tool's nearest column over the mark's rows is its left edge less the tilt's shift at
    the mark's top or bottom row; negative: a gap.
    """
    stator = spec.plates['stator']
    nearest = TOOL_LEFT - abs(math.tan(math.radians(tilt))) * stator.height / 2.0
    reach = np.full(FRAMES, -math.inf)
    for n in range(tool_from, FRAMES):
        times = (n + (np.arange(64) + 0.5) / 64 * spec.exposure * spec.fps) / spec.fps
        reach[n] = stator.motion(times).max() + stator.width / 2.0 - nearest
    return reach


@pytest.mark.parametrize('polarity, texture, tilt', [
    ('dark', 0.0, 0.0), ('dark', 0.0, 20.0), ('bright', 0.0, 0.0), ('bright', 6.0, 0.0),
    ('bright', 6.0, 20.0), ('dark', 6.0, 0.0)])
def test_a_tool_beside_the_path_loses_no_clear_frame_and_reports_no_hidden_mark(
        polarity, texture, tilt):
    scene, spec = _scene(polarity, texture, tilt)
    result = track(list(scene.frames), scene.rois, 5e-6, spec.fps, exposure=spec.exposure)
    x = np.asarray(result.position_px['stator'], dtype=float)
    error = x - scene.truth['stator']
    reach = _reach(spec, tilt)
    clear = reach < -3.0 * spec.psf  # 3 PSF sigmas from the tool at its nearest
    assert np.count_nonzero(clear) > 60
    lost = np.flatnonzero(clear & ~np.isfinite(x))
    assert lost.size <= 1, lost  # 1 % of the clear frames
    # The targets: 0.03 px on a plain plate, 0.1 on a textured one
    assert np.sqrt(np.mean(error[clear & np.isfinite(x)] ** 2)) < (0.1 if texture else 0.03)
    # A frame with the mark partly under the tool is not reported, or measured well
    reported = np.isfinite(x) & (reach > 0)
    assert np.all(np.abs(error[reported]) < 0.1), error[reported]
    assert not np.any(np.isfinite(x) & (reach > 0.25 * spec.plates['stator'].width))


@pytest.mark.parametrize('polarity, texture', [('dark', 0.0), ('bright', 0.0), ('bright', 6.0)])
def test_a_tool_held_from_the_first_frame_is_not_divided_away_from_a_mark_under_it(polarity,
                                                                                   texture):
    # Held still from the first frame, the tool is in every priming frame: it was learned as a
    # static pattern (a transmission of 5 %) and divided out, and a mark partly under it, its
    # hidden part now looking like plate, was reported 2.0 and 6.2 px off (dark) or 6.5 px off
    # (bright). What is opaque fixed in the image now hides the mark under it. On a textured
    # plate (no static pattern learned: the texture moves) a bright mark lost every frame
    # ('too dark': the centroid's lower envelope went down into the tool).
    scene, spec = _scene(polarity, texture, 0.0, tool_from=0)
    result = track(list(scene.frames), scene.rois, 5e-6, spec.fps, exposure=spec.exposure)
    x = np.asarray(result.position_px['stator'], dtype=float)
    error = x - scene.truth['stator']
    reach = _reach(spec, 0.0, tool_from=0)
    clear = reach < -3.0 * spec.psf
    assert np.count_nonzero(~np.isfinite(x) & clear) <= 1
    assert np.sqrt(np.mean(error[clear & np.isfinite(x)] ** 2)) < (0.1 if texture else 0.03)
    assert not np.any(np.isfinite(x) & (reach > 0)), error[np.isfinite(x) & (reach > 0)]


@pytest.mark.parametrize('beyond, left', [(1, 36), (4, 20), (8, 20)])
def test_the_light_beside_a_mark_is_the_one_expected_when_a_tool_fills_a_flank(beyond, left):
    # A tool (26 % of the light) from ``beyond`` px past the mark's window over the whole
    # right flank; ``left`` columns of plate on the other side (an ROI's end). Fitted through
    # both flanks and refitted near their median, the light was the tool's (0.26 at the mark:
    # p10's and b24's 'mark area changed' and 'no match'); with the light expected from the
    # last frames it is the clear flank's.
    from microball_ros.core.tracking import profile

    rng = np.random.default_rng(3)
    extent = 42.0
    center = left + extent / 2.0
    x = np.arange(int(center) + 100)
    ratio = 1.0 + 0.004 * rng.standard_normal(x.size)
    ratio[x >= center + extent / 2.0 + beyond] = 0.26
    at = int(center)
    plain = profile.light_level(ratio, 'dark', center, extent, flank=48.0, noise=0.004)
    assert plain is not None and abs(plain[at] - 0.26) < 0.02  # as it was
    level = profile.light_level(ratio, 'dark', center, extent, flank=48.0, noise=0.004,
                                expected=1.0)
    assert level is not None and abs(level[at] - 1.0) < 0.01
    # A flicker moves both flanks alike: the light found is kept, not the expected one
    flicker = profile.light_level(0.8 * (1.0 + 0.004 * rng.standard_normal(x.size)), 'dark',
                                  center, extent, flank=48.0, noise=0.004, expected=1.0)
    assert flicker is not None and abs(flicker[at] - 0.8) < 0.01


def test_the_rows_guard_does_not_take_a_tool_beside_the_mark_for_one_over_it():
    # A box mark, 16 px wide in 16 of 40 rows; the guard's window runs 4 px past it and 4 px
    # of pad beyond. A tool over all rows from 5 px past the mark reaches into that window:
    # its rows are every row, not the mark's. The mark's core (1 px past it, 2 px of pad)
    # holds the mark's own rows. Something over half of the mark's rows still shows there.
    from microball_ros.core.tracking.rows_guard import RowsGuard

    rng = np.random.default_rng(0)

    def frame(tool=None, over=False):
        image = 170.0 + 2.0 * rng.standard_normal((40, 120))
        image[12:28, 52:68] -= 100.0
        if tool is not None:
            image[:, tool:] = 10.0
        if over:
            image[12:20, 52:68] = 40.0
        return image

    guard = RowsGuard(4)
    guard.start_log()
    for _ in range(8):
        guard.hidden(frame(), 48, 71, 'dark')
    guard.learn(40)
    whole, core = (48, 71), (51, 68)
    assert not guard.hidden(frame(), *whole, 'dark', core)
    beside = frame(tool=73)
    assert guard.hidden(beside, *whole, 'dark')  # the whole window alone: refused
    assert not guard.hidden(beside, *whole, 'dark', core)
    assert guard.hidden(frame(over=True), *whole, 'dark', core)
    assert guard.hidden(frame(tool=64), *whole, 'dark', core)


def test_after_a_loss_the_candidates_shaped_like_the_mark_come_first():
    # A 13 px box mark (deficit 0.5) and a tool 90 px wide and twice as deep 30 px away: the
    # tool's score is the highest, at several peaks along it; shaped, the mark comes first.
    from microball_ros.core.tracking.plate_model import PlateModel
    from microball_ros.core.tracking.plate_search import match_plate

    plate = PlateModel(128, 40.0)
    plate.values = 0.5 * (np.abs(plate.grid) <= 6).astype(float)
    plate.spectrum = np.fft.rfft(plate.values)
    x = np.arange(300, dtype=float)
    d = 0.5 * (np.abs(x - 80.4) <= 6) + 1.0 * ((x >= 117) & (x < 207))
    kernels = [(0.0, 0.0), (16.0, 0.0)]
    by_score = match_plate(plate, d, 0, 300, kernels, 10.0, count=3, shaped=False)
    assert all(abs(column - 80.4) > 10 for column, _, _ in by_score)  # all on the tool
    shaped = match_plate(plate, d, 0, 300, kernels, 10.0, count=3)
    assert abs(shaped[0][0] - 80.4) < 0.5 and shaped[0][1] == 0.0
