"""Hard marks against exact ground truth: bright blobs, 16-bit, flicker, covers, texture.

Scenes from test/tracking_scenes.py (independent of core.camera's renderer): the paper's
motion (+-240 px at 2.95 Hz, 30 fps, 1/60 s exposure, so up to ~70 px of smear), 60 frames.
Errors are against the exposure-averaged mark column (px).
"""

from dataclasses import replace
import sys

import cv2
import numpy as np
import pytest

sys.path.insert(0, __file__.rsplit('/', 1)[0])
from tracking_scenes import PlateSpec, SceneSpec, plates, render  # noqa: E402

from microball_ros.core.tracking import Tracker, TrackerConfig, track  # noqa: E402
from microball_ros.io.video import image_to_gray  # noqa: E402

SCALE = 5e-6


def errors(scene, result):
    return {p: result.position_px[p] - scene.truth[p] for p in scene.truth}


def test_bright_blob_on_a_dark_plate_is_found_with_default_options():
    # IR-lit blobs: brighter than their plate. Before polarity 'auto' all but a few were lost.
    spec = SceneSpec(plates=plates(shape='blob', contrast=150.0, level=40.0, width=16.0),
                     gap_level=20.0)
    scene = render(spec, 60, seed=3)
    result = track(scene.frames, scene.rois, SCALE, fps=30.0)
    for plate, error in errors(scene, result).items():
        assert result.polarity[plate] == 'bright'
        assert np.all(np.isfinite(error)), plate
        assert np.sqrt(np.mean(error ** 2)) < 0.1 and np.max(np.abs(error)) < 0.5, plate
        # The reported standard error is of the size of the actual scatter.
        ratio = np.median(result.sigma_px[plate]) / np.sqrt(np.mean(error ** 2))
        assert 0.3 < ratio < 3.0, (plate, ratio)


def test_sixteen_bit_bright_bars_and_forced_polarity():
    spec = SceneSpec(plates=plates(contrast=60.0, level=100.0), bits=16)
    scene = render(spec, 40, seed=5)
    assert scene.frames.dtype == np.uint16
    result = track(scene.frames, scene.rois, SCALE, fps=30.0)
    for plate, error in errors(scene, result).items():
        assert np.all(np.isfinite(error)) and np.sqrt(np.mean(error ** 2)) < 0.1, plate
    dark = track(scene.frames, scene.rois, SCALE, fps=30.0,
                 config=TrackerConfig(polarity='dark'))
    # Forced to the wrong polarity, the tracker does not follow the bright mark.
    near = np.abs(dark.position_px['slider'] - scene.truth['slider']) < 1.0
    assert near.mean() < 0.1


def test_flicker_is_normalised():
    scene = render(SceneSpec(flicker=0.15), 40, seed=7)
    result = track(scene.frames, scene.rois, SCALE, fps=30.0)
    for plate, error in errors(scene, result).items():
        assert np.all(np.isfinite(error)) and np.sqrt(np.mean(error ** 2)) < 0.06, plate


def test_a_covered_mark_is_never_reported_and_is_reacquired():
    scene = render(SceneSpec(), 40, seed=9, covers=[('slider', 12, 15), ('stator', 30, 30)])
    for method in ('auto', 'template'):
        result = track(scene.frames, scene.rois, SCALE, fps=30.0,
                       config=TrackerConfig(method=method))
        err = errors(scene, result)
        covered = {'slider': [12, 13, 14, 15], 'stator': [30]}
        for plate, frames in covered.items():
            assert np.all(np.isnan(err[plate][frames])), (method, plate)
            clear = np.setdiff1d(np.arange(40), frames)
            assert np.isfinite(err[plate][clear]).mean() >= 0.9, (method, plate)
            assert np.nanmax(np.abs(err[plate][clear])) < 1.0, (method, plate)
        assert np.isfinite(err['slider'][16:19]).all()  # re-acquired at once


