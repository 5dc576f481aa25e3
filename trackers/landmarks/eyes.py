"""Eyelids: how far each eye is open, from MediaPipe's iris landmark model.

The face mesh follows the lids only part of the way: on the real clips' frames seen shut its
lids stay 0.55-0.60 of their open gap apart (``benchmarks/run.py eyes``). MediaPipe's iris
landmark model, run on a 64x64 crop of each eye placed from the mesh's eye corners (as
MediaPipe's own iris graph places it: a square 2.3 times the corner-to-corner distance,
turned so that the corners lie level; the subject's left eye mirrored to look like a right
eye), traces them 0.19-0.23 apart on the same frames. Both eyes cost about 2.5 ms a frame
with LiteRT.
"""

from __future__ import annotations

import cv2
import numpy as np

from trackers.landmarks._image import check_image, sample
from trackers.landmarks.mesh import N_LANDMARKS
from trackers.landmarks.models import ensure_models
from trackers.landmarks.runtime import check_runtime, load_network

__all__ = ["EYES", "EYE_CORNERS", "eye_roi_transform", "eyelid_contours", "lid_gaps"]

#: The eyes in the order of the results: the subject's left (the image's right), then right.
EYES = ("l", "r")
#: Per eye, the mesh's two corners from the image's left to its right: the subject's left
#: eye's inner then outer corner, the right eye's outer then inner. The crop is turned so
#: that they lie level, and the left eye's mirrored, so that on both crops the outer corner
#: is on the left, as the model (trained on right eyes) expects.
EYE_CORNERS = {"l": (362, 263), "r": (33, 133)}
_MIRRORED = {"l": True, "r": False}
_SIZE = 64
_SCALE = 2.3          # crop side / corner-to-corner distance, as MediaPipe
#: The iris model's eye contour: 16 points, the lower lid from the outer corner to the inner
#: (0-8), then the upper lid from outside to inside (9-15). The lid gap is the mean distance
#: of the three middle pairs, one above the other.
_LID_PAIRS = ((11, 3), (12, 4), (13, 5))
_CONTOUR = 16


def eye_roi_transform(points, eye: str) -> np.ndarray:
    """The 2x3 map from crop pixels (64x64) to image pixels of one eye's crop.

    Parameters
    ----------
    points : array_like, shape (468, 2) or (468, 3)
        Face-mesh landmarks in image pixels.
    eye : {'l', 'r'}
        The subject's left or right eye.

    Examples
    --------
    >>> pts = np.zeros((468, 2))
    >>> pts[33], pts[133] = (100, 50), (120, 50)            # the subject's right eye
    >>> m = eye_roi_transform(pts, "r")
    >>> (m @ [31.5, 31.5, 1]).round(6).tolist()          # the crop's centre
    [110.0, 50.0]
    >>> round(float(np.hypot(*m[:, 0])) * 64, 6)         # its side: 2.3 x 20 pixels
    46.0
    """
    if eye not in EYE_CORNERS:
        raise ValueError(f"eye must be one of {', '.join(map(repr, EYES))}, got {eye!r}")
    pts = np.asarray(points, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[0] != N_LANDMARKS or pts.shape[1] not in (2, 3):
        raise ValueError(f"points must have shape ({N_LANDMARKS}, 2|3), got {pts.shape}")
    a, b = EYE_CORNERS[eye]
    p0, p1 = pts[a, :2], pts[b, :2]
    d = p1 - p0
    theta = np.arctan2(d[1], d[0])
    k = _SCALE * float(np.hypot(*d)) / _SIZE
    rot = k * np.array([[np.cos(theta), -np.sin(theta)], [np.sin(theta), np.cos(theta)]])
    if _MIRRORED[eye]:
        rot = rot @ np.diag([-1.0, 1.0])
    centre = (p0 + p1) / 2
    return np.c_[rot, centre - rot @ np.full(2, _SIZE / 2 - 0.5)]


def eyelid_contours(image, points, *, channel_order: str = "rgb",
                    runtime: str = "auto") -> np.ndarray:
    """Both eyes' lid contours traced by the iris landmark model.

    Parameters
    ----------
    image : ndarray, shape (H, W) or (H, W, 3)
        uint8, or float in [0, 1].
    points : array_like, shape (468, 2) or (468, 3)
        The face mesh's landmarks on ``image`` (they place the eye crops).
    channel_order : {'rgb', 'bgr'}
    runtime : {'auto', 'litert', 'opencv'}

    Returns
    -------
    ndarray, shape (2, 16, 2)
        Per eye (:data:`EYES`: the subject's left, then right), the lower lid from the outer
        corner to the inner (0-8) then the upper lid from outside to inside (9-15), in image
        pixels.
    """
    image = check_image(image, channel_order)
    net = load_network(ensure_models()["iris_landmark"], runtime=check_runtime(runtime))
    return _run(net, image, points, channel_order)


def _run(net, image: np.ndarray, points, channel_order: str) -> np.ndarray:
    out = np.empty((len(EYES), _CONTOUR, 2))
    for j, eye in enumerate(EYES):
        m = eye_roi_transform(points, eye)
        crop = sample(image, m, _SIZE, channel_order, border=cv2.BORDER_REPLICATE)
        x = net.input_buffer((1, _SIZE, _SIZE, 3))
        np.divide(crop, np.float32(255), out=x[0])
        contour, _iris = net.run(x)   # 'output_eyes_contours_and_brows', 'output_iris'
        raw = contour.reshape(-1, 3)[:_CONTOUR, :2].astype(np.float64)
        out[j] = (raw - 0.5) @ m[:, :2].T + m[:, 2]
    return out


def lid_gaps(contours) -> np.ndarray:
    """Per eye, the mean distance between the upper and the lower lid (pixels).

    Parameters
    ----------
    contours : array_like, shape (..., 16, 2)
        Lid contours as :func:`eyelid_contours` gives them.

    Returns
    -------
    ndarray, shape (...)

    Examples
    --------
    >>> c = np.zeros((16, 2))
    >>> c[9:, 1] = -4.0                       # the upper lid 4 pixels above the lower
    >>> float(lid_gaps(c))
    4.0
    """
    c = np.asarray(contours, dtype=float)
    if c.ndim < 2 or c.shape[-2:] != (_CONTOUR, 2):
        raise ValueError(f"contours must have shape (..., {_CONTOUR}, 2), got {c.shape}")
    upper, lower = zip(*_LID_PAIRS)
    return np.linalg.norm(c[..., list(upper), :] - c[..., list(lower), :], axis=-1).mean(axis=-1)
