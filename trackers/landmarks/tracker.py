"""Frame-to-frame landmark tracking: detect once, then crop each frame from the last landmarks."""

from __future__ import annotations

import contextlib
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import cv2
import numpy as np

from trackers.landmarks._image import check_image
from trackers.landmarks.detection import FaceDetection
from trackers.landmarks.detection import _run as _detect
from trackers.landmarks.mesh import _SIZE, roi_transform
from trackers.landmarks.mesh import _run as _mesh
from trackers.landmarks.models import ensure_models
from trackers.landmarks.runtime import check_runtime, load_network

__all__ = ["RECROP", "FAR_SIZE", "REACQUIRE", "TILE_EVERY", "UPSIDE_DOWN_MARGIN", "Landmarks",
           "LandmarkTracker"]

#: Crop change (pixels of the 192-pixel crop) beyond which a tracking frame is read again
#: from the crop its own landmarks call for (:class:`LandmarkTracker`, ``recrop``). On
#: real clips 5-9 % of frames exceed it (cap13, WolfgangLanger).
RECROP = 4.0

# frames a lost face's position is remembered, so that a face returning after a short
# occlusion is preferred over a bystander (in a picture that has shown several faces, for
# as long as it is lost)
_MEMORY = 30

#: In a picture that has shown several faces at once, a face found farther than this many
#: times the lost face's size (its landmarks' extent) from where the followed face was
#: last seen is someone else's, not the face come back (:attr:`LandmarkTracker.others`):
#: a subject who turns away or leaves the picture is not replaced by the interviewer
#: beside them. (A face alone in the picture is taken wherever it comes back.)
REACQUIRE = 1.5

#: While a lost face is remembered, a face that only the full-range detector finds and that
#: is smaller than this share of it (its box's longer side against the lost face's
#: landmarks' extent) is taken for someone else, far behind, not the face come back.
FAR_SIZE = 0.5

# the crop's corners, homogeneous crop pixels
_CROP_CORNERS = np.array([[0, _SIZE - 1, 0, _SIZE - 1], [0, 0, _SIZE - 1, _SIZE - 1],
                          [1, 1, 1, 1]], float)


#: A face the full-range detector found is looked at again by the short-range one on a
#: square this many times its box round it, where it is large enough for that detector:
#: the full-range model's box and keypoints of a small face are coarse, and a face mesh
#: started from them can settle on a wrong fit (WolfgangLanger at 26 px between the eyes:
#: 43 px and presence 0.55 from the full-range box, 25.4 px and 1.0 from the second look).
CLOSER_LOOK = 4.0


#: With ``tiles``, the tiled search runs on every this many frames while no face is found
#: (18 tiles of a 16:9 frame: some 50 ms with OpenCV's reader), not on every one.
TILE_EVERY = 5


def _tiled(net, image, channel_order: str, min_score: float) -> list:
    """The faces the short-range detector ``net`` finds on square tiles of half the frame's
    shorter side, overlapping by half, in the frame's pixels."""
    h, w = image.shape[:2]
    side = min(h, w) // 2
    if side < 64:
        return []
    step = side // 2

    def starts(length):
        out = list(range(0, length - side + 1, step))
        return out if out[-1] + side >= length else [*out, length - side]

    return [f for y in starts(h) for x in starts(w)
            for f in _detect(net, image, channel_order, min_score,
                             region=(x, y, x + side, y + side))]


def _closer_look(net, image, face, channel_order: str, min_score: float):
    """``face`` (found far) as the short-range detector ``net`` sees it on a crop round it
    (:data:`CLOSER_LOOK`), in the image's pixels; ``face`` itself where that finds none."""
    x0, y0, x1, y1 = face.box
    half = 0.5 * CLOSER_LOOK * max(x1 - x0, y1 - y0)
    cx, cy = 0.5 * (x0 + x1), 0.5 * (y0 + y1)
    try:
        seen = _detect(net, image, channel_order, min_score,
                       region=(cx - half, cy - half, cx + half, cy + half))
    except ValueError:        # the square misses the image
        return face
    if not seen:
        return face
    centres = np.array([[(f.box[0] + f.box[2]) / 2, (f.box[1] + f.box[3]) / 2] for f in seen])
    return seen[int(np.argmin(np.hypot(*(centres - [cx, cy]).T)))]


