"""Face detection with MediaPipe's BlazeFace models: short range (faces within ~2 m, a 128x128
view of the frame) and full range (up to ~5 m, 192x192: faces down to about 2 % of the
frame's width)."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from trackers.landmarks._image import check_image, region_crop, sample
from trackers.landmarks.models import ensure_models
from trackers.landmarks.runtime import check_runtime, load_network

__all__ = ["FaceDetection", "detect_faces", "ssd_anchors", "decode_ssd", "letterbox",
           "DETECTORS"]

_SIZE = 128
_FULL_SIZE = 192
_IOU = 0.3
#: The detectors of :func:`detect_faces`: the model file (a key of
#: :data:`~trackers.landmarks.models.MODEL_FILES`) of each.
DETECTORS = {"short": "face_detection", "full": "face_detection_full_range"}


@dataclass(frozen=True, eq=False)
class FaceDetection:
    """One detected face, in image pixels.

    Attributes
    ----------
    box : tuple of float
        (x0, y0, x1, y1).
    keypoints : ndarray, shape (6, 2)
        Subject's right eye (image left), subject's left eye, nose tip, mouth centre, right
        ear tragion, left ear tragion.
    score : float
        Face probability.
    """

    box: tuple[float, float, float, float]
    keypoints: np.ndarray
    score: float


def ssd_anchors(cells: int) -> np.ndarray:
    """Anchor centres in [0, 1] of MediaPipe's BlazeFace-style detectors: ``cells`` x
    ``cells`` cells x 2 anchors, then ``cells / 2`` squared x 6 (fixed-size anchors: only
    their centres matter). 16 gives the face detector's 896, 24 the palm detector's 2016."""
    out = []
    for n, per_cell in ((cells, 2), (cells // 2, 6)):
        y, x = np.mgrid[:n, :n]
        centres = np.c_[(x.ravel() + 0.5) / n, (y.ravel() + 0.5) / n]
        out.append(np.repeat(centres, per_cell, axis=0))
    return np.concatenate(out).astype(np.float32)


_ANCHORS = ssd_anchors(16)
# the full-range model: one anchor per cell of a 48x48 grid (stride 4 of its 192 pixels)
_FULL_ANCHORS = np.stack(np.meshgrid((np.arange(48) + 0.5) / 48, (np.arange(48) + 0.5) / 48),
                         axis=-1).reshape(-1, 2).astype(np.float32)


def _iou(box: np.ndarray, boxes: np.ndarray) -> np.ndarray:
    lo = np.maximum(box[:2], boxes[:, :2])
    hi = np.minimum(box[2:], boxes[:, 2:])
    inter = np.prod(np.clip(hi - lo, 0, None), axis=1)
    area = lambda b: np.prod(b[..., 2:] - b[..., :2], axis=-1)  # noqa: E731
    return inter / np.maximum(area(box) + area(boxes) - inter, 1e-12)


def _weighted_nms(boxes, keypoints, scores):
    """MediaPipe's 'weighted' suppression: each cluster (IoU > 0.3 with its best member)
    becomes the score-weighted mean of its members, with the best member's score."""
    order = np.argsort(-scores)
    boxes, keypoints, scores = boxes[order], keypoints[order], scores[order]
    alive = np.ones(len(scores), bool)
    out = []
    for i in range(len(scores)):
        if not alive[i]:
            continue
        members = alive & (_iou(boxes[i], boxes) > _IOU)
        members[i] = True
        alive &= ~members
        w = scores[members] / scores[members].sum()
        out.append((w @ boxes[members], np.tensordot(w, keypoints[members], 1), scores[i]))
    return out


def letterbox(image: np.ndarray, size: int, channel_order: str):
    """The frame scaled to fit a ``size`` square (longer side), centred on a black border.

    Returns
    -------
    square : ndarray, shape (size, size, 3)
        uint8 RGB.
    to_image : callable
        From the square's [0, 1] coordinates, (..., 2), to image pixel indices (pixel
        centres on integers, OpenCV's convention).
    """
    h, w = image.shape[:2]
    # continuous coordinates map as square = s * image + t, pixel indices as
    # square_i = s * image_i + t + (s - 1) / 2
    s = size / max(h, w)
    t = (size - s * np.array([w, h])) / 2
    square_to_image = np.array([[1 / s, 0, -(t[0] + (s - 1) / 2) / s],
                                [0, 1 / s, -(t[1] + (s - 1) / 2) / s]])
    square = sample(image, square_to_image, size, channel_order, border=cv2.BORDER_CONSTANT)
    return square, lambda p: (np.asarray(p) * size - t) / s - 0.5