def test_a_static_texture_is_removed_by_default_and_by_the_template_method():
    # The default removes the static background (core.tracking.background); the centroid
    # alone is pulled by the texture.
    spec = SceneSpec(static_texture=12.0)
    scene = render(spec, 60, seed=3)
    # The profile centroid without the static background (as before it was learned).
    plain = errors(scene, track(scene.frames, scene.rois, SCALE, fps=30.0,
                                config=TrackerConfig(method='centroid', static_background=False)))
    for method in ('auto', 'template'):
        found = errors(scene, track(scene.frames, scene.rois, SCALE, fps=30.0,
                                    config=TrackerConfig(method=method)))
        for plate in scene.truth:
            rms_plain = np.sqrt(np.nanmean(plain[plate] ** 2))
            rms = np.sqrt(np.nanmean(found[plate] ** 2))
            assert rms < 0.12 and rms < 0.6 * rms_plain, (method, plate)
            assert np.isnan(found[plate]).mean() <= 0.1
            assert np.nanmax(np.abs(found[plate])) < 0.5


@pytest.mark.parametrize('ros, pattern', [('rggb', 'RGGB'), ('bggr', 'BGGR'), ('gbrg', 'GBRG'),
                                          ('grbg', 'GRBG')])
def test_bayer_images_are_demosaiced_with_the_ros_pattern(ros, pattern):
    # A scene whose red, green and blue differ: only the right pattern gives its gray.
    rng = np.random.default_rng(1)
    bgr = np.zeros((32, 48, 3), np.uint8)
    bgr[:] = (30, 120, 220)
    bgr = cv2.GaussianBlur(bgr + rng.integers(0, 3, bgr.shape, dtype=np.uint8), (0, 0), 1)
    offsets = {'R': 2, 'G': 1, 'B': 0}
    mosaic = np.empty((32, 48), np.uint8)
    for dy in (0, 1):
        for dx in (0, 1):
            channel = offsets[pattern[2 * dy + dx]]
            mosaic[dy::2, dx::2] = bgr[dy::2, dx::2, channel]
    gray = image_to_gray(f'bayer_{ros}8', 32, 48, 48, mosaic.tobytes())
    expected = cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY)
    assert gray.shape == (32, 48) and gray.dtype == np.uint8
    assert np.abs(gray[4:-4, 4:-4].astype(int) - expected[4:-4, 4:-4]).max() <= 3
    wide = image_to_gray(f'bayer_{ros}16', 32, 48, 96,
                         (mosaic.astype('<u2') * 257).tobytes())
    assert wide.dtype == np.uint16
    assert np.abs(wide[4:-4, 4:-4] / 257.0 - expected[4:-4, 4:-4]).max() <= 3


def test_sixteen_bit_messages_in_either_byte_order():
    frame = (np.arange(12 * 20, dtype=np.uint16).reshape(12, 20) * 250)
    little = image_to_gray('mono16', 12, 20, 40, frame.astype('<u2').tobytes())
    big = image_to_gray('mono16', 12, 20, 40, frame.astype('>u2').tobytes(), is_bigendian=1)
    np.testing.assert_array_equal(little, frame)
    np.testing.assert_array_equal(big, frame)
    rgb = np.repeat(frame[:, :, None], 3, axis=2)
    np.testing.assert_array_equal(image_to_gray('rgb16', 12, 20, 120, rgb.astype('<u2').tobytes()),
                                  frame)
    assert replace(SceneSpec(), bits=16).bits == 16


def test_a_pair_of_bars_is_one_mark_blurred_or_still():
    # Two 6 px bars 20 px apart: when the motion is slow the smoothed dip splits in two. The
    # two parts are joined (TrackerConfig.merge_gap_px); before, frames near the turning
    # points were lost ('mark area changed') or one bar alone was reported, 10 px off.
    spec = SceneSpec(plates=plates(shape='pair', stroke=6.0, gap=14.0, height=42.0))
    scene = render(spec, 60, seed=5)
    result = track(scene.frames, scene.rois, SCALE, fps=30.0)
    for plate, error in errors(scene, result).items():
        assert np.all(np.isfinite(error)), (plate, result.reason[plate])
        assert np.sqrt(np.mean(error ** 2)) < 0.1 and np.max(np.abs(error)) < 0.4, plate


