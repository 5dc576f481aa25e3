"""Optical flow of the face in the head reference frame, on a canonical face grid.

The flow of a face video is computed with OpenCV (DIS by default; Farneback and TV-L1 as
options) between *stabilised* face crops: every frame is warped by the similarity transform
of its head reference frame (:class:`trackers.fiducials.HeadFrame`: origin at the hairline,
x axis ``(cos roll, sin roll)`` toward the subject's left, y down, unit = the reference length
``scale`` in px) into a fixed crop around the face, so that head translation, in-plane
rotation and zoom are removed before the flow is measured. The flow is measured **directly
from the reference (neutral) frame to every frame t** rather than chained frame to frame:
it has no drift, and on small faces one large-displacement flow is more accurate than the
sum of many sub-pixel ones.

The crop flow is then resampled onto a :class:`FaceGrid`, a fixed grid of points in head
coordinates (default 64 rows x 48 columns, spanning ``u in [-0.63, 0.63]`` and
``v in [-0.10, 1.58]`` head units: hairline to below the chin, cheek to cheek), and expressed
in head units (divide by the crop scale). The same grid carries the model-made templates of
:mod:`faceanalysis.flow.templates`, so observed and model motion can be compared cell by cell.

A head frame from a tracker jitters (a degree of roll, a percent of scale); on the grid
that is a small *rigid* (similarity) motion of the whole face. :func:`rigid_basis` spans it
and :func:`remove_rigid` projects it out on the face mask; the estimator and the
recogniser fit it as a nuisance.

Head frames are given as arrays ``(x, y, scale, roll)`` (the ``head_x, head_y, head_scale,
head_roll`` columns of ``contractions.csv``) or :class:`~trackers.fiducials.HeadFrame`.
"""

from __future__ import annotations

import logging
import math
import os
import threading
from dataclasses import dataclass, field

import cv2
import numpy as np
import pandas as pd

from faceanalysis.flow.grid import (
    FaceGrid,
    head_array,
    smoothing_sigma,
)
from faceanalysis.flow.options import FLOW_METHODS

log = logging.getLogger(__name__)

__all__ = ["STABILIZATION", "FaceFlow", "compute_flow", "tvl1_scales",
           "stabilize", "face_flow", "video_face_flow", "VideoFlowStream",
           "flow_to_colour"]


# ---------------------------------------------------------------------------- flow
def _grey_u8(image) -> np.ndarray:
    img = np.asarray(image)
    if img.ndim == 3:
        if img.shape[2] == 4:
            img = img[..., :3]
        if img.shape[2] != 3:
            raise ValueError(f"image must be (H, W), (H, W, 3) or (H, W, 4), got {img.shape}")
        img = cv2.cvtColor(np.ascontiguousarray(img), cv2.COLOR_BGR2GRAY)
    elif img.ndim != 2:
        raise ValueError(f"image must be (H, W), (H, W, 3) or (H, W, 4), got {img.shape}")
    if img.dtype == np.uint8:
        return np.ascontiguousarray(img)
    if img.dtype == np.uint16:
        return (img >> 8).astype(np.uint8)
    f = img.astype(np.float32)
    if f.size and float(np.nanmax(f)) <= 1.0 + 1e-6:
        f = f * 255.0
    return np.clip(f + 0.5, 0, 255).astype(np.uint8)


def tvl1_scales(size: tuple[int, int], max_motion: float, *, scale_step: float = 0.5) -> int:
    """Pyramid depth for TV-L1 deep enough for ``max_motion`` px.

    The coarsest level must see the largest motion as about one pixel, while staying at
    least 16 px on its short side.

    Examples
    --------
    >>> tvl1_scales((256, 256), 20.0)
    5
    >>> tvl1_scales((64, 64), 20.0)
    3
    """
    if not 0 < scale_step < 1:
        raise ValueError(f"scale_step={scale_step} must be in (0, 1)")
    if max_motion < 0:
        raise ValueError(f"max_motion={max_motion} must be non-negative")
    need = 1 + math.ceil(math.log(max(max_motion, 1.0)) / -math.log(scale_step))
    fit = 1 + int(math.floor(math.log(max(min(size), 16) / 16.0) / -math.log(scale_step)))
    return int(max(1, min(max(need, 3), fit)))


