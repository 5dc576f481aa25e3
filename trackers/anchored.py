"""Snakes placed and held by a learned landmark model.

A landmark model (:class:`~trackers.landmarks.LandmarkTracker`, MediaPipe's face mesh)
finds the face on every frame and says when it is gone; it is right to a few percent of
the inter-ocular distance on real faces, where free snakes slide onto the wrong
feature, but it is smooth and off by pixels on crisp edges, where snakes are exact.
:class:`AnchoredTracker` uses each for what it does best:

* the nine contours are placed from the landmarks on the first frame with a face
  (:func:`~trackers.landmark_contours.layout_from_landmarks`);
* on every frame each node is pulled toward its landmark curve by a spring (an
  external force of eq. 7, ``Contour.spring``) while the image potential refines it
  where the image has an edge: with the default stiffness a node sits in its ravine
  when one is there and falls back on the landmark curve where the image has nothing
  to hold it (a faint furrow, a hand over the mouth);
* the head frame is the first frame's (004: from the contours) moved by the
  similarity that carries the first frame's rigid landmarks (eye corners, nose bridge)
  onto this frame's, and the head's pitch and yaw relative to the first frame come
  from the same points in 3-D;
* a frame is lost (``None``) when the model finds no face, and a contour is lost
  when it lies farther than ``max_disagreement`` inter-ocular distances from its
  landmark curve (the snake followed something else); the lower face is lost when
  its contours sit on edges far deeper than their features' (a hand over the mouth,
  :data:`OCCLUSION_WITNESSES`, or the chin alone on far deeper ones,
  :data:`OCCLUSION_CHIN`), and stays lost while the chin does (:data:`OCCLUSION_HOLD`);
* a face larger than :data:`MAX_IOD` is tracked on the frame shrunk by a whole factor
  to that size; every result is returned in the input's pixels.
"""

from __future__ import annotations

import math
from concurrent.futures import ThreadPoolExecutor
from dataclasses import replace

import cv2
import numba
import numpy as np

from trackers.head_search import _apply_similarity
from trackers.landmark_contours import (
    RIGID_POINTS,
    eye_centres,
    interocular_distance,
    landmark_curves,
    layout_from_landmarks,
)
from trackers.layout import CONTOUR_NAMES
from trackers.polyline import resample_polyline
from trackers.potentials import to_gray
from trackers.quality import TrackResult
from trackers.torch_backend import check_backend, make_tracker
from trackers.tracking import Tracker

__all__ = ["DEFAULT_SPRINGS", "EDGE_CONTOURS", "EDGE_WAIT", "END_HOLD", "HAND_START",
           "LIPS_EDGELESS", "LOWER_FACE", "MAX_DISAGREEMENT", "MAX_IOD", "OCCLUSION_CHIN",
           "OCCLUSION_HOLD", "OCCLUSION_WITNESSES", "AnchoredTracker", "rigid_similarity",
           "rotation_angles"]

#: Spring stiffness per contour (relative to the damping ``gamma/dt`` = 0.5). Weak: on
#: rendered faces, whose edges the snakes find to a fraction of a pixel, stiffer springs
#: (0.02) doubled the fiducial error by pulling the nodes toward the mesh's smoother
#: curves, and on photographs they did not place the mouth corners better; a contour
#: that slides away is caught by ``max_disagreement`` instead. The chin boss's is twice
#: as stiff: on a real chin the boss has no outline, and at 0.005 the snake spread over
#: the jaw's (stretched 1.6 times in four frames of a still face). The lower lip's is four
#: times as stiff: where its lower border is faint (cap12, 47 px between the eyes) the
#: snake left it for the mouth line's lower flank, an edge of the same sign a few pixels
#: up, and was lost on 756 of 1337 frames as the mouth opened (2 at 0.02); on 20 people's
#: photographs its centre lies 0.053 inter-ocular distances from the hand-placed border
#: instead of 0.077 (the mesh's own point 0.049), and the rendered faces' fiducials are
#: unchanged. The hairline has no landmarks: a free snake on the first frame, then
#: carried with the head (see :meth:`AnchoredTracker.track`).
DEFAULT_SPRINGS = {"hairline": 0.0, "brow_l": 0.005, "brow_r": 0.005, "furrow_l": 0.01,
                   "furrow_r": 0.01, "nose_tip": 0.005, "upper_lip": 0.005,
                   "lower_lip": 0.02, "chin_boss": 0.01}

#: Stiffer springs on the two end nodes of these contours. The mouth line's ends are the
#: mouth corners, which the mesh places better than the end of the dark line on real
#: faces (a free end creeps inward along the line, and from one frame to the next it
#: does not follow a widening smile: on neutral-then-smile photographs the corners were
#: 0.057 inter-ocular distances off on the smile with the contour's spring, 0.036 with
#: this one). A brow's ends fade (its head into the shading beside the nose, its tail
#: into the temple), and an image changed imperceptibly can settle them elsewhere along
#: the line: cap13 turned by half a degree moved the left brow's outer end by a median
#: 3.3 px, against 0.2 px with these springs, which hold the ends near the landmarks'
#: (offset as on the first frame). On the IMM side-lit neutrals 13 of 20 then read rest
#: instead of 10; at 0.5 the inner end of the right brow moved 2.7 px instead.
END_SPRINGS = {"upper_lip": 0.5, "brow_l": 0.05, "brow_r": 0.05}

#: Hysteresis on where along their lines the brows' and furrows' ends are relocated, in
#: each contour's sigma (:class:`~trackers.tracking.Tracker`, ``end_hold``). Where a
#: brow's tail fades into the temple, relocating its end afresh on each frame cycled it
#: by 4-8 px on a still face (WolfgangLanger's first frame, repeated); held within half
#: a sigma, every brow and furrow fiducial stays within 0.05 px there. A quarter sigma
#: left cap12's right furrow top flickering by 2 px.
END_HOLD = 0.5

#: The lower face is taken as covered (every contour of :data:`LOWER_FACE` lost) when
#: each of these contours lies on edges more than this many times as deep as on the first
#: frame. Under the hand held over the mouth in ``WolfgangLanger_Pexels.mp4`` the lower
#: lip's relative depth is a median 3.2 and the chin's 31; without a hand the lower lip
#: reaches 2.7 (cap13) and 2.5 (20 people's photographs) and the chin 2.2 on those
#: photographs, never both at once (a smile deepens the furrows up to 5.8 times, so
#: they are no witnesses).
OCCLUSION_WITNESSES = {"lower_lip": 2.0, "chin_boss": 2.5}

#: The chin alone also says the lower face is covered when it lies on edges more than
#: this many times as deep as on the first frame, and a covered lower face stays covered
#: while the chin lies on edges more than :data:`OCCLUSION_HOLD` times as deep
#: (hysteresis). A hand held over the mouth leaves the lower lip on the mesh's curve or
#: on a finger's edge no deeper than its own, so the witnesses miss most of the frames
#: it covers, but the chin stays on the fingers' edges: on ``WolfgangLanger_Pexels.mp4``
#: its relative depth is a median 31 (4.9-43) under the hand. Without a hand, on the
#: three real clips, the IMM photographs and renders of a jaw drop and a laugh, it stays
#: at or below 6.5 (a hand on cap12's chin, clear of the mouth), except in three frames
#: of a bowed laugh where the lower lip's edge enters the chin's ellipse (8.7-11.9), and
#: those follow no covered frame.
OCCLUSION_CHIN = 15.0
OCCLUSION_HOLD = 8.0
LOWER_FACE = ("upper_lip", "lower_lip", "chin_boss", "furrow_l", "furrow_r")
_LIPS = ("upper_lip", "lower_lip")

