"""Mark tracker: accuracy against the synthetic camera's ground truth, lost marks, inputs."""

from dataclasses import replace
import math

import cv2
import numpy as np
import pytest

from microball_ros.core.camera import CameraConfig, SyntheticCamera, render_frames
from microball_ros.core.errors import InputError
from microball_ros.core.motion import paper_motion
from microball_ros.core.tracking import (
    Tracker,
    TrackerConfig,
    check_roi,
    detect_rois,
    parse_roi,
    symmetric_center,
    track,
)
from microball_ros.io.positions_csv import read_positions_csv, write_positions_csv
from microball_ros.io.video import (
    FrameSource,
    codec_available,
    iter_frames,
    track_video,
    write_image_sequence,
    write_video,
)

CONFIG = CameraConfig()
NOISIER = replace(CONFIG, electrons_per_dn=8.0, read_noise_dn=2.0)
SCALE = CONFIG.meters_per_pixel


def rms(values):
    values = np.asarray(values, dtype=float)
    assert np.all(np.isfinite(values)), 'a sample was lost'
    return float(np.sqrt(np.mean(values ** 2)))


def jumping_motion(n_frames, speed, accel, seed, config=CONFIG, spread=0.8e-3):
    """Return x(t): in each frame a fresh random position, moving at speed (+ accel)."""
    rng = np.random.default_rng(seed)
    start = rng.uniform(-spread, spread, n_frames)
    sign = rng.choice([-1.0, 1.0], n_frames)
    mid = config.frame_time(np.arange(n_frames))

    def motion(t):
        t = np.asarray(t, dtype=float)
        k = np.clip(np.floor((t - config.start_time) * config.fps).astype(int), 0, n_frames - 1)
        dt = t - mid[k]
        return start[k] + sign[k] * speed * dt + 0.5 * accel * dt * dt
    return motion


def cramer_rao_px(config, stator, slider, plate, roi, step=0.01):
    """Return the Cramer-Rao bound (px) of the plate position from the ROI's pixels."""
    camera = SyntheticCamera(config)
    shift = step * config.meters_per_pixel

    def frame(offset):
        moved = (lambda t: stator(t) + offset) if plate == 'stator' else stator
        moved_slider = (lambda t: slider(t) + offset) if plate == 'slider' else slider
        return camera.expected_frame(0, moved, moved_slider)[0]

    x, y, w, h = roi
    window = np.s_[y:y + h, x:x + w]
    expected = frame(0.0)[window]
    derivative = (frame(shift)[window] - frame(-shift)[window]) / (2 * step)
    return 1.0 / math.sqrt(float(np.sum(derivative ** 2 / config.noise_variance(expected))))


def constant(value):
    return lambda t: np.full(np.shape(t), value)


def test_still_marks_reach_the_cramer_rao_bound():
    stator, slider = constant(0.37 * SCALE), constant(-151.62 * SCALE)
    video = render_frames(stator, slider, 40, CONFIG, seed=21)
    result = track(video.frames, video.rois, SCALE, fps=30.0)
    for plate in ('stator', 'slider'):
        error = result.position_px[plate] - getattr(video.truth, plate).pixel_mean
        bound = cramer_rao_px(CONFIG, stator, slider, plate, video.rois[plate])
        assert 0.002 < bound < 0.01
        assert rms(error) < 2.5 * bound, (plate, rms(error), bound)
        assert abs(np.mean(error)) < bound
        assert np.all(result.quality[plate] > 0.9)
        # The reported sigma is a fair estimate of the actual scatter.
        assert 0.5 < np.median(result.sigma_px[plate][1:]) / rms(error) < 2.0


@pytest.mark.parametrize('config', [CONFIG, NOISIER], ids=['default-noise', 'noisier'])
@pytest.mark.parametrize('speed,accel', [(0.01, 0.0), (0.02, 0.0), (0.015, 0.3), (0.0, 0.4)])
def test_moving_blurred_marks_at_paper_speeds(config, speed, accel):
    n = 30
    stator = jumping_motion(n, speed, accel, seed=4, config=config)
    video = render_frames(stator, constant(0.0), n, config, seed=8)
    assert speed * config.exposure / SCALE <= 67.0
    result = track(video.frames, video.rois, SCALE, fps=config.fps)
    error = result.position_px['stator'] - video.truth.stator.pixel_mean
    assert rms(error) < 0.15, rms(error)


