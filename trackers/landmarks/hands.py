"""Hands in the picture: MediaPipe's palm detector and 21-point hand landmarks (lite models).

The face tracker uses them to tell a hand held over the face: the face mesh goes on drawing
a mouth under fingers, and the snakes' edges alone depend on how faint the covered feature
was on the first frame. :class:`HandTracker` follows hands as MediaPipe's hand pipeline
does: a palm is detected on the whole frame (letterboxed to 192x192), the hand's 21 points
are read on a rotated crop around it (224x224), and later frames take their crop from the
last frame's points, so that the palm detector (about 8 ms a frame) runs only to find a new
hand and the landmarks (about 3.5-4.5 ms) only while a hand is followed.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from trackers.landmarks._image import check_image, region_crop, sample
from trackers.landmarks.detection import decode_ssd, letterbox, ssd_anchors
from trackers.landmarks.models import ensure_models
from trackers.landmarks.runtime import check_runtime, load_network

__all__ = ["N_HAND_LANDMARKS", "PalmDetection", "HandTracker", "detect_palms", "hand_landmarks",
           "palm_roi_transform", "hand_roi_transform"]

N_HAND_LANDMARKS = 21
_PALM_SIZE = 192
_HAND_SIZE = 224
_PALM_ANCHORS = ssd_anchors(24)
#: MediaPipe's hand crop from a palm: the palm box made square on its longer side, moved
#: half its height toward the fingers and scaled 2.6 times; the crop is turned so that the
#: line from the wrist to the middle finger's knuckle points up.
_PALM_SHIFT, _PALM_SCALE = -0.5, 2.6
#: The crop from a hand's own 21 points: the points' box (in the hand's turned frame)
#: scaled 1.6 times, which holds the hand as the palm's crop does.
_HAND_SCALE = 1.6
_WRIST, _MIDDLE_MCP = 0, 9


@dataclass(frozen=True, eq=False)
class PalmDetection:
    """One detected palm, in image pixels.

    Attributes
    ----------
    box : tuple of float
        (x0, y0, x1, y1) of the palm (without the fingers).
    keypoints : ndarray, shape (7, 2)
        Wrist, index, middle, ring and little finger knuckles, thumb base and thumb joint.
    score : float
    """

    box: tuple[float, float, float, float]
    keypoints: np.ndarray
    score: float


def _turned_square(centre, side: float, theta: float, size: int) -> np.ndarray:
    """The 2x3 map from the pixels of a ``size`` crop to the image, for a square of ``side``
    image pixels round ``centre`` whose 'up' is turned by ``theta`` (clockwise)."""
    k = side / size
    rot = k * np.array([[np.cos(theta), -np.sin(theta)], [np.sin(theta), np.cos(theta)]])
    return np.c_[rot, np.asarray(centre, float) - rot @ np.full(2, size / 2 - 0.5)]


def _up_angle(base, tip) -> float:
    """The turn that makes the line from ``base`` to ``tip`` point up in the crop."""
    dx, dy = np.subtract(tip, base)
    return float(np.pi / 2 - np.arctan2(-dy, dx))


def palm_roi_transform(palm: PalmDetection) -> np.ndarray:
    """The 2x3 map from hand-landmark crop pixels (224x224) to the image, for a palm."""
    (x0, y0, x1, y1), kp = palm.box, palm.keypoints
    theta = _up_angle(kp[0], kp[2])
    h = y1 - y0
    # the box's centre moved along the crop's vertical (turned) by shift * height
    centre = np.array([(x0 + x1) / 2, (y0 + y1) / 2]) \
        + _PALM_SHIFT * h * np.array([-np.sin(theta), np.cos(theta)])
    return _turned_square(centre, _PALM_SCALE * max(x1 - x0, h), theta, _HAND_SIZE)


def hand_roi_transform(points) -> np.ndarray:
    """The 2x3 map from hand-landmark crop pixels to the image, from a hand's 21 points."""
    pts = np.asarray(points, float)[:, :2]
    if pts.shape != (N_HAND_LANDMARKS, 2):
        raise ValueError(f"points must have shape ({N_HAND_LANDMARKS}, 2|3), got "
                         f"{np.shape(points)}")
    theta = _up_angle(pts[_WRIST], pts[_MIDDLE_MCP])
    c, s = np.cos(theta), np.sin(theta)
    # the points in the crop's turned axes, their box's centre back in the image
    local = pts @ np.array([[c, -s], [s, c]])
    lo, hi = local.min(0), local.max(0)
    centre = np.array([[c, s], [-s, c]]).T @ ((lo + hi) / 2)
    return _turned_square(centre, _HAND_SCALE * float((hi - lo).max()), theta, _HAND_SIZE)