def test_a_faint_mark_smeared_to_about_one_percent_is_not_lost():
    # A 17 px mark 5 % deep, smeared over up to ~70 px: its peak deficit falls to about 1.2 %.
    # Its signal-to-noise ratio still clears min_snr (16-bit, low noise), so it is measured;
    # before, a fixed 2 % depth floor lost the fast frames. Exposure averages are unbiased.
    spec = SceneSpec(plates=plates(width=17.0, height=42.0, contrast=-8.5), bits=16,
                     gain=200.0)
    scene = render(spec, 60, seed=6)
    result = track(scene.frames, scene.rois, SCALE, fps=30.0)
    for plate, error in errors(scene, result).items():
        assert np.all(np.isfinite(error)), (plate, result.reason[plate])
        rms = np.sqrt(np.mean(error ** 2))
        assert rms < 0.5 and np.max(np.abs(error)) < 1.5, plate
        # Noise-limited: the scatter is what the reported standard error says, no bias
        # beyond 3.5 standard errors of the mean of 60 frames.
        assert 0.3 < np.median(result.sigma_px[plate]) / rms < 3.0, plate
        assert abs(np.mean(error)) < 3.5 * rms / np.sqrt(error.size), plate


def _rms(error):
    return float(np.sqrt(np.nanmean(error ** 2)))


@pytest.mark.parametrize('kind, shape', [('added', 'bar'), ('added', 'cross'),
                                         ('transmitted', 'pair')])
def test_default_tracker_removes_a_static_texture(kind, shape):
    # A pattern fixed in the image (light added by scratches or glare, or a window's
    # transmission) over which the marks move: the default tracker learns it on the priming
    # frames and removes it, to within 25 % (+0.01 px) of the RMS error on the same scene
    # without the pattern (same noise). Without that it is off by tenths of a pixel or more
    # (asserted, so the scene is a hard one).
    texture = {'static_texture': 25.0} if kind == 'added' else {'static_transmission': 0.12}
    changes = {'cross': dict(width=40.0, height=40.0), 'pair': {}, 'bar': {}}[shape]
    spec = SceneSpec(plates=plates(shape=shape, **changes), **texture)
    scene = render(spec, 60, seed=11)
    twin = render(replace(spec, static_texture=0.0, static_transmission=0.0), 60, seed=11)
    result = track(scene.frames, scene.rois, SCALE, fps=30.0)
    clean = errors(twin, track(twin.frames, twin.rois, SCALE, fps=30.0))
    plain = track(scene.frames, scene.rois, SCALE, fps=30.0,
                  config=TrackerConfig(method='centroid', static_background=False))
    for plate, error in errors(scene, result).items():
        assert np.all(np.isfinite(error)), (plate, np.flatnonzero(np.isnan(error)))
        bound = 1.25 * _rms(clean[plate]) + 0.01
        assert _rms(error) < min(bound, 0.12), (plate, _rms(error), bound)
        assert np.max(np.abs(error)) < 0.4, plate
        before = plain.position_px[plate] - scene.truth[plate]
        assert _rms(before) > 2 * _rms(error), (plate, _rms(before), _rms(error))


@pytest.mark.parametrize('kind, shape', [('added', 'pair'), ('transmitted', 'pair'),
                                         ('transmitted', 'bar')])
def test_a_static_pattern_is_removed_as_what_it_is_under_fast_periodic_motion(kind, shape):
    # Issue 14 (blind case 5): bars under a window's transmission, 4 Hz at 60 fps (15
    # frames a period, so the priming frames show 15 positions), exposure a quarter of the
    # frame. The pattern's fine part is either light added (subtracted) or a transmission
    # (divided): only on the mark do the two differ, and the wrong one leaves the pattern
    # darkened by the mark on it (blind case 5's slider: 0.2 px RMS, 0.5 px at worst; its
    # choice, by the fine structure left on the mark, was a coin toss there, 1 % apart, and
    # right on these scenes). The kind learned must be the one rendered, and the error
    # within 25 % (+0.01 px) of the same scene's without the pattern.
    from microball_ros.core.tracking.mark import MarkTracker

    texture = {'static_texture': 20.0} if kind == 'added' else {'static_transmission': 0.12}
    spec = SceneSpec(plates=plates(shape=shape, amplitude=110.0, frequency=4.0),
                     fps=60.0, exposure=1.0 / 240.0, **texture)
    scene = render(spec, 90, seed=5)
    twin = render(replace(spec, static_texture=0.0, static_transmission=0.0), 90, seed=5)
    result = track(scene.frames, scene.rois, SCALE, fps=60.0, exposure=1.0 / 240.0)
    clean = errors(twin, track(twin.frames, twin.rois, SCALE, fps=60.0, exposure=1.0 / 240.0))
    for plate, error in errors(scene, result).items():
        tracker = MarkTracker(scene.rois[plate], TrackerConfig(), plate)
        tracker.prime(scene.frames[:60])
        expected = 'subtracted' if kind == 'added' else 'divided'
        assert tracker.learned['static_background'] == expected, plate
        assert np.all(np.isfinite(error)), plate
        bound = 1.25 * _rms(clean[plate]) + 0.01
        assert _rms(error) < bound, (plate, _rms(error), bound)
        assert np.max(np.abs(error)) < 0.3, plate


