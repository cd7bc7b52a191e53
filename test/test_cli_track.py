"""`microball render` / `microball track`: frames of the simulated rig -> positions -> analysis."""

import json
import subprocess
import sys

import cv2
import numpy as np
import pytest

from microball_ros.cli import main
from microball_ros.core import bench, rig
from microball_ros.io.positions_csv import read_positions_csv, write_positions_csv
from microball_ros.io.video import FrameSource, write_image_sequence, write_video


@pytest.fixture(scope='module')
def paper_video(tmp_path_factory):
    folder = tmp_path_factory.mktemp('video')
    video, _ = rig.render_bench(bench.get_scenario('paper'), 20.0)
    path = str(folder / 'paper.mkv')
    write_video(path, video.frames, fps=video.config.fps)
    return folder, path, video


def _track_args(video, path, output):
    rois = {name: ','.join(map(str, roi)) for name, roi in video.rois.items()}
    return ['track', path, '--slider-roi', rois['slider'], '--stator-roi', rois['stator'],
            '--meters-per-pixel', repr(video.config.meters_per_pixel),
            '--exposure', repr(video.config.exposure), '--output', output]


def _analyze(csv_path, json_path):
    assert main(['analyze', str(csv_path), '--json', str(json_path)]) == 0
    return json.loads(json_path.read_text())


def test_tracked_video_gives_the_same_verdict_and_model_as_the_true_positions(paper_video):
    folder, path, video = paper_video
    tracked_csv = folder / 'tracked.csv'
    assert main(_track_args(video, path, str(tracked_csv))) == 0
    record = read_positions_csv(str(tracked_csv))
    assert record.valid.all()
    # Sub-pixel: the tracked positions follow the exposure-averaged truth (up to the constant
    # offset between image and plate coordinates).
    scale = video.config.meters_per_pixel
    for mark in ('slider', 'stator'):
        truth = getattr(video.truth, mark).pixel_mean * scale
        error = getattr(record, f'{mark}_position') - truth
        assert np.std(error) / scale < 0.1
    np.testing.assert_allclose(record.time, video.truth.time, atol=1e-6)

    true_csv = folder / 'true.csv'
    write_positions_csv(str(true_csv), {
        'time': video.truth.time, 'stator_position': video.truth.stator.position_mean,
        'slider_position': video.truth.slider.position_mean})
    tracked = _analyze(tracked_csv, folder / 'tracked.json')
    true = _analyze(true_csv, folder / 'true.json')
    assert tracked['memoryless'] is true['memoryless'] is True
    assert tracked['phase_difference'] == pytest.approx(true['phase_difference'], abs=0.02)
    slope = true['model']['A'] * true['model']['alpha'] / 3
    assert tracked['model']['A'] * tracked['model']['alpha'] / 3 == pytest.approx(slope,
                                                                                  rel=0.03)
    # The model from the true positions lies within the tracked model's own intervals.
    for name in ('A', 'alpha'):
        low, high = tracked['model'][f'{name}_ci95']
        assert low <= true['model'][name] <= (high if high is not None else np.inf)


def test_a_hidden_mark_leaves_empty_cells_and_is_reacquired(paper_video, tmp_path):
    _, _, video = paper_video
    frames = video.frames[:120].copy()
    x, y, w, h = video.rois['slider']
    frames[40:46, y:y + h, x:x + w] = 170  # the mark is covered by a bright particle
    images = tmp_path / 'frames'
    write_image_sequence(str(images), frames)
    output = tmp_path / 'tracked.csv'
    assert main(_track_args(video, str(images), str(output)) + ['--fps', '30']) == 0
    lines = output.read_text().splitlines()
    assert lines[0] == ('time,stator_position,slider_position,slider_quality,stator_quality,'
                        'slider_sigma,stator_sigma')
    rows = [line.split(',') for line in lines[1:]]
    assert len(rows) == 120
    lost = [k for k, row in enumerate(rows) if row[2] == '']
    assert lost == list(range(40, 46))
    # The standard error is empty exactly where the position is, and sub-pixel elsewhere.
    assert [k for k, row in enumerate(rows) if row[5] == ''] == lost
    scale = video.config.meters_per_pixel
    assert all(0 < float(row[5]) / scale < 0.2 for k, row in enumerate(rows) if k not in lost)
    assert all(float(rows[k][3]) < 0.5 for k in lost)
    assert all(row[1] != '' for row in rows)
    assert float(rows[46][3]) > 0.5