def decode_ssd(regressors, logits, anchors, size: int, min_score: float):
    """Boxes, keypoints and scores of a BlazeFace-style detector's outputs.

    Parameters
    ----------
    regressors : ndarray, shape (1, A, 4 + 2K)
        Per anchor: box centre offset and size, then K keypoints, in input pixels.
    logits : ndarray, shape (1, A, 1)
    anchors : ndarray, shape (A, 2)
    size : int
        The square input's side in pixels.
    min_score : float

    Returns
    -------
    list of (box (4,), keypoints (K, 2), score)
        In [0, 1] coordinates of the input square, after MediaPipe's weighted suppression.
    """
    logits = logits.reshape(-1).astype(np.float64)  # float32 exp overflows
    scores = 1 / (1 + np.exp(-np.clip(logits, -100, 100)))
    keep = scores >= min_score
    if not keep.any():
        return []
    raw = regressors.reshape(len(anchors), -1)[keep] / size
    anchors = anchors[keep]
    centre = raw[:, :2] + anchors
    boxes = np.c_[centre - raw[:, 2:4] / 2, centre + raw[:, 2:4] / 2]
    keypoints = raw[:, 4:].reshape(len(raw), -1, 2) + anchors[:, None]
    return _weighted_nms(boxes, keypoints, scores[keep])


def detect_faces(image, *, channel_order: str = "rgb", min_score: float = 0.5,
                 runtime: str = "auto", model: str = "short") -> list[FaceDetection]:
    """Detect faces in a frame.

    Parameters
    ----------
    image : ndarray, shape (H, W) or (H, W, 3)
        uint8, or float in [0, 1].
    channel_order : {'rgb', 'bgr'}
        Channel order of a colour frame (OpenCV frames are 'bgr').
    min_score : float
        Lowest face probability kept, in (0, 1).
    runtime : {'auto', 'litert', 'opencv'}
        See :func:`trackers.landmarks.runtime.load_network`.
    model : {'short', 'full'}
        'short' (default): BlazeFace's short-range model, the face mesh's own detector
        for faces near the camera (it misses faces narrower than about a tenth of the
        frame's longer side). 'full': the full-range model, for faces farther away or
        small in a wide frame (down to about 2 % of the frame's longer side; 2-3 times
        the short model's time); it needs ``runtime='litert'`` (OpenCV's TFLite reader
        lacks its DENSIFY operator).

    Returns
    -------
    list of FaceDetection
        Highest score first; empty when no face is found.
    """
    image = check_image(image, channel_order)
    if not 0 < min_score < 1:
        raise ValueError(f"min_score={min_score!r} must lie in (0, 1)")
    if model not in DETECTORS:
        raise ValueError(f"model={model!r} is not one of {', '.join(map(repr, DETECTORS))}")
    runtime = check_runtime(runtime)
    if model == "full" and runtime != "litert":
        raise ValueError("the full-range face detector needs runtime='litert' (OpenCV's "
                         "TFLite reader lacks its DENSIFY operator)")
    net = load_network(ensure_models()[DETECTORS[model]], runtime=runtime)
    return _run(net, image, channel_order, min_score, full=model == "full")


def _run(net, image: np.ndarray, channel_order: str, min_score: float, *,
         full: bool = False, region=None) -> list[FaceDetection]:
    """:func:`detect_faces` with the network given and the arguments checked; with
    ``region`` (x0, y0, x1, y1), on that part of the image only (which the detector then
    sees at a larger scale), the faces in the whole image's pixels."""
    size, anchors = (_FULL_SIZE, _FULL_ANCHORS) if full else (_SIZE, _ANCHORS)
    offset = np.zeros(2)
    if region is not None:
        image, offset = region_crop(image, region)
    square, to_image = letterbox(image, size, channel_order)
    x = square[None].astype(np.float32) / 127.5 - 1
    if full:
        regressors, scores_logit = net.run(x)   # 'Identity', 'Identity_1' (name order)
    else:
        scores_logit, regressors = net.run(x)   # 'classificators', 'regressors'
    faces = []
    for box, kp, score in decode_ssd(regressors, scores_logit, anchors, size, min_score):
        box = (to_image(box.reshape(2, 2)) + offset).ravel()
        faces.append(FaceDetection(tuple(float(v) for v in box), to_image(kp) + offset,
                                   float(score)))
    return faces