def test_blur_from_accelerated_motion_is_not_mistaken_for_a_still_mark():
    # Every exposure averages to nearly the same place (as under vibration aliased by the
    # frame rate), but the marks are smeared asymmetrically: symmetry would be off by ~0.15 px.
    n = 20
    stator = jumping_motion(n, 0.005, 0.4, seed=3, spread=1e-8)
    video = render_frames(stator, constant(0.0), n, CONFIG, seed=4)
    result = track(video.frames, video.rois, SCALE, fps=30.0)
    error = result.position_px['stator'] - video.truth.stator.pixel_mean
    assert rms(error) < 0.05
    symmetric = track(video.frames, video.rois, SCALE, fps=30.0,
                      config=TrackerConfig(method='symmetric'))
    assert rms(symmetric.position_px['stator'] - video.truth.stator.pixel_mean) > 0.08


@pytest.mark.parametrize('config', [CONFIG, NOISIER], ids=['default-noise', 'noisier'])
def test_paper_motion_tracks_the_exposure_average(config):
    stator, slider = paper_motion(slider_drift=2e-5)
    video = render_frames(stator, slider, 30, config, seed=9)
    result = track(video.frames, video.rois, SCALE, fps=config.fps, exposure=config.exposure)
    np.testing.assert_allclose(result.time, video.truth.time, atol=1e-12)
    for plate in ('stator', 'slider'):
        truth = getattr(video.truth, plate)
        assert rms(result.position_px[plate] - truth.pixel_mean) < 0.12
        # At 2.95 Hz the exposure average differs from mid-exposure by up to ~1 px.
        assert rms(result.position_px[plate] - truth.pixel_mid) > 0.3
        np.testing.assert_allclose(result.position[plate], result.position_px[plate] * SCALE)


def test_cross_marks_and_tall_rois():
    config = replace(CONFIG, mark_shape='cross')
    stator, slider = paper_motion()
    video = render_frames(stator, slider, 20, config, seed=2)
    x, y, w, h = video.rois['slider']
    rois = {'slider': (x, max(y - 60, 0), w, h + 120), 'stator': video.rois['stator']}
    result = track(video.frames, rois, SCALE, fps=30.0)
    for plate in ('stator', 'slider'):
        assert rms(result.position_px[plate] - getattr(video.truth, plate).pixel_mean) < 0.2


def test_lost_marks_give_nan_and_low_quality_then_recover():
    stator, slider = paper_motion()
    video = render_frames(stator, slider, 24, CONFIG, seed=5)
    frames = video.frames.copy()
    sx, sy, sw, sh = video.rois['slider']
    hidden = (6, 7, 8)
    for k in hidden:
        region = frames[k, sy:sy + sh, sx:sx + sw]
        region[:] = np.median(region, axis=1, keepdims=True).astype(np.uint8)
    frames[12] = 0
    frames[13] = 255
    half = int(round(video.truth.slider.pixel_mean[16]))
    frames[16, sy:sy + sh, half - 40:half] = np.median(
        frames[16, sy:sy + sh, sx:sx + sw], axis=1, keepdims=True).astype(np.uint8)
    # The stator ROI covers only the middle of the stroke: the mark leaves it and comes back.
    x, y, w, h = video.rois['stator']
    narrow = (x + 150, y, w - 300, h)
    result = track(frames, {'slider': video.rois['slider'], 'stator': narrow}, SCALE, fps=30.0)
    lost = np.zeros(24, dtype=bool)
    lost[list(hidden) + [12, 13, 16]] = True
    q, p = result.quality['slider'], result.position_px['slider']
    assert np.all(np.isnan(p[lost])) and np.all(q[lost] < 0.5)
    assert np.all(np.isfinite(p[~lost])) and np.all(q[~lost] > 0.9)
    assert rms(p[~lost] - video.truth.slider.pixel_mean[~lost]) < 0.15
    assert {result.reason['slider'][k] for k in (12, 13, 16)} == {
        'too dark', 'saturated', 'mark area changed'}
    centre = video.truth.stator.pixel_mean
    half_w = CONFIG.mark_half_extent_px()[0]
    inside = (centre - half_w - 8 > narrow[0]) & (centre + half_w + 8 < narrow[0] + narrow[2])
    outside = (centre + half_w < narrow[0]) | (centre - half_w > narrow[0] + narrow[2])
    inside[[12, 13]] = False  # blank and saturated frames
    assert inside.sum() >= 5 and outside.sum() >= 5
    p, q = result.position_px['stator'], result.quality['stator']
    assert np.all(np.isfinite(p[inside]) & (q[inside] > 0.9))
    assert np.all(np.isnan(p[~inside]) & (q[~inside] < 0.5))
    assert rms(p[inside] - centre[inside]) < 0.15


