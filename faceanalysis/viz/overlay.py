"""Drawing contours, fiducial points and the head frame on video frames (``overlay.mp4``).

Coordinates are image pixels, x to the right, y down, origin at the centre of
the top-left pixel (the convention of OpenCV's drawing functions too). Points are
drawn with sub-pixel precision and anti-aliasing.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence

import cv2
import numpy as np

from faceanalysis.io.frames import to_bgr_uint8
from faceanalysis.io.table import FIDUCIALS

__all__ = ["draw_overlay", "fiducials_from_row"]

_SHIFT = 4  # fractional bits for sub-pixel drawing
_ONE = 1 << _SHIFT

# BGR colours: contours yellow, subject's left green, right magenta, midline cyan, head white.
_CONTOUR = (0, 220, 255)
_CONTOUR_LOST = (150, 150, 150)   # grey: a contour the tracker does not hold on this frame
_LEFT = (60, 200, 60)
_RIGHT = (220, 60, 220)
_MIDLINE = (255, 200, 0)
_HEAD = (255, 255, 255)
_LOST = (40, 40, 230)
_HAND = (0, 140, 255)       # BGR orange: a hand over the face
_EYELID = (255, 200, 0)     # BGR light blue: the lids traced by the iris model
#: The lid contour's points round the eye: the lower lid from the outer corner to the inner,
#: then the upper lid back from inside to outside.
_ROUND_THE_EYE = [*range(9), *range(15, 8, -1)]


def _fixed(points: np.ndarray) -> np.ndarray:
    return np.rint(points * _ONE).astype(np.int32)


def _segments(points: np.ndarray) -> list[np.ndarray]:
    """Split a polyline at NaN points (a contour may be partly lost)."""
    finite = np.isfinite(points).all(axis=1)
    out, current = [], []
    for ok, p in zip(finite, points):
        if ok:
            current.append(p)
        elif current:
            out.append(np.array(current))
            current = []
    if current:
        out.append(np.array(current))
    return out


def fiducials_from_row(row: Mapping) -> dict[str, tuple[float, float]]:
    """Fiducial positions from one row of a contractions table (``fid_<name>_x/_y``).

    Examples
    --------
    >>> fiducials_from_row({"fid_chin_x": 10.0, "fid_chin_y": 20.0})
    {'chin': (10.0, 20.0)}
    """
    out = {}
    for name in FIDUCIALS:
        kx, ky = f"fid_{name}_x", f"fid_{name}_y"
        if kx in row and ky in row:
            out[name] = (float(row[kx]), float(row[ky]))
    return out


def draw_overlay(image, *, contours: Mapping[str, np.ndarray] | Sequence[np.ndarray] | None
                 = None, fiducials: Mapping[str, Sequence[float]] | None = None,
                 head: Sequence[float] | None = None, lost: bool | str = False,
                 label: str | None = None,
                 hands: Sequence[np.ndarray] | None = None,
                 eyelids: Sequence[np.ndarray] | None = None,
                 lost_contours: Iterable[str] = ()) -> np.ndarray:
    """Draw tracking results on a copy of a frame.

    Parameters
    ----------
    image : ndarray
        The frame, any layout and type accepted by
        :func:`faceanalysis.io.frames.to_bgr_uint8` (grey, 16-bit...). Not modified.
    contours : mapping or sequence of (K, 2) arrays, optional
        Snake node positions ``(x, y)`` in pixels, drawn as open polylines
        (repeat the first node to close one). NaN nodes break the line.
    fiducials : mapping, optional
        Name -> ``(x, y)``; names ending in ``_l`` (subject's left) are drawn in
        green, ``_r`` in magenta, others in cyan. NaN points are skipped.
    head : sequence of 4 floats, optional
        Head frame ``(x, y, scale, roll)`` as in ``contractions.csv`` (and
        ``trackers.fiducials.HeadFrame``): origin in pixels, reference length in
        pixels, roll in radians. Drawn as its two axes, each half the reference
        length long: x (subject's left) along ``(cos roll, sin roll)`` and y (down
        the face) along ``(-sin roll, cos roll)``, in image coordinates.
    lost : bool or str, optional
        Mark the frame as lost (red border and "lost" label); a string says why
        (e.g. ``"under a hand"``: "lost: under a hand").
    label : str, optional
        Text for the top-left corner (e.g. frame number and time).
    hands : sequence of (21, 2) arrays, optional
        Hands over the face (``TrackResult.extra['hands']``), each drawn as the outline of
        its points' convex hull.
    eyelids : sequence of (16, 2) arrays, optional
        Each eye's lid contour (``TrackResult.extra['eyelids']``, ``--eyes``; the order of
        :func:`trackers.landmarks.eyes.eyelid_contours`), drawn as a closed outline.
    lost_contours : iterable of str, optional
        Names (keys of a ``contours`` mapping) of contours the tracker reports lost on
        this frame (``TrackResult.quality[name].lost``: off their feature, under a hand,
        or carried with the head rather than held by the image); drawn thin and grey, so
        that what the measurements read is told apart from what they leave out.

    Returns
    -------
    ndarray
        ``(H, W, 3)`` ``uint8`` BGR image.

    Examples
    --------
    >>> import numpy as np
    >>> frame = np.zeros((64, 64), np.uint16)
    >>> out = draw_overlay(frame, contours={"brow": np.array([[10, 20], [30, 18], [50, 20.5]])},
    ...                    fiducials={"chin": (32, 50)}, label="frame 0")
    >>> out.shape, out.dtype, bool(out.any())
    ((64, 64, 3), dtype('uint8'), True)
    """
    canvas = to_bgr_uint8(image)
    height, width = canvas.shape[:2]
    # lines and marks as wide as the frame calls for, but no wider than the face does: in a
    # wide shot, marks sized by the frame would hide a small face's features
    frame_thick = thick = max(1, round(min(height, width) / 320))
    radius = max(2, round(min(height, width) / 120))
    face = float(head[2]) if head is not None and len(head) == 4 else math.nan
    if math.isfinite(face) and face > 0:
        thick = min(thick, max(1, round(face / 60)))
        radius = min(radius, max(2, round(face / 25)))

    if contours is not None:
        items = (contours.items() if isinstance(contours, Mapping)
                 else ((None, c) for c in contours))
        muted = set(lost_contours)
        for name, curve in items:
            points = np.asarray(curve, dtype=float)
            if points.ndim != 2 or points.shape[1] != 2:
                raise ValueError(f"contours must be (K, 2) arrays of (x, y), got shape "
                                 f"{points.shape}")
            colour, width = ((_CONTOUR_LOST, max(1, thick // 2)) if name in muted
                             else (_CONTOUR, thick))
            for segment in _segments(points):
                if len(segment) >= 2:
                    cv2.polylines(canvas, [_fixed(segment)], False, colour, width,
                                  cv2.LINE_AA, _SHIFT)

    for hand in hands or ():
        points = np.asarray(hand, dtype=float)
        if points.ndim != 2 or points.shape[1] != 2:
            raise ValueError(f"hands must be (K, 2) arrays of (x, y), got shape {points.shape}")
        hull = cv2.convexHull(points.astype(np.float32))[:, 0]
        cv2.polylines(canvas, [_fixed(hull)], True, _HAND, thick, cv2.LINE_AA, _SHIFT)

    for lids in () if eyelids is None else eyelids:
        points = np.asarray(lids, dtype=float)
        if points.shape != (16, 2):
            raise ValueError(f"eyelids must be (16, 2) arrays of (x, y), got shape "
                             f"{points.shape}")
        if np.isfinite(points).all():
            cv2.polylines(canvas, [_fixed(points[_ROUND_THE_EYE])], True, _EYELID, thick,
                          cv2.LINE_AA, _SHIFT)

    if fiducials is not None:
        for name, point in fiducials.items():
            x, y = (float(v) for v in point)
            if not (math.isfinite(x) and math.isfinite(y)):
                continue
            colour = _LEFT if name.endswith("_l") else _RIGHT if name.endswith("_r") else _MIDLINE
            centre = tuple(_fixed(np.array([x, y])))
            cv2.circle(canvas, centre, radius * _ONE, colour, thick, cv2.LINE_AA, _SHIFT)
            cv2.circle(canvas, centre, _ONE, colour, -1, cv2.LINE_AA, _SHIFT)

    if head is not None:
        hx, hy, scale, roll = (float(v) for v in head)
        if all(math.isfinite(v) for v in (hx, hy, scale, roll)) and scale > 0:
            origin = np.array([hx, hy])
            c, s = math.cos(roll), math.sin(roll)
            x_axis = origin + 0.5 * scale * np.array([c, s])
            y_axis = origin + 0.5 * scale * np.array([-s, c])
            for end in (x_axis, y_axis):
                cv2.line(canvas, tuple(_fixed(origin)), tuple(_fixed(end)), _HEAD, thick,
                         cv2.LINE_AA, _SHIFT)
            cv2.circle(canvas, tuple(_fixed(origin)), (radius + 1) * _ONE, _HEAD, thick,
                       cv2.LINE_AA, _SHIFT)

    thick = frame_thick
    font_scale = max(0.35, min(height, width) / 600)
    if lost:
        cv2.rectangle(canvas, (0, 0), (width - 1, height - 1), _LOST, 2 * thick)
        text = f"lost: {lost}" if isinstance(lost, str) and lost else "lost"
        (tw, th), _ = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, font_scale, thick)
        cv2.putText(canvas, text, (width - tw - 4 * thick, th + 4 * thick),
                    cv2.FONT_HERSHEY_SIMPLEX, font_scale, _LOST, thick, cv2.LINE_AA)
    if label:
        (_, th), _ = cv2.getTextSize(label, cv2.FONT_HERSHEY_SIMPLEX, font_scale, thick)
        org = (4 * thick, th + 4 * thick)
        cv2.putText(canvas, label, org, cv2.FONT_HERSHEY_SIMPLEX, font_scale, (0, 0, 0),
                    thick + 2, cv2.LINE_AA)
        cv2.putText(canvas, label, org, cv2.FONT_HERSHEY_SIMPLEX, font_scale, (255, 255, 255),
                    thick, cv2.LINE_AA)
    return canvas
