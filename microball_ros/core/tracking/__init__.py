"""Sub-pixel, blur-robust tracking of the slider and stator marks along the bearing axis (x).

What a blurred frame encodes: a mark that moves during the exposure is imaged as the still mark
convolved with the distribution of its positions during the exposure (the motion kernel). The
centroid of a convolution is the sum of the centroids, so the centroid of the mark's intensity
deficit is the position *averaged over the exposure*, for any motion and any mark shape, and
that is what the tracker reports, stamped at mid-exposure. (For a sinusoid the exposure average
is the mid-exposure value scaled by sinc(w T / 2), in phase: 0.4 % at 2.95 Hz and 1/60 s.) A
template cut from a still frame does not match a smeared mark, and a symmetric matcher finds the
centre of symmetry of the smeared mark, which differs from the exposure average by up to a few
tenths of a pixel when the speed changes during the exposure (seen with the paper's motion).

Per mark and frame, the centroid tracker (core.tracking.centroid; its state and priming in
core.tracking.centroid_priming) has one module per stage
(all 1-D after one pass over the ROI):

0. ``background``: a pattern fixed in the image (a window, dust, scratches), learned on the
   priming frames outside the mark's footprint, is divided out (or subtracted, if it is light
   added), only when it stands out from the noise; plain plates are left as they are;
1. ``profile`` (the mark model): the ROI's rows averaged with weights proportional to the
   mark's depth in each row (the mark's own rows and weights, learned from the first 20
   priming frames it is found in, or while tracking without priming; a frame whose rows
   depart from them is 'mark partly hidden'); the relative deficit
   ``d = 1 - profile / baseline``, the baseline a polynomial fitted to the ROI outside the
   mark, which removes uneven illumination and flicker;
2. ``search``: the strongest dip of the smoothed deficit, its extent where it exceeds a
   fraction of its peak, plus a pad;
3. ``centroid``: the checks (signal-to-noise, the mark clear of the ROI edges, no saturation,
   an integrated deficit consistent with recent frames) and the quality;
4. ``subpixel``: the deficit centroid over the extent (exact for any blur), or, when the mark
   has barely moved since the previous frame, the centre of mirror symmetry (Gauss-Newton on
   the antisymmetric energy, band-limited interpolation); if the two disagree by more than 3
   sigma the blur is asymmetric and the centroid is kept.

The default method 'auto' (core.tracking.plate; its state and priming in
core.tracking.plate_priming) measures every frame so, unless priming finds
better (core.tracking.priming has what it measures): on a plate whose texture moves with the
mark, and on a plain plate when its track is steadier than the centroid's and agrees with it as
their standard errors allow, it learns the plate itself (mark and texture,
core.tracking.plate_model, by core.tracking.plate_solver: jointly with the static field and
each frame's light, twice) and fits each frame with the exposure's motion kernel, its standard
errors scaled to the track's scatter over the priming frames; core.tracking.gains refuses a
frame whose mark gain jumps (something passing beside the mark), core.tracking.smear starts the
plate of a textured plate smeared over most of the ROI from a periodic motion fitted to the
smears (and refuses it when its track cannot be checked), core.tracking.plate_search holds the
plate's search. On a textured plate the mark's centre is where its edges are most nearly
mirror-symmetric, row by row (core.tracking.plate_rows); a mark still over the priming frames
on a textured plate is registered against them (core.tracking.still).

A soft shadow sweeping over an ROI (core.tracking.shade, for the default methods on plates
plain beside the mark) is measured on the ROI's rows above and below the mark, which it darkens
alike, shifted by its tilt: ``Tracker`` divides the ROI by that light (above the camera's
``black_level``) before the mark's tracker sees the frame; frames without one are as they were.

The polarity is 'auto' by default: the first frame the mark is found in fixes it (dark or
bright, from the skewness of the profile, else whichever detection stands out more). The
method 'template' (core.tracking.learned, opt-in) instead learns a template of any shape from
the video (multi-frame deconvolution, core.tracking.template), removes a static background,
gates the search by a motion prediction (core.tracking.predict) and fits the template smeared
by the exposure's motion. Batch tracking primes every mark on the first frames, then tracks
from the first frame again. ``draw_tracking`` draws ROIs, marks and track (core.tracking.draw).

A failed check gives NaN and a quality below ``min_quality``: positions are never invented, and
each frame is searched over the whole ROI, so a mark is re-acquired as soon as it returns.

Frames are arrays (N x H x W, N x H x W x 3, or any iterable of 2-D arrays); video files and
image folders are opened by microball_ros.io.video. A gamma-encoding camera's frames are
decoded to linear light first (``TrackerConfig.gamma``, core.tracking.gamma). Positions
are image columns times ``meters_per_pixel`` (column k is the centre of pixel k); time of
frame n is ``start_time + n / fps + exposure / 2``.

Entry points: ``track`` (a whole sequence -> TrackResult, ``to_columns()`` gives the position
CSV columns), ``Tracker`` (frame by frame, for a node), ``MarkTracker`` (one mark),
``detect_rois`` (ROIs found automatically), ``parse_roi`` / ``check_roi`` / ``check_scale``
(input validation with one-line InputErrors).
"""

from microball_ros.core.tracking.config import METHODS, POLARITIES, TrackerConfig
from microball_ros.core.tracking.draw import draw_tracking
from microball_ros.core.tracking.image import (
    Roi,
    check_distinct_rois,
    check_roi,
    check_scale,
    detect_rois,
    gray_frames,
    parse_roi,
    to_gray,
)
from microball_ros.core.tracking.mark import MarkTracker
from microball_ros.core.tracking.results import MarkMeasurement, TrackedFrame, TrackResult
from microball_ros.core.tracking.subpixel import symmetric_center
from microball_ros.core.tracking.tracker import Tracker, track

__all__ = ['METHODS', 'POLARITIES', 'MarkMeasurement', 'MarkTracker', 'Roi', 'TrackResult',
           'TrackedFrame', 'Tracker', 'TrackerConfig', 'check_distinct_rois', 'check_roi',
           'check_scale', 'detect_rois', 'draw_tracking', 'gray_frames', 'parse_roi',
           'symmetric_center', 'to_gray', 'track']
