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
from microball_ros.core.errors import InputError
from microball_ros.core.motion import as_motion


@dataclass(frozen=True)
class RigMotion:
    """True stator and slider positions (m) on a fine time grid (s), drift included."""

    time: np.ndarray
    stator_position: np.ndarray
    slider_position: np.ndarray


# How far either mark may travel, in stator amplitudes: the slider of a lagged (resonant)
# law overshoots the stator by up to 20 %, plus drift and the crank's second harmonic.
REACH = 1.5


def camera_for(scenario: bench.Scenario,
               config: camera.CameraConfig | None = None) -> camera.CameraConfig:
    """Return a CameraConfig for the scenario: its frame rate, a scale that fits the stroke.

    The scale is the camera's (5 um/px by default) unless a travel of REACH stator amplitudes
    either way would not fit in 85 % of the width: then it is coarsened until it does.
    """
    config = camera.CameraConfig() if config is None else config
    travel = 2.0 * REACH * scenario.stator_amplitude
    scale = max(config.meters_per_pixel, travel / (0.85 * config.width))
    return replace(config, fps=scenario.frame_rate, meters_per_pixel=scale,
                   exposure=min(config.exposure, scenario.exposure, 1.0 / scenario.frame_rate))


def suggested_rois(scenario: bench.Scenario, config: camera.CameraConfig | None = None
                   ) -> dict[str, tuple[int, int, int, int]]:
    """Return {'slider': roi, 'stator': roi} (x, y, w, h px) covering REACH amplitudes."""
    config = camera_for(scenario, config)
    cam = camera.SyntheticCamera(config)
    reach = REACH * scenario.stator_amplitude
    return {plate: cam.suggest_roi(plate, tuple(config.to_px(plate, [-reach, reach])))
            for plate in ('slider', 'stator')}


def rig_motion(scenario: bench.Scenario, duration: float, *, dt: float = 0.001) -> RigMotion:
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


def render_bench(scenario: bench.Scenario, duration: float,
                 config: camera.CameraConfig | None = None,
                 seed: int | None = None) -> tuple[camera.RenderedVideo, RigMotion]:
    """Render duration s of the scenario; return (RenderedVideo, RigMotion).

    The last frame's exposure must end inside the simulated span, so the motion is simulated
    one frame period longer than the frames cover.
    """
    config = camera_for(scenario, config)
    n_frames = math.floor(duration * config.fps + 1e-9)
    if n_frames < 1:
        raise InputError(f'duration {duration!r} s holds no frame at {config.fps:g} fps')
    motion = rig_motion(scenario, n_frames / config.fps + 1.0 / config.fps)
    video = camera.render_frames((motion.time, motion.stator_position),
                                 (motion.time, motion.slider_position), n_frames, config,
                                 seed=scenario.seed if seed is None else seed)
    return video, motion


@dataclass(frozen=True)
class RigFrame:
    """One camera frame of the running rig and the truth at its mid-exposure instant."""

    index: int
    stamp: float
    image: np.ndarray
    truth: camera.FrameTruth
    state: bench.BenchState
    crank_angular_velocity: float


class RigStepper:
    """The simulated rig frame by frame, driven by servo commands (the bench_simulator's core).

    The motor follows commands through core.servo.MotorModel (ramp, then a first-order lag);
    the bench is integrated every ``dt`` with the motor's speed; the slider drifts slowly
    (streaming form of bench.slider_drift); frame n is exposed over
    [n / fps, n / fps + exposure] and stamped at its middle. Deterministic: the frames depend
    only on the scenario, the seed and the commands with the frame index they arrive before.
    The rig starts at rest; time 0 is the first frame's exposure start.
    """

    def __init__(self, scenario: bench.Scenario, config: camera.CameraConfig | None = None,
                 seed: int | None = None, motor_lag: float = 0.05, dt: float = 0.001):
        from microball_ros.core.servo import MotorModel

        self.scenario = scenario
        self.config = camera_for(scenario, config)
        self.camera = camera.SyntheticCamera(self.config,
                                             scenario.seed if seed is None else seed)
        self.motor = MotorModel(motor_lag)
        self.dt = dt
        self.index = 0
        self._integrator = bench.BenchIntegrator(scenario, dt=dt)
        self._rng = np.random.default_rng([scenario.seed if seed is None else seed, 2])
        self._drift_position = 0.0
        self._drift_velocity = scenario.drift_velocity * self._rng.standard_normal()
        self._samples = [self._sample()]

    @property
    def time(self) -> float:
        """Return the rig's current time, s."""
        return self._integrator.time

    def command(self, omega: float, ramp_time: float = 0.0) -> None:
        """Set the crank's target angular velocity (rad/s) from now on."""
        self.motor.command(self.time, omega, ramp_time)

    def _sample(self):
        state = self._integrator.state
        return (state.time, state.stator_position, state.slider_position + self._drift_position)

    def _advance(self, t_end):
        """Integrate to t_end in steps of dt, recording positions at every step."""
        scenario = self.scenario
        rho = math.exp(-self.dt / scenario.drift_time)
        kick = scenario.drift_velocity * math.sqrt(1.0 - rho * rho)
        while self.time < t_end - 1e-12:
            step = min(self.dt, t_end - self.time)
            omega = self.motor.advance(self.time, step)
            self._integrator.step_to(self.time + step, omega)
            velocity = rho * self._drift_velocity + kick * self._rng.standard_normal()
            self._drift_position += 0.5 * (velocity + self._drift_velocity) * step
            self._drift_velocity = velocity
            self._samples.append(self._sample())

    def next_frame(self) -> RigFrame:
        """Advance through the next frame's exposure and return the RigFrame."""
        cfg = self.config
        start = self.index / cfg.fps
        middle, end = start + cfg.exposure / 2.0, start + cfg.exposure
        self._advance(middle)
        state = replace(self._integrator.state,
                        slider_position=self._integrator.state.slider_position
                        + self._drift_position)
        omega = self._integrator.omega
        self._advance(end)
        # Keep only the samples this frame's exposure needs (plus a margin for the spline).
        samples = np.array([s for s in self._samples if s[0] >= start - 3 * self.dt])
        stator, slider = (samples[:, 0], samples[:, 1]), (samples[:, 0], samples[:, 2])
        image, truth = self.camera.render_frame(self.index, as_motion(stator),
                                                as_motion(slider))
        self._samples = self._samples[-4:]
        frame = RigFrame(index=self.index, stamp=middle, image=image, truth=truth, state=state,
                         crank_angular_velocity=omega)
        self.index += 1
        return frame