#: Where the contours are placed, the lips are taken as covered (a card, a cup, a blur
#: over the mouth from the start) when both lie on edges shallower than this many times
#: the mean depth of the brows' and the nose's (:data:`_LIP_GAUGE`) there. The larger of
#: the two is at least 0.196 of it on the first frame of 150 faces (the 120 IMM
#: photographs, 24 frames of the three real clips, 6 rendered faces), against 0.001 under
#: a card the colour of the cheek and 0.082 with the mouth blurred away.
LIPS_EDGELESS = 0.12
_LIP_GAUGE = ("brow_l", "brow_r", "nose_tip")

#: A hand is looked for (:class:`~trackers.landmarks.hands.HandTracker`'s palm detector) on
#: a frame where the lower lip or the chin lies on edges more than this many times as deep
#: as on the first frame, each first frame's depth taken at least
#: :data:`HAND_GATE_FLOOR` times the upper lip's (the chin boss has no outline: its own
#: first depth is noise, 0.12-2.3 intensity units on ``WolfgangLanger_Pexels.mp4`` as
#: given, shrunk, enlarged or turned, against 13.5-17 for the upper lip). A hand found is
#: then followed by its own landmarks (:data:`HAND_EVERY`) until it leaves. On that clip
#: (hand over the mouth on frames 59-227) as given, enlarged 3 times, halved, flipped, in
#: grey and turned by 20 degrees, the cue first fires on frame 60 and on 145-162 of the 169
#: covered frames, and on 0-26 of the 303 others; on cap12 it fires on 131 of 1337 frames
#: (a hand holds the chin on about 100), on cap13 on 23 of 765.
HAND_GATE = 2.0
HAND_GATE_FLOOR = 0.2

#: A contour is covered by a hand when at least this share of its nodes lies inside a
#: hand: the convex hull of its 21 points grown by :data:`HAND_MARGIN` inter-ocular
#: distances (the points run along the fingers' middles). A hand over either lip covers
#: the whole lower face (:data:`LOWER_FACE`): fingers pressed on the mouth move its corners
#: and the furrows beside them.
HAND_COVER = 0.3
HAND_MARGIN = 0.1

#: With the hand detector, the chin alone (:data:`OCCLUSION_CHIN`) covers the lower face
#: only within this many frames of one that showed a hand. On ``WolfgangLanger_Pexels.mp4``
#: mirrored, the chin alone lost 22 frames of the laugh (its first frame's chin fainter
#: than the clip's as given); the hand's own frames lost stay as they were on the clip as
#: given, enlarged, halved, turned and mirrored. On grey frames, where the palm detector
#: finds no hand, 156 of the 169 covered frames are lost instead of 167 (and 11 of the
#: laugh's instead of 24).
HAND_MEMORY = 5

#: A followed hand's landmarks are read on every this many frames; the frames between
#: take the last ones (a hand moves a few pixels a frame; the cover's margin takes that).
#: Where the edges alone covered the lower face on the last frame (:data:`OCCLUSION_WITNESSES`,
#: :data:`OCCLUSION_HOLD`), on every :data:`HAND_EVERY_COVERED`: the hand is then only kept
#: in sight. On ``WolfgangLanger_Pexels.mp4`` (a hand over the mouth for 169 frames, as given /
#: enlarged 3 times / turned by 20 degrees / mirrored) the hand's frames lost were 168 / 158 /
#: 163 / 168 reading every frame (177 reads as given), 168 / 165 / 161 / 168 every second
#: (88), 168 / 161 / 161 / 167 with every sixth where covered (30); every third frame lost
#: two frames of the laugh too.
HAND_EVERY = 2
HAND_EVERY_COVERED = 6

#: After the palm detector found no hand, it looks again only this many frames later (the
#: edges that call for it stay deep for a while without a hand). On cap12 and cap13 it ran
#: on 12 and 11 frames instead of 27 and 24; the hand's frames lost on the clip as given,
#: enlarged and turned stayed the same.
HAND_RETRY = 3

#: The palm detector looks on each of the first this many frames since the contours were
#: placed, whatever their edges: the first frame's edges are the reference that a later
#: frame's deepening is judged against, so a hand over the face from the start does not
#: deepen them, and the detector, which needs the palm in view, can miss a hand's fingers
#: on one frame and find them on the next. The analysis takes a hand as covering the frames
#: just before the one it is found on (``faceanalysis.tracking.HAND_LEAD`` = 2), so one
#: found on the second or third frame covers the first too. ``WolfgangLanger_Pexels.mp4``
#: from frame 120 (fingers over the nose and mouth): not found on the first frame, found on
#: the second; with a look on the first frame only, it was found on the fourth, and the
#: first, under the fingers, was the analysis's neutral frame.
HAND_START = 3

#: The palm detector looks for a new hand within a square this many times the face's size
#: (its landmarks' extent) round the face, not in the whole frame: it sees the frame at 192
#: pixels, so a hand in a wide shot, a few tens of pixels across, is lost to it, while a
#: hand over the face fills a fifth of this square at any frame size.
HAND_SEARCH = 3.0

#: The face's brightness may change by this factor from where the contours were placed
#: before a frame's grey levels are evened out (``video``); only the change beyond it
#: is. The real clips' faces keep their light within it.
LIGHT_TOLERANCE = 1.1

#: The contours whose curves must lie inside the picture where the contours are placed
#: (:data:`EDGE_WAIT`): all but the chin boss (a close-up's chin is often cut off, and a
#: contour lost where it is placed takes its references where it is first seen) and the
#: hairline (carried with the head).
EDGE_CONTOURS = ("brow_l", "brow_r", "furrow_l", "furrow_r", "nose_tip", "upper_lip",
                 "lower_lip")

#: A face whose :data:`EDGE_CONTOURS` the picture cuts off where the contours would be
#: placed (one entering the picture; with ``video`` and the next frame given) has its frame
#: lost (``extra['edge']``) and the contours placed on the next one, for at most this many
#: frames: the contours take their references, and the analysis its neutral frame, from
#: the face in full. A face the picture cuts off for longer (a close-up framed tight) is
#: placed as it is. cap13's face coming in from below over 30 frames was placed with its
#: mouth below the picture, and its later frames read muscles 0.91 off those of the clip as
#: it is, from the same neutral frame (median of the largest); coming in from the right,
#: 0.49; now 0.32 and 0.12. A mouth covered where the contours would be placed
#: (:data:`LIPS_EDGELESS`) is waited for within the same count.
EDGE_WAIT = 30

#: Most that a frame's grey levels are raised or lowered by (``video``).
MAX_RELIGHT = 4.0

#: A contour whose nodes lie farther than this from their landmark curve, on average,
#: in inter-ocular distances, is lost.
MAX_DISAGREEMENT = 0.12