#: DIS instances per thread: an OpenCV algorithm keeps its working buffers in itself, so two
#: threads calculating with one instance corrupt each other's flow (or crash).
_DIS_PER_THREAD = threading.local()


def _dis(finest: int):
    """This thread's DIS flow (medium preset) refined down to pyramid level ``finest``
    (0: full resolution)."""
    levels = _DIS_PER_THREAD.__dict__.setdefault("by_level", {})
    dis = levels.get(finest)
    if dis is None:
        dis = levels[finest] = cv2.DISOpticalFlow_create(cv2.DISOPTICAL_FLOW_PRESET_MEDIUM)
        dis.setFinestScale(finest)
    return dis


def compute_flow(image0, image1, method: str = "dis", *, max_motion: float | None = None
                 ) -> np.ndarray:
    """Dense optical flow from ``image0`` to ``image1`` with OpenCV.

    Parameters
    ----------
    image0, image1 : ndarray
        Grey ``(H, W)`` or colour ``(H, W, 3)`` (BGR) frames of the same size, any dtype.
    method : {'dis', 'farneback', 'tvl1'}
        ``dis``: DIS optical flow, medium preset refined down to full resolution (finest
        scale 0; default); ``farneback``: Farneback's
        polynomial expansion; ``tvl1``: Dual TV-L1 (``cv2.optflow``) with a pyramid deep
        enough for ``max_motion`` (:func:`tvl1_scales`).
    max_motion : float, optional
        Largest expected displacement in px (default: a tenth of the short side); sets the
        pyramid depth of ``farneback`` and ``tvl1``.

    Returns
    -------
    ndarray, shape (H, W, 2), float32
        Displacement ``(dx, dy)`` in px of the pixel of ``image0`` (x right, y down).

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> a = cv2.GaussianBlur((rng.random((64, 64)) * 255).astype(np.uint8), (0, 0), 1.5)
    >>> b = np.roll(a, 2, axis=1)
    >>> fl = compute_flow(a, b)
    >>> round(float(np.median(fl[16:48, 16:48, 0])), 1)
    2.0
    """
    if method not in FLOW_METHODS:
        raise ValueError(f"unknown flow method {method!r}; choose from {', '.join(FLOW_METHODS)}")
    a, b = _grey_u8(image0), _grey_u8(image1)
    if a.shape != b.shape:
        raise ValueError(f"images differ in size: {a.shape} and {b.shape}")
    if min(a.shape) < 8:
        raise ValueError(f"images of {a.shape[1]}x{a.shape[0]} px are too small for flow")
    if max_motion is None:
        max_motion = 0.1 * min(a.shape)
    if method == "dis":
        flow = _dis(0).calc(a, b, None)     # full resolution: sub-pixel face motion needs it
    elif method == "farneback":
        levels = int(max(3, min(6, math.ceil(math.log2(max(max_motion, 1.0))) + 1)))
        flow = cv2.calcOpticalFlowFarneback(a, b, None, 0.5, levels, 15, 5, 5, 1.1, 0)
    else:
        n = tvl1_scales(a.shape, max_motion)
        tv = cv2.optflow.DualTVL1OpticalFlow_create(nscales=n, scaleStep=0.5, warps=5)
        flow = tv.calc(a, b, None)
    return np.asarray(flow, dtype=np.float32)


# ---------------------------------------------------------------------------- stabilised crops
@dataclass(frozen=True)
class _Crop:
    grid: FaceGrid
    px_per_unit: float
    pad: float

    @property
    def origin(self) -> tuple[float, float]:
        return (self.grid.u[0] - self.pad, self.grid.v[0] - self.pad)

    @property
    def size(self) -> tuple[int, int]:
        w = (self.grid.u[1] - self.grid.u[0] + 2 * self.pad) * self.px_per_unit
        h = (self.grid.v[1] - self.grid.v[0] + 2 * self.pad) * self.px_per_unit
        return int(math.ceil(w)) + 1, int(math.ceil(h)) + 1

    def matrix(self, head) -> np.ndarray:
        """2x3 affine map from crop px to image px."""
        x, y, s, r = head_array(head)
        c, sn = math.cos(r), math.sin(r)
        k = s / self.px_per_unit
        u0, v0 = self.origin
        # head point (u, v) = (u0 + cx / ppu, v0 + cy / ppu)
        a = np.array([[c * k, -sn * k], [sn * k, c * k]])
        b = np.array([x, y]) + s * np.array([c * u0 - sn * v0, sn * u0 + c * v0])
        return np.c_[a, b]

    def grid_px(self) -> np.ndarray:
        u0, v0 = self.origin
        p = self.grid.points
        return np.stack([(p[..., 0] - u0) * self.px_per_unit,
                         (p[..., 1] - v0) * self.px_per_unit], axis=-1).astype(np.float32)