#: A face the short-range detector finds is looked at upside down too, and taken so when
#: it scores at least this much higher that way. The detector places its keypoints as on an
#: upright face, so on a face upside down in the picture (a camera mounted so, a subject
#: lying down) the eyes come out swapped, and the face mesh, read from a crop turned the
#: wrong way, still fits a face with full confidence: the contours then land on the wrong
#: features. The detector's own score tells: on 30 frames of the real clips and the 120
#: IMM photographs, the upright picture scored higher than the turned one in every case, by
#: 0.065-0.43 (median 0.21).
UPSIDE_DOWN_MARGIN = 0.03

#: A face's turned detection is the one whose centre lies within this share of the face's
#: box size from the face's own centre.
_SAME_FACE = 0.5


def _upright(net, image, face, channel_order: str, min_score: float):
    """``face`` and its detection in ``image`` turned by 180 degrees (mapped back; None where
    that finds none there), the likelier first: the turned one where it scores
    :data:`UPSIDE_DOWN_MARGIN` higher (the face is upside down)."""
    h, w = image.shape[:2]
    far_corner = np.array([w - 1, h - 1], float)
    x0, y0, x1, y1 = face.box
    centre, size = np.array([x0 + x1, y0 + y1]) / 2, max(x1 - x0, y1 - y0)
    for other in _detect(net, cv2.rotate(image, cv2.ROTATE_180), channel_order, min_score):
        u0, v0, u1, v1 = other.box
        box = (far_corner[0] - u1, far_corner[1] - v1, far_corner[0] - u0, far_corner[1] - v0)
        if np.hypot(*(np.array([box[0] + box[2], box[1] + box[3]]) / 2 - centre)) \
                <= _SAME_FACE * size:
            turned = FaceDetection(tuple(float(v) for v in box), far_corner - other.keypoints,
                                   other.score)
            if turned.score >= face.score + UPSIDE_DOWN_MARGIN:
                return turned, face
            return face, turned
    return face, None