#: Largest inter-ocular distance (pixels) a face is tracked at. A larger face is tracked
#: on the frame shrunk by the smallest whole factor that brings it to this size or below
#: (the factor is fixed on the first frame with a face). The snakes' parameters are
#: pixel quantities set on faces of 40-100 px (rendered 65, the real clips 42-100), and
#: their image work grows faster than the face's area (blurs as wide as the features):
#: a 1920x1080 video of a face 300 px across the eyes tracked at 70 frames/s, against
#: 220 at 640x360. On the IMM photographs the mouth corners and brows are as accurate
#: with the face shrunk to 33 px as at 280 px (within 0.001 and 0.006 IOD).
MAX_IOD = 128.0

#: A face whose brightest twentieth (the 95th percentile of grey levels within its
#: landmarks' box) lies below this on the first frame with a face is tracked on frames
#: brightened to it (``uint8`` frames; by at most :data:`MAX_GAIN`; the factor is fixed
#: then). The snakes' potentials are in grey levels, and a dim face's edges are shallow:
#: WolfgangLanger at a quarter of its brightness (its face's 95th percentile 42 instead of
#: 174) read 0.11 more zygomaticus major laughing than crying instead of 0.22 and lost 124
#: of the 169 hand frames under a hand; brightened again (same pixels times four), 0.24
#: and 160. Faces as filmed and rendered lie at 113-200 (the 20 IMM people, the real clips
#: 137-174, the rendered suite 147-200): at this level nothing of theirs changes.
MIN_FACE_LEVEL = 110.0
MAX_GAIN = 4.0

_RIGID_INDEX = np.array(RIGID_POINTS, np.intp)
_END = object()


def _inside(curves: dict, size, names) -> bool:
    """Whether every point of the ``names`` curves lies inside a picture of ``size`` (w, h)."""
    w, h = size
    pts = np.vstack([curves[n] for n in names if n in curves])
    return bool(((pts >= 0) & (pts <= [w - 1, h - 1])).all())


def _skin_level(frame, points, channel_order: str) -> float:
    """The median grey level of ``frame`` under the face mesh's ``points`` (468, 2): the
    face's brightness, mostly skin (the few points in the eyes and the mouth's opening
    barely move the median)."""
    img = np.asarray(frame)
    pts = np.asarray(points, dtype=np.float64)[:, :2]
    if img.dtype == np.uint8 and img.ndim == 3 and img.shape[2] >= 3:
        # one compiled call: beside the landmarks' and the decoder's threads, a dozen small
        # NumPy calls a frame cost a tenth of a millisecond each
        blue = 2 if channel_order == "rgb" else 0
        return float(_skin_level_nb(img, np.ascontiguousarray(pts), blue))
    h, w = img.shape[:2]
    xy = np.rint(pts).astype(np.intp)
    px = img[np.clip(xy[:, 1], 0, h - 1), np.clip(xy[:, 0], 0, w - 1)].astype(np.float64)
    if px.ndim == 2:
        rgb = px[:, :3] if channel_order == "rgb" else px[:, 2::-1]
        px = rgb @ np.array([0.299, 0.587, 0.114])
    return float(np.median(px))


@numba.njit(cache=True, nogil=True)
def _skin_level_nb(img, pts, blue):
    h, w = img.shape[0], img.shape[1]
    red = 2 - blue
    grey = np.empty(pts.shape[0])
    for i in range(pts.shape[0]):
        x = min(max(int(np.rint(pts[i, 0])), 0), w - 1)
        y = min(max(int(np.rint(pts[i, 1])), 0), h - 1)
        grey[i] = (0.299 * img[y, x, red] + 0.587 * img[y, x, 1]
                   + 0.114 * img[y, x, blue])
    return np.median(grey)


def near_convex_polygon(points, polygon, margin: float) -> np.ndarray:
    """Whether each point lies inside a convex polygon or within ``margin`` of it.

    The same verdict as ``cv2.pointPolygonTest(polygon, p, True) >= -margin`` for each
    point, for all points at once.

    Parameters
    ----------
    points : array_like, shape (N, 2)
    polygon : array_like, shape (V, 2)
        The vertices of a convex polygon in order (either direction), V >= 1.
    margin : float

    Returns
    -------
    ndarray of bool, shape (N,)

    Examples
    --------
    >>> square = [[0, 0], [2, 0], [2, 2], [0, 2]]
    >>> near_convex_polygon([[1, 1], [2.5, 1], [3, 3]], square, 0.6).tolist()
    [True, True, False]
    """
    p = np.asarray(points, dtype=float).reshape(-1, 2)
    a = np.asarray(polygon, dtype=float).reshape(-1, 2)
    b = np.roll(a, -1, axis=0)
    e = b - a                                                         # (V, 2)
    rel = p[:, None, :] - a[None]                                     # (N, V, 2)
    cross = e[None, :, 0] * rel[..., 1] - e[None, :, 1] * rel[..., 0]
    # on the same side of every edge; a segment or a point has no inside
    inside = ((cross >= 0).all(axis=1) | (cross <= 0).all(axis=1)) & (len(a) > 2)
    t = np.clip((rel * e[None]).sum(axis=2) / np.maximum((e * e).sum(axis=1), 1e-300),
                0.0, 1.0)
    gap = np.hypot(*(rel - t[..., None] * e[None]).transpose(2, 0, 1)).min(axis=1)
    return inside | (gap <= margin)


def rigid_similarity(src, dst):
    """Least-squares similarity ``z -> a z + b`` (complex numbers) from ``src`` to ``dst``.

    Examples
    --------
    >>> a, b = rigid_similarity([[0, 0], [1, 0], [0, 1]], [[1, 1], [1, 3], [-1, 1]])
    >>> [round(v, 6) + 0.0 for v in (a.real, a.imag, b.real, b.imag)]
    [0.0, 2.0, 1.0, 1.0]
    """
    s = np.asarray(src, float)
    d = np.asarray(dst, float)
    zs = s[:, 0] + 1j * s[:, 1]
    zd = d[:, 0] + 1j * d[:, 1]
    ms, md = zs.mean(), zd.mean()
    den = float(np.sum(np.abs(zs - ms) ** 2))
    if den < 1e-12:
        raise ValueError("the source points coincide")
    a = complex(np.sum(np.conj(zs - ms) * (zd - md)) / den)
    return a, complex(md - a * ms)


