"""Synthetic camera: the frames agree with the ground truth it returns."""

from dataclasses import replace
import math

import numpy as np
import pytest

from microball_ros.core.camera import CameraConfig, SyntheticCamera, box_profile, render_frames
from microball_ros.core.errors import InputError
from microball_ros.core.motion import as_motion, paper_motion
from microball_ros.io.video import codec_available, write_image_sequence, write_video

CONFIG = CameraConfig()


def relative_deficit(camera, frame, plate):
    """Return the x-profile of 1 - frame / (same scene without marks) over the mark's rows."""
    empty = SyntheticCamera(replace(camera.config, mark_depth=0.0))
    background, _ = empty.expected_frame(0, 0.0, 0.0)
    row = camera.config.mark_row_px(plate)
    half_h = camera.config.mark_half_extent_px()[1]
    rows = slice(int(row - half_h - 5), int(row + half_h + 6))
    return (1.0 - frame[rows] / background[rows]).sum(axis=0)


def centroid(profile):
    columns = np.arange(profile.size)
    return float(profile @ columns / profile.sum())


@pytest.mark.parametrize('shape', ['bar', 'cross'])
@pytest.mark.parametrize('plate,position', [('stator', 0.37 * 5e-6), ('slider', -123.81 * 5e-6)])
def test_still_mark_centroid_is_its_true_position(shape, plate, position):
    camera = SyntheticCamera(replace(CONFIG, mark_shape=shape))
    stator, slider = (position, 2e-4) if plate == 'stator' else (2e-4, position)
    frame, truth = camera.expected_frame(0, stator, slider)
    expected_px = CONFIG.to_px(plate, position)
    assert getattr(truth, f'{plate}_mid') == pytest.approx(position, abs=1e-15)
    assert abs(centroid(relative_deficit(camera, frame, plate)) - expected_px) < 0.05
    # The analytic edge model integrates to the box width (anti-aliasing conserves area).
    area = box_profile(np.arange(100.0), [50.3], 7.2, 0.9).sum()
    assert area == pytest.approx(14.4, abs=1e-9)


def test_blur_length_is_speed_times_exposure_and_centroid_the_exposure_average():
    camera = SyntheticCamera(CONFIG)
    speed = 0.012
    still, _ = camera.expected_frame(0, 0.0, 0.0)
    moving, truth = camera.expected_frame(0, lambda t: speed * (t - 0.005), 0.0)
    var = {}
    for name, frame in (('still', still), ('moving', moving)):
        profile = relative_deficit(camera, frame, 'stator')
        c = centroid(profile)
        var[name] = float(profile @ (np.arange(profile.size) - c) ** 2 / profile.sum())
    blur_px = math.sqrt(12.0 * (var['moving'] - var['still']))
    expected = speed * CONFIG.exposure / CONFIG.meters_per_pixel
    assert expected == pytest.approx(40.0)
    assert blur_px == pytest.approx(expected, rel=0.01)
    # Accelerated motion: the blurred centroid is the exposure average, not mid-exposure.
    accel = 0.4
    frame, truth = camera.expected_frame(
        0, lambda t: 0.5 * accel * (t - CONFIG.exposure / 2) ** 2, 0.0)
    mean_px, mid_px = CONFIG.to_px('stator', truth.stator_mean), CONFIG.to_px('stator', 0.0)
    assert truth.stator_mid == pytest.approx(0.0, abs=1e-15)
    # (The exposure is sampled at >= 16 sub-interval midpoints: 0.4 % quadrature error.)
    assert mean_px - mid_px == pytest.approx(
        accel * CONFIG.exposure ** 2 / 24 / CONFIG.meters_per_pixel, rel=4e-3)
    assert abs(centroid(relative_deficit(camera, frame, 'stator')) - mean_px) < 0.01


def test_ground_truth_times_positions_and_rois():
    stator, slider = paper_motion()
    video = render_frames(stator, slider, 6, CONFIG, seed=1)
    truth = video.truth
    assert video.frames.shape == (6, 480, 720) and video.frames.dtype == np.uint8
    np.testing.assert_allclose(truth.time, np.arange(6) / 30.0 + 1.0 / 120.0, atol=1e-12)
    np.testing.assert_allclose(truth.stator.position_mid, stator(truth.time), atol=1e-15)
    for plate in ('slider', 'stator'):
        mark = getattr(truth, plate)
        np.testing.assert_allclose(mark.pixel_mid,
                                   359.5 + mark.position_mid / CONFIG.meters_per_pixel)
        x, y, w, h = video.rois[plate]
        half_w, half_h = CONFIG.mark_half_extent_px()
        assert x <= mark.span_px[0] - half_w - 2 and mark.span_px[1] + half_w + 2 <= x + w
        row = CONFIG.mark_row_px(plate)
        assert y <= row - half_h and row + half_h <= y + h
        assert 0 <= x and x + w <= 720 and 0 <= y and y + h <= 480
    # Exposure average of a sinusoid: the mid-exposure value times sinc(w T / 2).
    wt2 = 2 * math.pi * 2.95 * CONFIG.exposure / 2
    np.testing.assert_allclose(truth.stator.position_mean,
                               truth.stator.position_mid * math.sin(wt2) / wt2, atol=2e-9)