def stabilize(image, head, grid: FaceGrid | None = None, *, px_per_unit: float = 128.0,
              pad: float = 0.2) -> np.ndarray:
    """Warp a frame into the canonical face crop of its head frame (grey uint8).

    Crop pixel ``(cx, cy)`` shows head point ``(u0 - pad + cx / px_per_unit,
    v0 - pad + cy / px_per_unit)`` where ``(u0, v0)`` is the grid's first point.

    Examples
    --------
    >>> img = np.zeros((200, 200), np.uint8); img[100, 120] = 255
    >>> crop = stabilize(img, (100, 100, 50, 0.0), FaceGrid(u=(-1, 1), v=(-1, 1)),
    ...                  px_per_unit=50, pad=0.0)
    >>> np.unravel_index(np.argmax(crop), crop.shape)   # head point (0.4, 0)
    (np.int64(50), np.int64(70))
    """
    grid = grid or FaceGrid()
    if not px_per_unit > 0:
        raise ValueError(f"px_per_unit={px_per_unit} must be positive")
    crop = _Crop(grid, float(px_per_unit), float(pad))
    return _warp(_grey_u8(image), crop, head)


def _warp(grey: np.ndarray, crop: _Crop, head) -> np.ndarray:
    m = crop.matrix(head)
    return cv2.warpAffine(grey, m, crop.size, flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                          borderMode=cv2.BORDER_REPLICATE)


def _normalise(grey: np.ndarray, sigma: float) -> np.ndarray:
    """Local contrast normalisation against illumination change: a fine high-pass (the
    skin texture; shading is smooth) divided by its local amplitude."""
    f = grey.astype(np.float32)
    mean = cv2.GaussianBlur(f, (0, 0), sigma)
    d = f - mean
    sd = np.sqrt(cv2.GaussianBlur(d * d, (0, 0), 2.0 * sigma)) + 4.0
    return np.clip(128.0 + 40.0 * d / sd, 0, 255).astype(np.uint8)


@dataclass
class FaceFlow:
    """Face motion from a reference frame, on the face grid.

    Attributes
    ----------
    displacement : ndarray (T, rows, cols, 2)
        Displacement from the reference frame, head units (u toward the subject's left,
        v down); NaN for frames without a head frame.
    valid : ndarray (T,) bool
    frames : ndarray (T,) int
        Frame numbers.
    reference : int
        Frame number of the reference (neutral) frame.
    grid : FaceGrid
    method : str
    px_per_unit : float
        Scale of the stabilised crop in which the flow was measured.
    """

    displacement: np.ndarray
    valid: np.ndarray
    frames: np.ndarray
    reference: int
    grid: FaceGrid
    method: str = "dis"
    px_per_unit: float = 128.0
    timings: dict = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.displacement)


def _crop_scale(ref_scale: float, px_per_unit) -> float:
    if px_per_unit is not None:
        if not px_per_unit > 0:
            raise ValueError(f"px_per_unit={px_per_unit} must be positive")
        return float(px_per_unit)
    # measure at about the resolution of the face in the video, within sane limits
    return float(np.clip(ref_scale, 64.0, 160.0))


#: Ways of putting a frame into the reference's head frame (see :func:`face_flow`).
STABILIZATION = ("flow", "head")

#: Short side (px) of the finest pyramid level of the DIS flow that aligns a frame before its
#: flow is measured (``stabilization="flow"``): the similarity fitted to it needs the face's
#: common motion, not its fine detail, so that flow stops at the coarsest level (halving the
#: crop each time) whose short side is still this large: a crop of 267 px (160 px to the
#: head unit) at a quarter of its resolution, one of 128 at half, one under 128 at full. Below
#: it the coarse flow blurs the moving mouth into the cheeks and the alignment follows the
#: expression (at 27 px, a relaxing smile's rest frames swing by a third of the smile).
ALIGN_MIN_SIDE = 64


