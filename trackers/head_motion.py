"""Rigid head motion from corner features on the upper face.

The irises (:class:`~trackers.anchors.IrisAnchors`) are the head frame's best anchors,
but on real video they are often not there: eyes squeezed shut when crying, narrowed
when laughing, a hand in front of them. The contours' own frame (hairline and nose,
004) moves with the expression and jumps when a contour slides onto another feature,
and chaining it frame after frame carries every such error on. This module gives the
tracker a third anchor that does not depend on the contours at all.

:class:`FeatureAnchors` seeds Shi-Tomasi corners (``cv2.goodFeaturesToTrack``) on the
reference frame in the parts of the face that the facial muscles move least: the band
of the eyes (canthi, lid folds, the bridge of the nose) and the nose itself. Each
feature keeps its *reference* position. On every frame the features are followed by
pyramidal Lucas-Kanade (``cv2.calcOpticalFlowPyrLK``) with a forward-backward check,
and the similarity from the reference positions to the tracked ones is fitted with
RANSAC (``cv2.estimateAffinePartial2D``): a hand, a lid or a cheek that moves on its own
is outvoted and its features are dropped. Because the fit is always made from the
reference positions, the error does not accumulate frame by frame as a chain of
frame-to-frame motions would; it grows only when features are re-seeded (their
reference positions are then inferred from the current similarity), which happens
when fewer than half remain.

All points are image pixels (x right, y down).

References
----------
.. [1] J. Shi and C. Tomasi, "Good features to track", CVPR 1994.
.. [2] J.-Y. Bouguet, "Pyramidal implementation of the Lucas Kanade feature tracker",
       Intel Corporation, 2000.
.. [3] M. A. Fischler and R. C. Bolles, "Random sample consensus", CACM 24(6), 1981.
"""

from __future__ import annotations

import cv2
import numpy as np

from trackers.layout import _eye_similarity
from trackers.potentials import to_gray

__all__ = ["FeatureAnchors", "gray_u8", "rigid_face_region"]

#: Polygons of the rigid upper face in the eye frame (origin midway between the eye
#: centres, unit = inter-eye distance, x toward the eye on the image's right, y down):
#: the band of the eyes (without the brows, which the frontalis and corrugator move)
#: and the nose down to above the nostrils (the alae flare with the levators).
RIGID_REGION = (
    np.array([(-0.78, -0.14), (0.78, -0.14), (0.78, 0.22), (-0.78, 0.22)]),
    np.array([(-0.22, 0.22), (0.22, 0.22), (0.26, 0.85), (-0.26, 0.85)]),
)


def rigid_face_region(eyes, image_size) -> np.ndarray:
    """Mask (uint8, 255 inside) of the rigid upper face for eye centres ``eyes``.

    Parameters
    ----------
    eyes : array_like (2, 2)
        Eye centres (x, y), the one on the image's left first.
    image_size : (width, height)

    Returns
    -------
    ndarray (height, width) uint8

    Examples
    --------
    >>> m = rigid_face_region([(40, 50), (80, 50)], (120, 100))
    >>> bool(m[50, 60]), bool(m[50, 5]), bool(m[90, 60])
    (True, False, False)
    """
    M = _eye_similarity(*np.asarray(eyes, float).reshape(2, 2))
    W, H = (int(v) for v in image_size)
    if W < 1 or H < 1:
        raise ValueError(f"image_size must be positive, got {image_size}")
    mask = np.zeros((H, W), np.uint8)
    for poly in RIGID_REGION:
        pts = poly @ M[:, :2].T + M[:, 2]
        cv2.fillPoly(mask, [np.round(pts * 16).astype(np.int32)], 255, shift=4)
    return mask


def gray_u8(frame, channel_order: str = "rgb") -> np.ndarray:
    """8-bit grey version of a frame (what OpenCV's feature tracking takes).

    8-bit frames are converted by OpenCV directly; other dtypes go through
    :func:`~trackers.potentials.to_gray` (which validates them) and are rounded.
    """
    img = np.asarray(frame)
    if img.dtype != np.uint8 or img.ndim not in (2, 3) or (
            img.ndim == 3 and img.shape[2] not in (1, 3, 4)):
        return np.clip(to_gray(img, channel_order=channel_order) + 0.5, 0, 255).astype(np.uint8)
    if img.ndim == 3:
        if img.shape[2] == 1:
            return np.ascontiguousarray(img[:, :, 0])
        code = cv2.COLOR_BGR2GRAY if channel_order == "bgr" else cv2.COLOR_RGB2GRAY
        return cv2.cvtColor(np.ascontiguousarray(img[:, :, :3]), code)
    return np.ascontiguousarray(img)