def _run(*argv):
    return subprocess.run([sys.executable, '-m', 'microball_ros.cli', *argv],
                          capture_output=True, text=True, timeout=120)


@pytest.mark.parametrize('change, message', [
    ({'video': 'absent.mkv'}, 'no such file'),
    ({'video': 'garbage.mkv'}, 'cannot read video'),
    ({'--slider-roi': '700,10,300,40'}, 'outside'),
    ({'--meters-per-pixel': '0'}, 'positive'),
    ({'--meters-per-pixel': '-2e-6'}, 'positive'),
    ({'--stator-roi': '1,2,3'}, 'four integers'),
    ({'--black-level': '-3'}, '>= 0'),
    ({'--black-level': 'dark'}, 'not a number'),
    ({'--gamma': '0'}, 'positive'),
    ({'--gamma': '9'}, 'gamma must be in 0.2 .. 5'),
    ({'--gamma': 'sRGB'}, 'not a number'),
])
def test_bad_track_input_gives_one_line_and_exit_2(paper_video, tmp_path, change, message):
    _, path, video = paper_video
    (tmp_path / 'garbage.mkv').write_bytes(b'not a video at all')
    args = _track_args(video, path, str(tmp_path / 'out.csv'))
    for key, value in change.items():
        if key == 'video':
            args[1] = str(tmp_path / value)
        elif key not in args:
            args.append(f'{key}={value}')
        else:  # KEY=VALUE, so that argparse takes a negative number as the value
            at = args.index(key)
            args[at:at + 2] = [f'{key}={value}']
    result = _run(*args)
    assert result.returncode == 2
    lines = [line for line in result.stderr.splitlines() if not line.startswith('tracked ')]
    assert len(lines) == 1 and message in lines[0], result.stderr
    assert not (tmp_path / 'out.csv').exists()