def test_bright_blob_under_a_static_texture_and_flicker():
    spec = SceneSpec(plates=plates(shape='blob', contrast=150.0, level=40.0, width=16.0),
                     gap_level=20.0, static_texture=12.0, flicker=0.15)
    scene = render(spec, 60, seed=13)
    result = track(scene.frames, scene.rois, SCALE, fps=30.0)
    for plate, error in errors(scene, result).items():
        assert result.polarity[plate] == 'bright'
        assert np.all(np.isfinite(error)) and _rms(error) < 0.1, (plate, _rms(error))


def test_a_plain_plate_learns_no_static_background():
    # The mean of noisy frames would only add fixed-pattern noise: nothing is removed, and
    # the positions are those of the tracker without the option, to the last bit.
    scene = render(SceneSpec(), 60, seed=3)
    tracker = Tracker(scene.rois, SCALE, 30.0)
    tracker.prime(list(scene.frames))
    assert all('static_background' not in m.learned for m in tracker.marks.values())
    on = track(scene.frames, scene.rois, SCALE, fps=30.0)
    off = track(scene.frames, scene.rois, SCALE, fps=30.0,
                config=TrackerConfig(static_background=False))
    for plate in scene.truth:
        np.testing.assert_array_equal(on.position_px[plate], off.position_px[plate])


def test_covered_marks_on_a_static_texture_are_not_reported_and_are_reacquired():
    scene = render(SceneSpec(static_texture=15.0), 60, seed=3,
                   covers=[('slider', 20, 23), ('stator', 40, 40)])
    result = track(scene.frames, scene.rois, SCALE, fps=30.0)
    err = errors(scene, result)
    covered = {'slider': [20, 21, 22, 23], 'stator': [40]}
    for plate, frames in covered.items():
        assert np.all(np.isnan(err[plate][frames])), plate
        clear = np.setdiff1d(np.arange(60), frames)
        assert np.isfinite(err[plate][clear]).all(), plate
        assert _rms(err[plate][clear]) < 0.1, plate


@pytest.mark.parametrize('dy, beside', [(46.0, True), (-46.0, True), (40.0, False),
                                        (26.0, False)])
def test_a_dark_ball_beside_or_over_the_mark_does_not_pull_its_position(dy, beside):
    # A dark ball (28 px, 30 DN on a 170 DN plate) rides 22 px beside the mark for frames
    # 30-45, above or below it (dy from the mark's centre row; the mark is 50 px tall), or
    # over its lower rows. Rows outside the mark's own are ignored, so a ball beside it
    # changes nothing (before: 0.5-1.1 px off); a ball that reaches its rows gives
    # 'mark partly hidden' (before: 5-12 px off, reported), and the mark is back at once.
    discs = [('slider', 30, 45, 22.0, dy, 14.0, 30.0), ('stator', 30, 45, -22.0, dy, 14.0, 30.0)]
    scene = render(SceneSpec(), 60, seed=5, discs=discs)
    result = track(scene.frames, scene.rois, SCALE, fps=30.0)
    for plate, error in errors(scene, result).items():
        clear = np.r_[0:30, 46:60]
        assert np.isfinite(error[clear]).all() and _rms(error[clear]) < 0.06, plate
        during = error[30:46]
        if beside:
            assert np.isfinite(during).all() and np.max(np.abs(during)) < 0.2, plate
        else:
            reported = during[np.isfinite(during)]
            assert reported.size == 0 or np.max(np.abs(reported)) < 0.3, plate
            assert any(r == 'mark partly hidden' for r in result.reason[plate][30:46]), plate


