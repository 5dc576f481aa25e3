"""The nine contours of 004 read off a 468-point face mesh.

MediaPipe's face mesh (:mod:`trackers.landmarks`) puts 468 points on a face; this module
says which of them trace each contour of :data:`~trackers.layout.CONTOUR_NAMES`, so
that the contours can be placed from the landmarks on a first frame and pulled toward
them on every frame (:class:`~trackers.anchored.AnchoredTracker`). Curves run in the
layout template's direction (:data:`~trackers.layout.TEMPLATE`): brows from the inner
end, furrows from the top, the lips and nose from the image's left, the chin boss
clockwise on screen from its image-right side.

The mesh has no hairline: that contour is placed from the template by the eyes and is
left to its snake.
"""

from __future__ import annotations

import numpy as np

from trackers.layout import CONTOUR_NAMES, FaceLayout, LayoutContour, layout_from_eyes
from trackers.polyline import resample_polyline

__all__ = [
    "CHIN_CENTRE",
    "EYE_POINTS",
    "LANDMARK_ENDS",
    "MOUTH_CORNER_OFFSET",
    "MESH_CURVES",
    "RIGID_POINTS",
    "eye_centres",
    "interocular_distance",
    "landmark_curves",
    "layout_from_landmarks",
    "lip_gap",
    "mouth_width",
]

# Eyebrow band: (upper edge, lower edge), inner end first; the contour is its centre line.
_BROW_EDGES = {
    "brow_r": ((107, 66, 105, 63, 70), (55, 65, 52, 53, 46)),
    "brow_l": ((336, 296, 334, 293, 300), (285, 295, 282, 283, 276)),
}
# The mouth line is the centre line between the inner borders of the two lips, from
# one outer corner (61, image left) to the other (291).
_LIP_INNER = ((191, 80, 81, 82, 13, 312, 311, 310, 415),
              (95, 88, 178, 87, 14, 317, 402, 318, 324))

#: Mesh points (single indices) of the contours that follow one row of points.
MESH_CURVES: dict[str, tuple[int, ...]] = {
    # alar crease down along the cheek, lateral to the mouth corner
    "furrow_r": (129, 203, 206, 216, 212, 202),
    "furrow_l": (358, 423, 426, 436, 432, 422),
    # the lower border of the nostrils, through the subnasale
    "nose_tip": (98, 97, 2, 326, 327),
    "lower_lip": (146, 91, 181, 84, 17, 314, 405, 321, 375),
}

#: The chin boss: the layout template's ellipse (:data:`~trackers.layout.TEMPLATE`,
#: half axes in inter-eye distances, turned with the eye line), centred this fraction of
#: the way from the lower lip's lowest point (17) to the chin's tip (152). The mesh has
#: no outline of the boss; on renders of the face model, whose chin boss defines the
#: ``chin`` fiducial, its centroid lies at 0.58 +- 0.07 of that segment (five faces).
CHIN_CENTRE = 0.58
_CHIN_AXES = (0.262, 0.148)

#: Where the mouth corners lie from the mesh's (points 61 and 291), in inter-ocular
#: distances: outward along the eye line and down across it. The mesh's points sit on the
#: lips' outline just inside the commissure: on 20 people's photographs (IMM, 40 images)
#: hand-placed corners lie 0.015 outward and 0.012 lower; fitted on ten people and applied
#: to the other ten, the offset lowered their corner error from 0.032 to 0.027 and from
#: 0.037 to 0.032.
MOUTH_CORNER_OFFSET = (0.015, 0.012)

#: Eye centres as the mean of four eyelid points (corners, mid upper and lower lid):
#: row 0 the subject's right eye (image left).
EYE_POINTS = ((33, 133, 159, 145), (362, 263, 386, 374))

#: End handling that replaces the template's (:data:`~trackers.layout.CONTOUR_DEFAULTS`)
#: for contours placed from the landmarks: the mesh's mouth corners (61, 291) lie
#: closer to hand-placed corners than the end of the dark mouth line does.
LANDMARK_ENDS = {"upper_lip": "free"}