def rotation_angles(src, dst) -> tuple[float, float]:
    """Pitch and yaw (degrees) of the rotation that best carries 3-D ``src`` onto ``dst``.

    Both point sets are centred and scaled to unit size before the rotation is fitted
    (Kabsch). Image axes: x right, y down, z away from the camera; a positive pitch
    turns the face down (chin toward the chest), a positive yaw turns it toward the
    image's right.

    Examples
    --------
    >>> pts = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, -1.0]])   # nose: z < 0
    >>> t = np.radians(10)
    >>> Ry = np.array([[np.cos(t), 0, -np.sin(t)], [0, 1, 0], [np.sin(t), 0, np.cos(t)]])
    >>> bool((pts @ Ry.T)[3, 0] > 0)          # the nose moves to the image's right
    True
    >>> [round(v, 6) + 0.0 for v in rotation_angles(pts, pts @ Ry.T)]
    [0.0, 10.0]
    """
    a = np.ascontiguousarray(src, dtype=np.float64)
    b = np.ascontiguousarray(dst, dtype=np.float64)
    if a.ndim != 2 or a.shape[1] != 3 or b.shape != a.shape:
        raise ValueError(f"src and dst must be two (n, 3) arrays, got {a.shape} and {b.shape}")
    u, _, vt = np.linalg.svd(_kabsch_covariance_nb(a, b))
    d = 1.0 if np.linalg.det(u @ vt) >= 0 else -1.0
    R = (u * (1.0, 1.0, d)) @ vt
    pitch = math.degrees(math.atan2(R[2, 1], R[2, 2]))
    # the nose (z < 0) goes to +x when the face turns toward the image's right: R[0, 2] < 0
    yaw = math.degrees(math.asin(min(max(-R[0, 2], -1.0), 1.0)))
    return pitch, yaw


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _kabsch_covariance_nb(a, b):
    # b'a of the centred point sets, each scaled to unit size: on every frame of the
    # landmark tracker, the dozen NumPy calls this takes cost more than the arithmetic.
    # The 3x3 SVD stays in NumPy: Numba's linear algebra takes seconds to compile.
    n = a.shape[0]
    ma = np.zeros(3)
    mb = np.zeros(3)
    for i in range(n):
        for k in range(3):
            ma[k] += a[i, k]
            mb[k] += b[i, k]
    sa = 0.0
    sb = 0.0
    for i in range(n):
        for k in range(3):
            sa += (a[i, k] - ma[k] / n) ** 2
            sb += (b[i, k] - mb[k] / n) ** 2
    scale = 1.0 / (max(np.sqrt(sa), 1e-12) * max(np.sqrt(sb), 1e-12))
    h = np.zeros((3, 3))
    for i in range(n):
        for j in range(3):
            bj = b[i, j] - mb[j] / n
            for k in range(3):
                h[j, k] += bj * (a[i, k] - ma[k] / n)
    return h * scale