def _compose_similarity(flow: np.ndarray, inverse: np.ndarray) -> np.ndarray:
    """The flow to a crop resampled by a similarity ``S``, from the flow to the crop as it
    was and ``inverse`` = ``S^-1`` (3x3): a point ``x + flow(x)`` of the old crop lies at
    ``S^-1 (x + flow(x))`` in the new one."""
    h, w = flow.shape[:2]
    x, y = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))
    px, py = x + flow[..., 0], y + flow[..., 1]
    a = inverse.astype(np.float32)
    return np.stack([a[0, 0] * px + a[0, 1] * py + a[0, 2] - x,
                     a[1, 0] * px + a[1, 1] * py + a[1, 2] - y], axis=-1)


class _FlowStep:
    """Reference crop + per-frame flow to it (shared by :func:`face_flow` and videos)."""

    def __init__(self, ref_image, ref_head, grid, method, px_per_unit, normalize, pad=0.2,
                 stabilization="flow"):
        if method not in FLOW_METHODS:
            raise ValueError(f"unknown flow method {method!r}; choose from "
                             f"{', '.join(FLOW_METHODS)}")
        if stabilization not in STABILIZATION:
            raise ValueError(f"unknown stabilization {stabilization!r}; choose from "
                             f"{', '.join(STABILIZATION)}")
        h = head_array(ref_head)
        if not np.isfinite(h).all() or h[2] <= 0:
            raise ValueError("the reference frame needs a finite head frame with positive scale")
        self.grid = grid
        self.method = method
        self.stabilization = stabilization
        self.crop = _Crop(grid, _crop_scale(h[2], px_per_unit), pad)
        self.normalize = bool(normalize)
        self.sigma = max(0.8, 0.01 * self.crop.px_per_unit)
        self.ref = self._prep(ref_image, self.crop.matrix(h))
        self.gpx = self.crop.grid_px()
        self.blur = smoothing_sigma(grid, self.crop.px_per_unit)
        self.max_motion = 0.25 * self.crop.px_per_unit
        self.prev = None                              # last crop->image matrix (3x3)
        self.align_level = max(0, int(np.log2(min(self.crop.size) / ALIGN_MIN_SIDE)))
        # points of the face (an ellipse inside the grid) for the rigid fit
        cx = 0.5 * (grid.u[0] + grid.u[1])
        cy = 0.5 * (grid.v[0] + grid.v[1])
        ax, ay = 0.45 * (grid.u[1] - grid.u[0]), 0.45 * (grid.v[1] - grid.v[0])
        step = max(3, int(round(0.03 * self.crop.px_per_unit)))
        w, hgt = self.crop.size
        X, Y = np.meshgrid(np.arange(0, w, step), np.arange(0, hgt, step))
        u0, v0 = self.crop.origin
        U = u0 + X / self.crop.px_per_unit
        V = v0 + Y / self.crop.px_per_unit
        inside = ((U - cx) / ax) ** 2 + ((V - cy) / ay) ** 2 <= 1.0
        self.fit_pts = np.c_[X[inside], Y[inside]].astype(np.float32)

    def _prep(self, image, matrix):
        g = cv2.warpAffine(_grey_u8(image), np.asarray(matrix, dtype=np.float64)[:2],
                           self.crop.size, flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                           borderMode=cv2.BORDER_REPLICATE)
        return _normalise(g, self.sigma) if self.normalize else g

    def _flow(self, cur):
        return compute_flow(self.ref, cur, self.method, max_motion=self.max_motion)

    def _align_flow(self, cur):
        """The coarse DIS flow from which a frame's alignment is fitted."""
        return _dis(self.align_level).calc(self.ref, cur, None)

    def _rigid(self, fl):
        """Similarity (3x3, reference crop -> current crop) fitted robustly to the flow."""
        p = self.fit_pts
        d = fl[p[:, 1].astype(int), p[:, 0].astype(int)]
        S, inl = cv2.estimateAffinePartial2D(p, p + d, method=cv2.RANSAC,
                                             ransacReprojThreshold=1.5, maxIters=500,
                                             confidence=0.99, refineIters=10)
        if S is None:
            return None, 0.0
        return np.vstack([S, [0.0, 0.0, 1.0]]), float(np.mean(inl))

    def __call__(self, image, head) -> np.ndarray:
        h = head_array(head)
        have_head = bool(np.isfinite(h).all() and h[2] > 0)
        if have_head:
            # each tracked frame starts from its own head frame: started from the last
            # frame's alignment, the correction fed back on itself, and on a still face
            # held at an expression it swung by 0.1-0.2 px from one frame to the next
            M = np.vstack([self.crop.matrix(h), [0.0, 0.0, 1.0]])
        elif self.stabilization == "head" or self.prev is None:
            return np.full((*self.grid.shape, 2), np.nan)
        else:
            M = self.prev                     # no head frame: bridged from the last one
        cur = self._prep(image, M)
        if self.stabilization == "flow":
            S, frac = self._rigid(self._align_flow(cur))
            if S is None or frac < 0.1:
                self.prev = None if not have_head else self.prev
                return np.full((*self.grid.shape, 2), np.nan)
            M = M @ S
            cur = self._prep(image, M)
        fl = self._flow(cur)
        if self.stabilization == "flow":
            # what the coarse flow's alignment left, from the measured flow itself
            S, frac = self._rigid(fl)
            if S is not None and frac >= 0.1:
                M = M @ S
                fl = _compose_similarity(fl, np.linalg.inv(S))
            self.prev = M
        if self.blur > 0.3:
            fl = cv2.GaussianBlur(fl, (0, 0), self.blur)
        out = np.stack([cv2.remap(np.ascontiguousarray(fl[..., k]), self.gpx[..., 0],
                                  self.gpx[..., 1], cv2.INTER_LINEAR,
                                  borderMode=cv2.BORDER_REPLICATE) for k in range(2)], axis=-1)
        return out.astype(np.float64) / self.crop.px_per_unit