#: Points on the skull that expressions barely move (eye corners, nose bridge and
#: dorsum): the head's rigid motion is read off them.
RIGID_POINTS = (33, 133, 362, 263, 168, 6, 197, 195, 5)


def _check(points):
    p = np.asarray(points, dtype=float)
    if p.ndim != 2 or p.shape[0] != 468 or p.shape[1] < 2:
        raise ValueError(f"landmarks must have shape (468, 2) or (468, 3), got {p.shape}")
    return p[:, :2]


# the point lists above as index arrays, gathered once per frame by the tracker
_EYE_INDEX = np.array(EYE_POINTS, np.intp)
_BROW_INDEX = {name: (np.array(up, np.intp), np.array(lo, np.intp))
               for name, (up, lo) in _BROW_EDGES.items()}
_LIP_INDEX = tuple(np.array(idx, np.intp) for idx in _LIP_INNER)
_CURVE_INDEX = {name: np.array(idx, np.intp) for name, idx in MESH_CURVES.items()}
# the chin boss's ellipse in inter-ocular distances, before it is turned and placed
_t = np.linspace(0.0, 2.0 * np.pi, 24, endpoint=False)
_CHIN_ELLIPSE = np.c_[_CHIN_AXES[0] * np.cos(_t), _CHIN_AXES[1] * np.sin(_t)]
del _t


def eye_centres(points) -> np.ndarray:
    """(2, 2) eye centres from the mesh: row 0 subject's right (image left)."""
    p = _check(points)
    return p[_EYE_INDEX].mean(axis=1)


def interocular_distance(points) -> float:
    """The distance between the mesh's eye centres (:func:`eye_centres`), in its units."""
    return float(np.hypot(*np.subtract(*eye_centres(points))))


def _mouth_points(points) -> np.ndarray:
    """Landmarks of one frame (468, 2|3) or of several (..., 468, 2|3), x and y."""
    p = np.asarray(points, dtype=float)
    if p.ndim < 2 or p.shape[-2] != 468 or p.shape[-1] < 2:
        raise ValueError(f"landmarks must have shape (..., 468, 2) or (..., 468, 3), got "
                         f"{p.shape}")
    return p[..., :2]


def _per_interocular(length, p):
    eyes = p[..., _EYE_INDEX, :].mean(axis=-2)                           # (..., 2, 2)
    iod = np.linalg.norm(eyes[..., 0, :] - eyes[..., 1, :], axis=-1)
    out = length / np.maximum(iod, 1e-12)
    return float(out) if np.ndim(out) == 0 else out


def lip_gap(points):
    """How far the mouth is open: the mean distance between the inner lips' middle three
    landmark pairs, in inter-ocular distances (:func:`interocular_distance`).

    Lips at rest touch (0.01-0.02: the landmarks lie on either lip's inner border); a
    talking mouth opens 0.05-0.3. ``points``: one frame's landmarks (468, 2|3), or several
    frames' (..., 468, 2|3) for an array of gaps.

    Examples
    --------
    >>> pts = np.zeros((468, 2))
    >>> pts[list(EYE_POINTS[1]), 0] = 60.0          # eye centres 60 px apart
    >>> pts[[87, 14, 317], 1] = 6.0                 # lower lip 6 px below the upper
    >>> round(lip_gap(pts), 3)
    0.1
    """
    p = _mouth_points(points)
    upper, lower = _LIP_INDEX[0][3:6], _LIP_INDEX[1][3:6]
    gap = np.linalg.norm(p[..., upper, :] - p[..., lower, :], axis=-1).mean(axis=-1)
    return _per_interocular(gap, p)


def mouth_width(points):
    """The distance between the mouth corners (61, 291), in inter-ocular distances
    (:func:`interocular_distance`): 0.75-0.85 on faces at rest, 0.1-0.2 more in a smile.
    ``points`` as :func:`lip_gap` takes them.

    Examples
    --------
    >>> pts = np.zeros((468, 2))
    >>> pts[list(EYE_POINTS[1]), 0] = 60.0          # eye centres 60 px apart
    >>> pts[291, 0] = 48.0                          # corners 48 px apart
    >>> round(mouth_width(pts), 3)
    0.8
    """
    p = _mouth_points(points)
    return _per_interocular(np.linalg.norm(p[..., 291, :] - p[..., 61, :], axis=-1), p)


