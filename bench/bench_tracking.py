"""Benchmark the mark tracker against ground truth, the Cramer-Rao bound and OpenCV baselines.

Run: ``python bench/bench_tracking.py [--frames N] [--seed S]``. Prints plain tables; asserts
nothing. Frames come from the synthetic camera (microball_ros.core.camera) with its default
settings (720 x 480, 30 fps, 1/60 s exposure, 5 um/px, 100 x 250 um bar marks) and a noisier
variant. Errors are in pixels against the exposure-averaged position (what a blurred frame
encodes); the Cramer-Rao bound (CRB) is computed numerically from the noiseless rendered ROI:
var >= 1 / sum((dI/dx)^2 / sigma_i^2), sigma_i^2 the configured per-pixel noise variance.

Baselines, all given the same ROI:
  cv2.matchTemplate  TM_CCOEFF_NORMED, template cut from a noiseless still frame, integer peak
  + parabola         the same with a 3-point parabolic sub-pixel fit of the peak
  cv2.phaseCorrelate the ROI against the same ROI of a noiseless still frame, both high-passed
                     (minus a 15 px Gaussian blur, which removes the static illumination that
                     otherwise pins the peak at zero shift; better than a Hanning window here)
"""

import os

for _name in ('OMP_NUM_THREADS', 'OPENBLAS_NUM_THREADS', 'MKL_NUM_THREADS'):
    os.environ.setdefault(_name, '1')

import argparse  # noqa: E402
from dataclasses import replace  # noqa: E402
import math  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402

import cv2  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from microball_ros.core.camera import CameraConfig, SyntheticCamera, render_frames  # noqa: E402
from microball_ros.core.motion import paper_motion  # noqa: E402
from microball_ros.core.tracking import Tracker, track  # noqa: E402
from microball_ros.io.video import codec_available, track_video, write_video  # noqa: E402

OMEGA = 2 * math.pi * 2.95
AMPLITUDE = 1.2e-3
CAMERA_FPS = 30.0


def rms(values):
    values = np.asarray(values, dtype=float)
    return float(np.sqrt(np.nanmean(values ** 2))), int(np.count_nonzero(np.isnan(values)))


def jumping_motion(config, n_frames, speed, accel, seed):
    """x(t): each frame at a fresh random position, moving at +-speed with acceleration accel."""
    rng = np.random.default_rng(seed)
    start = rng.uniform(-0.8e-3, 0.8e-3, n_frames)
    sign = rng.choice([-1.0, 1.0], n_frames)
    accel_sign = rng.choice([-1.0, 1.0], n_frames)
    mid = config.frame_time(np.arange(n_frames))

    def motion(t):
        t = np.asarray(t, dtype=float)
        k = np.clip(np.floor((t - config.start_time) * config.fps).astype(int), 0, n_frames - 1)
        dt = t - mid[k]
        return start[k] + sign[k] * speed * dt + 0.5 * accel_sign[k] * accel * dt * dt
    return motion


def cramer_rao(config, motion, roi, frame=0, step=0.01):
    camera = SyntheticCamera(config)
    shift = step * config.meters_per_pixel
    x, y, w, h = roi
    window = np.s_[y:y + h, x:x + w]

    def render(offset):
        return camera.expected_frame(frame, lambda t: motion(t) + offset, 0.0)[0][window]
    expected = render(0.0)
    derivative = (render(shift) - render(-shift)) / (2 * step)
    return 1.0 / math.sqrt(float(np.sum(derivative ** 2 / config.noise_variance(expected))))


def high_pass(image, sigma=15.0):
    image = image.astype(np.float32)
    return image - cv2.GaussianBlur(image, (0, 0), sigma)