def test_low_contrast_mark_is_not_invented():
    video = render_frames(0.0, 0.0, 3, replace(CONFIG, mark_depth=0.004), seed=1)
    result = track(video.frames, video.rois, SCALE, fps=30.0)
    for plate in ('slider', 'stator'):
        assert np.all(np.isnan(result.position[plate]))
        assert np.all(result.quality[plate] < 0.5)


def test_streaming_equals_batch_and_csv_has_empty_cells(tmp_path):
    stator, slider = paper_motion()
    video = render_frames(stator, slider, 8, CONFIG, seed=6)
    frames = video.frames.copy()
    frames[3] = 0
    batch = track(frames, video.rois, SCALE, fps=30.0, exposure=CONFIG.exposure)
    tracker = Tracker(video.rois, SCALE, fps=30.0, exposure=CONFIG.exposure,
                      frame_size=(720, 480))
    for k, frame in enumerate(frames):
        out = tracker.process(frame)
        assert out.index == k and out.time == pytest.approx(batch.time[k])
        for plate in ('slider', 'stator'):
            np.testing.assert_equal(out.position(plate), batch.position[plate][k])
            assert out.quality(plate) == batch.quality[plate][k]
    stamped = track(frames, video.rois, SCALE, times=video.truth.time + 100.0)
    np.testing.assert_allclose(stamped.time, video.truth.time + 100.0)
    assert stamped.fps == pytest.approx(30.0)
    np.testing.assert_array_equal(stamped.position['slider'], batch.position['slider'])
    path = tmp_path / 'tracked.csv'
    write_positions_csv(str(path), batch.to_columns())
    header = path.read_text().splitlines()[0]
    assert header == ('time,stator_position,slider_position,slider_quality,stator_quality,'
                      'slider_sigma,stator_sigma')
    record = read_positions_csv(str(path))
    assert np.isnan(record.slider_position[3]) and np.isfinite(record.slider_position[2])
    np.testing.assert_allclose(record.stator_position, batch.position['stator'])


def test_lossless_video_and_image_folder_track_like_arrays(tmp_path):
    if not codec_available('FFV1', '.mkv'):
        pytest.skip('this OpenCV build has no FFV1 encoder (lossless video)')
    stator, slider = paper_motion()
    video = render_frames(stator, slider, 6, CONFIG, seed=7)
    from_arrays = track(video.frames, video.rois, SCALE, fps=30.0)
    path = write_video(str(tmp_path / 'marks.mkv'), video.frames, fps=30.0, codec='FFV1')
    source = FrameSource(path)
    assert source.fps == pytest.approx(30.0) and source.frame_size == (720, 480)
    from_video = track_video(path, video.rois, SCALE)
    write_image_sequence(str(tmp_path / 'frames'), video.frames)
    from_folder = track_video(str(tmp_path / 'frames'), video.rois, SCALE, fps=30.0)
    for other in (from_video, from_folder):
        np.testing.assert_array_equal(other.time, from_arrays.time)
        for plate in ('slider', 'stator'):
            np.testing.assert_array_equal(other.position[plate], from_arrays.position[plate])
            np.testing.assert_array_equal(other.quality[plate], from_arrays.quality[plate])
    colour = np.repeat(video.frames[:2, :, :, None], 3, axis=3)
    np.testing.assert_array_equal(np.array(list(iter_frames(colour))), video.frames[:2])
    # A 16-bit TIFF sequence (a scientific camera's export) tracks like its 16-bit arrays.
    deep = video.frames.astype(np.uint16) * 257
    tiffs = tmp_path / 'tiff'
    tiffs.mkdir()
    for n, frame in enumerate(deep):
        assert cv2.imwrite(str(tiffs / f'frame_{n:05d}.tif'), frame)
    from_tiff = track_video(str(tiffs), video.rois, SCALE, fps=30.0)
    from_deep = track(deep, video.rois, SCALE, fps=30.0)
    for plate in ('slider', 'stator'):
        np.testing.assert_array_equal(from_tiff.position[plate], from_deep.position[plate])
        assert np.count_nonzero(np.isfinite(from_tiff.position[plate])) == len(deep)