def _detect(net, image: np.ndarray, channel_order: str, min_score: float, region=None):
    offset = np.zeros(2)
    if region is not None:
        image, offset = region_crop(image, region)
    square, to_image = letterbox(image, _PALM_SIZE, channel_order)
    x = net.input_buffer((1, _PALM_SIZE, _PALM_SIZE, 3))
    np.divide(square, np.float32(255), out=x[0])
    regressors, logits = net.run(x)   # 'Identity', 'Identity_1'
    palms = []
    for box, kp, score in decode_ssd(regressors, logits, _PALM_ANCHORS, _PALM_SIZE,
                                     min_score):
        box = (to_image(box.reshape(2, 2)) + offset).ravel()
        palms.append(PalmDetection(tuple(float(v) for v in box), to_image(kp) + offset,
                                   float(score)))
    return palms


def _landmarks(net, image: np.ndarray, crop_to_image: np.ndarray, channel_order: str):
    crop = sample(image, crop_to_image, _HAND_SIZE, channel_order, border=cv2.BORDER_CONSTANT)
    x = net.input_buffer((1, _HAND_SIZE, _HAND_SIZE, 3))
    np.divide(crop, np.float32(255), out=x[0])
    coords, presence = net.run(x)[:2]   # 'Identity' (screen points), 'Identity_1' (hand flag)
    raw = coords.reshape(N_HAND_LANDMARKS, 3)[:, :2].astype(np.float64)
    points = (raw - 0.5) @ crop_to_image[:, :2].T + crop_to_image[:, 2]
    return points, float(np.clip(presence.reshape(-1)[0], 0.0, 1.0))


def detect_palms(image, *, channel_order: str = "rgb", min_score: float = 0.5,
                 runtime: str = "auto", region=None) -> list[PalmDetection]:
    """Detect palms in a frame (MediaPipe's lite palm detector).

    Parameters
    ----------
    image : ndarray, shape (H, W) or (H, W, 3)
        uint8, or float in [0, 1].
    channel_order : {'rgb', 'bgr'}
    min_score : float
        Lowest palm probability kept, in (0, 1).
    runtime : {'auto', 'litert', 'opencv'}
    region : tuple of float, optional
        (x0, y0, x1, y1): look only in this part of the frame (clipped to it), which the
        detector then sees at a larger scale: its 192-pixel view of a whole wide frame
        misses a hand a few tens of pixels across. Default: the whole frame.

    Returns
    -------
    list of PalmDetection
        Highest score first, in the whole frame's pixels.
    """
    image = check_image(image, channel_order)
    if not 0 < min_score < 1:
        raise ValueError(f"min_score={min_score!r} must lie in (0, 1)")
    net = load_network(ensure_models()["palm_detection"], runtime=check_runtime(runtime))
    return _detect(net, image, channel_order, min_score, region)


def hand_landmarks(image, roi, *, channel_order: str = "rgb",
                   runtime: str = "auto") -> tuple[np.ndarray, float]:
    """A hand's 21 landmarks in a region of interest.

    Parameters
    ----------
    image : ndarray, shape (H, W) or (H, W, 3)
    roi : PalmDetection or ndarray, shape (21, 2)
        A palm, or the hand's points on the previous frame (tracking).
    channel_order : {'rgb', 'bgr'}
    runtime : {'auto', 'litert', 'opencv'}

    Returns
    -------
    points : ndarray, shape (21, 2)
        Wrist, then four points per finger from the thumb to the little finger, in image
        pixels.
    presence : float
        Probability that the crop holds a hand (below 0.5: no hand).
    """
    image = check_image(image, channel_order)
    m = palm_roi_transform(roi) if isinstance(roi, PalmDetection) else hand_roi_transform(roi)
    net = load_network(ensure_models()["hand_landmark"], runtime=check_runtime(runtime))
    return _landmarks(net, image, m, channel_order)