def face_flow(frames, heads, *, grid: FaceGrid | None = None, method: str = "dis",
              reference: int = 0, px_per_unit: float | None = None, normalize: bool = True,
              stabilization: str = "flow", frame_numbers=None) -> FaceFlow:
    """Face displacement from a reference frame to every frame, on the face grid.

    Parameters
    ----------
    frames : sequence of images
        Grey or BGR frames (``(T, H, W[, 3])`` array or a list).
    heads : array_like (T, 4)
        Head frame of every frame (x, y, scale, roll), trackers' convention; NaN rows
        mark frames without a face.
    grid : FaceGrid, optional
    method : {'dis', 'farneback', 'tvl1'}
    reference : int
        Position (in ``frames``) of the neutral reference frame.
    px_per_unit : float, optional
        Scale of the stabilised crop (default: the reference head scale, within 64-160).
    normalize : bool
        Local contrast normalisation of the crops (robust to illumination change).
    stabilization : {'flow', 'head'}
        ``head``: every frame is warped by its own head frame. ``flow`` (default): every
        frame starts from its head frame (a frame without one from the previous frame's
        alignment); a similarity fitted robustly (RANSAC) to a first, coarse flow on the
        face (DIS down to :data:`ALIGN_MIN_SIDE`) then corrects the alignment, the flow is
        measured on the aligned crop, and the similarity fitted to it takes out what the
        alignment left. It corrects head-frame jitter and bridges frames where the tracker
        lost the face; frames where fewer than a tenth of the face points fit a common
        rigid motion are lost.
    frame_numbers : array_like, optional
        Frame numbers to record (default ``0..T-1``).

    Returns
    -------
    FaceFlow
    """
    import time

    grid = grid or FaceGrid()
    H = np.asarray(heads, dtype=float)
    T = len(frames)
    if H.shape != (T, 4):
        raise ValueError(f"heads must have shape ({T}, 4) for {T} frames, got {H.shape}")
    if not 0 <= reference < T:
        raise ValueError(f"reference={reference} is outside 0..{T - 1}")
    t0 = time.perf_counter()
    step = _FlowStep(frames[reference], H[reference], grid, method, px_per_unit, normalize,
                     stabilization=stabilization)
    disp = np.full((T, *grid.shape, 2), np.nan)
    for t in range(reference, T):
        disp[t] = 0.0 if t == reference else step(frames[t], H[t])
    step.prev = None
    for t in range(reference - 1, -1, -1):        # frames before the reference, backwards
        disp[t] = step(frames[t], H[t])
    valid = np.isfinite(disp).all(axis=(1, 2, 3))
    fn = np.arange(T) if frame_numbers is None else np.asarray(frame_numbers, dtype=int)
    return FaceFlow(disp, valid, fn, int(fn[reference]), grid, method, step.crop.px_per_unit,
                    timings={"flow_s": time.perf_counter() - t0})