class AnchoredTracker:
    """Track the nine contours with springs to a landmark model's curves.

    Parameters
    ----------
    landmarks : LandmarkTracker, optional
        The landmark model (default a new :class:`~trackers.landmarks.LandmarkTracker`
        with ``channel_order`` and ``runtime``).
    channel_order : {'rgb', 'bgr'}
    springs : float or dict name -> float
        Spring stiffness per contour (:data:`DEFAULT_SPRINGS`).
    max_disagreement : float
        Mean node distance from the landmark curve, in inter-ocular distances, beyond
        which a contour is lost (:data:`MAX_DISAGREEMENT`).
    head_frame : {'landmarks', 'tracker'}
        Where the head frame after the first frame comes from: the similarity of the
        rigid landmarks ('landmarks', default), or the snakes' own search (the irises,
        :class:`~trackers.tracking.Tracker`, ``head_anchor``) with the landmarks' frame
        standing in where the irises are not found ('tracker'). On rendered faces the
        mesh's rigid points move with strong expressions (a surprise reads up to 3
        degrees of pitch on a still head) and 'tracker' halved the frontalis error of a
        rendered surprise; on real video, the landmarks follow turns the irises lose.
    occlusion : bool
        Lose the lower face where its contours lie on edges far deeper than their
        features' (:data:`OCCLUSION_WITNESSES`, :data:`OCCLUSION_CHIN`): a hand over the
        mouth; it stays lost while the chin does (:data:`OCCLUSION_HOLD`). Lose it too
        where both lips are lost (their edges gone, or off their landmark curves): an
        occluder with no deep edges of its own (a card, a cup, a blur), under which the
        face mesh goes on drawing a mouth. Both lips are never lost otherwise on the
        three real clips, the 120 IMM photographs or rendered expressions. Where the
        contours are placed on lips without edges (:data:`LIPS_EDGELESS`), ``video``
        places them afresh on the next frame (for at most :data:`EDGE_WAIT` frames), so
        that their references come from the mouth itself, not its cover.
    hands : bool
        Lose the contours a hand covers (:data:`HAND_COVER`), the hands found by
        MediaPipe's palm detector where the lower face's edges deepen (:data:`HAND_GATE`)
        and followed by their landmarks (:class:`~trackers.landmarks.hands.HandTracker`).
        Each frame's hands are in ``extra['hands']``, and the contours a hand or the
        occlusion rule lost in ``extra['occluded']``.
    eyes : bool
        Trace both eyes' lids with MediaPipe's iris model (:mod:`trackers.landmarks.eyes`)
        on every frame: ``extra['eye_gaps']``, each eye's lid gap (subject's left, then
        right) over the inter-ocular distance, and ``extra['eyelids']``, their contours
        (:func:`~trackers.landmarks.eyes.eyelid_contours`). Read in a thread while the
        snakes relax (``prefetch``); about 2.5 ms a frame with LiteRT, 5 with ``cv2.dnn``.
    runtime : str
        The landmark model's runtime (see :func:`trackers.landmarks.load_network`).
    prefetch : bool
        Where :meth:`track` is told the next frame, run its landmarks in a second thread
        while this frame's snakes relax (False: one thread, as a batch of videos run
        side by side on every core wants).
    backend, device
        Where the snakes relax (:func:`~trackers.torch_backend.make_tracker`).
    max_iod : float or None
        A face whose eye centres lie farther apart than this many pixels on the first
        frame with a face is tracked on frames shrunk by a whole factor (area
        averaging) to at most this size (:data:`MAX_IOD`); None tracks every frame at
        its own size. Results are always in the input's pixels; the factor is
        :attr:`downscale`.
    video : bool
        The frames are one video in time, not photographs one by one (False). Then the
        snakes see each frame's face as bright as where the contours were placed, within
        :data:`LIGHT_TOLERANCE`: where the face's brightness (the median grey level under
        the face mesh) has changed by more than that, its grey levels are multiplied by the
        change beyond it (at most :data:`MAX_RELIGHT`). The image force, the edges' depths
        (which lose a contour, or call a hand) and the ends found scale with the grey
        levels: a light turned up, a camera's exposure, the end of a slow fade-in then move
        no contour (photographs may each be lit from elsewhere: a side light is no uniform
        change). And a face the picture cuts off where the contours would be placed waits,
        for at most :data:`EDGE_WAIT` frames, for a frame that shows it in full (a
        photograph has none to wait for).
    photographs : bool
        The frames are photographs, unrelated but for the face (needs ``video=False``):
        each is read as found, detected and its contours put on their landmark curves
        again, not from the last one's crop, contours and hands, so that a photograph
        reads the same wherever it stands among the others. (On the IMM photographs,
        neutral then smile and side-lit neutral, tracking one from the other read the same
        photograph's muscles up to 0.38 apart in the two orders.) The first still gives
        the references every later one is judged against.
    start_near : (float, float), optional
        A point (x, y, the input's pixels) on or near the face to follow where no face is
        followed yet, instead of the largest
        (:class:`~trackers.landmarks.LandmarkTracker`, ``start_near``); for the tracker made
        here.
    **tracker_options
        Passed to :class:`~trackers.tracking.Tracker` (``tol``, ``brow_mid``...).

    Notes
    -----
    :meth:`track` returns ``None`` on a frame without a face. When the face comes back
    (the model had to detect it again) every contour is placed on its landmark curve
    again; the head frame stays tied to the first frame's by the rigid landmarks, so
    measurements before and after the gap are comparable.
    """

    def __init__(self, *, landmarks=None, channel_order: str = "rgb",
                 springs=None, max_disagreement: float = MAX_DISAGREEMENT,
                 occlusion: bool = True, hands: bool = True, eyes: bool = False,
                 head_frame: str = "landmarks",
                 runtime: str = "auto", prefetch: bool = True, backend: str = "numpy",
                 device=None, max_iod: float | None = MAX_IOD, video: bool = False,
                 photographs: bool = False, start_near=None, **tracker_options):
        if channel_order not in ("rgb", "bgr"):
            raise ValueError(f"channel_order must be 'rgb' or 'bgr', got {channel_order!r}")
        if not np.isfinite(max_disagreement) or max_disagreement <= 0:
            raise ValueError(f"max_disagreement must be positive, got {max_disagreement}")
        if max_iod is not None and not (np.isfinite(max_iod) and max_iod > 0):
            raise ValueError(f"max_iod must be positive or None, got {max_iod}")
        self.max_iod = None if max_iod is None else float(max_iod)
        self.video = bool(video)
        self.photographs = bool(photographs)
        if self.video and self.photographs:
            raise ValueError("video=True and photographs=True exclude each other")
        self._ref_level = 1.0      # the face's grey level where the contours were placed
        #: Whole factor the frames are shrunk by before tracking (None until a face
        #: has been seen, then fixed; 1: the input's size).
        self.downscale: int | None = None
        #: Factor the grey levels of ``uint8`` frames are raised by before tracking
        #: (:data:`MIN_FACE_LEVEL`; None until a face has been seen, then fixed).
        self.gain: float | None = None
        self._lut: np.ndarray | None = None
        self._ahead = None     # (next frame as given, as worked on) for the prefetch
        self.occlusion = bool(occlusion)
        self.hand_tracker = None
        self._hand_pool: ThreadPoolExecutor | None = None
        self._edges_covered = False   # the last frame's edges covered the lower face
        self._hand_age = 0          # frames since a followed hand's landmarks were read
        self._since_palm = HAND_RETRY   # frames since the palm detector last found nothing
        self._since_init = 0        # frames since the contours were placed
        self._restart = False       # place them afresh on the next frame with a face
        # frames whose contours were held back for the face in full (at the picture's
        # edge, its mouth covered where they would be placed): at most EDGE_WAIT
        self._waited = 0
        self.others = 0             # faces on the last frame taken for others' (landmarks)
        if hands:
            from trackers.landmarks.hands import HandTracker

            self.hand_tracker = HandTracker(channel_order=channel_order, runtime=runtime)
        self.prefetch = bool(prefetch)
        self.eyes = bool(eyes)
        self.runtime = runtime
        self._eye_pool: ThreadPoolExecutor | None = None
        self._iris = None      # (model path, runtime) of the eyes, resolved on first use
        if head_frame not in ("landmarks", "tracker"):
            raise ValueError(f"head_frame must be 'landmarks' or 'tracker', got {head_frame!r}")
        self.head_frame = head_frame
        for key in ("redetect", "springs", "channel_order"):
            if key in tracker_options:
                raise ValueError(f"{key!r} is set by the AnchoredTracker itself")
        if landmarks is None:
            from trackers.landmarks import LandmarkTracker

            landmarks = LandmarkTracker(channel_order=channel_order, runtime=runtime,
                                        start_near=start_near)
        elif start_near is not None:
            raise ValueError("start_near is for the landmark tracker made here; give it to "
                             "the LandmarkTracker passed as landmarks")
        self.landmarks = landmarks
        self.channel_order = channel_order
        self.springs = dict(DEFAULT_SPRINGS) if springs is None else springs
        self.max_disagreement = float(max_disagreement)
        check_backend(backend, device)
        self.backend, self.device = backend, device
        # the mouth corners are the contour's ends, held by the mesh's corners moved to
        # where hand-placed corners lie (MOUTH_CORNER_OFFSET, END_SPRINGS). Snapping them
        # onto the image's corner (mouth_corner='snap', corner_reach=0.04,
        # corner_follow=0.1) keeps rendered faces' corners where the mesh drifts from an
        # opening mouth, but on photographs it moved some off: 0.036 against 0.028
        # inter-ocular distances with the offset
        # the brows relax at their layout's sigma (Tracker, brow_band): their springs
        # hold them across the band where its ravine is flat, and the wider potential
        # moved the rendered faces' fiducials by +0.02 px for nothing measured on
        # photographs
        self.tracker_options = {"mouth_corner": "ends", "end_hold": END_HOLD,
                                "brow_band": 1.0, **tracker_options}
        if head_frame == "landmarks":
            # the hairline only serves 004's head frame, which the rigid landmarks
            # replace here: re-placing it when lost would cost a second relaxation of
            # the frame (on 45 of WolfgangLanger's 472 frames) for nothing measured
            self.tracker_options.setdefault("replace_lost", tuple(
                n for n in CONTOUR_NAMES if n != "hairline"))
        self.tracker: Tracker | None = None
        self.index = 0
        self._ref_rigid: np.ndarray | None = None
        self._ref_rigid3: np.ndarray | None = None
        self._gap = False
        self._covered = False   # the last tracked frame's lower face was covered
        self._since_hand = HAND_MEMORY + 1   # tracked frames since one showed a hand
        self._offsets: dict[str, np.ndarray] = {}
        self._unreferenced: set[str] = set()
        self._carried: dict[int, np.ndarray] = {}   # frozen contours: first frame's nodes

    def track(self, frame, *, next_frame=None) -> TrackResult | None:
        """Track one frame; ``None`` when no face is found on it.

        ``next_frame``, the frame that will be tracked next where it is known, lets its
        landmarks run in a background thread while this frame's snakes relax
        (``prefetch``); the results are the same either way.
        """
        index = self.index
        self.index += 1
        if self._restart:
            self._unplace()
        elif self.photographs and self.tracker is not None:
            # photographs one by one: each is read as found (detected, its contours put
            # on their curves again), not from the last one's crop, contours and hands,
            # so that a photograph reads the same wherever it stands among the others
            reset = getattr(self.landmarks, "reset", None)
            if reset is not None:
                reset()
            self._gap = True
            self._covered = self._edges_covered = False
            if self.hand_tracker is not None:
                self.hand_tracker.hands = []
        given, frame = frame, self._working(frame)
        lm = placed = self.landmarks.track(frame)
        if lm is not None and self.downscale is None:
            # the first face sets the working size and brightness for the whole video
            self.downscale = self._factor(lm.points)
            self._set_gain(frame, lm.box)
            if self.downscale > 1 or self._lut is not None:
                # the model tracks on from this frame's points: they must be the
                # working frame's
                reset = getattr(self.landmarks, "reset", None)
                if reset is not None:
                    reset()
                near = getattr(self.landmarks, "start_near", None)
                if near is not None:
                    self.landmarks.start_near = (near + 0.5) / self.downscale - 0.5
                frame = self._working(given)
                lm = placed = self.landmarks.track(frame)
        if lm is not None and (self.tracker is None or lm.detected):
            # the later frames are compared with this one (the head's similarity, pitch
            # and yaw, the contours' offsets from their curves, the estimators' neutral),
            # and their points come from crops of the last frame's landmarks: its
            # landmarks are those tracking settles on (against the detector's box's, a
            # still real face moved by 1.3-3 px on the next frame). The contours are
            # placed from the detector's box's, which lie nearer the features on a
            # single photograph (IMM mouth corners 0.030 against 0.032 IOD).
            lm = self.landmarks.settle(frame) or lm
        if lm is not None and self.tracker is None:
            ref_rigid = lm.points[_RIGID_INDEX]
            ref_rigid3 = np.c_[ref_rigid, lm.z[_RIGID_INDEX]]
        if (next_frame is not None and self.prefetch and not self.photographs
                and hasattr(self.landmarks, "prefetch")):
            # the next frame's landmarks depend only on this frame's: they run in a
            # thread while this frame's snakes relax
            ahead = self._working(next_frame)
            self._ahead = (next_frame, ahead)
            self.landmarks.prefetch(ahead)
        following = None   # this frame's followed hands: a list, or a future of one
        if lm is not None and self.hand_tracker is not None and self.hand_tracker.hands:
            self._hand_age += 1
            # where the edges covered the lower face on the last frame, the hand only
            # has to be kept in sight
            every = HAND_EVERY_COVERED if self._edges_covered else HAND_EVERY
            if self._hand_age < every:
                following = list(self.hand_tracker.hands)
            elif self.prefetch:
                # a followed hand's points on this frame depend only on its last ones:
                # they are read in a thread while this frame's snakes relax
                if self._hand_pool is None:
                    self._hand_pool = ThreadPoolExecutor(max_workers=1,
                                                         thread_name_prefix="hands")
                following = self._hand_pool.submit(self.hand_tracker.track, frame,
                                                   detect=False)
        # faces found on this frame and taken for someone else's than the followed one
        self.others = 0 if lm is not None else int(getattr(self.landmarks, "others", 0))
        if lm is None:
            self._gap = True
            return None
        lids = None      # this frame's eyelids: a future, or read at the end
        if self.eyes and self.prefetch:
            if self._eye_pool is None:
                self._eye_pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="eyes")
            lids = self._eye_pool.submit(self._eyelids, frame, lm.points)
        eyes = eye_centres(lm.points)
        curves = landmark_curves(lm.points, eyes=eyes)
        rigid = lm.points[_RIGID_INDEX]
        rigid3 = np.c_[rigid, lm.z[_RIGID_INDEX]]
        iod = float(np.hypot(*np.subtract(*eyes)))
        edge = False      # the contours are placed on a face the picture cuts off
        if self.tracker is None:
            h, w = frame.shape[:2]
            placed_curves = landmark_curves(placed.points)
            if (self.video and next_frame is not None and self._waited < EDGE_WAIT
                    and not _inside(placed_curves, (w, h), EDGE_CONTOURS)):
                self._waited += 1
                edge = True
            layout = layout_from_landmarks(placed.points, (w, h))
            springs = self.springs
            if isinstance(springs, dict):
                springs = dict(springs)
                for name, c in layout.contours.items():
                    per_node = np.full(len(c.points), float(springs.get(name, 0.0)))
                    if name in END_SPRINGS:
                        per_node[[0, -1]] = END_SPRINGS[name]
                    springs[name] = per_node
            self.tracker = make_tracker(layout, backend=self.backend, device=self.device,
                                        channel_order=self.channel_order,
                                        springs=springs, redetect=False,
                                        **self.tracker_options)
            # no offsets learnt yet
            targets = self._node_targets(placed_curves, 1 + 0j)
            # the chin boss is held where it was placed (the mesh has no outline of it)
            targets["chin_boss"] = self.tracker.system.contour_points(
                self.tracker.names.index("chin_boss")).copy()
            res = self.tracker.track(frame, targets=targets)
            self._ref_rigid, self._ref_rigid3 = rigid, rigid3 = ref_rigid, ref_rigid3
            # offsets from the settled landmarks' curves, the ones later frames' follow
            settled = self._node_targets(curves, 1 + 0j)
            settled["chin_boss"] = targets["chin_boss"]
            self._learn_offsets(settled, res, iod)
            targets = self._node_targets(curves, 1 + 0j)
            # settle once more toward the offset targets: the first equilibrium held a
            # spring's pull toward the raw curves, which would otherwise be released
            # over the next frames as a creep
            res = self.tracker.track(frame, targets=targets, head=self.tracker.ref_head)
            self._ref_level = _skin_level(frame, lm.points, self.channel_order)
            if self.head_frame == "landmarks" and self.backend == "numpy":
                # the hairline served the first frame's head frame (004's); from here on
                # the rigid landmarks carry the head frame and nothing reads the hairline,
                # which, free, crept down the temples on real faces: it is carried with
                # the head instead of relaxed (a fifth of the nodes, a quarter of the
                # potentials' area)
                k = self.tracker.names.index("hairline")
                self.tracker.system.freeze(k)
                self._carried = {k: self.tracker.system.contour_points(k)}
            first = True
            self._since_init = 0
        else:
            first = False
            self._since_init += 1
            a, b = rigid_similarity(self._ref_rigid, rigid)
            head = _apply_similarity(self.tracker.ref_head, a, b)
            for k, ref in self._carried.items():
                z = a * (ref[:, 0] + 1j * ref[:, 1]) + b
                self.tracker.system.set_contour(k, np.c_[z.real, z.imag], reset_rest=False)
            targets = self._node_targets(curves, a)
            if self._gap:
                self._replace(targets, head)
            contrast = self._relight(frame, lm.points) if self.video else 1.0
            if self.head_frame == "landmarks":
                res = self.tracker.track(frame, targets=targets, head=head, contrast=contrast)
            else:
                res = self.tracker.track(frame, targets=targets, fallback_head=head,
                                         contrast=contrast)
        self._gap = False
        quality = dict(res.quality)
        system = self.tracker.system
        # each node's distance from its spring's target, for all contours at once
        dist = np.hypot(*(system.X - system.anchor).T)
        gaps = {}
        for name in targets:
            k = self.tracker.names.index(name)
            gaps[name] = float(np.mean(dist[system.contour_slice(k)])) / max(iod, 1e-9)
            if gaps[name] > self.max_disagreement:
                quality[name] = replace(quality[name], lost=True)
        if first:
            # a contour the first frame lost has no references yet: where it settled
            # then is not where its landmark curve holds it later (a furrow cut short at
            # its faint end, then pulled along the whole curve)
            self._unreferenced = {n for n in targets if quality[n].lost}
        else:
            agreeing = [n for n in self._unreferenced if gaps[n] <= self.max_disagreement]
            if agreeing:
                # the first frame it agrees with its curve sets them
                self.tracker.rebase_references(frame, agreeing)
                for name in agreeing:
                    quality[name] = replace(quality[name], depth=1.0, stretch=1.0, shape=0.0,
                                            lost=False)
                self._unreferenced -= set(agreeing)
        # an edge much stronger than the features' own across the lower face: a hand,
        # fingers, a microphone; the mesh goes on drawing a mouth under it. A face seen
        # smaller than on the first frame has its edges squeezed into fewer pixels, their
        # gradients steeper by up to as much: its depths count for that much less here
        shrink = min(1.0, abs(a)) if not first else 1.0
        chin = quality["chin_boss"].depth * shrink
        hands, under_hand, deepened = self._hands(frame, quality, iod, following, lm.box,
                                                  shrink)
        self._since_hand = 0 if hands else self._since_hand + 1
        # the chin alone stands for a hand only where one was seen lately (or none can
        # be: no hand detector): a chin whose first frame's edges were faint reaches 15
        # times them in a laugh
        chin_alone = chin > OCCLUSION_CHIN and (self.hand_tracker is None
                                                 or self._since_hand <= HAND_MEMORY)
        # an occluder with no edges of its own over the mouth (a card, a mask, a cup) takes
        # both lips' edges away: the mesh goes on drawing a mouth there too. Where the
        # contours are placed (``first``) the lips have no references yet: both lost there
        # is a mouth covered from the start
        if first:
            ref = self.tracker.ref_depth
            flat = (max(ref[n] for n in _LIPS)
                    < LIPS_EDGELESS * np.mean([ref[n] for n in _LIP_GAUGE]))
            lipless = flat or all(quality[n].lost for n in _LIPS)
        else:
            lipless = (all(quality[n].lost for n in _LIPS)
                       and not self._unreferenced.intersection(_LIPS))
        # their references would be taken on the cover (a flat one: every later edge
        # seems far deeper, and the lower face stays covered): placed afresh on the next
        # frame, for at most EDGE_WAIT frames (lips never found are placed as they are)
        unplaced = (self.occlusion and first and lipless and self.video
                    and next_frame is not None and self._waited < EDGE_WAIT)
        self._waited += unplaced
        covered = self.occlusion and (
            all(not quality[n].lost and quality[n].depth * shrink > d
                for n, d in OCCLUSION_WITNESSES.items())
            or chin_alone or lipless or self._covered and chin > OCCLUSION_HOLD)
        self._edges_covered = covered
        # a covered lower face stays covered while its edges stay deep, on frames where
        # the hand's landmarks or the palm detector lose the hand for a moment
        covered = covered or bool(under_hand & set(_LIPS)) or self._covered and deepened
        self._covered = covered
        occluded = set(LOWER_FACE) if covered else under_hand
        # a hand over the face on one of the first frames since the contours were placed:
        # the first frame's references (its edges' depths, the contours' offsets from
        # their curves) may lie under it, and would then hide the hand from every later
        # frame's edges; the contours are placed afresh on the next frame
        self._restart = (edge or unplaced
                         or bool(hands and occluded and self._since_init < HAND_START))
        # a face entering the picture: its features there are not yet where the contours
        # would take their references (and the analysis its neutral frame) from
        for name in quality if edge else occluded:
            quality[name] = replace(quality[name], lost=True)
        pitch, yaw = rotation_angles(self._ref_rigid3, rigid3)
        source = "landmarks" if self.head_frame == "landmarks" else res.extra["head_source"]
        extra = dict(res.extra, head_source=source, presence=float(lm.presence),
                     head_pitch=pitch, head_yaw=yaw, landmarks=lm.points, landmarks_z=lm.z,
                     detected=bool(placed.detected), hands=hands,
                     occluded=tuple(sorted(occluded)), edge=edge)
        if self.eyes:
            from trackers.landmarks.eyes import lid_gaps

            contours = lids.result() if lids is not None else self._eyelids(frame, lm.points)
            extra["eye_gaps"] = lid_gaps(contours) / max(iod, 1e-9)
            extra["eyelids"] = contours
        return self._in_input_pixels(TrackResult(index, res.contours, quality,
                                                 res.iterations, res.converged, res.head,
                                                 res.fiducials, extra))

    def _relight(self, frame, points) -> float:
        """The factor this frame's grey levels are multiplied by (``video``)."""
        ratio = self._ref_level / max(_skin_level(frame, points, self.channel_order), 1e-9)
        # only the change beyond the tolerance: a face's own light within it (a turn, a
        # smile's teeth, the encoder) is left as it was
        beyond = ratio / np.clip(ratio, 1.0 / LIGHT_TOLERANCE, LIGHT_TOLERANCE)
        return float(np.clip(beyond, 1.0 / MAX_RELIGHT, MAX_RELIGHT))

    def _unplace(self) -> None:
        """Forget the contours and what was learnt on the frame they were placed on (the
        working size, brightness and hands are kept): the next frame with a face places
        them as a first frame does, from the face detector's read of it."""
        self._restart = False
        # the same face, placed again: looked for where it was, not taken afresh from
        # the picture's faces
        reset = (getattr(self.landmarks, "redetect", None)
                 or getattr(self.landmarks, "reset", None))
        if reset is not None:
            reset()
        self.tracker = None
        self._ref_rigid = self._ref_rigid3 = None
        self._offsets, self._unreferenced, self._carried = {}, set(), {}
        self._gap = self._covered = self._edges_covered = False

    def _hands(self, frame, quality, iod: float, following=None, face=None,
               shrink: float = 1.0):
        """This frame's hands, the contours they cover (:data:`HAND_COVER`), and whether
        the lower face's edges deepened (:data:`HAND_GATE`). ``following``: the followed
        hands' points on this frame (a list: the last frame's, kept; a future: being read
        in a thread), or None (nothing followed, or to be read here); ``face``: the face's
        box (x0, y0, x1, y1), round which a new hand is looked for (:data:`HAND_SEARCH`);
        ``shrink``: the factor the edges' depths count for (a face seen smaller)."""
        if self.hand_tracker is None:
            return [], set(), False
        ref = self.tracker.ref_depth
        floor = HAND_GATE_FLOOR * ref["upper_lip"]
        deepened = any(quality[n].depth * shrink * ref[n] / max(ref[n], floor, 1e-12)
                       > HAND_GATE
                       for n in ("lower_lip", "chin_boss"))
        hands = following.result() if hasattr(following, "result") else following
        self._since_palm += 1
        look = (self._since_init < HAND_START
                or deepened and self._since_palm >= HAND_RETRY)
        if hands is None or not hands and look:
            # nothing was followed, or the followed hands were lost: the palm detector
            # looks for one where the edges call for it
            region = None
            if face is not None:
                x0, y0, x1, y1 = face
                half = 0.5 * HAND_SEARCH * max(x1 - x0, y1 - y0)
                cx, cy = 0.5 * (x0 + x1), 0.5 * (y0 + y1)
                h, w = np.shape(frame)[:2]
                if cx + half > 1 and cy + half > 1 and cx - half < w - 2 and cy - half < h - 2:
                    region = (cx - half, cy - half, cx + half, cy + half)
            hands = self.hand_tracker.track(frame, detect=look, region=region)
            if look and not hands:
                self._since_palm = 0
        if not isinstance(following, list):     # read on this frame
            self._hand_age = 0
        under = set()
        if hands:
            system = self.tracker.system
            hulls = [cv2.convexHull(h.astype(np.float32))[:, 0].astype(float) for h in hands]
            margin = HAND_MARGIN * iod
            # all nodes at once, then each contour's share
            inside = np.zeros(system.n_nodes, bool)
            for hull in hulls:
                inside |= near_convex_polygon(system.X, hull, margin)
            share = np.add.reduceat(inside, system.starts[:-1]) / np.diff(system.starts)
            under = {name for name, f in zip(self.tracker.names, share) if f >= HAND_COVER}
        return hands, under, deepened

    def _factor(self, points) -> int:
        """The whole factor that brings the face of ``points`` to ``max_iod`` or below."""
        if self.max_iod is None:
            return 1
        iod = interocular_distance(points)
        return max(1, math.ceil(iod / self.max_iod))

    def _set_gain(self, frame, box) -> None:
        """Fix :attr:`gain` from the face in ``box`` (x0, y0, x1, y1) on ``frame``."""
        self.gain, self._lut = 1.0, None
        img = np.asarray(frame)
        if img.dtype != np.uint8:
            return
        h, w = img.shape[:2]
        x0, y0 = max(0, int(box[0])), max(0, int(box[1]))
        x1, y1 = min(w, int(np.ceil(box[2]))), min(h, int(np.ceil(box[3])))
        if x1 - x0 < 3 or y1 - y0 < 3:
            return
        level = float(np.percentile(to_gray(img[y0:y1, x0:x1],
                                            channel_order=self.channel_order), 95))
        if level < MIN_FACE_LEVEL:
            self.gain = min(MAX_GAIN, MIN_FACE_LEVEL / max(level, 1.0))
            self._lut = np.clip(np.round(np.arange(256) * self.gain), 0, 255).astype(np.uint8)

    def _working(self, frame):
        """``frame`` at the working size and brightness (the same array where neither
        changes it)."""
        k = self.downscale
        lut = self._lut
        if (k is None or k == 1) and lut is None:
            return frame
        if self._ahead is not None and self._ahead[0] is frame:
            return self._ahead[1]
        img = np.asarray(frame)
        if img.dtype == bool:
            img = img.astype(np.uint8) * 255
        if k is not None and k > 1:
            h, w = img.shape[:2]
            if h < 3 * k or w < 3 * k:
                raise ValueError(f"frame {self.index - 1}: {w}x{h} pixels is smaller than "
                                 f"the first face's frames, shrunk by {k}")
            # a whole factor: each working pixel is the mean of k x k input pixels (the
            # last rows and columns that do not fill a block are left out), so that the
            # input pixel of a working position is (x + 0.5) k - 0.5 exactly
            img = cv2.resize(img[: h // k * k, : w // k * k], (w // k, h // k),
                             interpolation=cv2.INTER_AREA)
        if lut is not None and img.dtype == np.uint8:
            img = cv2.LUT(img, lut)
        return img

    def _in_input_pixels(self, result: TrackResult) -> TrackResult:
        """``result``, tracked on shrunk frames, in the input's pixels."""
        k = self.downscale
        if k is None or k == 1:
            return result

        def up(p):
            return (np.asarray(p, float) + 0.5) * k - 0.5

        head = replace(result.head, x=float(up(result.head.x)), y=float(up(result.head.y)),
                       scale=result.head.scale * k)
        extra = dict(result.extra)
        extra["landmarks"] = up(extra["landmarks"])
        extra["hands"] = [up(h) for h in extra.get("hands", [])]
        if "eyelids" in extra:
            extra["eyelids"] = up(extra["eyelids"])
        extra["landmarks_z"] = np.asarray(extra["landmarks_z"], float) * k
        return replace(result, contours={n: up(c) for n, c in result.contours.items()},
                       fiducials={n: tuple(float(v) for v in up(f))
                                  for n, f in result.fiducials.items()},
                       head=head, extra=extra)

    def _node_targets(self, curves, a):
        """The landmark curves at the contours' node counts, each node moved by its
        offset from the first frame (turned and scaled by ``a``, the similarity since)."""
        t = self.tracker
        out = {}
        for k, name in enumerate(t.names):
            curve = curves.get(name)
            if curve is None:
                continue
            sl = t.system.contour_slice(k)
            pts = resample_polyline(curve, sl.stop - sl.start,
                                    closed=t.layout.contours[name].closed)
            off = self._offsets.get(name)
            if off is not None:
                pts = pts + (a * off).view(np.float64).reshape(-1, 2)   # (real, imag) rows
            out[name] = pts
        return out

    def _learn_offsets(self, targets, res, iod):
        """Where the first frame's snakes settled relative to their landmark curves.

        The mesh's curves and the image's features differ by a steady, per-face amount
        (the mesh's brow line lies below the centre of a thick brow, its chin is a guess,
        its mouth line is smoother than the lips' meeting line); from here on the
        springs pull toward each curve moved by that amount, so that they resist the
        snakes' motion relative to the landmarks, not the snakes' precision. A contour
        lost on the first frame, or farther than ``max_disagreement`` from its curve,
        keeps no offset.
        """
        self._offsets = {}
        for name, pts in targets.items():
            q = res.quality[name]
            k = self.tracker.names.index(name)
            d = self.tracker.system.contour_points(k) - pts
            if q.lost or np.mean(np.hypot(*d.T)) > self.max_disagreement * iod:
                continue
            self._offsets[name] = d[:, 0] + 1j * d[:, 1]

    def _replace(self, targets, head):
        """Put every contour on its landmark curve again (the face came back)."""
        t = self.tracker
        placed = t._set_targets(targets)
        t._held_ends.clear()
        for k, name in enumerate(t.names):
            if t.system.frozen[k]:
                continue                      # carried with the head, not placed
            pts = placed.get(name)
            if pts is None:
                pts = t._layout_points(k, head)
            t.system.set_contour(k, pts, reset_rest=True)

    def run(self, frames):
        """Generator of :meth:`track` results for an iterable of frames."""
        it = iter(frames)
        frame = next(it, _END)
        try:
            while frame is not _END:
                nxt = next(it, _END)
                yield self.track(frame, next_frame=None if nxt is _END else nxt)
                frame = nxt
        finally:
            self.close()

    def _eyelids(self, frame, points) -> np.ndarray:
        """Both eyes' lid contours on ``frame``
        (:func:`trackers.landmarks.eyes.eyelid_contours`)."""
        from trackers.landmarks._image import check_image
        from trackers.landmarks.eyes import _run
        from trackers.landmarks.models import ensure_models
        from trackers.landmarks.runtime import check_runtime, load_network

        if self._iris is None:
            # resolved once: the model files' checks and 'auto''s search for LiteRT cost
            # file-system calls, which a frame need not repeat
            self._iris = (str(ensure_models()["iris_landmark"]), check_runtime(self.runtime))
        net = load_network(self._iris[0], runtime=self._iris[1])
        return _run(net, check_image(frame, self.channel_order), points, self.channel_order)

    def close(self) -> None:
        """Stop the landmark model's prefetch thread and the hands' and eyes' threads, if
        started."""
        close = getattr(self.landmarks, "close", None)
        if close is not None:
            close()
        if self._eye_pool is not None:
            self._eye_pool.shutdown()
            self._eye_pool = None
        if self._hand_pool is not None:
            self._hand_pool.shutdown()
            self._hand_pool = None