class FeatureAnchors:
    """Head motion from corner features on the eyes and nose (see the module docstring).

    Parameters
    ----------
    frame : array_like
        Reference frame (grey or colour, any dtype).
    eyes : array_like (2, 2)
        Eye centres on the reference frame (the one on the image's left first).
    channel_order : {'rgb', 'bgr'}
    max_features : int
        Features seeded (and kept up to).
    min_inliers : int
        Least number of features agreeing on a similarity for it to be trusted.
    threshold : float
        RANSAC inlier distance and forward-backward tolerance, as a fraction of the
        inter-eye distance (at least 1 px).

    Attributes
    ----------
    ref : ndarray (n, 2)
        Reference-frame positions of the features being followed.
    points : ndarray (n, 2)
        Their positions on the last frame.
    inliers : int
        Features that agreed on the last similarity (0 when none was found).

    Raises
    ------
    ValueError
        When the reference frame has too few features in the rigid region.

    Examples
    --------
    >>> import numpy as np
    >>> rng = np.random.default_rng(0)
    >>> img = cv2.GaussianBlur(rng.integers(0, 255, (120, 160)).astype(np.uint8), (0, 0), 1.5)
    >>> anc = FeatureAnchors(img, [(60, 50), (100, 50)])
    >>> a, b = anc.similarity(np.roll(img, (2, 3), axis=(0, 1)))
    >>> round(abs(a), 3), round(b.real, 1), round(b.imag, 1)
    (1.0, 3.0, 2.0)
    """

    def __init__(self, frame, eyes, *, channel_order: str = "rgb", max_features: int = 60,
                 min_inliers: int = 8, threshold: float = 0.02):
        if channel_order not in ("rgb", "bgr"):
            raise ValueError(f"channel_order must be 'rgb' or 'bgr', got {channel_order!r}")
        if int(max_features) < 4 or int(min_inliers) < 3 or int(min_inliers) > int(max_features):
            raise ValueError(f"need 4 <= max_features and 3 <= min_inliers <= max_features, "
                             f"got {max_features}, {min_inliers}")
        if not 0 < threshold < 0.5:
            raise ValueError(f"threshold must be in (0, 0.5), got {threshold}")
        self.channel_order = channel_order
        gray = gray_u8(frame, channel_order)
        H, W = gray.shape[:2]
        self.image_size = (W, H)
        self.eyes = np.asarray(eyes, float).reshape(2, 2)
        self.iod = float(np.hypot(*(self.eyes[1] - self.eyes[0])))
        if not self.iod >= 10:
            raise ValueError(f"eye centres {self.eyes.tolist()} are too close (or not finite) "
                             f"for features between them")
        self.max_features = int(max_features)
        self.min_inliers = int(min_inliers)
        self.tol = max(1.0, float(threshold) * self.iod)
        # features a few pixels apart at least; corners finer than the face's scale
        # (pores, noise) are not followed reliably
        self._min_distance = max(3.0, 0.04 * self.iod)
        self._block = max(3, int(round(0.04 * self.iod)) | 1)
        self._win = (max(9, int(round(0.15 * self.iod)) | 1),) * 2
        self._levels = 3
        self._region = rigid_face_region(self.eyes, self.image_size)
        pts = self._seed(gray, self._region, self.max_features)
        if len(pts) < self.min_inliers:
            raise ValueError(f"only {len(pts)} features on the eyes and nose of the reference "
                             f"frame (at least {self.min_inliers} needed)")
        self.ref = pts.copy()
        self.points = pts
        self._prev = gray
        self.sim = (1.0 + 0j, 0j)
        self.inliers = len(pts)

    def _seed(self, gray, mask, n):
        # on the mask's bounding box only: the corner response of a whole frame costs
        # ten times as much
        ys, xs = np.nonzero(mask.any(axis=1))[0], np.nonzero(mask.any(axis=0))[0]
        if len(ys) == 0:
            return np.zeros((0, 2), np.float32)
        m = self._block
        y0, y1 = max(ys[0] - m, 0), min(ys[-1] + m + 1, mask.shape[0])
        x0, x1 = max(xs[0] - m, 0), min(xs[-1] + m + 1, mask.shape[1])
        p = cv2.goodFeaturesToTrack(np.ascontiguousarray(gray[y0:y1, x0:x1]),
                                    maxCorners=int(n), qualityLevel=0.01,
                                    minDistance=self._min_distance,
                                    mask=np.ascontiguousarray(mask[y0:y1, x0:x1]),
                                    blockSize=self._block)
        if p is None:
            return np.zeros((0, 2), np.float32)
        return (p.reshape(-1, 2) + [x0, y0]).astype(np.float32)

    def _box(self, H, W):
        """Crop around the features that leaves room for a frame's motion and the
        search windows at every pyramid level."""
        m = 0.5 * self.iod + 2 * self._win[0]
        lo = np.floor(self.points.min(axis=0) - m).astype(int)
        hi = np.ceil(self.points.max(axis=0) + m).astype(int) + 1
        return max(lo[0], 0), max(lo[1], 0), min(hi[0], W), min(hi[1], H)

    def _track(self, gray):
        """Features followed from the last frame to ``gray``: (kept mask, new points)."""
        crit = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 20, 0.03)
        # both frames cropped alike around the features (OpenCV's Python binding
        # cannot take prebuilt pyramids, so each call builds two: smaller is faster)
        x0, y0, x1, y1 = self._box(*gray.shape)
        g0 = np.ascontiguousarray(self._prev[y0:y1, x0:x1])
        g1 = np.ascontiguousarray(gray[y0:y1, x0:x1])
        off = np.array([x0, y0], np.float32)
        p0 = (self.points - off).reshape(-1, 1, 2)
        p1, st, _ = cv2.calcOpticalFlowPyrLK(g0, g1, p0, None, winSize=self._win,
                                             maxLevel=self._levels, criteria=crit)
        back, st2, _ = cv2.calcOpticalFlowPyrLK(g1, g0, p1, p0.copy(), winSize=self._win,
                                                maxLevel=self._levels, criteria=crit,
                                                flags=cv2.OPTFLOW_USE_INITIAL_FLOW)
        fb = np.hypot(*(back - p0).reshape(-1, 2).T)
        ok = (st.ravel() == 1) & (st2.ravel() == 1) & (fb < 0.5 * self.tol)
        return ok, p1.reshape(-1, 2) + off

    def similarity(self, frame):
        """Similarity ``z -> a z + b`` (complex a, b) carrying the reference frame's
        features onto ``frame``'s, or None when too few agree.

        The frames must come in order: features are followed from the last frame
        given. On a miss the features stay where they were last found; the next call
        follows them from there.
        """
        gray = gray_u8(frame, self.channel_order)
        if gray.shape[1::-1] != self.image_size:
            raise ValueError(f"frame is {gray.shape[1]}x{gray.shape[0]} but the reference "
                             f"was {self.image_size[0]}x{self.image_size[1]}")
        if len(self.points) == 0:
            self._prev = gray
            self.inliers = 0
            return None
        ok, p1 = self._track(gray)
        result = None
        self.inliers = 0
        if ok.sum() >= self.min_inliers:
            M, inl = cv2.estimateAffinePartial2D(self.ref[ok], p1[ok], method=cv2.RANSAC,
                                                 ransacReprojThreshold=self.tol,
                                                 maxIters=200, confidence=0.995, refineIters=10)
            if M is not None and int(inl.sum()) >= self.min_inliers:
                keep = np.flatnonzero(ok)[inl.ravel() == 1]
                self.ref, self.points = self.ref[keep], p1[keep]
                self.inliers = int(inl.sum())
                result = (complex(M[0, 0], M[1, 0]), complex(M[0, 2], M[1, 2]))
                self.sim = result
        if result is None:
            # keep following what moved consistently; the features lost are dropped
            self.ref, self.points = self.ref[ok], p1[ok]
        self._prev = gray
        if result is not None and len(self.points) < self.max_features // 2:
            self._reseed(gray)
        return result

    def _reseed(self, gray):
        """Add features in the rigid region as the current similarity maps it, their
        reference positions inferred from that similarity."""
        a, b = self.sim
        M = np.array([[a.real, -a.imag, b.real], [a.imag, a.real, b.imag]], np.float32)
        W, H = self.image_size
        mask = cv2.warpAffine(self._region, M, (W, H), flags=cv2.INTER_NEAREST)
        for p in self.points:
            cv2.circle(mask, (int(round(p[0])), int(round(p[1]))),
                       int(np.ceil(self._min_distance)), 0, -1)
        new = self._seed(gray, mask, self.max_features - len(self.points))
        if len(new) == 0:
            return
        z = (new[:, 0] + 1j * new[:, 1] - b) / a
        ref = np.c_[z.real, z.imag].astype(np.float32)
        self.ref = np.vstack([self.ref, ref])
        self.points = np.vstack([self.points, new])
