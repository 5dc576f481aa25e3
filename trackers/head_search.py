"""Where the tracker's head frame comes from on each frame.

The first frame's head frame is that of the contours (004). Afterwards the
:class:`~trackers.tracking.Tracker` moves it with the irises
(:class:`~trackers.anchors.IrisAnchors`), or where they are not found with corner
features on the eyes and nose (:class:`~trackers.head_motion.FeatureAnchors`), or
failing both with the contours' own motion since the last frame either gave, with
checks that each candidate agrees with the contours and with the last frame.
:class:`HeadFrameSearch` holds the tracker's methods for this, apart from the
contours' relaxation, so that the whole choice of the head frame reads in one place.
"""

from __future__ import annotations

import numpy as np

from trackers.anchors import IrisAnchors
from trackers.fiducials import HeadFrame, centroid, head_frame
from trackers.head_motion import FeatureAnchors, gray_u8

__all__ = ["IRIS_RETRY_EVERY", "HeadFrameSearch"]

#: While the features give the head frame, the irises are searched for on every
#: this many frames only.
IRIS_RETRY_EVERY = 4


def _similarity_between(h0: HeadFrame, h1: HeadFrame):
    """Similarity (complex a, b: z -> a z + b) carrying head frame ``h0`` onto ``h1``."""
    a = (h1.scale / h0.scale) * np.exp(1j * (h1.roll - h0.roll))
    return complex(a), complex((h1.x + 1j * h1.y) - a * (h0.x + 1j * h0.y))


def _brow_angle(system, names):
    """Image angle of the line from the right to the left eyebrow's centroid."""
    cl = centroid(system.contour_points(names.index("brow_l")))
    cr = centroid(system.contour_points(names.index("brow_r")))
    return float(np.arctan2(cl[1] - cr[1], cl[0] - cr[0]))


def _apply_similarity(h: HeadFrame, a, b) -> HeadFrame:
    """Head frame ``h`` moved by the similarity z -> a z + b."""
    z = a * (h.x + 1j * h.y) + b
    return HeadFrame(float(z.real), float(z.imag), float(h.scale * abs(a)),
                     float(h.roll + np.angle(a)))


class _ContourHead:
    """The contours' head frame at the nodes' current positions, computed only when
    asked for: where the irises or the features give the frame it is kept only in
    case a later frame has to fall back on the contours' motion (0.2 ms a frame)."""

    __slots__ = ("_X", "_starts", "_names", "_value", "_done")

    def __init__(self, system, names):
        self._X = system.X.copy()
        self._starts, self._names = system.starts, names
        self._done = False
        self._value = None

    @property
    def value(self) -> HeadFrame | None:
        if not self._done:
            self._value = _contours_head(self._X, self._starts, self._names)
            self._done = True
            self._X = None
        return self._value


def _contours_head(X, starts, names) -> HeadFrame | None:
    """:func:`~trackers.fiducials.head_frame` of the contours whose nodes are ``X``, or
    None where it cannot be computed."""
    try:
        return head_frame({n: X[starts[k]:starts[k + 1]] for k, n in enumerate(names)})
    except ValueError:
        return None


