"""The whole simulated rig as a camera sees it: the bench's motion rendered into frames.

Joins core.bench (crank-slider stator, slider moved by friction) and core.camera (the
synthetic camera): the bench is integrated on a fine time grid, the slider's slow drift added
(real slider motion, so the camera sees it), and the camera renders blurred, noisy frames of it
with the ground truth. Used by ``microball render`` and the end-to-end tests; the
bench_simulator node does the same frame by frame.
"""

from dataclasses import dataclass, replace
import math

import numpy as np

from microball_ros.core import bench, camera


@dataclass(frozen=True)
class RigMotion:
    """True stator and slider positions (m) on a fine time grid (s), drift included."""

    time: np.ndarray
    stator_position: np.ndarray
    slider_position: np.ndarray


def camera_for(scenario, config=None):
    """Return a CameraConfig for the scenario: its frame rate, a scale that fits the stroke.

    The default 5 um/px makes the paper's +-1.2 mm stroke span 480 of 720 px; a longer stroke
    gets a coarser scale so the marks stay in the frame (two thirds of the width).
    """
    config = camera.CameraConfig() if config is None else config
    travel = 2.0 * scenario.stator_amplitude * 1.15
    scale = max(config.meters_per_pixel, travel / (config.width * 2.0 / 3.0))
    return replace(config, fps=scenario.frame_rate, meters_per_pixel=scale,
                   exposure=min(config.exposure, scenario.exposure, 1.0 / scenario.frame_rate))


def rig_motion(scenario, duration, *, dt=0.001):
    """Integrate the rig for duration s (after its settle time) on a dt grid."""
    omega = scenario.angular_frequency
    n = math.floor(duration / dt + 1e-9) + 1
    integrator = bench.BenchIntegrator(scenario, dt=dt, time=-scenario.settle,
                                       crank_angle=-math.pi / 2 - omega * scenario.settle)
    time = np.arange(n) * dt
    states = [integrator.step_to(t, omega) for t in time]
    rng = np.random.default_rng([scenario.seed, 1])
    drift = bench.slider_drift(rng, n, dt, scenario.drift_velocity, scenario.drift_time)
    return RigMotion(time=time,
                     stator_position=np.array([s.stator_position for s in states]),
                     slider_position=np.array([s.slider_position for s in states]) + drift)


def render_bench(scenario, duration, config=None, seed=None):
    """Render duration s of the scenario; return (RenderedVideo, RigMotion).

    The last frame's exposure must end inside the simulated span, so the motion is simulated
    one frame period longer than the frames cover.
    """
    config = camera_for(scenario, config)
    n_frames = math.floor(duration * config.fps + 1e-9)
    if n_frames < 1:
        raise ValueError(f'duration {duration!r} s holds no frame at {config.fps:g} fps')
    motion = rig_motion(scenario, n_frames / config.fps + 1.0 / config.fps)
    video = camera.render_frames((motion.time, motion.stator_position),
                                 (motion.time, motion.slider_position), n_frames, config,
                                 seed=scenario.seed if seed is None else seed)
    return video, motion
