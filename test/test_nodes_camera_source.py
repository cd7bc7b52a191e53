"""camera_source as a process: files -> sensor_msgs/Image over DDS, pixels and stamps exact."""

import signal
import subprocess
import sys

import numpy as np
import pytest
from sensor_msgs.msg import Image

from microball_ros.io.video import codec_available, write_image_sequence, write_video
from microball_ros.nodes.camera_source import file_stamp, frame_message
from microball_ros.nodes.common import IMAGE_QOS
from microball_ros.testing import Harness

pytestmark = pytest.mark.ros


def _frames(n, height, width, dtype, scale):
    """Distinct frames: a gradient plus a bright square moving one pixel a frame."""
    frames = []
    for k in range(n):
        frame = (np.add.outer(np.arange(height), np.arange(width)) % 50 * scale).astype(dtype)
        frame[10:20, 10 + k:20 + k] = np.iinfo(dtype).max - k
        frames.append(frame)
    return frames


def _run_source(harness, *parameters, count):
    received = []
    harness.probe.create_subscription(Image, 'camera/image_raw', received.append, IMAGE_QOS)
    args = [sys.executable, '-m', 'microball_ros.nodes.camera_source', '--ros-args',
            '-p', 'wait_for_subscribers:=1']
    for parameter in parameters:
        args += ['-p', parameter]
    node = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        harness.spin_until(lambda: len(received) >= count or node.poll() is not None,
                           timeout=60, message=f'{count} images')
        assert node.poll() is None, node.communicate()[0]
        node.send_signal(signal.SIGINT)
        output = node.communicate(timeout=20)[0]
        assert node.returncode == 0, output
    finally:
        if node.poll() is None:
            node.kill()
            node.wait()
    return received, output


def _pixels(msg, dtype):
    return np.frombuffer(bytes(msg.data), dtype=dtype).reshape(msg.height, msg.width)


def test_a_rendered_video_is_published_frame_by_frame_with_mid_exposure_stamps(
        ros_context, tmp_path):
    if not codec_available('FFV1', '.mkv'):
        pytest.skip('this OpenCV build writes no FFV1')
    frames = _frames(15, 48, 64, np.uint8, 3)
    path = write_video(tmp_path / 'run.mkv', frames, fps=30.0)
    harness = Harness(ros_context)
    try:
        received, _ = _run_source(harness, f'device:={path}', 'frame_id:=lab_camera',
                                  count=len(frames))
    finally:
        harness.close()
    assert len(received) == len(frames)
    for k, (msg, frame) in enumerate(zip(received, frames, strict=True)):
        assert msg.encoding == 'mono8' and msg.header.frame_id == 'lab_camera'
        assert (msg.width, msg.height, msg.step) == (64, 48, 64)
        np.testing.assert_array_equal(_pixels(msg, np.uint8), frame)  # FFV1 is lossless
        # The container's 30 fps; exposure 0 means half the frame period: k/30 + 1/120 s.
        stamp = msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec
        assert stamp == round((k / 30 + 1 / 120) * 1e9)


def test_a_16_bit_png_sequence_is_published_as_mono16(ros_context, tmp_path):
    frames = _frames(6, 40, 50, np.uint16, 1000)
    write_image_sequence(tmp_path / 'seq', frames)
    harness = Harness(ros_context)
    try:
        received, _ = _run_source(harness, f'device:={tmp_path / "seq"}', 'fps:=25.0',
                                  'exposure:=0.01', count=len(frames))
    finally:
        harness.close()
    assert len(received) == len(frames)
    for k, (msg, frame) in enumerate(zip(received, frames, strict=True)):
        assert msg.encoding == 'mono16' and msg.is_bigendian == 0
        assert msg.step == 2 * msg.width
        assert frame.max() > 255
        np.testing.assert_array_equal(_pixels(msg, np.uint16), frame)
        stamp = msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec
        assert stamp == file_stamp(k, 25.0, 0.01) == round((k / 25 + 0.005) * 1e9)


def test_colour_frames_are_bgr8_and_other_pixels_are_refused():
    frame = np.zeros((4, 5, 3), np.uint8)
    frame[1, 2] = (10, 20, 30)
    msg = frame_message(frame, 1.5, 'cam')
    assert (msg.encoding, msg.width, msg.height, msg.step) == ('bgr8', 5, 4, 15)
    assert bytes(msg.data)[(1 * 5 + 2) * 3:(1 * 5 + 2) * 3 + 3] == bytes((10, 20, 30))
    assert (msg.header.stamp.sec, msg.header.stamp.nanosec) == (1, 500_000_000)
    from microball_ros.core.errors import InputError
    with pytest.raises(InputError, match='no supported encoding'):
        frame_message(np.zeros((4, 5), np.float32), 0.0, 'cam')


@pytest.mark.parametrize('parameters, message', [
    ([], 'device is required'),
    (['device:=/nonexistent/run.avi'], 'no such file'),
    (['device:={folder}'], 'unknown frame rate'),
    (['device:={folder}', 'fps:=30.0', 'exposure:=0.1'], 'exceeds the frame period'),
])
def test_a_bad_parameter_exits_2_with_one_line(tmp_path, parameters, message):
    write_image_sequence(tmp_path / 'seq', _frames(2, 8, 8, np.uint8, 1))
    args = [sys.executable, '-m', 'microball_ros.nodes.camera_source', '--ros-args']
    for parameter in parameters:
        args += ['-p', parameter.format(folder=tmp_path / 'seq')]
    result = subprocess.run(args, capture_output=True, text=True, timeout=60)
    assert result.returncode == 2, result.stderr
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and message in lines[0], result.stderr