# ---------------------------------------------------------------------------- videos
def video_face_flow(video: str | os.PathLike, *, table: pd.DataFrame | None = None,
                    neutral: int | None = None, method: str = "dis",
                    grid: FaceGrid | None = None, fps: float | None = None, start: int = 0,
                    end: int | None = None, px_per_unit: float | None = None,
                    normalize: bool = True, stabilization: str = "flow",
                    hidden=None, dtype=np.float64) -> FaceFlow:
    """Face flow of a video file, streamed (frames are not kept in memory).

    Parameters
    ----------
    video : path-like, Frames or array_like
        As :func:`faceanalysis.analysis.pipeline.analyze` takes it.
    table : DataFrame, optional
        Head frames per frame (``frame, head_*`` and ``success`` columns, e.g. an analysis's
        ``contractions.csv``); default: tracked with
        :func:`faceanalysis.tracking.track` (``redetect=True``).
    neutral : int, optional
        Frame number of the reference (neutral) frame; default the first tracked frame.
    method, grid, px_per_unit, normalize, stabilization
        See :func:`face_flow` (frames before the neutral one are aligned from the head
        frame only, as the video is streamed forward).
    fps, start, end
        Input options, as for ``analyze``.
    hidden : iterable of int, optional
        Frame numbers on which the face cannot be seen (lost for no face, a hand over it
        or no picture: :func:`faceanalysis.tracking.hidden_frames`): their flow is lost
        (NaN) instead of bridged from the last frame's alignment. Default: those of the
        tracks when ``table`` is tracked here, none of a given table's.
    dtype : numpy float dtype, keyword-only
        Type of the stored displacement: ``float64`` (default) or ``float32``, which halves
        the memory a long video needs (a 64 x 48 grid: 49 kB a frame in ``float64``).

    Returns
    -------
    FaceFlow
    """
    import time

    grid = grid or FaceGrid()
    t0 = time.perf_counter()
    stream = VideoFlowStream(video, table=table, neutral=neutral, method=method, grid=grid,
                             fps=fps, start=start, end=end, px_per_unit=px_per_unit,
                             normalize=normalize, stabilization=stabilization, hidden=hidden)
    frames = stream.frames
    disp = np.full((len(frames), *grid.shape, 2), np.nan, dtype=dtype)
    for i, d in stream:
        disp[i] = d
    seen = np.isfinite(disp).all(axis=(1, 2, 3))
    return FaceFlow(disp, seen, frames, stream.reference, grid, method, stream.px_per_unit,
                    timings={"flow_s": time.perf_counter() - t0})