class HeadFrameSearch:
    """The head-frame search of :class:`~trackers.tracking.Tracker` (a mixin).

    Where each frame's head frame comes from (``head_anchor`` in the tracker's
    docstring): the irises, the corner features on the eyes and nose, or the contours'
    motion chained on from the last frame either gave. The state these methods read
    and write (``anchors``, ``features``, ``last_head``, ``ref_head``...) is set up by
    ``Tracker.__init__``.
    """

    def _head(self, frame, first=False):
        """Head frame of this frame (see the class docstring, ``head_anchor``)."""
        hc = _ContourHead(self.system, self.names)
        if first:
            self.head_source = "contours"
            if self.head_anchor in ("auto", "eyes") and self.layout.eyes is not None:
                try:
                    self.anchors = IrisAnchors(frame, self.layout.eyes,
                                               channel_order=self.channel_order)
                except ValueError:
                    if self.head_anchor == "eyes":
                        raise
                    self.anchors = None
            if hc.value is not None:
                self._anchor_base = (hc, hc.value)
            self._ref_brow_angle = _brow_angle(self.system, self.names)
            self._keep_gray(frame)
            return hc.value if hc.value is not None else self.last_head
        # the irises first; while the features stand in for them, searched for only
        # every few frames (a search that fails costs as much as the features)
        if self.anchors is not None and self.ref_head is not None and (
                self.features is None or self.index % IRIS_RETRY_EVERY == 0):
            head = self._iris_head(frame, hc)
            if head is not None:
                self.head_source = "eyes"
                self._anchor_base = (hc, head)
                self.features = None  # seeded again from here when the irises go
                self._keep_gray(frame)
                return head
        fallback = self._fallback_head
        if fallback is not None:
            # where the irises are not found, a head frame known from elsewhere (rigid
            # landmarks) stands in for the features and the contours
            self.head_source = "landmarks"
            self._anchor_base = (hc, fallback)
            if self.anchors is not None:
                self._move_iris_search(fallback)
            return fallback
        head = self._feature_head(frame)
        if head is not None:
            self.head_source = "features"
            self._anchor_base = (hc, head)
            if self.anchors is not None:
                self._move_iris_search(head)
            return head
        fallback = self._chained(hc)
        if fallback is not None and self.anchors is not None:
            self._move_iris_search(fallback)
        self.head_source = "contours"
        self._keep_gray(frame)
        return fallback

    def _keep_gray(self, frame):
        """Keep this frame's 8-bit grey while the features may be seeded on it."""
        if self._features_wanted():
            self._last_gray = gray_u8(frame, self.channel_order)
            self._last_gray_index = self.index

    def _features_wanted(self):
        return self.head_anchor != "contours" and self.layout.eyes is not None

    def _move_iris_search(self, head):
        """Search the irises next where ``head`` puts them."""
        self.anchors.last = head.to_image(self.ref_head.to_head(self.anchors.centres))

    def _iris_head(self, frame, hc):
        """Head frame from the irises, or None (not found, or implausible)."""
        # search around the irises last found (a wider window after a miss)
        wide = self.head_source != "eyes"
        if self._sim_cache is not None and self._sim_cache[0] == self.index:
            sim = self._sim_cache[1]  # the irises do not depend on the contours
        else:
            sim = self.anchors.similarity(
                frame, None, search=3.0 * self.anchors.radius if wide else None)
            self._sim_cache = (self.index, sim)
        if sim is not None and self._ref_brow_angle is not None and not self._brows_lost:
            # the brow line's turn, unless it disagrees with the irises' (a brow
            # contour that slid away)
            rot = _brow_angle(self.system, self.names) - self._ref_brow_angle
            rot = (rot + np.pi) % (2 * np.pi) - np.pi
            if abs(rot - np.angle(sim[0])) < 0.05:
                sim = self.anchors.similarity_with_rotation(sim, rot)
        if sim is None:
            return None
        head = _apply_similarity(self.ref_head, *sim)
        return head if self._plausible(head, hc) else None

    def _feature_head(self, frame):
        """Head frame from the features on the eyes and nose (:class:`~trackers.
        head_motion.FeatureAnchors`), seeded on the last frame whose head frame came
        from elsewhere; None when they do not agree or the frame jumps."""
        if not self._features_wanted() or self.last_head is None or self.ref_head is None:
            return None
        if self._feature_cache[0] == self.index:
            return self._feature_cache[1]  # asked again after contours were re-placed
        head = self._follow_features(frame)
        self._feature_cache = (self.index, head)
        return head

    def _follow_features(self, frame):
        if self.features is None or self._feature_index != self.index - 1:
            if self._last_gray is None or self._last_gray_index != self.index - 1:
                return None
            eyes = self.last_head.to_image(self.ref_head.to_head(self.layout.eyes))
            try:
                self.features = FeatureAnchors(self._last_gray, eyes)
            except ValueError:
                self.features = None
                return None
            self._feature_base = self.last_head
        self._feature_index = self.index
        self._last_gray = None
        sim = self.features.similarity(gray_u8(frame, self.channel_order))
        if sim is None:
            self.features = None
            return None
        head = _apply_similarity(self._feature_base, *sim)
        if not self._plausible(head, None):
            self.features = None
            return None
        return head

    def _plausible(self, head, hc):
        """Whether a head frame from the irises agrees with the contours' frame (``hc``,
        a :class:`_ContourHead`, or None to skip that check: scale, roll) and with the
        last frame (a drifted iris match jumps)."""
        def turn(a, b):
            return abs((a - b + np.pi) % (2 * np.pi) - np.pi)

        hc = hc.value if hc is not None and not self._head_contours_lost else None
        if hc is not None and (
                abs(head.scale / hc.scale - 1) > 0.12 or turn(head.roll, hc.roll) > 0.1):
            # expressions change the contours' scale by a few per cent, no more
            return False
        last = self.last_head
        if last is not None:
            tight = self.head_source == "eyes"
            ds, dp, dr = (0.04, 0.1, 0.05) if tight else (0.1, 0.2, 0.1)
            if (abs(head.scale / last.scale - 1) > ds or turn(head.roll, last.roll) > dr
                    or np.hypot(head.x - last.x, head.y - last.y) > dp * last.scale):
                return False
        return True

    def _chained(self, lazy):
        """Fallback frame: the contours' motion (``lazy``, this frame's
        :class:`_ContourHead`) since the last frame the irises or features gave."""
        hc = lazy.value
        if hc is None or self._head_contours_lost:
            # the frame's own contours are unreliable: hold the last frame
            return self.last_head if self.last_head is not None else hc
        hc0 = self._anchor_base[0].value if self._anchor_base is not None else None
        if hc0 is None:
            return hc
        # the contours' motion since the last frame whose frame the irises gave
        h0 = self._anchor_base[1]
        a, b = _similarity_between(hc0, hc)
        moved = _apply_similarity(h0, a, b)
        # a contour frame that jumped (a hairline contour on a hand, the nose contour
        # on a nostril's edge) is not followed: the last frame is held instead
        if abs(abs(a) - 1) > 0.08 or abs(np.angle(a)) > 0.1 \
                or np.hypot(moved.x - h0.x, moved.y - h0.y) > 0.25 * h0.scale:
            self._held += 1
            if self._held <= 5 and self.last_head is not None:
                return self.last_head
            # the contours have settled elsewhere for good: start over from them
            self._anchor_base = (lazy, hc)
            self._held = 0
            return hc
        self._held = 0
        return moved
