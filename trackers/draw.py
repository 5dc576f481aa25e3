"""Drawing helpers: contours, fiducials and the head frame over a frame (new image).

Colours are given in the frame's own channel order (``(r, g, b)`` for an RGB frame).
Grey frames are converted to three channels first. Points are drawn with sub-pixel
precision (OpenCV fixed point, 4 fractional bits).
"""

from __future__ import annotations

import cv2
import numpy as np

from trackers.fiducials import HeadFrame

__all__ = ["draw_contours", "draw_fiducials", "draw_head_frame"]

_SHIFT = 4


def _canvas(image) -> np.ndarray:
    img = np.asarray(image)
    if img.ndim not in (2, 3) or img.size == 0:
        raise ValueError(f"image must be a non-empty (H, W) or (H, W, C) array, got {img.shape}")
    if img.dtype != np.uint8:
        f = img.astype(np.float64)
        if not np.isfinite(f).all():
            raise ValueError("image has NaN or infinite pixels")
        if np.issubdtype(img.dtype, np.floating) or img.dtype == bool:
            f = f * 255.0
        elif np.issubdtype(img.dtype, np.integer):
            f = f * (255.0 / np.iinfo(img.dtype).max)
        img = np.clip(np.round(f), 0, 255).astype(np.uint8)
    if img.ndim == 2:
        return cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
    if img.shape[2] == 1:
        return cv2.cvtColor(img[:, :, 0], cv2.COLOR_GRAY2BGR)
    if img.shape[2] == 4:
        return np.ascontiguousarray(img[:, :, :3])
    if img.shape[2] != 3:
        raise ValueError(f"image must have 1, 3 or 4 channels, got {img.shape[2]}")
    return img.copy()


def _fx(points):
    p = np.asarray(points, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 2 or not np.isfinite(p).all():
        raise ValueError(f"points must be a finite (n, 2) array, got shape {p.shape}")
    return np.round(p * (1 << _SHIFT)).astype(np.int32)


def draw_contours(image, contours, *, color=(0, 0, 0), thickness: int = 1, closed=None,
                  lost=None, lost_color=(255, 0, 0), nodes: bool = False) -> np.ndarray:
    """Draw contours as polylines; returns a new uint8 image with 3 channels.

    Parameters
    ----------
    image : array_like
        Frame (grey or colour, any dtype; floats in [0, 1]).
    contours : mapping name -> (n, 2) or sequence of (n, 2)
        Node positions (x, y) in pixels.
    color, lost_color : 3-tuple
        Colours of tracked and lost contours.
    thickness : int
    closed : set of names or bool, optional
        Which contours to close (``chin_boss`` by default for a mapping).
    lost : set of names, optional
        Contours drawn in ``lost_color``.
    nodes : bool
        Also mark every node.

    Examples
    --------
    >>> import numpy as np
    >>> out = draw_contours(np.zeros((20, 20)), [np.array([[2.0, 2], [17, 17], [2, 17]])],
    ...                     color=(255, 255, 255))
    >>> out.shape, int(out[10, 10, 0]) > 0
    ((20, 20, 3), True)
    """
    out = _canvas(image)
    items = contours.items() if isinstance(contours, dict) else enumerate(contours)
    if closed is None:
        closed = {"chin_boss"} if isinstance(contours, dict) else set()
    lost = set(lost or ())
    for name, pts in items:
        col = tuple(int(c) for c in (lost_color if name in lost else color))
        p = _fx(pts)
        is_closed = closed if isinstance(closed, bool) else name in closed
        cv2.polylines(out, [p.reshape(-1, 1, 2)], is_closed, col, int(thickness),
                      lineType=cv2.LINE_AA, shift=_SHIFT)
        if nodes:
            for q in p:
                cv2.circle(out, (int(q[0]), int(q[1])), 1 << _SHIFT, col, -1,
                           lineType=cv2.LINE_AA, shift=_SHIFT)
    return out


def draw_fiducials(image, points, *, color=(255, 255, 0), radius: float = 2.0,
                   labels: bool = False, font_scale: float = 0.3) -> np.ndarray:
    """Draw fiducial points (dots, optional name labels); returns a new uint8 image.

    Parameters
    ----------
    image : array_like
    points : mapping name -> (x, y)
    color : 3-tuple
    radius : float
    labels : bool
    font_scale : float

    Examples
    --------
    >>> import numpy as np
    >>> out = draw_fiducials(np.zeros((20, 20, 3), np.uint8), {"chin": (10.0, 10.0)})
    >>> tuple(int(v) for v in out[10, 10])
    (255, 255, 0)
    """
    out = _canvas(image)
    col = tuple(int(c) for c in color)
    for name, xy in points.items():
        (x, y), = _fx([xy])
        cv2.circle(out, (int(x), int(y)), int(round(radius * (1 << _SHIFT))), col, -1,
                   lineType=cv2.LINE_AA, shift=_SHIFT)
        if labels:
            cv2.putText(out, str(name), (int(x >> _SHIFT) + 3, int(y >> _SHIFT) - 3),
                        cv2.FONT_HERSHEY_SIMPLEX, font_scale, col, 1, cv2.LINE_AA)
    return out


def draw_head_frame(image, head: HeadFrame, *, color=(0, 255, 255), size: float = 10.0,
                    thickness: int = 1) -> np.ndarray:
    """Draw the head frame's origin as a crosshair aligned with its axes (like Fig. 6).

    Examples
    --------
    >>> import numpy as np
    >>> out = draw_head_frame(np.zeros((30, 30)), HeadFrame(15.0, 15.0, 50.0, 0.0))
    >>> int(out[15, 20].max()) > 0
    True
    """
    if not isinstance(head, HeadFrame):
        raise ValueError(f"head must be a HeadFrame, got {type(head).__name__}")
    out = _canvas(image)
    ex, ey = head.axes
    o = np.array([head.x, head.y])
    col = tuple(int(c) for c in color)
    for ax in (ex, ey):
        a, b = _fx([o - size * ax, o + size * ax])
        cv2.line(out, tuple(int(v) for v in a), tuple(int(v) for v in b), col, int(thickness),
                 lineType=cv2.LINE_AA, shift=_SHIFT)
    return out
