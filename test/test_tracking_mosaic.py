"""A raw colour mosaic read as grey frames is found and smoothed (core.tracking.mosaic).

Scenes from test/tracking_scenes.py, their noiseless frames seen through a Bayer pattern: the
plate through raw channel gains 0.8 / 1 / 1 / 0.7, the mark (another colour) through 1 / 0.8
/ 0.8 / 1.3, then shot and read noise. Truth as for the grey scene.
"""

from dataclasses import replace
import sys

import numpy as np
import pytest

sys.path.insert(0, __file__.rsplit('/', 1)[0])
from tracking_scenes import SceneSpec, plates, render  # noqa: E402

from microball_ros.core.tracking import mosaic, track  # noqa: E402

SCALE = 5e-6


def bayer(shape, gains):
    pattern = np.empty(shape)
    pattern[0::2, 0::2], pattern[0::2, 1::2], pattern[1::2, 0::2], pattern[1::2, 1::2] = gains
    return pattern


def mosaic_scene(spec, n_frames, seed):
    """Return the grey scene and its frames as a raw mosaic (uint8)."""
    scene = render(spec, n_frames, seed=seed, keep_expected=True)
    bare = render(replace(spec, plates={name: replace(plate, contrast=0.0)
                                        for name, plate in spec.plates.items()}),
                  n_frames, seed=seed, keep_expected=True)
    rng = np.random.default_rng(seed + 1)
    frames = []
    for full, plate in zip(scene.expected, bare.expected, strict=True):
        raw = (plate * bayer(plate.shape, (0.8, 1.0, 1.0, 0.7))
               + (full - plate) * bayer(plate.shape, (1.0, 0.8, 0.8, 1.3)))
        raw = raw + np.sqrt(np.clip(raw, 0, None) / spec.gain + spec.read_noise ** 2) * (
            rng.standard_normal(raw.shape))
        frames.append(np.clip(np.rint(raw), 0, 255).astype(np.uint8))
    return scene, np.array(frames)


def rms(result, scene):
    return {name: float(np.sqrt(np.nanmean((result.position_px[name] - truth) ** 2)))
            for name, truth in scene.truth.items()}


def test_a_raw_mosaic_on_a_textured_plate_is_tracked_as_its_grey_scene(monkeypatch):
    # A blob on a 6 DN texture: through the mosaic 0.23 / 0.48 px RMS; smoothed 0.05 / 0.16,
    # as the grey scene itself (0.06 / 0.19: a textured blob's centre offset).
    spec = SceneSpec(plates=plates(shape='blob', width=14.0, amplitude=120.0, texture=6.0))
    scene, frames = mosaic_scene(spec, 60, seed=8)
    grey = rms(track(scene.frames, scene.rois, SCALE, spec.fps, spec.exposure), scene)
    result = track(frames, scene.rois, SCALE, spec.fps, spec.exposure)
    assert result.mosaic
    smoothed = rms(result, scene)
    monkeypatch.setattr(mosaic, 'MOSAIC_SPREAD', np.inf)
    raw = track(frames, scene.rois, SCALE, spec.fps, spec.exposure)
    assert not raw.mosaic
    unsmoothed = rms(raw, scene)
    for name in scene.truth:
        assert smoothed[name] < 1.2 * grey[name] + 0.01, name
        assert unsmoothed[name] > 2.0 * smoothed[name], name


def test_only_a_mosaic_is_taken_for_one():
    spec = SceneSpec(plates=plates(texture=6.0))
    scene, frames = mosaic_scene(spec, 8, seed=3)
    assert mosaic.phase_spread(scene.frames) < 0.1 * mosaic.MOSAIC_SPREAD
    assert not mosaic.is_mosaic(scene.frames)
    assert mosaic.phase_spread(frames) > 3 * mosaic.MOSAIC_SPREAD
    assert mosaic.is_mosaic(frames)


@pytest.mark.parametrize('dtype', [np.uint8, np.uint16, np.float32])
def test_unmosaic_removes_the_pattern_and_moves_nothing(dtype):
    level = 100.0 if dtype == np.uint8 else 20000.0
    flat = (level * bayer((40, 60), (0.8, 1.0, 1.0, 0.7))).astype(dtype)
    out = mosaic.unmosaic(flat)
    assert out.dtype == dtype
    inner = out[1:-1, 1:-1].astype(float)
    assert np.ptp(inner) <= 1.0  # rounding to the pixel type at most
    assert inner.mean() == pytest.approx(0.875 * level, abs=0.5)
    # A symmetric line stays where it was: its centroid does not move.
    line = np.zeros((40, 60), dtype=np.float32)
    line[:, 29:32] = [1.0, 2.0, 1.0]
    smoothed = mosaic.unmosaic(line)[20]
    assert float(smoothed @ np.arange(60) / smoothed.sum()) == pytest.approx(30.0, abs=1e-6)