def check_point(point, name: str) -> np.ndarray | None:
    """``point`` as a (2,) float array, or None; ValueError unless two finite numbers."""
    if point is None:
        return None
    try:
        out = np.asarray(point, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        out = np.array([])
    if out.shape != (2,) or not np.isfinite(out).all():
        raise ValueError(f"{name} must be a point (x, y) of two finite numbers, got {point!r}")
    return out


def _crop_change(a, b) -> float:
    """How far the crop from landmarks ``b`` lies from the crop from ``a``: the largest
    move of a crop corner, in pixels of the 192-pixel crop."""
    ma, mb = roi_transform(a), roi_transform(b)
    return float(np.hypot(*(ma @ _CROP_CORNERS - mb @ _CROP_CORNERS)).max()
                 / np.hypot(*mb[:, 0]))


@dataclass(frozen=True, eq=False)
class Landmarks:
    """The 468 landmarks of one frame.

    Attributes
    ----------
    points : ndarray, shape (468, 2)
        x, y in image pixels (pixel centres on integers).
    z : ndarray, shape (468,)
        Relative depth in the same pixel scale (smaller is nearer the camera).
    presence : float
        Probability that the landmarks lie on a face: the confidence.
    box : tuple of float
        (x0, y0, x1, y1) bounding box of ``points``.
    detected : bool
        The face detector ran on this frame (first frame, or the track was lost).
    """

    points: np.ndarray
    z: np.ndarray
    presence: float
    box: tuple[float, float, float, float]
    detected: bool


class LandmarkTracker:
    """Follow one face through a video with MediaPipe's face detector and 468-point mesh.

    Parameters
    ----------
    channel_order : {'rgb', 'bgr'}
        Channel order of colour frames (OpenCV frames are 'bgr').
    runtime : {'auto', 'litert', 'opencv'}
        See :func:`trackers.landmarks.runtime.load_network`.
    min_presence : float
        Landmarks whose face presence is lower are lost, in (0, 1).
    min_score : float
        Lowest detection score, in (0, 1).
    refine_first : bool
        After a detection, run the landmark model again on the crop from its own landmarks
        (a tighter, better aligned crop than the detector's; lowers the error of that frame).
    recrop : float
        On a tracking frame whose landmarks call for a crop whose corners lie more than
        this many crop pixels (of 192) from the last frame's, run the model again on
        that crop: a face that moved or changed much between frames is read from a crop
        that fits it (``inf``: never).
    full_range : bool, optional
        Where the short-range detector (the face mesh's own) finds no face, look again with
        the full-range one (:func:`~trackers.landmarks.detection.detect_faces`,
        ``model='full'``), which finds faces down to about 2 % of the frame's width (a
        person across a room in a wide shot) where the short one stops at about a tenth.
        Default: where the runtime can run it (LiteRT).
    tiles : bool, optional
        Where neither detector finds a face, look with the short-range one on half-size
        square tiles of the frame (overlapping by half; :data:`TILE_EVERY`), which shows it
        a far face at twice the scale: for OpenCV's reader, which cannot run the full-range
        detector. Default: where ``full_range`` is off.
    start_near : (float, float), optional
        A point (x, y, pixels) on or near the face to follow: where no face is followed yet
        (the start, or a face lost for long), the face whose box centre lies nearest it is
        taken instead of the largest (a subject beside a larger face: an interviewer, a
        face on a screen behind).

    Attributes
    ----------
    others : int
        Faces found on the last frame tracked and taken for someone else's: once the
        picture has shown several faces at once, a lost face is looked for where it was
        last seen, for as long as it is lost, and a face farther than :data:`REACQUIRE`
        times its size from there is not taken for it (:meth:`track` returns None).

    Notes
    -----
    :meth:`prefetch` starts the next frame's landmarks in a background thread: the
    network runs without Python's global lock, so a caller that has other work for the
    current frame (the snakes of :class:`~trackers.AnchoredTracker`) overlaps the two.
    Results are those of calling :meth:`track` on the frames in order.

    Examples
    --------
    >>> tracker = LandmarkTracker(channel_order="bgr")   # doctest: +SKIP
    >>> for frame in frames:                               # doctest: +SKIP
    ...     lm = tracker.track(frame)                      # None: no face in this frame
    """

    def __init__(self, *, channel_order: str = "rgb", runtime: str = "auto",
                 min_presence: float = 0.5, min_score: float = 0.5, refine_first: bool = True,
                 recrop: float = RECROP, full_range: bool | None = None,
                 tiles: bool | None = None, start_near=None):
        check_image(np.zeros((2, 2), np.uint8), channel_order)
        # resolved once: 'auto' looks for LiteRT on the import path, which costs
        # file-system calls (and, with decoding in another thread, the GIL) every frame
        self._runtime = check_runtime(runtime)
        self._models = None    # model paths, checked on the first frame
        for name, value in (("min_presence", min_presence), ("min_score", min_score)):
            if not 0 < value < 1:
                raise ValueError(f"{name}={value!r} must lie in (0, 1)")
        self.channel_order, self.runtime = channel_order, runtime
        self.min_presence, self.min_score = float(min_presence), float(min_score)
        self.refine_first = bool(refine_first)
        if not recrop > 0:
            raise ValueError(f"recrop={recrop!r} must be positive (inf: never)")
        self.recrop = float(recrop)
        if full_range and self._runtime != "litert":
            raise ValueError("full_range=True needs the LiteRT runtime (OpenCV's TFLite "
                             "reader lacks the full-range detector's DENSIFY operator)")
        self.full_range = self._runtime == "litert" if full_range is None else bool(full_range)
        self.tiles = not self.full_range if tiles is None else bool(tiles)
        self.start_near = check_point(start_near, "start_near")
        self._executor: ThreadPoolExecutor | None = None
        self._pending = None       # (frame, future, state before it) of a prefetch
        self._crowd = False        # several faces were found at once on some frame
        self.reset()

    def redetect(self) -> None:
        """Start the next frame with a detection, of the face followed so far: the face
        found nearest where it was last seen (:data:`REACQUIRE`), as after a loss."""
        self._discard()
        self._previous = None      # (468, 3) landmarks of the last frame, while tracking
        self.others = 0            # faces found on the last frame but taken for others

    def reset(self) -> None:
        """Forget the face: the next frame starts with a detection."""
        self.redetect()
        self._last_centre = None   # where the face was last seen
        self._last_size = None     # and its landmarks' extent (pixels)
        self._lost = 0             # frames since then

    def prefetch(self, frame) -> None:
        """Start tracking ``frame`` in a background thread.

        The next :meth:`track` of this same array object returns the result; any other
        call first waits for it and undoes it, so results never depend on whether a
        prefetch was made. The frame is read in the thread: leave it unchanged until it
        is tracked. Call :meth:`close` (or use the tracker as a context manager) to stop
        the thread.
        """
        self._discard()
        if self._executor is None:
            self._executor = ThreadPoolExecutor(max_workers=1,
                                                thread_name_prefix="landmarks")
        # before the thread moves it
        state = self._previous, self._last_centre, self._last_size, self._lost, self._crowd
        self._pending = (frame, self._executor.submit(self._track, frame), state)

    def close(self) -> None:
        """Stop the prefetch thread (a later :meth:`prefetch` starts a new one)."""
        self._discard()
        if self._executor is not None:
            self._executor.shutdown()
            self._executor = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def _discard(self) -> None:
        """Wait for a pending prefetch and restore the state from before it."""
        pending, self._pending = self._pending, None
        if pending is not None:
            _, future, state = pending
            # its frame is not tracked: an error there is not this caller's
            with contextlib.suppress(Exception):
                future.result()
            (self._previous, self._last_centre, self._last_size, self._lost,
             self._crowd) = state

    def _net(self, name):
        # the networks are cached per thread by load_network; the files are checked (and
        # installed if missing) once per tracker, not on every frame
        if self._models is None:
            self._models = ensure_models()
        return load_network(self._models[name], runtime=self._runtime)

    def _landmarks(self, image, roi):
        return _mesh(self._net("face_landmark"), image, roi, self.channel_order)

    def _detect(self, image):
        near = self._net("face_detection")
        faces = _detect(near, image, self.channel_order, self.min_score)
        far = not faces and self.full_range
        tiled = not faces and not far and self.tiles and self._lost % TILE_EVERY == 0
        if far:
            faces = _detect(self._net("face_detection_full_range"), image, self.channel_order,
                            self.min_score, full=True)
        elif tiled:
            faces = _tiled(near, image, self.channel_order, self.min_score)
        if (far or tiled) and self._last_size is not None:
            # a face far smaller than the one just lost is someone else's
            faces = [f for f in faces if max(f.box[2] - f.box[0], f.box[3] - f.box[1])
                     >= FAR_SIZE * self._last_size]
        self._crowd = self._crowd or len(faces) > 1
        refused = 0
        if faces and self._last_centre is not None and self._crowd:
            # in a picture that has shown several faces, a face far from where the
            # followed one was last seen is someone else's
            centres = np.array([f.box for f in faces], float).reshape(-1, 2, 2).mean(axis=1)
            close = (np.hypot(*(centres - self._last_centre).T)
                     <= REACQUIRE * self._last_size)
            refused = int(np.count_nonzero(~close))
            faces = [f for f, k in zip(faces, close) if k]
        if not faces:
            return None, 0.0, refused
        boxes = np.array([f.box for f in faces])
        target = self._last_centre if self._last_centre is not None else self.start_near
        if target is not None:
            dist = np.hypot(*((boxes[:, :2] + boxes[:, 2:]) / 2 - target).T)
            face = faces[int(np.argmin(dist))]
        else:
            face = faces[int(np.argmax(np.prod(boxes[:, 2:] - boxes[:, :2], axis=1)))]
        other = None
        if far:
            face = _closer_look(near, image, face, self.channel_order, self.min_score)
        elif not tiled:
            face, other = _upright(near, image, face, self.channel_order, self.min_score)
        points, presence = self._landmarks(image, face)
        if presence < self.min_presence and other is not None:
            # a face on its side the detector scores alike both ways: the mesh tells
            points, presence = self._landmarks(image, other)
        if self.refine_first and presence >= self.min_presence:
            points, presence = self._converge(image, points, presence, max_runs=1)
        return points, presence, refused

    def _converge(self, image, points, presence, max_runs: int = 5, shift: float = 0.25):
        """Run the model from the crop of its own landmarks until they move less than
        ``shift`` pixels (at most ``max_runs`` times); a run that loses the face is
        not taken."""
        for _ in range(max_runs):
            again, p = self._landmarks(image, points)
            if p < self.min_presence:
                break
            moved = float(np.abs(again[:, :2] - points[:, :2]).max())
            points, presence = again, p
            if moved < shift:
                break
        return points, presence

    def settle(self, frame, *, max_runs: int = 5, shift: float = 0.25) -> Landmarks | None:
        """The landmarks that tracking converges to on ``frame``, the last frame tracked.

        Each tracking frame is read from the crop of the last frame's landmarks, so on a
        still face the landmarks move over the first frames after a detection until the
        crop and the landmarks agree: on a still real face they moved by 1.3-3 px from
        the detection frame to the next. This runs the model on ``frame`` from its own
        landmarks until they move less than ``shift`` pixels (at most ``max_runs`` times)
        and tracks on from there. For references that later tracking frames are compared
        against.

        Returns None when no face is being tracked.
        """
        self._discard()
        if self._previous is None:
            return None
        image = check_image(frame, self.channel_order)
        points, presence = self._converge(image, self._previous, None, max_runs, shift)
        return None if presence is None else self._accept(points, presence, False)

    def track(self, frame) -> Landmarks | None:
        """The landmarks of the followed face in ``frame``, or None when no face is found.

        Parameters
        ----------
        frame : ndarray, shape (H, W) or (H, W, 3)
            uint8, or float in [0, 1].
        """
        pending = self._pending
        if pending is not None and pending[0] is frame:
            self._pending = None
            out, self.others = pending[1].result()
            return out
        self._discard()
        out, self.others = self._track(frame)
        return out

    def _track(self, frame) -> tuple[Landmarks | None, int]:
        """This frame's landmarks (None: no face followed) and how many faces were
        found and taken for others'."""
        image = check_image(frame, self.channel_order)
        points, presence, detected, refused = None, 0.0, False, 0
        if self._previous is not None:
            points, presence = self._landmarks(image, self._previous)
            if (presence >= self.min_presence
                    and _crop_change(self._previous, points) > self.recrop):
                again, p = self._landmarks(image, points)
                if p >= self.min_presence:
                    points, presence = again, p
        if points is None or presence < self.min_presence:
            (points, presence, refused), detected = self._detect(image), True
        if points is None or presence < self.min_presence:
            self._previous = None
            self._lost += 1
            if self._lost > _MEMORY and not self._crowd:
                # alone in the picture, a face found after long is the face come back
                self._last_centre = self._last_size = None
            return None, refused
        return self._accept(points, presence, detected), 0

    def _accept(self, points, presence, detected) -> Landmarks:
        """Track on from ``points`` (468, 3) and return them as this frame's landmarks."""
        self._previous, self._lost = points, 0
        lo, hi = points[:, :2].min(0), points[:, :2].max(0)
        self._last_centre = (lo + hi) / 2
        self._last_size = float((hi - lo).max())
        return Landmarks(points[:, :2].copy(), points[:, 2].copy(), float(presence),
                         (*map(float, lo), *map(float, hi)), detected)
