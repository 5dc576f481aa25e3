"""Shot cuts: frames where a video's whole picture changes at once (an edit, not motion).

A face after a cut may be another person or the same one seen by another camera; the
tracker follows whichever face lies nearest the last one, and the analysis measures it
against a neutral frame from another shot. Cuts are found as PySceneDetect's content
detector finds them: the mean absolute change of hue, saturation and value between
consecutive frames (each shrunk to :data:`THUMB_WIDTH` pixels across, hue taken the short
way round its circle; grey frames: value alone), a cut where it reaches
:data:`CUT_THRESHOLD` (PySceneDetect's default, on OpenCV's 0-179 / 0-255 scales) at
least :data:`MIN_SHOT` frames after the last one (or the first frame).

On the real clips of ``../shared/data/real`` the largest change between consecutive
frames without a cut is 7.2 (a laughing, turning head); the edits between a face and a
title card change by 68-132. A 640x360 frame costs 0.2 ms (most of it the area-mean
shrinking, which keeps sensor noise out of the change: a plain bilinear shrink took the
laughing head's largest change to 10.6).
"""

from __future__ import annotations

import cv2
import numpy as np

__all__ = ["CUT_THRESHOLD", "MIN_SHOT", "THUMB_WIDTH", "content_change", "frame_changes",
           "shot_cuts", "thumbnail"]

#: Change between consecutive frames (mean of |dH|, |dS|, |dV|) at which a cut is found.
CUT_THRESHOLD = 27.0
#: Frames a shot lasts at least: a change within this many frames of a cut is not another.
MIN_SHOT = 15
#: Width in pixels of the frames compared (their aspect kept): a cut changes the whole
#: picture, and a small copy compares in microseconds.
THUMB_WIDTH = 64


def thumbnail(frame, *, channel_order: str = "bgr") -> np.ndarray:
    """The small HSV copy of ``frame`` (grey: its values) that :func:`content_change` compares.

    Parameters
    ----------
    frame : ndarray, shape (H, W) or (H, W, 1|3|4), uint8 or uint16
    channel_order : {'bgr', 'rgb'}

    Returns
    -------
    ndarray of float32, shape (h, THUMB_WIDTH, 3) or (h, THUMB_WIDTH)

    Examples
    --------
    >>> thumbnail(np.zeros((90, 160, 3), np.uint8)).shape
    (36, 64, 3)
    """
    if channel_order not in ("bgr", "rgb"):
        raise ValueError(f"channel_order must be 'bgr' or 'rgb', got {channel_order!r}")
    img = np.asarray(frame)
    if img.ndim == 3 and img.shape[2] == 4:
        img = img[:, :, :3]                      # alpha is not picture
    elif img.ndim == 3 and img.shape[2] == 1:
        img = img[:, :, 0]
    if img.dtype == np.uint16:
        img = cv2.convertScaleAbs(img, alpha=1.0 / 257.0)      # 16-bit images: to 8 bits
    if img.ndim not in (2, 3) or img.ndim == 3 and img.shape[2] != 3 or img.dtype != np.uint8:
        raise ValueError(f"frame must be a uint8 or uint16 (H, W) or (H, W, 1|3|4) array, "
                         f"got {img.dtype} {np.shape(frame)}")
    h, w = img.shape[:2]
    small = cv2.resize(img, (THUMB_WIDTH, max(1, round(h * THUMB_WIDTH / w))),
                       interpolation=cv2.INTER_AREA)
    if small.ndim == 2:
        return small.astype(np.float32)
    code = cv2.COLOR_BGR2HSV if channel_order == "bgr" else cv2.COLOR_RGB2HSV
    return cv2.cvtColor(small, code).astype(np.float32)


def content_change(a: np.ndarray, b: np.ndarray) -> float:
    """Mean absolute change between two :func:`thumbnail` s: of hue (the short way round
    OpenCV's 180-step circle), saturation and value, averaged; of value alone for grey.

    Examples
    --------
    >>> black = thumbnail(np.zeros((36, 64, 3), np.uint8))
    >>> white = thumbnail(np.full((36, 64, 3), 255, np.uint8))
    >>> content_change(black, black), content_change(black, white)
    (0.0, 85.0)
    """
    if a.shape != b.shape:
        return float("inf")          # another size: not the same shot
    d = np.abs(a - b)
    if d.ndim == 2:
        return float(d.mean())
    d[..., 0] = np.minimum(d[..., 0], 180.0 - d[..., 0])
    return float(d.reshape(-1, 3).mean(axis=0).mean())


def frame_changes(frames):
    """Each frame of ``frames`` with its :func:`content_change` from the last decoded one.

    ``frames`` yields objects with ``ok`` and ``image`` (:class:`faceanalysis.io.video.Frame`);
    the change is NaN for the first decoded frame and for frames that did not decode.

    Examples
    --------
    >>> from types import SimpleNamespace as F
    >>> dark, light = np.zeros((36, 64), np.uint8), np.full((36, 64), 90, np.uint8)
    >>> frames = [F(ok=True, image=dark), F(ok=False, image=None), F(ok=True, image=light)]
    >>> [round(c, 1) for _, c in frame_changes(frames)]
    [nan, nan, 90.0]
    """
    last = None
    for frame in frames:
        change = float("nan")
        if frame.ok and frame.image is not None:
            thumb = thumbnail(frame.image)
            if last is not None:
                change = content_change(last, thumb)
            last = thumb
        yield frame, change


def shot_cuts(changes, frames=None, *, threshold: float = CUT_THRESHOLD,
              min_shot: int = MIN_SHOT) -> list[int]:
    """The frames that begin a new shot.

    Parameters
    ----------
    changes : array_like, shape (T,)
        :func:`content_change` of each frame from the one before it (NaN for the first
        frame and for frames not compared, e.g. undecodable ones).
    frames : array_like of int, shape (T,), optional
        Their frame numbers (default ``0..T-1``).
    threshold : float
    min_shot : int
        A change within ``min_shot`` rows of the last cut, or of the first row, is not a
        cut: a shot lasts at least that long (two photographs of a face under another
        light are not two shots).

    Returns
    -------
    list of int
        Frame numbers.

    Examples
    --------
    >>> shot_cuts([np.nan, 1.0, 1.0, 90.0, 2.0, 60.0, 1.0], min_shot=3)
    [3]
    >>> shot_cuts([np.nan, 1.0, 1.0, 90.0, 2.0, 1.0, 60.0], range(10, 17), min_shot=3)
    [13, 16]
    >>> shot_cuts([np.nan, 90.0], min_shot=3)
    []
    """
    c = np.asarray(changes, dtype=float)
    f = np.arange(len(c)) if frames is None else np.asarray(frames)
    if f.shape != c.shape:
        raise ValueError(f"changes and frames must have the same length, got {c.shape} "
                         f"and {f.shape}")
    if not (np.isfinite(threshold) and threshold > 0) or min_shot < 0:
        raise ValueError("threshold must be positive and min_shot >= 0")
    out: list[int] = []
    last = 0                       # the first row begins the first shot
    for i in np.flatnonzero(np.nan_to_num(c, nan=0.0, posinf=np.inf) >= threshold):
        if i - last >= min_shot:
            out.append(int(f[i]))
            last = i
    return out