def test_symmetric_center_is_subpixel_exact():
    x = np.arange(64.0)
    for centre in (20.0, 31.37, 40.81):
        signal = np.exp(-0.5 * ((x - centre) / 3.0) ** 2) + np.exp(
            -0.5 * ((x - centre) / 1.2) ** 2)
        assert symmetric_center(signal, round(centre) + 0.4, 4) == pytest.approx(
            centre, abs=1e-4)


def test_bad_inputs_fail_with_one_line_messages(tmp_path):
    frames = np.zeros((2, 48, 64), dtype=np.uint8)
    cases = [
        (lambda: track_video(str(tmp_path / 'missing.avi'), {'a': (0, 0, 20, 5)}, 1e-6, 30),
         'no such file'),
        (lambda: track_video(str(_write(tmp_path / 'junk.avi', b'not a video')),
                             {'a': (0, 0, 20, 5)}, 1e-6, 30), 'cannot read video'),
        (lambda: track_video(str(tmp_path), {'a': (0, 0, 20, 5)}, 1e-6, 30), 'no image files'),
        (lambda: track(frames, {'a': (50, 0, 20, 5)}, 1e-6, 30), 'outside the 64x48 frame'),
        (lambda: track(frames, {'a': (0, 40, 20, 10)}, 1e-6, 30), 'outside the 64x48 frame'),
        (lambda: track(frames, {'a': (-1, 0, 20, 5)}, 1e-6, 30), 'starts outside'),
        (lambda: track(frames, {'a': (0, 0, 20, 5)}, 0.0, 30), 'positive'),
        (lambda: track(frames, {'a': (0, 0, 20, 5)}, -1e-6, 30), 'positive'),
        (lambda: track(frames, {'a': (0, 0, 20, 5)}, 'x', 30), 'not a number'),
        (lambda: track(frames, {'a': (0, 0, 20, 5)}, 1e-6), 'frame rate is unknown'),
        (lambda: track(frames, {'a': (0, 0, 20, 5)}, 1e-6, 0.0), 'fps'),
        (lambda: track(frames, {}, 1e-6, 30), 'at least one'),
        (lambda: track(frames, {'a': (0, 0, 20, 5)}, 1e-6, 30, times=[0.0]), 'time stamps'),
        (lambda: track(np.zeros((0, 4, 4)), {'a': (0, 0, 20, 5)}, 1e-6, 30), 'N x H x W'),
        (lambda: parse_roi('1,2,3'), 'four integers'),
        (lambda: parse_roi('1,2,a,4'), 'four integers'),
        (lambda: check_roi((0, 0, 8, 5)), 'too small'),
        (lambda: TrackerConfig(method='magic'), 'method'),
    ]
    for call, match in cases:
        with pytest.raises(InputError, match=match) as info:
            call()
        assert '\n' not in str(info.value)
    assert parse_roi(' 10, 20,30 ,40') == (10, 20, 30, 40)


def _write(path, content):
    path.write_bytes(content)
    return path


@pytest.mark.parametrize('moving', [True, False], ids=['moving', 'still'])
def test_rois_are_found_automatically(moving):
    stator, slider = paper_motion() if moving else (constant(1e-4), constant(-3e-4))
    video = render_frames(stator, slider, 24, CONFIG, seed=2)
    rois = detect_rois(video.frames)
    assert list(rois) == ['slider', 'stator']
    for plate in ('slider', 'stator'):
        x, y, w, h = rois[plate]
        span = getattr(video.truth, plate).span_px
        assert x < span[0] - 10 and span[1] + 10 < x + w
        assert y <= CONFIG.mark_row_px(plate) <= y + h
    result = track(video.frames, rois, SCALE, fps=30.0)
    for plate in ('slider', 'stator'):
        assert rms(result.position_px[plate] - getattr(video.truth, plate).pixel_mean) < 0.1
    with pytest.raises(InputError, match='no marks'):
        detect_rois(np.full((3, 48, 64), 100, np.uint8))


