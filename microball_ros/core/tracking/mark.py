"""One mark in one ROI, frame by frame: the tracker the configured method asks for.

``MarkTracker`` returns, for method 'auto' (the default), a PlateMarkTracker
(core.tracking.plate): on a plain plate exactly the centroid tracker, on a plate whose texture
moves with the mark (found while priming) the learned plate registered per frame; for
'centroid' and 'symmetric' a CentroidMarkTracker (core.tracking.centroid: the deficit
centroid, or the centre of symmetry of a still mark); for 'template' a LearnedMarkTracker
(core.tracking.learned: a template of any shape learned from the video and fitted with the
exposure's motion blur, gated by a motion prediction). All take the same arguments and have
``measure(frame)``, ``prime(frames)``, ``reset()`` and ``learned``; all resolve polarity
'auto' from the first frame the mark is found in.
"""

from microball_ros.core.tracking.centroid import CentroidMarkTracker
from microball_ros.core.tracking.config import TrackerConfig
from microball_ros.core.tracking.image import Roi
from microball_ros.core.tracking.learned import LearnedMarkTracker
from microball_ros.core.tracking.plate import PlateMarkTracker

AnyMarkTracker = CentroidMarkTracker | LearnedMarkTracker | PlateMarkTracker


def MarkTracker(roi: Roi, config: TrackerConfig | None = None, name: str = 'mark',  # noqa: N802
                exposure_fraction: float = 0.5) -> AnyMarkTracker:
    """Return the tracker of one mark in ``roi`` for ``config.method``."""
    config = TrackerConfig() if config is None else config
    if config.method == 'template':
        return LearnedMarkTracker(roi, config, name, exposure_fraction)
    if config.method == 'auto':
        return PlateMarkTracker(roi, config, name, exposure_fraction)
    return CentroidMarkTracker(roi, config, name, exposure_fraction)