class Baselines:
    """OpenCV baselines for one ROI, referenced to a noiseless still frame of the mark."""

    def __init__(self, config, roi):
        self.roi = x, y, w, h = roi
        centre = x + (w - 1) / 2.0
        camera = SyntheticCamera(config)
        position = (centre - config.origin_px('stator')) * config.meters_per_pixel
        still, _ = camera.expected_frame(0, position, 0.0)
        still = np.clip(np.rint(still), 0, 255).astype(np.float32)
        half_w = config.mark_half_extent_px()[0] + 3 * config.psf_sigma_px + 4
        left = int(math.floor(centre - half_w))
        right = int(math.ceil(centre + half_w)) + 1
        self.template = still[y:y + h, left:right].copy()
        self.template_centre = centre - left
        self.reference = high_pass(still[y:y + h, x:x + w])
        self.reference_centre = centre

    def match(self, frame):
        """Return the integer-peak and parabola-refined mark positions (image columns)."""
        x, y, w, h = self.roi
        score = cv2.matchTemplate(frame[y:y + h, x:x + w].astype(np.float32), self.template,
                                  cv2.TM_CCOEFF_NORMED)[0]
        k = int(np.argmax(score))
        integer = x + k + self.template_centre
        if 0 < k < score.size - 1:
            left, mid, right = score[k - 1], score[k], score[k + 1]
            denominator = left - 2 * mid + right
            offset = 0.5 * (left - right) / denominator if denominator < 0 else 0.0
        else:
            offset = 0.0
        return integer, integer + offset

    def phase(self, frame):
        """Return the mark position (image column) from phase correlation."""
        x, y, w, h = self.roi
        (dx, _), _ = cv2.phaseCorrelate(self.reference, high_pass(frame[y:y + h, x:x + w]))
        return self.reference_centre + dx


def evaluate(video, plate='stator'):
    """Return errors (px) of ours and the baselines on one rendered video."""
    truth = getattr(video.truth, plate).pixel_mean
    roi = video.rois[plate]
    ours = track(video.frames, {plate: roi}, video.config.meters_per_pixel,
                 fps=video.config.fps).position_px[plate]
    base = Baselines(video.config, roi)
    integer, parabola, phase = [], [], []
    for frame in video.frames:
        i, p = base.match(frame)
        integer.append(i)
        parabola.append(p)
        phase.append(base.phase(frame))
    return {'ours': ours - truth, 'matchTemplate': np.array(integer) - truth,
            '+parabola': np.array(parabola) - truth, 'phaseCorrelate': np.array(phase) - truth}