def _texture_frames(static, moving, n=60, noise=2.0, seed=4, period=10.3):
    """Plain 60 x 200 ROIs: a static pattern and/or one shifting along x, with noise."""
    import cv2

    rng = np.random.default_rng(seed)
    pattern = cv2.GaussianBlur(rng.standard_normal((60, 600)).astype(np.float32), (0, 0), 1.0)
    pattern /= pattern.std()
    window = cv2.GaussianBlur(rng.standard_normal((60, 200)).astype(np.float32), (0, 0), 0.8)
    window = 1 + static * window / window.std()
    shifts = np.round(150 * np.sin(2 * np.pi * np.arange(n) / period)).astype(int) + 200
    frames = np.array([150.0 * window * (1 + moving * pattern[:, s:s + 200]) for s in shifts])
    return frames + noise * rng.standard_normal(frames.shape), window


@pytest.mark.parametrize('static, moving, period, learned', [
    (0.08, 0.0, 10.3, True), (0.0, 0.08, 10.3, False), (0.0, 0.0, 10.3, False),
    # Every 20th frame alike: the mean keeps pixel-scale structure (a test that the texture
    # moves is needed, the noise of the mean alone does not tell).
    (0.0, 0.08, 20.0, False), (0.0, 0.2, 20.0, False)])
def test_static_background_is_learned_only_for_a_pattern_fixed_in_the_image(
        static, moving, period, learned):
    from microball_ros.core.tracking.background import StaticBackground

    frames, window = _texture_frames(static, moving, period=period)
    background = StaticBackground()
    background.learn(frames, np.zeros((frames.shape[0], frames.shape[2]), dtype=bool))
    assert (background.inverse is not None) == learned, background.gain
    if learned:
        # The pattern is removed to the noise of a mean of 60 frames (2 DN / 150 / sqrt(60)
        # = 0.17 %), against 8 % before.
        corrected = window * background.inverse
        assert np.std(corrected / corrected.mean()) < 0.004
        assert background.kind == 'divided'


@pytest.mark.parametrize('multiplicative', [1.0, 0.0])
@pytest.mark.parametrize('grain', [0.7, 1.5])
def test_static_pattern_is_divided_when_a_transmission_and_subtracted_when_light_added(
        multiplicative, grain):
    # A pair of bars (60 % deep) moving 4 Hz at 60 fps under a fine pattern fixed in the image
    # (12 % std): a transmission darkens with the mark, light added does not. The learner
    # must tell them apart (by the spread of the mark's integrated deficit over the priming
    # frames), and what it removes must leave the mark's columns flat to the noise.
    import cv2

    from microball_ros.core.tracking.background import StaticBackground, area_scatter

    rng = np.random.default_rng(7)
    h, w, level = 60, 300, 160.0
    pattern = cv2.GaussianBlur(rng.standard_normal((h, w)).astype(np.float32), (0, 0), grain)
    pattern *= 0.12 / pattern.std()
    columns = np.arange(w)
    frames, covered = [], np.zeros((60, w), dtype=bool)
    for i in range(60):
        center = 150 + 110 * np.sin(2 * np.pi * i / 15 + 0.3)
        mark = np.ones(w)
        for offset in (-10, 10):
            mark -= 0.6 * np.clip(np.minimum(columns - (center + offset - 3) + 0.5,
                                             center + offset + 3 - columns + 0.5), 0, 1)
        mark = np.tile(mark, (h, 1))
        mark[:12] = mark[-12:] = 1
        a = multiplicative
        frames.append(level * mark * (1 + a * pattern) + (1 - a) * level * pattern
                      + rng.standard_normal((h, w)))
        covered[i, int(center - 25):int(center + 26)] = True
    frames = np.array(frames, dtype=np.float32)
    background = StaticBackground()
    background.learn(frames, covered)
    assert background.kind == ('divided' if multiplicative else 'subtracted')
    # The other way leaves the pattern on the mark: its integrated deficit spreads at least
    # 1.3 times as much over the frames.
    if multiplicative:
        other = area_scatter(frames, covered, level * pattern, np.ones((h, w), np.float32),
                             level)
        own = area_scatter(frames, covered, None, background.inverse, level)
    else:
        other = area_scatter(frames, covered, None,
                             (1.0 / (1.0 + pattern)).astype(np.float32), level)
        own = area_scatter(frames, covered, background.added, background.inverse,
                           background.reference)
    assert other > 1.3 * own, (other, own)
