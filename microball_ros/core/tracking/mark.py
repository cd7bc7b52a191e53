"""One mark in one ROI, frame by frame: the tracker the configured method asks for.

``MarkTracker`` returns a CentroidMarkTracker (core.tracking.centroid: the deficit centroid,
or the centre of symmetry of a still mark; methods 'auto', 'centroid', 'symmetric') or a
LearnedMarkTracker (core.tracking.learned: a template of any shape learned from the video and
fitted with the exposure's motion blur, gated by a motion prediction; method 'template').
Both take the same arguments and have ``measure(frame)``, ``prime(frames)``, ``reset()`` and
``learned``; both resolve polarity 'auto' from the first frame the mark is found in.
"""

from microball_ros.core.tracking.centroid import CentroidMarkTracker
from microball_ros.core.tracking.config import TrackerConfig
from microball_ros.core.tracking.image import Roi
from microball_ros.core.tracking.learned import LearnedMarkTracker


def MarkTracker(roi: Roi, config: TrackerConfig | None = None, name: str = 'mark',  # noqa: N802
                exposure_fraction: float = 0.5) -> CentroidMarkTracker | LearnedMarkTracker:
    """Return the tracker of one mark in ``roi`` for ``config.method``."""
    config = TrackerConfig() if config is None else config
    kind = LearnedMarkTracker if config.method == 'template' else CentroidMarkTracker
    return kind(roi, config, name, exposure_fraction)