class HandTracker:
    """Follow the hands in a video.

    Parameters
    ----------
    channel_order : {'rgb', 'bgr'}
    runtime : {'auto', 'litert', 'opencv'}
    max_hands : int
        Most hands followed at once.
    min_presence : float
        A hand whose landmarks' presence falls below this is dropped.

    Notes
    -----
    :meth:`track` reads each followed hand's points on a crop from its last points; it runs
    the palm detector only when asked (``detect=True``) and no hand is followed (or every
    followed one was lost on the frame), so that a caller decides when a new hand is worth
    looking for (its costliest step).

    Examples
    --------
    >>> import numpy as np
    >>> tracker = HandTracker()                                 # doctest: +SKIP
    >>> tracker.track(np.zeros((360, 640, 3), np.uint8), detect=True)   # doctest: +SKIP
    []
    """

    def __init__(self, *, channel_order: str = "rgb", runtime: str = "auto",
                 max_hands: int = 2, min_presence: float = 0.5):
        if channel_order not in ("rgb", "bgr"):
            raise ValueError(f"channel_order must be 'rgb' or 'bgr', got {channel_order!r}")
        if int(max_hands) < 1:
            raise ValueError(f"max_hands must be at least 1, got {max_hands}")
        if not 0 < min_presence < 1:
            raise ValueError(f"min_presence={min_presence!r} must lie in (0, 1)")
        self.channel_order = channel_order
        self.runtime = check_runtime(runtime)
        self.max_hands = int(max_hands)
        self.min_presence = float(min_presence)
        self.hands: list[np.ndarray] = []
        self._models = None

    def reset(self) -> None:
        """Forget the followed hands."""
        self.hands = []

    def track(self, frame, *, detect: bool = True, region=None) -> list[np.ndarray]:
        """The (21, 2) points of each hand on ``frame`` (an empty list: none); a new hand
        is looked for within ``region`` (x0, y0, x1, y1; default the whole frame, see
        :func:`detect_palms`)."""
        if not self.hands and not detect:
            return []                   # nothing followed, nothing to look for
        image = check_image(frame, self.channel_order)
        hand_net = self._net("hand_landmark")
        hands = self._read(image, hand_net, [hand_roi_transform(p) for p in self.hands])
        if not hands and detect:
            # nothing followed, or every followed hand lost on this frame
            palms = _detect(self._net("palm_detection"), image, self.channel_order, 0.5,
                            region)
            hands = self._read(image, hand_net,
                               [palm_roi_transform(p) for p in palms[:self.max_hands]])
        self.hands = hands
        return list(hands)

    def _net(self, name):
        # as LandmarkTracker's: the files are checked once per tracker, the networks are
        # cached per thread by load_network
        if self._models is None:
            self._models = ensure_models()
        return load_network(self._models[name], runtime=self.runtime)

    def _read(self, image, net, crops) -> list[np.ndarray]:
        hands = []
        for m in crops:
            points, presence = _landmarks(net, image, m, self.channel_order)
            if presence >= self.min_presence and not any(_same_hand(points, h) for h in hands):
                hands.append(points)
        return hands


def _same_hand(a: np.ndarray, b: np.ndarray) -> bool:
    """Two point sets on one hand (two crops that converged on it): their wrists and middle
    knuckles lie within a fifth of the hand's size of each other."""
    size = float(np.hypot(*(b.max(0) - b.min(0))))
    return bool(np.hypot(*(a[[_WRIST, _MIDDLE_MCP]] - b[[_WRIST, _MIDDLE_MCP]]).T).max()
                < 0.2 * size)