def landmark_curves(points, *, eyes=None) -> dict[str, np.ndarray]:
    """The eight mesh-traced contours (all but the hairline) in image pixels.

    Parameters
    ----------
    points : array_like, shape (468, 2) or (468, 3)
        Face-mesh landmarks in image pixels.
    eyes : ndarray, shape (2, 2), optional
        ``eye_centres(points)``, when the caller has it already.

    Returns
    -------
    dict name -> ndarray (m, 2)

    Examples
    --------
    >>> pts = np.random.default_rng(0).uniform(0, 100, (468, 2))
    >>> sorted(landmark_curves(pts))[:3]
    ['brow_l', 'brow_r', 'chin_boss']
    """
    p = _check(points)
    out = {name: 0.5 * (p[up] + p[lo]) for name, (up, lo) in _BROW_INDEX.items()}
    upper, lower = (p[idx] for idx in _LIP_INDEX)
    if eyes is None:
        eyes = eye_centres(p)
    d = eyes[1] - eyes[0]
    iod = float(np.hypot(*d))
    ex = d / max(iod, 1e-9)
    ey = np.array([-ex[1], ex[0]])                  # down the face
    out_, down = MOUTH_CORNER_OFFSET
    corner_r = p[61] + iod * (-out_ * ex + down * ey)
    corner_l = p[291] + iod * (out_ * ex + down * ey)
    out["upper_lip"] = np.vstack([corner_r, 0.5 * (upper + lower), corner_l])
    for name, idx in _CURVE_INDEX.items():
        out[name] = p[idx]
    c, s = ex
    local = _CHIN_ELLIPSE * iod
    centre = p[17] + CHIN_CENTRE * (p[152] - p[17])
    out["chin_boss"] = centre + local @ np.array([[c, s], [-s, c]])
    return out


def layout_from_landmarks(points, image_size, *, spacing: float | None = None) -> FaceLayout:
    """A :class:`~trackers.layout.FaceLayout` placed from face-mesh landmarks.

    The template is placed by the mesh's eye centres
    (:func:`~trackers.layout.layout_from_eyes`, which sets each contour's potential,
    width and end handling); every contour but the hairline is then replaced by its
    mesh curve, resampled to the same node spacing.

    Parameters
    ----------
    points : array_like, shape (468, 2) or (468, 3)
    image_size : (width, height)
    spacing : float, optional
        Node spacing in pixels (default 3 % of the inter-eye distance, at least 1).

    Returns
    -------
    FaceLayout
        ``source='landmarks'``.
    """
    eyes = eye_centres(points)
    lay = layout_from_eyes(eyes[0], eyes[1], image_size, spacing=spacing, source="landmarks")
    iod = lay.inter_eye
    step = max(1.0, 0.03 * iod) if spacing is None else float(spacing)
    w, h = lay.image_size
    contours = dict(lay.contours)
    curves = landmark_curves(points)
    # the chin boss starts where the template has it below the mesh's lower lip (as the
    # snakes' layout places it below the lower lip it found): the snake then settles on
    # the boss's outline from the same side as on a template layout
    shift = curves["lower_lip"].mean(axis=0) - lay.contours["lower_lip"].points.mean(axis=0)
    curves["chin_boss"] = lay.contours["chin_boss"].points + shift
    for name, curve in curves.items():
        c = lay.contours[name]
        n = max(5 if c.closed else 3, len(c.points),
                int(round(_length(curve, c.closed) / step)) + (0 if c.closed else 1))
        pts = np.clip(resample_polyline(curve, n, closed=c.closed), 0, [w - 1, h - 1])
        contours[name] = LayoutContour(pts, c.closed, c.kind, c.sigma,
                                       LANDMARK_ENDS.get(name, c.ends))
    return FaceLayout({n: contours[n] for n in CONTOUR_NAMES}, (w, h), eyes, None,
                      "landmarks")


def _length(curve, closed):
    d = np.diff(np.vstack([curve, curve[:1]]) if closed else curve, axis=0)
    return float(np.hypot(d[:, 0], d[:, 1]).sum())