def test_flicker_and_a_drifting_gradient_on_a_plain_plate_lose_nothing():
    # Flicker of +-15 % and an illumination gradient across x that drifts over the video
    # (40 fps, 1/80 s: short smears). The plain plate learned for long smears, times one
    # gain, took the drift for a smear longer than a quarter of the ROI: 101-102 of 120
    # frames were lost ('mark at the ROI edge'; a blind case alike, 146 / 138 of 160). The
    # plate is now learned only when the priming frames show long smears.
    scene = render(SceneSpec(flicker=0.15, drift=0.3, fps=40.0, exposure=1 / 80,
                             plates=plates(amplitude=150.0, frequency=2.0)), 120, seed=2)
    result = track(scene.frames, scene.rois, SCALE, fps=40.0, exposure=1 / 80)
    for plate, error in errors(scene, result).items():
        assert np.isfinite(error).all(), plate
        assert _rms(error) < 0.05, plate


def test_a_mark_that_hardly_moves_is_not_taken_for_a_static_background():
    # Moving +-3 px, the mark is in the temporal median of the frames: dividing by it would
    # remove the mark (measured: 0.36 px RMS on the stator, polarity taken for 'bright' on
    # the blind set's like). The median is refused when it still shows the mark.
    scene = render(SceneSpec(plates=plates(amplitude=3.0)), 70, seed=3)
    result = track(scene.frames, scene.rois, SCALE, fps=30.0)
    for plate, error in errors(scene, result).items():
        assert np.all(np.isfinite(error)), plate
        assert _rms(error) < 0.03, (plate, _rms(error))
        assert 'static_background' not in result_learned(scene, plate)


def result_learned(scene, plate):
    """Return what the default tracker learned from the priming frames for one plate."""
    tracker = Tracker({plate: scene.rois[plate]}, SCALE, 30.0)
    tracker.prime(scene.frames[:60])
    return tracker.marks[plate].learned


def test_a_smear_over_half_the_roi_is_tracked_against_the_learned_plate():
    # 15 fps, exposure the whole frame period: the mark (20 px) smears over up to ~300 px of
    # a ~575 px ROI, a shallow dip deeper at the slow end. A baseline fitted to the frame's
    # own columns lost 24-58 of 60 frames here, with errors up to 62 px (seeds 3 and 11);
    # against the plate learned while priming, measured: 0.24-0.27 px RMS, max 0.87 px.
    spec = SceneSpec(fps=15.0, exposure=1.0 / 15.0)
    scene = render(spec, 60, seed=11)
    result = track(scene.frames, scene.rois, SCALE, fps=15.0, exposure=1.0 / 15.0)
    for plate, error in errors(scene, result).items():
        assert np.all(np.isfinite(error)), (plate, np.flatnonzero(~np.isfinite(error)))
        assert _rms(error) < 0.4, (plate, _rms(error))
        assert np.max(np.abs(error)) < 1.5, (plate, np.max(np.abs(error)))
        # The reported standard error is of the size of the actual scatter.
        ratio = np.median(result.sigma_px[plate]) / _rms(error)
        assert 0.5 < ratio < 2.0, (plate, ratio)


def test_a_short_mark_in_a_narrow_roi_under_a_drifting_light_keeps_its_own_baseline():
    # Two bars 4 px wide, 12 px apart, at 15 fps (exposure 0.3 of the period) moving +-50-60
    # px in ROIs ~200 px wide, the light's gradient across the view drifting from -30 % to
    # +30 %: smeared over up to ~0.18 of the ROI, the mark is short for its own baseline. The
    # plain plate learned while priming (for long smears) does not hold the drift: measured
    # against it, 92 and 90 of 120 frames were lost. Measured now: none lost, 0.014-0.017 px.
    pair = dict(shape='pair', stroke=4.0, gap=12.0, width=20.0, height=24.0, frequency=1.5)
    spec = SceneSpec(plates={'slider': PlateSpec(band=(20.0, 190.0), amplitude=50.0, **pair),
                             'stator': PlateSpec(band=(290.0, 460.0), amplitude=60.0, phase=1.0,
                                                 **pair)},
                     fps=15.0, exposure=0.3 / 15.0, drift=0.3)
    scene = render(spec, 120, seed=4)
    result = track(scene.frames, scene.rois, SCALE, fps=15.0, exposure=0.3 / 15.0)
    for plate, error in errors(scene, result).items():
        assert np.count_nonzero(~np.isfinite(error)) <= 1, plate
        assert _rms(error[np.isfinite(error)]) < 0.04, (plate, _rms(error[np.isfinite(error)]))