def test_polarity_and_preview(paper_video, tmp_path):
    _, path, video = paper_video
    preview = tmp_path / 'preview.png'
    args = _track_args(video, path, str(tmp_path / 'out.csv'))
    at = args.index('--output')
    del args[at:at + 2]
    assert main(args + ['--preview', str(preview), '--preview-frames', '30']) == 0
    import cv2

    image = cv2.imread(str(preview))
    assert image.shape == (480, 720, 3)
    x, y, w, h = video.rois['slider']
    assert tuple(image[y, x + w // 2]) == (255, 128, 0)  # the ROI box is drawn
    assert not (tmp_path / 'out.csv').exists()  # a preview only: no CSV
    # Forcing the wrong polarity finds no dark mark's twin: every sample is lost.
    bright = tmp_path / 'bright.csv'
    assert main(_track_args(video, path, str(bright)) + ['--polarity', 'bright']) == 0
    record = read_positions_csv(str(bright))
    assert np.isnan(record.slider_position).mean() > 0.9
    result = _run('track', path, '--slider-roi', '1,1,40,10', '--stator-roi', '1,20,40,10',
                  '--meters-per-pixel', '1e-6', '--polarity', 'grey', '--output', 'x.csv')
    assert result.returncode == 2 and 'polarity' in result.stderr


def test_track_says_how_well_a_textured_marks_centre_is_known(tmp_path, capsys):
    """The error of a textured mark's centre is one in every frame: said once, in sigma too."""
    from tracking_scenes import SceneSpec, plates
    from tracking_scenes import render as render_scene

    scene = render_scene(SceneSpec(plates=plates(shape='cross', width=40.0, height=40.0,
                                                 texture=8.0)), 90, seed=6)
    write_image_sequence(tmp_path / 'frames', scene.frames)
    rois = {name: ','.join(map(str, roi)) for name, roi in scene.rois.items()}
    output = tmp_path / 'out.csv'
    assert main(['track', str(tmp_path / 'frames'), '--slider-roi', rois['slider'],
                 '--stator-roi', rois['stator'], '--meters-per-pixel', '1e-6', '--fps', '30',
                 '--exposure', repr(scene.spec.exposure), '--output', str(output)]) == 0
    said = capsys.readouterr().out.splitlines()[-1]
    assert said.startswith("marks' centres on their plates: slider +-")
    table = np.genfromtxt(output, delimiter=',', names=True)
    for name in ('slider', 'stator'):
        centre = float(said.split(f'{name} +-')[1].split(' px')[0]) * 1e-6
        # the centre's part is in every frame's sigma (printed to 0.001 px)
        assert 0.0 < centre <= np.nanmin(table[f'{name}_sigma']) + 0.5e-9
        error = table[f'{name}_position'] - scene.truth[name] * 1e-6
        assert abs(float(np.nanmean(error))) < 3.0 * centre + 3.0 * float(
            np.nanstd(error)) / np.sqrt(np.count_nonzero(np.isfinite(error)))


@pytest.mark.parametrize(('codec', 'suffix', 'warned'), [('MJPG', 'avi', True),
                                                         ('FFV1', 'mkv', False)])
def test_track_warns_that_a_lossy_videos_centre_errors_may_be_low(tmp_path, capsys, codec,
                                                                 suffix, warned):
    """A textured mark's centre error is said with a caveat on MJPEG, not on FFV1."""
    from tracking_scenes import SceneSpec, plates
    from tracking_scenes import render as render_scene

    scene = render_scene(SceneSpec(plates=plates(shape='cross', width=40.0, height=40.0,
                                                 texture=8.0)), 70, seed=6)
    frames = [np.clip(np.rint(f), 0, 255).astype(np.uint8) for f in scene.frames]
    video = write_video(tmp_path / f'video.{suffix}', frames, codec=codec)
    rois = {name: ','.join(map(str, roi)) for name, roi in scene.rois.items()}
    assert main(['track', str(video), '--slider-roi', rois['slider'], '--stator-roi',
                 rois['stator'], '--meters-per-pixel', '1e-6', '--fps', '30', '--exposure',
                 repr(scene.spec.exposure), '--output', str(tmp_path / 'out.csv')]) == 0
    said = capsys.readouterr().out.splitlines()
    assert any(line.startswith("marks' centres on their plates:") for line in said)
    lossy = [line for line in said if line.startswith('lossy video')]
    assert lossy == ([f'lossy video ({codec}): on MPEG-4 and MJPEG videos a textured mark'
                      "'s centre was up to 5 times further off than said (2 of 4 marks "
                      'tested; README)'] if warned else [])


@pytest.mark.parametrize('black, given', [(0.0, False), (10.0, True), (10.0, False)])
def test_track_says_how_many_frames_a_shadow_was_divided_out_of(tmp_path, capsys, black,
                                                                 given):
    """A shadow sweeping over both marks: the frames are counted, the dark offset said.

    The camera's dark offset, when not given, is said as estimated from the shadow
    (core.tracking.shade.BlackLevel).
    """
    from dataclasses import replace

    from tracking_scenes import PlateSpec, SceneSpec
    from tracking_scenes import render as render_scene

    mark = PlateSpec(band=(30.0, 150.0), width=16.0, height=30.0, contrast=-120.0,
                     level=150.0, amplitude=90.0, frequency=0.9, origin=240.0)
    spec = SceneSpec(plates={'slider': mark, 'stator': replace(mark, band=(200.0, 320.0),
                                                                phase=1.0)},
                     width=480, height=350, fps=25.0, exposure=0.02, black=black,
                     shadow=(60, 110, 60.0, 420.0, 40.0, 8.0, 0.45, 20.0))
    scene = render_scene(spec, 120, seed=4)
    video = write_video(tmp_path / 'video.mkv', list(scene.frames), codec='FFV1')
    argv = ['track', str(video), '--slider-roi', '100,55,280,70', '--stator-roi',
            '100,225,280,70', '--meters-per-pixel', '1e-6', '--fps', '25', '--exposure', '0.02',
            '--output', str(tmp_path / 'out.csv')]
    assert main(argv + (['--black-level', '10'] if given else [])) == 0
    said = [line for line in capsys.readouterr().out.splitlines() if 'shadow' in line]
    assert len(said) == 1, said
    counts = said[0].split('divided out of ')[1].split(' frames')[0].split(' / ')
    assert all(30 <= int(count) <= 50 for count in counts), said  # 41: the band over an ROI
    assert said[0].endswith('--black-level DN)') is not given
    if not given:
        offset, sigma = map(float, said[0].split('from the shadow: ')[1].split(' DN')[0]
                            .split(' +- '))
        assert 0.0 < sigma < 1.5
        assert abs(offset - black) < max(3.0 * sigma, 0.5), said
    table = np.genfromtxt(tmp_path / 'out.csv', delimiter=',', names=True)
    for name in ('slider', 'stator'):
        assert np.count_nonzero(np.isnan(table[f'{name}_position'])) <= 2


def test_a_folder_of_jpeg_images_is_lossy_and_of_png_is_not(tmp_path):
    frame = np.full((20, 30), 100, np.uint8)
    for kind in ('png', 'jpg'):
        (tmp_path / kind).mkdir()
        assert cv2.imwrite(str(tmp_path / kind / f'f0.{kind}'), frame)
    assert FrameSource(tmp_path / 'jpg').lossy and not FrameSource(tmp_path / 'png').lossy
    assert FrameSource(tmp_path / 'png').codec == '' and FrameSource(frame).lossy is False


def test_track_says_when_the_video_is_a_raw_colour_mosaic(tmp_path, capsys):
    """Raw Bayer frames saved as a grey video (FFV1) are smoothed, and the command says so."""
    from test_tracking_mosaic import mosaic_scene
    from tracking_scenes import SceneSpec, plates

    scene, frames = mosaic_scene(SceneSpec(plates=plates(amplitude=120.0)), 70, seed=5)
    video = write_video(tmp_path / 'raw.mkv', frames)
    rois = {name: ','.join(map(str, roi)) for name, roi in scene.rois.items()}
    output = tmp_path / 'out.csv'
    assert main(['track', str(video), '--slider-roi', rois['slider'], '--stator-roi',
                 rois['stator'], '--meters-per-pixel', '1e-6', '--fps', '30', '--exposure',
                 repr(scene.spec.exposure), '--output', str(output)]) == 0
    said = capsys.readouterr().out.splitlines()
    assert sum('raw colour mosaic' in line for line in said) == 1
    table = np.genfromtxt(output, delimiter=',', names=True)
    for name in ('slider', 'stator'):
        error = table[f'{name}_position'] / 1e-6 - scene.truth[name]
        assert np.all(np.isfinite(error)), name
        assert float(np.sqrt(np.mean(error ** 2))) < 0.06, name


def test_track_finds_and_says_a_cameras_gamma(tmp_path, capsys):
    """Frames encoded with gamma 2.2 (core.tracking.gamma): found, decoded, and said once."""
    from tracking_scenes import SceneSpec
    from tracking_scenes import render as render_scene

    scene = render_scene(SceneSpec(gamma=2.2), 90, seed=11)
    video = write_video(tmp_path / 'video.mkv', list(scene.frames), codec='FFV1')
    rois = {name: ','.join(map(str, roi)) for name, roi in scene.rois.items()}
    argv = ['track', str(video), '--slider-roi', rois['slider'], '--stator-roi',
            rois['stator'], '--meters-per-pixel', '5e-6', '--fps', '30',
            '--exposure', repr(1.0 / 60.0)]
    assert main(argv + ['--output', str(tmp_path / 'found.csv')]) == 0
    said = [line for line in capsys.readouterr().out.splitlines() if 'gamma' in line]
    assert len(said) == 1 and 'decoded with gamma 2.' in said[0], said
    assert main(argv + ['--gamma', '1', '--output', str(tmp_path / 'read.csv')]) == 0
    assert not [line for line in capsys.readouterr().out.splitlines() if 'gamma' in line]
    found = np.genfromtxt(tmp_path / 'found.csv', delimiter=',', names=True)
    for name in ('slider', 'stator'):
        error = found[f'{name}_position'] / 5e-6 - scene.truth[name]
        assert np.all(np.isfinite(error)) and np.sqrt(np.mean(error ** 2)) < 0.06, name
