"""Messages <-> numpy: the only module that knows both microball_msgs and the core types."""

import importlib
import math

from builtin_interfaces.msg import Time
from microball_msgs.msg import DerivativeEstimate, FrictionModel, TrackedPositions
import numpy as np


def stamp_to_seconds(stamp):
    """Return a builtin_interfaces/Time as float seconds."""
    return stamp.sec + stamp.nanosec * 1e-9


def seconds_to_stamp(seconds):
    """Return float seconds (>= 0) as a builtin_interfaces/Time, rounded to the nanosecond."""
    return nanoseconds_to_stamp(int(round(seconds * 1e9)))


def nanoseconds_to_stamp(nanoseconds):
    """Return integer nanoseconds (>= 0) as a builtin_interfaces/Time, exactly."""
    return Time(sec=nanoseconds // 1_000_000_000, nanosec=nanoseconds % 1_000_000_000)


def tracked_positions(stamp, frame_index, slider, stator, slider_quality, stator_quality,
                      frame_id='camera', slider_sigma=math.nan, stator_sigma=math.nan):
    """Build a TrackedPositions message; a NaN position is marked invalid (and its sigma NaN)."""
    msg = TrackedPositions()
    msg.header.stamp = stamp if isinstance(stamp, Time) else seconds_to_stamp(stamp)
    msg.header.frame_id = frame_id
    msg.frame_index = int(frame_index)
    msg.slider_position = float(slider)
    msg.stator_position = float(stator)
    msg.slider_quality = float(slider_quality)
    msg.stator_quality = float(stator_quality)
    msg.slider_valid = bool(np.isfinite(slider))
    msg.stator_valid = bool(np.isfinite(stator))
    msg.slider_sigma = float(slider_sigma) if msg.slider_valid else math.nan
    msg.stator_sigma = float(stator_sigma) if msg.stator_valid else math.nan
    return msg


def derivative_estimate(header, window, est, memory, epsilon):
    """Build a DerivativeEstimate from a core Window, Estimate and MemoryTest."""
    msg = DerivativeEstimate()
    msg.header = header
    msg.method = est.method
    msg.sample_period = float(est.sample_period)
    msg.fundamental_frequency = float(memory.frequency)
    msg.time = est.time.astype(float).tolist()
    msg.stator_position = window.stator_position[est.index].astype(float).tolist()
    msg.slider_position = window.slider_position[est.index].astype(float).tolist()
    msg.relative_velocity = est.velocity.astype(float).tolist()
    msg.slider_acceleration = est.acceleration.astype(float).tolist()
    msg.phase_difference = float(memory.phase_difference)
    msg.phase_uncertainty = float(memory.uncertainty)
    msg.memoryless = bool(memory.memoryless)
    msg.epsilon = float(epsilon)
    msg.kept_frequencies = np.asarray(est.acceleration_frequencies, dtype=float).tolist()
    msg.sample_count = len(window.time)
    msg.invalid_count = 0
    return msg


def estimate_arrays(msg):
    """Return (time, relative_velocity, slider_acceleration, stator, slider) arrays."""
    return tuple(np.asarray(values, dtype=float) for values in (
        msg.time, msg.relative_velocity, msg.slider_acceleration, msg.stator_position,
        msg.slider_position))


def friction_model(header, result, window_count):
    """Build a FrictionModel from a core pipeline result (its Langevin fit and validation).

    A fit that failed (warning 'fit-failed') gives name 'none' and NaN numbers; no
    validation gives NaN validation fields. The verdict and warnings are carried as given.
    """
    msg = FrictionModel()
    msg.header = header
    fit, validation = result.fit, result.validation
    msg.name = fit.name if fit is not None else 'none'
    nan = math.nan
    msg.a = float(fit.params['A']) if fit is not None else nan
    msg.alpha = float(fit.params['alpha']) if fit is not None else nan
    msg.a_ci95 = [float(b) for b in fit.ci95['A']] if fit is not None else [nan, nan]
    msg.alpha_ci95 = [float(b) for b in fit.ci95['alpha']] if fit is not None else [nan, nan]
    correlation = float(fit.correlation[0, 1]) if fit is not None else nan
    msg.a_alpha_correlation = correlation if math.isfinite(correlation) else nan
    msg.rmse = float(fit.rmse) if fit is not None else nan
    msg.sample_count = int(result.samples_used)
    msg.window_count = int(window_count)
    for name in ('slider_amplitude_simulated', 'slider_amplitude_measured', 'phase_simulated',
                 'phase_measured'):
        setattr(msg, name, float(getattr(validation, name)) if validation is not None else nan)
    msg.memory_verdict = result.memory_verdict
    msg.warnings = [f'{code}: {message}' for code, message in result.warnings]
    return msg


def image_message(frame, stamp, frame_id='camera'):
    """Return a mono8 (H x W uint8) or bgr8 (H x W x 3) array as a sensor_msgs/Image."""
    from sensor_msgs.msg import Image

    frame = np.ascontiguousarray(frame, dtype=np.uint8)
    msg = Image()
    msg.header.stamp = stamp if isinstance(stamp, Time) else seconds_to_stamp(stamp)
    msg.header.frame_id = frame_id
    msg.height, msg.width = frame.shape[:2]
    msg.encoding = 'mono8' if frame.ndim == 2 else 'bgr8'
    msg.is_bigendian = 0
    msg.step = frame.strides[0]
    msg.data = frame.tobytes()
    return msg


def image_array(msg):
    """Return a sensor_msgs/Image as a grey H x W uint8 array (8-bit encodings only)."""
    from microball_ros.io.video import image_to_gray

    return image_to_gray(msg.encoding, msg.height, msg.width, msg.step, msg.data,
                         msg.is_bigendian)


def message_class(type_name):
    """Import the Python class of 'pkg/msg/Type'; raise ValueError if it is not installed."""
    package, _, name = type_name.partition('/msg/')
    try:
        return getattr(importlib.import_module(f'{package}.msg'), name)
    except (ImportError, AttributeError):
        raise ValueError(f'message type {type_name} is not installed') from None
