"""Track the camera frames of a bag offline, as camera_tracker would (no ROS runtime).

A bag recorded without /tracking/positions (only /camera/image_raw) is tracked first by
``microball analyze`` (here, in process) and by ``microball reprocess`` (through a fresh
camera_tracker node, with the same parameters). The parameters are those given on the command
line, else those the recording kept in metadata.yaml custom_data 'microball.camera_tracker'
(``microball experiment --output`` keeps them); ROIs that neither gives are detected in the
first frames; the image scale cannot be guessed.
"""

import itertools

import numpy as np

from microball_ros.core.records import PositionRecord, check_time_base
from microball_ros.core.tracking import (
    Tracker,
    TrackerConfig,
    check_roi,
    check_scale,
    detect_rois,
)
from microball_ros.io.bags.reader import BagError, read_frames, recorded_parameters

TRACKER = 'camera_tracker'
DETECTION_FRAMES = 60


def tracker_parameters(bag, slider_roi=None, stator_roi=None, meters_per_pixel=None):
    """Return the camera_tracker parameters to track the bag's frames with.

    A dict with slider_roi, stator_roi (x, y, w, h lists), meters_per_pixel, stamp_offset,
    polarity, prime_frames, black_level and gamma.
    Given values win over recorded ones. Raise BagError (one line) if the scale is neither
    given nor recorded, or if ROIs must be detected and cannot be.
    """
    recorded = recorded_parameters(bag, TRACKER)
    given = {'slider_roi': slider_roi, 'stator_roi': stator_roi,
             'meters_per_pixel': meters_per_pixel}
    values = {name: value if value is not None else recorded.get(name)
              for name, value in given.items()}
    values['stamp_offset'] = float(recorded.get('stamp_offset', 0.0))
    values['polarity'] = str(recorded.get('polarity', 'auto'))
    values['prime_frames'] = int(recorded.get('prime_frames', TrackerConfig().prime_frames))
    values['black_level'] = float(recorded.get('black_level', 0.0))
    values['gamma'] = float(recorded.get('gamma', 0.0))  # the node's default: found
    if values['meters_per_pixel'] is None:
        raise BagError(f'{bag.path}: the bag has only camera frames and no recorded image '
                       'scale: give --meters-per-pixel (and --slider-roi/--stator-roi)')
    try:
        values['meters_per_pixel'] = check_scale(values['meters_per_pixel'])
        if values['slider_roi'] is None or values['stator_roi'] is None:
            first = [frame for _, frame in
                     itertools.islice(read_frames(bag), DETECTION_FRAMES)]
            detected = detect_rois(first)
            for name in ('slider', 'stator'):
                if values[f'{name}_roi'] is None:
                    values[f'{name}_roi'] = detected[name]
        for name in ('slider', 'stator'):
            values[f'{name}_roi'] = list(check_roi(values[f'{name}_roi'], name=name))
    except ValueError as error:
        raise BagError(f'{bag.path}: {error}') from None
    return values


def tracked_frames(bag, parameters):
    """Yield what camera_tracker publishes for each of the bag's frames, tracked in process.

    Tuples (stamp_ns, frame_index, stator, slider, slider_quality, stator_quality): the core
    Tracker with ``parameters``, primed on the first ``prime_frames`` frames as the node is
    (and as core.tracking.track), stamp = header stamp + stamp_offset rounded to the
    nanosecond (as a message stamp), frame_index counting from 0, NaN for a lost mark.
    """
    rois = {'slider': tuple(parameters['slider_roi']),
            'stator': tuple(parameters['stator_roi'])}
    config = TrackerConfig(polarity=parameters.get('polarity', 'auto'),
                           black_level=float(parameters.get('black_level', 0.0)),
                           gamma=float(parameters.get('gamma', 0.0)))
    frames = read_frames(bag)
    head = list(itertools.islice(frames, max(int(parameters.get(
        'prime_frames', config.prime_frames)), 0)))
    tracker = None
    for stamp, frame in itertools.chain(head, frames):
        if tracker is None:
            try:
                tracker = Tracker(rois, parameters['meters_per_pixel'], config=config,
                                  frame_size=(frame.shape[1], frame.shape[0]))
            except ValueError as error:
                raise BagError(f'{bag.path}: {error}') from None
            tracker.prime([f for _, f in head])
        stamp_ns = round((stamp + parameters['stamp_offset']) * 1e9)
        result = tracker.process(frame, stamp_ns * 1e-9)
        yield (stamp_ns, result.index, result.position('stator'), result.position('slider'),
               result.quality('slider'), result.quality('stator'))


def track_bag(bag, parameters, progress=None):
    """Track the bag's /camera/image_raw with ``parameters``; return a PositionRecord.

    Exactly what camera_tracker would publish (tracked_frames), with the qualities in
    ``extra``. ``progress(frames)`` is called every 300 frames.
    """
    rows = []
    for row in tracked_frames(bag, parameters):
        rows.append(row)
        if progress is not None and len(rows) % 300 == 0:
            progress(len(rows))
    stamps = np.array([row[0] for row in rows], dtype=np.int64)
    values = np.array([row[2:] for row in rows], dtype=float)
    record = PositionRecord(time=stamps / 1e9, stator_position=values[:, 0],
                            slider_position=values[:, 1],
                            extra={'slider_quality': values[:, 2],
                                   'stator_quality': values[:, 3]})
    check_time_base(record.time, source=f'{bag.path} camera frames')
    return record