def test_a_window_that_cuts_a_smear_is_detected():
    # Against the plate the deficit is the mark's alone: a window over part of the smear
    # leaves deficit outside it. A smear of 200 px, 2 % deep, deeper at one end, in white
    # noise of 0.2 %: the whole window passes, a window over the deep end does not.
    from microball_ros.core.tracking.centroid import cut_smear

    rng = np.random.default_rng(1)
    columns = np.arange(500)
    smear = np.where((columns >= 150) & (columns < 350), 0.02 * (1 + (columns - 150) / 50), 0)
    deficit = smear + 0.002 * rng.standard_normal(columns.size)
    assert not cut_smear(deficit, 150, 349, 4, 0.002)
    assert cut_smear(deficit, 290, 349, 4, 0.002)
    # Something else dark in the ROI, away from the whole smear, also counts.
    other = deficit + np.where((columns > 40) & (columns < 60), 0.05, 0.0)
    assert cut_smear(other, 150, 349, 4, 0.002)


def test_a_long_smear_cut_by_the_window_is_rejected_not_reported():
    # A long smear whose window holds only part of it (the rest beyond a gap wider than
    # merge_gap_px, here the middle 100 px painted over with the plate as another frame shows
    # it): rejected, not reported at the centroid of one end (tens of px off).
    from microball_ros.core.tracking.centroid import CentroidMarkTracker

    spec = SceneSpec(fps=15.0, exposure=1.0 / 15.0)
    scene = render(spec, 60, seed=3)
    truth = scene.truth['stator']
    tracker = CentroidMarkTracker(scene.rois['stator'], exposure_fraction=1.0)
    tracker.prime(scene.frames)
    speed = np.abs(np.gradient(truth))
    n = int(np.argmax(speed[1:-1])) + 1  # ~250 px/frame
    center = int(round(truth[n]))
    # A frame whose own smear is far from these columns shows the plain plate there.
    other = int(np.argmax(np.abs(truth - center) - 2.0 * speed))
    assert abs(truth[other] - center) - speed[other] > 150, other
    frame = scene.frames[n].copy()
    frame[:, center - 50:center + 50] = scene.frames[other][:, center - 50:center + 50]
    cut = tracker.measure(frame)
    assert not cut.valid and cut.reason == 'smear cut by the window', cut
    # The frame as it was is measured.
    tracker.reset()
    whole = tracker.measure(scene.frames[n])
    assert whole.valid and abs(whole.position_px - truth[n]) < 1.0, (whole, truth[n])


def _glint(scene, plate, dx, dy, peak, sigma=(10.0, 2.5)):
    """Return the scene's frames with a static glint added (uint8, clipped).

    The glint is a Gaussian streak of ``peak`` DN, ``sigma`` (x, y) px, centred ``dx``,
    ``dy`` px from where the plate's mark rests.
    """
    spec = scene.spec.plates[plate]
    row = (spec.band[0] + spec.band[1]) / 2.0
    y, x = np.mgrid[0:scene.spec.height, 0:scene.spec.width].astype(float)
    streak = peak * np.exp(-0.5 * (((x - spec.origin - dx) / sigma[0]) ** 2
                                   + ((y - row - dy) / sigma[1]) ** 2))
    return np.clip(np.rint(scene.frames + streak), 0, 255).astype(np.uint8)