class VideoFlowStream:
    """Face flow of a video, one frame at a time: ``for position, displacement in ...``.

    The same flow as :func:`video_face_flow` (same parameters, without ``dtype``), without
    keeping it: a caller that reduces each frame to a few numbers holds memory that does
    not grow with the video's length. ``frames`` (frame numbers of the table's rows in the
    range), ``reference`` (frame number of the neutral frame) and ``px_per_unit`` are known
    before the iteration; it yields ``(position in frames, (rows, cols, 2) float64
    displacement)`` for every decoded frame, in video order, NaN where the face is lost.
    """

    def __init__(self, video: str | os.PathLike, *, table: pd.DataFrame | None = None,
                 neutral: int | None = None, method: str = "dis",
                 grid: FaceGrid | None = None, fps: float | None = None, start: int = 0,
                 end: int | None = None, px_per_unit: float | None = None,
                 normalize: bool = True, stabilization: str = "flow", hidden=None):
        from faceanalysis.io.table import heads_from_table
        from faceanalysis.io.video import as_video, open_video
        from faceanalysis.tracking import hidden_frames, track

        video = as_video(video)
        grid = grid or FaceGrid()
        if table is None:
            tracks = track(video, fps=fps, start=start, end=end, redetect=True,
                           keep_contours=False)
            table = tracks.table
            if hidden is None:
                hidden = hidden_frames(tracks.frames, tracks.lost_reasons)
        if "frame" not in table.columns:
            raise ValueError("table lacks the 'frame' column")
        heads = heads_from_table(table)
        frames = table["frame"].to_numpy(int)
        if end is not None or start:
            keep = (frames >= start) & (frames < (end if end is not None
                                                  else np.iinfo(int).max))
            heads, frames = heads[keep], frames[keep]
        ok = np.isfinite(heads).all(axis=1)
        if not ok.any():
            raise ValueError(f"{video}: no frame has a head frame (face lost throughout)")
        if neutral is None:
            ref_pos = int(np.argmax(ok))
        else:
            hits = np.flatnonzero(frames == neutral)
            if hits.size == 0 or not ok[hits[0]]:
                raise ValueError(f"neutral frame {neutral} is not a tracked frame of {video}")
            ref_pos = int(hits[0])
        ref_frame = int(frames[ref_pos])
        with open_video(video, fps=fps, start=ref_frame, end=ref_frame + 1,
                        eight_bit=True) as src:
            ref_img = next((f.image for f in src if f.ok), None)
        if ref_img is None:
            raise ValueError(f"{video}: reference frame {ref_frame} cannot be decoded")
        self._step = _FlowStep(ref_img, heads[ref_pos], grid, method, px_per_unit, normalize,
                               stabilization=stabilization)
        self._back = _FlowStep(ref_img, heads[ref_pos], grid, method, px_per_unit, normalize,
                               stabilization="head")
        self._video, self._fps, self._heads, self._ok = video, fps, heads, ok
        self._hidden = frozenset(int(f) for f in (() if hidden is None else hidden))
        self._ref_pos = ref_pos
        self.frames = frames
        self.reference = ref_frame
        self.grid = grid
        self.px_per_unit = self._step.crop.px_per_unit

    def __iter__(self):
        from faceanalysis.io.video import open_video

        frames, heads, ok, ref_pos = self.frames, self._heads, self._ok, self._ref_pos
        pos = {int(f): i for i, f in enumerate(frames)}
        lost = np.full((*self.grid.shape, 2), np.nan)
        with open_video(self._video, fps=self._fps, start=int(frames.min()),
                        end=int(frames.max()) + 1, eight_bit=True) as src:
            for f in src:
                i = pos.get(f.index)
                if i is None or not f.ok:
                    continue
                if f.index in self._hidden and i != ref_pos:
                    # nothing of the face to align on: bridged, the flow would measure
                    # the hand or the background as the face's motion
                    yield i, lost
                    continue
                if i == ref_pos:
                    yield i, np.zeros((*self.grid.shape, 2))
                elif i > ref_pos:
                    yield i, self._step(f.image, heads[i])
                else:
                    # frames before the reference are aligned from their head frame only,
                    # as the video is streamed forward
                    yield i, (self._back(f.image, heads[i]) if ok[i] else lost)


# ---------------------------------------------------------------------------- drawing
def flow_to_colour(flow: np.ndarray, *, max_magnitude: float | None = None) -> np.ndarray:
    """Colour-wheel picture of a flow field (hue = direction, saturation = magnitude), RGB.

    Parameters
    ----------
    flow : (H, W, 2)
        Vectors (x right, y down); NaN is drawn white.
    max_magnitude : float, optional
        Magnitude drawn fully saturated (default: the 99th percentile).

    Returns
    -------
    (H, W, 3) uint8 RGB
    """
    f = np.asarray(flow, dtype=np.float64)
    if f.ndim != 3 or f.shape[2] != 2:
        raise ValueError(f"flow must have shape (H, W, 2), got {f.shape}")
    bad = ~np.isfinite(f).all(axis=2)
    f = np.where(bad[..., None], 0.0, f)
    mag = np.hypot(f[..., 0], f[..., 1])
    if max_magnitude is None:
        max_magnitude = float(np.percentile(mag, 99)) if mag.size else 1.0
    max_magnitude = max(float(max_magnitude), 1e-12)
    ang = (np.degrees(np.arctan2(f[..., 1], f[..., 0])) % 360.0) / 2.0
    hsv = np.zeros((*f.shape[:2], 3), np.uint8)
    hsv[..., 0] = ang.astype(np.uint8)
    hsv[..., 1] = np.clip(255.0 * mag / max_magnitude, 0, 255).astype(np.uint8)
    hsv[..., 2] = 255
    rgb = cv2.cvtColor(hsv, cv2.COLOR_HSV2RGB)
    rgb[bad] = 255
    return rgb