def test_seeded_and_frame_by_frame_reproducible():
    stator, slider = paper_motion()
    a = render_frames(stator, slider, 3, CONFIG, seed=5)
    b = render_frames(stator, slider, 3, CONFIG, seed=5)
    c = render_frames(stator, slider, 3, CONFIG, seed=6)
    np.testing.assert_array_equal(a.frames, b.frames)
    assert np.mean(a.frames != c.frames) > 0.5
    alone, truth = SyntheticCamera(CONFIG, seed=5).render_frame(2, stator, slider)
    np.testing.assert_array_equal(alone, a.frames[2])
    assert truth.stator_mean == a.truth.stator.position_mean[2]


@pytest.mark.parametrize('gain,read', [(20.0, 1.0), (4.0, 3.0)])
def test_noise_level_is_as_configured(gain, read):
    config = replace(CONFIG, electrons_per_dn=gain, read_noise_dn=read)
    camera = SyntheticCamera(config, seed=2)
    expected, _ = camera.expected_frame(0, 0.0, 0.0)
    first, second = camera.add_noise(expected, 0), camera.add_noise(expected, 1)
    plate = np.s_[360:440, 30:300]
    difference = first[plate].astype(float) - second[plate].astype(float)
    measured = difference.var() / 2.0
    predicted = config.noise_variance(expected[plate]).mean()
    assert measured == pytest.approx(predicted, rel=0.05)
    assert abs(first[plate].mean() - expected[plate].mean()) < 0.1


def test_saturation_clips_at_255():
    config = replace(CONFIG, plate_level=300.0)
    frame, _ = SyntheticCamera(config).render_frame(0, 0.0, 0.0)
    assert frame.max() == 255 and np.mean(frame[360:440] == 255) > 0.9


def test_sampled_motion_equals_function_and_checks_its_range():
    stator, slider = paper_motion()
    times = np.arange(0.0, 0.2, 1e-3)
    by_samples = render_frames((times, stator(times)), (times, slider(times)), 3, CONFIG)
    by_function = render_frames(stator, slider, 3, CONFIG)
    np.testing.assert_allclose(by_samples.truth.stator.position_mean,
                               by_function.truth.stator.position_mean, atol=1e-11)
    assert np.mean(by_samples.frames != by_function.frames) < 1e-3
    with pytest.raises(InputError, match='cover t in'):
        render_frames((times, stator(times)), 0.0, 10, CONFIG)
    with pytest.raises(InputError, match='increase'):
        as_motion((times[::-1], times))


@pytest.mark.parametrize('change,match', [
    ({'meters_per_pixel': 0.0}, 'meters_per_pixel'), ({'exposure': 0.05}, 'frame period'),
    ({'mark_shape': 'star'}, 'mark_shape'), ({'mark_depth': 1.5}, 'mark_depth'),
    ({'slider_band': (0.7, 0.9)}, 'above')])
def test_bad_configuration_is_rejected(change, match):
    with pytest.raises(InputError, match=match):
        replace(CONFIG, **change)


def test_infrared_mode_shows_balls_rolling_at_the_mean_plate_position():
    config = replace(CONFIG, infrared=True)
    video = render_frames(1e-4, 3e-4, 1, config, noise=False)
    balls = video.truth.balls
    assert balls.position_mean[0] == pytest.approx(2e-4)
    camera = SyntheticCamera(config)
    row = int(round((config.slider_band[1] + config.stator_band[0]) / 2 * config.height))
    profile = config.infrared_gap_level - video.frames[0, row - 5:row + 6].mean(axis=0)
    center = balls.pixel_mean[0]
    window = np.arange(int(center) - 35, int(center) + 36)
    assert profile[window].max() > 50
    assert abs(centroid(np.clip(profile[window], 0, None)) + window[0] - center) < 0.5
    assert camera.config.ball_diameter / config.meters_per_pixel == pytest.approx(57.0)


def test_lossless_video_and_image_folder_round_trip(tmp_path):
    import cv2

    if not codec_available('FFV1', '.mkv'):
        pytest.skip('this OpenCV build has no FFV1 encoder (lossless video)')
    stator, slider = paper_motion()
    frames = render_frames(stator, slider, 3, CONFIG, seed=3).frames
    path = write_video(str(tmp_path / 'v.mkv'), frames, fps=30.0, codec='FFV1')
    capture = cv2.VideoCapture(path)
    back = []
    while True:
        ok, frame = capture.read()
        if not ok:
            break
        back.append(cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY) if frame.ndim == 3 else frame)
    capture.release()
    np.testing.assert_array_equal(np.array(back), frames)
    paths = write_image_sequence(str(tmp_path / 'images'), frames)
    np.testing.assert_array_equal(cv2.imread(paths[1], cv2.IMREAD_UNCHANGED), frames[1])


def test_lossy_video_is_close(tmp_path):
    import cv2

    if not codec_available('MJPG', '.avi'):
        pytest.skip('this OpenCV build has no MJPG encoder (lossy video)')
    frames = render_frames(0.0, 0.0, 2, CONFIG, seed=3).frames
    path = write_video(str(tmp_path / 'v.avi'), frames, codec='MJPG')
    ok, frame = cv2.VideoCapture(path).read()
    error = np.abs(frame[:, :, 0].astype(float) - frames[0])
    assert ok and 0 < error.mean() < 3.0


def test_write_video_rejects_bad_input(tmp_path):
    with pytest.raises(InputError, match='FourCC'):
        write_video(str(tmp_path / 'v.avi'), [np.zeros((8, 8), np.uint8)], codec='FFV')
    with pytest.raises(InputError, match='2-D uint8'):
        write_video(str(tmp_path / 'v.avi'), [np.zeros((8, 8), np.float32)])