def test_a_stuck_bright_mark_beside_a_static_glint_is_never_lost():
    # A polished square on a stuck slider with a glint above and to the right of it in a
    # narrow ROI (the sixth blind set's b23). Until the mark's rows are known every row
    # counts, and in some frames the glint's shoulder joins the mark's dip ('mark fills the
    # ROI'): 9-18 of these 60 frames were lost (seeds 4-7), b23's slider 24 of its first 43.
    # The rows are now learned while priming and kept from the first frame on; the stuck
    # mark (in the frames' median: no static background) is found on the frames as they are.
    mark = PlateSpec(band=(20.0, 190.0), shape='bar', contrast=150.0, level=60.0, width=12.0,
                     height=12.0, amplitude=0.0, origin=300.3)
    scene = render(SceneSpec(plates={'slider': mark}, gap_level=20.0), 60, seed=5)
    frames = _glint(scene, 'slider', 29.0, -15.0, 95.0, (16.0, 3.0))
    row = int((mark.band[0] + mark.band[1]) / 2)
    rois = {'slider': (274, row - 24, 54, 48)}
    result = track(frames, rois, SCALE, fps=30.0)
    error = result.position_px['slider'] - scene.truth['slider']
    assert np.all(np.isfinite(error)), np.flatnonzero(~np.isfinite(error))
    assert result.polarity['slider'] == 'bright'
    assert _rms(error) < 0.03, _rms(error)
    # Priming knows the polarity and the rows (it knew neither: the background learned from
    # the frames' median took the stuck mark away, and the polarity was then never found)
    tracker = Tracker(rois, SCALE, 30.0)
    tracker.prime(frames)
    learned = tracker.marks['slider'].learned
    assert learned['polarity'] == 'bright' and 'static_background' not in learned
    first, last = learned['rows']
    # The mark's rows are 18-30 of the ROI, the glint's centre row 9
    assert 9 < first <= 18 and last >= 30, learned['rows']


def test_the_polarity_is_what_most_priming_frames_guess():
    """The priming frames' clear guesses vote (centroid_priming.voted_polarity).

    A dark 20 x 40 px box 30 % deep on a plate with noise, in 20 ROIs; 40 more ROIs of the
    plate alone guess nothing. Before, the first frame the mark was found in decided alone: a
    textured rectangle at 15 frames/s smeared over 0.7 of the period guessed dark in 31 of 60
    frames and bright in none, and was taken for bright (every frame then refused).
    """
    from microball_ros.core.tracking.centroid_priming import voted_polarity

    rng = np.random.default_rng(4)

    def roi(depth):
        region = np.full((80, 300), 150.0)
        start = int(rng.integers(20, 260))
        region[20:60, start:start + 20] *= 1.0 - depth
        return region + rng.normal(0.0, 2.0, region.shape)

    marked = [roi(0.3) for _ in range(20)]
    plain = [roi(0.0) for _ in range(40)]
    assert voted_polarity(plain + marked) == 'dark'
    assert voted_polarity([roi(-0.3) for _ in range(20)] + plain) == 'bright'
    assert voted_polarity(plain) is None  # nothing clear
    assert voted_polarity(marked[:2] + plain) is None  # too few clear guesses
    mixed = marked[:3] + [roi(-0.3) for _ in range(2)]
    assert voted_polarity(mixed) is None  # 3 of 5 is no verdict


def test_the_middle_rows_vote_first_where_a_texture_fills_the_rest():
    """A thin cross (21 px, strokes 5 px, 30 DN deep) on a texture of 8 DN (3-40 px waves).

    The ROI (68 rows) holds the cross in its middle rows and the texture everywhere: over
    the whole ROI the priming frames gave no verdict (too few clear guesses), and the first
    frame the centroid found a mark in took a bright spot of the texture for it (measured:
    100 px RMS, 55 of 60 frames lost). The middle third votes dark (measured: every frame
    found; its centre is still 2.6 px off, the texture's coarse dips beside the thin strokes
    taken for part of the mark, not fixed).
    """
    from microball_ros.core.tracking.centroid_priming import _vote, voted_polarity
    from microball_ros.core.tracking.plate import PlateMarkTracker

    slider = plates(shape='cross', contrast=-30.0, width=21.0, height=21.0, stroke=5.0,
                    texture=8.0, band=(20.0, 92.0), amplitude=150.0)['slider']
    scene = render(SceneSpec(plates={'slider': slider}, exposure=0.004), 60, seed=21)
    x, _, w, _ = scene.rois['slider']
    roi = (x, 22, w, 68)
    regions = [frame[22:90, x:x + w].astype(float) for frame in scene.frames]
    assert _vote(regions) is None  # the case: the whole ROI gives no verdict
    assert voted_polarity(regions) == 'dark'
    tracker = PlateMarkTracker(roi, TrackerConfig(), 'slider', 0.004 * 30.0)
    tracker.prime(list(scene.frames))
    assert tracker.polarity == 'dark'
    found = [tracker.measure(frame) for frame in scene.frames]
    assert all(m.valid for m in found)