def static_table(configs, n_frames, seed):
    print('Static marks: RMS error (px) and ratio to the Cramer-Rao bound')
    print(f'{"noise":<10} {"CRB":>8} {"ours":>8} {"ratio":>6} {"matchT":>8} {"+parab":>8} '
          f'{"phaseC":>8}')
    rng = np.random.default_rng(seed)
    for label, config in configs.items():
        errors = {}
        bounds = []
        for k in range(4):
            position = rng.uniform(-0.5e-3, 0.5e-3)
            video = render_frames(position, 0.0, n_frames // 4, config, seed=seed + k)
            bounds.append(cramer_rao(config, lambda t, p=position: np.full(np.shape(t), p),
                                     video.rois['stator']))
            for name, error in evaluate(video).items():
                errors.setdefault(name, []).append(error)
        bound = float(np.sqrt(np.mean(np.square(bounds))))
        err = {name: rms(np.concatenate(v))[0] for name, v in errors.items()}
        print(f'{label:<10} {bound:8.4f} {err["ours"]:8.4f} {err["ours"] / bound:6.2f} '
              f'{err["matchTemplate"]:8.4f} {err["+parabola"]:8.4f} '
              f'{err["phaseCorrelate"]:8.4f}')
    print()


def moving_table(configs, n_frames, seed):
    print('Moving, blurred marks (exposure 1/60 s): RMS error (px) vs exposure-averaged truth')
    print("speed = |v| during the exposure; acceleration as in the paper's sinusoid at that "
          'speed (1.2 mm, 2.95 Hz); "paper" = the sinusoid itself; [n] = samples lost')
    print(f'{"noise":<10} {"speed m/s":>9} {"blur px":>7} {"CRB":>7} {"ours":>7} {"ratio":>5} '
          f'{"matchT":>7} {"+parab":>7} {"phaseC":>7}')
    for label, config in configs.items():
        cases = [(s, OMEGA ** 2 * math.sqrt(max(AMPLITUDE ** 2 - (s / OMEGA) ** 2, 0.0)))
                 for s in (0.005, 0.01, 0.015, 0.02)]
        for speed, accel in cases + [('paper', None)]:
            if speed == 'paper':
                stator, _ = paper_motion()
                bound_motion = None
            else:
                stator = jumping_motion(config, n_frames, speed, accel, seed)
                bound_motion = stator
            video = render_frames(stator, 0.0, n_frames, config, seed=seed)
            errors = evaluate(video)
            cells = {name: rms(error) for name, error in errors.items()}
            bound = cramer_rao(config, bound_motion, video.rois['stator']) if bound_motion else (
                float('nan'))
            blur = (f'{speed * config.exposure / config.meters_per_pixel:7.1f}'
                    if speed != 'paper' else f'{"0-71":>7}')
            speed_text = f'{speed:9.3f}' if speed != 'paper' else f'{"paper":>9}'

            def cell(name, cells=cells):
                value, lost = cells[name]
                return f'{value:7.3f}' + (f'[{lost}]' if lost else '')
            ratio = f'{cells["ours"][0] / bound:5.2f}' if math.isfinite(bound) else f'{"-":>5}'
            bound_text = f'{bound:7.3f}' if math.isfinite(bound) else f'{"-":>7}'
            print(f'{label:<10} {speed_text} {blur} {bound_text} {cell("ours")} {ratio} '
                  f'{cell("matchTemplate")} {cell("+parabola")} {cell("phaseCorrelate")}')
    print()


def video_table(n_frames, seed, directory):
    print('Video round trip (paper motion, default noise): RMS error (px), slider / stator')
    config = CameraConfig()
    stator, slider = paper_motion()
    video = render_frames(stator, slider, n_frames, config, seed=seed)
    arrays = track(video.frames, video.rois, config.meters_per_pixel, fps=30.0)
    rows = [('arrays', arrays)]
    for codec, suffix in (('FFV1', '.mkv'), ('MJPG', '.avi')):
        if not codec_available(codec, suffix):
            print(f'{codec}: not available in this OpenCV build')
            continue
        path = write_video(os.path.join(directory, f'bench{suffix}'), video.frames, 30.0, codec)
        rows.append((f'{codec}{suffix}', track_video(path, video.rois, config.meters_per_pixel)))
    for label, result in rows:
        values = [rms(result.position_px[p] - getattr(video.truth, p).pixel_mean)[0]
                  for p in ('slider', 'stator')]
        same = all(np.array_equal(result.position_px[p], arrays.position_px[p])
                   for p in ('slider', 'stator'))
        print(f'{label:<10} {values[0]:7.4f} / {values[1]:7.4f}'
              + ('   identical to arrays' if same and label != 'arrays' else ''))
    print()


def throughput_table(n_frames, seed):
    cv2.setNumThreads(1)
    config = CameraConfig()
    stator, slider = paper_motion()
    video = render_frames(stator, slider, 60, config, seed=seed)
    frames = [video.frames[k % 60] for k in range(n_frames)]
    print(f'Throughput on one core, {config.width} x {config.height} mono8, two ROIs '
          f'({video.rois["slider"][2]} x {video.rois["slider"][3]} px each)')
    tracker = Tracker(video.rois, config.meters_per_pixel, fps=30.0)
    for frame in frames[:20]:
        tracker.process(frame)
    start = time.perf_counter()
    for frame in frames:
        tracker.process(frame)
    ours = n_frames / (time.perf_counter() - start)
    bases = {p: Baselines(config, video.rois[p]) for p in ('slider', 'stator')}
    start = time.perf_counter()
    for frame in frames:
        for base in bases.values():
            base.match(frame)
    match = n_frames / (time.perf_counter() - start)
    start = time.perf_counter()
    for frame in frames:
        for base in bases.values():
            base.phase(frame)
    phase = n_frames / (time.perf_counter() - start)
    print(f'{"method":<26} {"frames/s":>9} {"x camera (30 fps)":>18}')
    for name, fps in (('ours (tracking.Tracker)', ours), ('matchTemplate + parabola', match),
                      ('phaseCorrelate', phase)):
        print(f'{name:<26} {fps:9.0f} {fps / CAMERA_FPS:18.1f}')
    print()


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--frames', type=int, default=80, help='frames per case (default 80)')
    parser.add_argument('--seed', type=int, default=1)
    args = parser.parse_args(argv)
    import tempfile

    configs = {'default': CameraConfig(),
               'noisier': replace(CameraConfig(), electrons_per_dn=4.0, read_noise_dn=3.0)}
    print(f'OpenCV {cv2.__version__}, numpy {np.__version__}; {args.frames} frames per case\n')
    static_table(configs, 2 * args.frames, args.seed)
    moving_table(configs, args.frames, args.seed)
    with tempfile.TemporaryDirectory() as directory:
        video_table(args.frames, args.seed, directory)
    throughput_table(max(300, args.frames), args.seed)
    return 0


if __name__ == '__main__':
    sys.exit(main())
