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

from __future__ import annotations

import importlib

# Public name -> the module that defines it: loaded on first use, so that importing one
# module of the package (the snakes, the polylines) does not load the landmark models'
# runtime and every tracker.
_EXPORTS: dict[str, str] = {
    "AnchoredTracker": "trackers.anchored",
    "CONTOUR_NAMES": "trackers.layout",
    "FIDUCIAL_NAMES": "trackers.fiducials",
    "Contour": "trackers.snake_types",
    "ContourQuality": "trackers.quality",
    "ContourSystem": "trackers.snakes",
    "FaceLayout": "trackers.layout",
    "HeadFrame": "trackers.fiducials",
    "LayoutContour": "trackers.layout",
    "RelaxResult": "trackers.snake_types",
    "SnakeParams": "trackers.snake_types",
    "TrackResult": "trackers.quality",
    "Tracker": "trackers.tracking",
    "detect_layout": "trackers.layout",
    "draw_contours": "trackers.draw",
    "draw_fiducials": "trackers.draw",
    "draw_head_frame": "trackers.draw",
    "factorization_count": "trackers.snakes",
    "fiducials": "trackers.fiducials",
    "force_field": "trackers.sampling",
    "gaussian_potential": "trackers.potentials",
    "head_frame": "trackers.fiducials",
    "layout_from_eyes": "trackers.layout",
    "paper_equivalent_strength": "trackers.snakes",
    "paper_potential": "trackers.potentials",
    "potential_from_gray": "trackers.potentials",
    "potentials_in_boxes": "trackers.potentials",
    "refine_end": "trackers.contour_ends",
    "refine_layout": "trackers.layout",
    "resample_polyline": "trackers.polyline",
    "sample_bilinear": "trackers.sampling",
    "to_gray": "trackers.potentials",
    "valley_potential": "trackers.potentials",
    "dark_below_potential": "trackers.potentials",
    "IrisAnchors": "trackers.anchors",
    "find_iris": "trackers.anchors",
}

__all__ = [*_EXPORTS]

# ``fiducials`` names both a module of the package and the function it defines: bound now,
# the package's attribute is the function, as the import of the module would otherwise leave
# the module there
from trackers.fiducials import fiducials  # noqa: E402,F401


def __getattr__(name: str):
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value         # later look-ups skip this function
    return value


def __dir__() -> list[str]:
    return sorted(__all__)
