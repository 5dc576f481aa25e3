"""Deformable contours (snakes), image potentials, face layout and fiducial points.

``trackers`` works on any image sequence and knows nothing about the face model.

- :mod:`trackers.potentials`: image potentials (eq. 13 of 004, the paper's own filter,
  a dark-line "valley" potential); :mod:`trackers.sampling`: force fields, bilinear
  sampling;
- :mod:`trackers.snakes`: deformable contours (eqs. 7-12) integrated by semi-implicit
  Euler with one factorisation per contour system; its parts:
  :mod:`trackers.snake_types` (parameters, contours, results),
  :mod:`trackers.snake_kernel` (the compiled relaxation loop) and
  :mod:`trackers.polyline` (resampling);
- :mod:`trackers.layout`: the nine facial contours, placed from OpenCV's face and eye
  detectors or loaded from JSON;
- :mod:`trackers.tracking`: frame-to-frame tracking with quality and lost flags, in
  :class:`Tracker`; its parts: :mod:`trackers.quality` (per-contour quality, the
  per-frame :class:`TrackResult`), :mod:`trackers.contour_fields` (potentials around
  the contours, image-force strength), :mod:`trackers.contour_ends` (ends relocated on
  the features' ends), :mod:`trackers.mouth` (mouth corners) and
  :mod:`trackers.head_search` (where each frame's head frame comes from);
- :mod:`trackers.fiducials`: head reference frame and the 11 fiducial points;
- :mod:`trackers.anchors`: the irises as rigid anchors that keep the head frame
  still under expressions;
- :mod:`trackers.draw`: overlays;
- :mod:`trackers.landmarks`: MediaPipe's face detection and 468-point face mesh (pinned
  model files, OpenCV or LiteRT runtime, :class:`~trackers.landmarks.LandmarkTracker`);
  :mod:`trackers.landmark_contours`: the nine contours on the mesh;
  :mod:`trackers.anchored`: :class:`AnchoredTracker`, snakes placed and held by the
  landmarks, with lost frames where there is no face.
"""

from trackers.anchored import AnchoredTracker
from trackers.anchors import IrisAnchors, find_iris
from trackers.contour_ends import refine_end
from trackers.draw import draw_contours, draw_fiducials, draw_head_frame
from trackers.fiducials import FIDUCIAL_NAMES, HeadFrame, fiducials, head_frame
from trackers.layout import (
    CONTOUR_NAMES,
    FaceLayout,
    LayoutContour,
    detect_layout,
    layout_from_eyes,
    refine_layout,
)
from trackers.polyline import resample_polyline
from trackers.potentials import (
    dark_below_potential,
    gaussian_potential,
    paper_potential,
    potential_from_gray,
    potentials_in_boxes,
    to_gray,
    valley_potential,
)
from trackers.quality import ContourQuality, TrackResult
from trackers.sampling import force_field, sample_bilinear
from trackers.snake_types import Contour, RelaxResult, SnakeParams
from trackers.snakes import ContourSystem, factorization_count, paper_equivalent_strength
from trackers.tracking import Tracker

__all__ = [
    "AnchoredTracker",
    "CONTOUR_NAMES", "FIDUCIAL_NAMES", "Contour", "ContourQuality", "ContourSystem",
    "FaceLayout", "HeadFrame", "LayoutContour", "RelaxResult", "SnakeParams", "TrackResult",
    "Tracker", "detect_layout", "draw_contours", "draw_fiducials", "draw_head_frame",
    "factorization_count", "fiducials", "force_field", "gaussian_potential", "head_frame",
    "layout_from_eyes", "paper_equivalent_strength", "paper_potential",
    "potential_from_gray", "potentials_in_boxes", "refine_end", "refine_layout",
    "resample_polyline", "sample_bilinear", "to_gray", "valley_potential",
    "dark_below_potential", "IrisAnchors", "find_iris",
]
