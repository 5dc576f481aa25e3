"""MediaPipe's 468-point face mesh on an eye-aligned crop of the face."""

from __future__ import annotations

import cv2
import numpy as np

from trackers.landmarks._image import check_image, sample
from trackers.landmarks.detection import FaceDetection
from trackers.landmarks.models import ensure_models
from trackers.landmarks.runtime import check_runtime, load_network

__all__ = ["FACE_OVAL", "N_LANDMARKS", "face_landmarks", "roi_transform"]

N_LANDMARKS = 468
#: The mesh's face oval, a closed loop from the forehead's top (10) round the subject's left
#: (the image's right), under the chin (152) and back: the silhouette, which slides over
#: the face's surface as the head turns.
FACE_OVAL = (10, 338, 297, 332, 284, 251, 389, 356, 454, 323, 361, 288, 397, 365, 379, 378,
             400, 377, 152, 148, 176, 149, 150, 136, 172, 58, 132, 93, 234, 127, 162, 21,
             54, 103, 67, 109)
_SIZE = 192
_SCALE = 1.5             # crop side / longer side of the face box, as MediaPipe
_EYES = (33, 263)        # outer eye corners, subject's right (image left) then left
_HALF = np.full(2, _SIZE / 2 - 0.5)


def roi_transform(roi) -> np.ndarray:
    """The 2x3 map from crop pixels (192x192) to image pixels for a detection or landmarks.

    The crop is a square of side 1.5 x the longer side of the face box, centred on the box and
    rotated so that the line from the subject's right eye to the left eye is horizontal.
    """
    if isinstance(roi, FaceDetection):
        (x0, y0, x1, y1), eyes = roi.box, roi.keypoints[:2]
        dx, dy = eyes[1] - eyes[0]
    else:
        pts = np.asarray(roi, dtype=np.float64)
        if pts.ndim != 2 or pts.shape[0] != N_LANDMARKS or pts.shape[1] not in (2, 3):
            raise ValueError(f"roi of shape {pts.shape} is neither a FaceDetection nor "
                             f"({N_LANDMARKS}, 2|3) landmarks")
        xs, ys = pts[:, 0], pts[:, 1]
        x0, x1, y0, y1 = xs.min(), xs.max(), ys.min(), ys.max()
        dx, dy = pts[_EYES[1], :2] - pts[_EYES[0], :2]
    # scalar arithmetic, NumPy's own trigonometry (the tracker calls this three times a
    # frame; array construction cost three times the arithmetic)
    theta = np.arctan2(dy, dx)
    k = _SCALE * max(x1 - x0, y1 - y0) / _SIZE
    cos, sin = np.cos(theta), np.sin(theta)
    out = np.empty((2, 3))
    out[0, 0], out[0, 1], out[1, 0], out[1, 1] = k * cos, k * -sin, k * sin, k * cos
    # pixel indices: crop continuous = index + 0.5, around the crop centre at 96
    out[:, 2] = np.array([(x0 + x1) / 2, (y0 + y1) / 2]) - out[:, :2] @ _HALF
    return out


def face_landmarks(image, roi, *, channel_order: str = "rgb",
                   runtime: str = "auto") -> tuple[np.ndarray, float]:
    """The 468 landmarks of the face in a region of interest.

    Parameters
    ----------
    image : ndarray, shape (H, W) or (H, W, 3)
        uint8, or float in [0, 1].
    roi : FaceDetection or ndarray, shape (468, 2) or (468, 3)
        A detection, or the previous frame's landmarks (tracking).
    channel_order : {'rgb', 'bgr'}
    runtime : {'auto', 'litert', 'opencv'}

    Returns
    -------
    points : ndarray, shape (468, 3)
        x, y in image pixels (pixel centres on integers) and z, depth relative to the face
        centre in the same pixel scale (smaller is nearer the camera).
    presence : float
        Probability that the crop shows a face (below 0.5: the face is lost).
    """
    image = check_image(image, channel_order)
    net = load_network(ensure_models()["face_landmark"], runtime=check_runtime(runtime))
    return _run(net, image, roi, channel_order)


def _run(net, image: np.ndarray, roi, channel_order: str) -> tuple[np.ndarray, float]:
    """:func:`face_landmarks` with the network given and the image checked (the tracker's
    per-frame path: no model-file checks)."""
    m = roi_transform(roi)
    crop = sample(image, m, _SIZE, channel_order, border=cv2.BORDER_REPLICATE)
    # scaled to [0, 1] straight into the network's own input array: a new batch each
    # frame (and OpenCV's NCHW copy of it) cost as much as the warp and scaling together
    # (channels first on both sides: the loop then runs in the order of an NCHW buffer's
    # memory, four times faster there than channels last, and no slower on NHWC)
    x = net.input_buffer((1, _SIZE, _SIZE, 3))
    np.divide(crop.transpose(2, 0, 1), np.float32(255), out=x[0].transpose(2, 0, 1))
    coords, logit = net.run(x)  # 'conv2d_21', 'conv2d_31'
    raw = coords.reshape(N_LANDMARKS, 3).astype(np.float64)
    points = np.empty_like(raw)
    points[:, :2] = (raw[:, :2] - 0.5) @ m[:, :2].T + m[:, 2]
    points[:, 2] = raw[:, 2] * np.hypot(*m[:, 0])
    presence = 1 / (1 + np.exp(-np.clip(float(logit.reshape(-1)[0]), -100, 100)))
    return points, float(presence)
