"""Render the simulated rig to a video file (``microball render``): frames to track.

The bench's scenario is filmed by the rig's camera model (core.rig) and written with OpenCV
(io.video). Work that would not fit in memory is refused before it starts.
"""

from collections.abc import Callable

from microball_ros.core import bench, rig
from microball_ros.core.camera import RenderedVideo
from microball_ros.core.errors import InputError
from microball_ros.io import video

MAX_RENDERED_BYTES = 4 * 1024 ** 3   # every frame is kept in memory
VIDEO_SUFFIXES = ('.mkv', '.avi')


def render_video(scenario_name: str, output: str, duration: float, seed: int | None = None,
                 lossless: bool = False,
                 progress: Callable[[str], None] | None = None) -> tuple[RenderedVideo, str]:
    """Render ``duration`` s of a bench scenario to ``output``; return (the video, its codec).

    InputError (one line) for a file name that is not a video's or a video over
    ``MAX_RENDERED_BYTES``.
    """
    scenario = bench.get_scenario(scenario_name, **({'seed': seed} if seed is not None else {}))
    if not output.lower().endswith(VIDEO_SUFFIXES):
        raise InputError(f'{output}: a video file name must end in '
                         f'{" or ".join(VIDEO_SUFFIXES)}')
    config = rig.camera_for(scenario)
    frame_bytes = config.width * config.height
    frames = duration * config.fps
    if frames * frame_bytes > MAX_RENDERED_BYTES:
        raise InputError(f'--duration {duration:g} s is {frames:.0f} frames '
                         f'({frames * frame_bytes / 1024 ** 3:.1f} GiB in memory); render at '
                         f'most {MAX_RENDERED_BYTES / (config.fps * frame_bytes):.0f} s')
    if progress is not None:
        progress(f'rendering {duration:g} s of scenario {scenario_name!r} ...')
    rendered, _ = rig.render_bench(scenario, duration)
    codec = video.LOSSLESS_CODEC if lossless else video.LOSSY_CODEC
    video.write_video(output, rendered.frames, fps=rendered.config.fps, codec=codec)
    return rendered, codec
