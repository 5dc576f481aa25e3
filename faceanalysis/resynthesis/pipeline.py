"""Resynthesis: drive the face model with a contraction time series and render it again.

004 closes its loop by feeding the estimated contractions to the face model (Fig. 7c): "the
model quickly attains dynamic equilibrium on each frame input". :func:`resynthesize` does the
same for a ``contractions.csv`` (or an :class:`~faceanalysis.analysis.pipeline.Analysis`, or an
analysis folder): every frame sets the muscle contractions and the jaw, relaxes the tissue
lattice to equilibrium (warm-started from the previous frame's) and renders it.

Framing. When the series carries head frames (``head_x, head_y, head_scale, head_roll``) and
the input's frame size is known (``analysis.json``), the frontal view places the model in the
input's framing: the model's own head reference frame (the hairline centroid and the nostrils,
:func:`synth.personalize.head_frame_points`) is mapped onto the tracked head frame of each
frame by a similarity (orthographic scale, in-plane roll, translation), so the resynthesis
moves with the head. Otherwise a fixed camera frames the face.

Personalisation (``subject=``). The generic model is deformed to the subject's neutral frame
by a landmark-driven warp of the whole structure (Kähler 001, ch. 8;
:mod:`synth.personalize`): the 11 neutral fiducials (taken from the image into model space by
the neutral frame's similarity; their unobserved depth is the model's, scaled by the
subject's overall size in the image plane), the hairline centroid and the nostrils (pinned:
they define the framing) drive a 3-D radial-basis interpolation. Should the warp fold space
or leave a muscle without tissue to pull, it is blended toward the best affine map of the
landmarks until the model is valid (a warning says so; the landmark error in the report
shows the cost). The
personalised model is textured with the neutral frame itself, projected through the
framing (uv = image position / image size), and rendered unlit, so that its neutral frame
reproduces the input and its expressions move the subject's own skin.

Lost frames (``success == 0``) hold the last good contractions and head frame.
"""

from __future__ import annotations

import json
import logging
import math
import os
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from faceanalysis.io.table import FIDUCIALS, HEAD_COLUMNS, JAW, MUSCLES

log = logging.getLogger(__name__)

__all__ = ["resynthesize", "Resynthesis", "FrameState", "personalize", "SubjectInfo",
           "Framing", "framing_from_head", "head_reference", "transfer_head_motion",
           "round_trip", "VIEWS", "SHADINGS", "MESH_FORMATS"]

#: Views of :func:`resynthesize`: yaw of the head in degrees.
VIEWS: dict[str, float] = {"front": 0.0, "three-quarter": 40.0, "profile": 90.0}
#: Shadings of :func:`resynthesize`.
SHADINGS: tuple[str, ...] = ("textured", "plain", "wireframe")
#: Per-frame mesh formats of ``export_meshes`` (a path ending in ``.npz`` writes one file).
MESH_FORMATS: tuple[str, ...] = ("obj", "ply")

_DEFAULT_FPS = 30.0


# ----------------------------------------------------------------------------- input
@dataclass
class _Series:
    """The drive: per-frame controls, bookkeeping and (optionally) head frames."""

    frames: np.ndarray            # (T,) frame numbers
    timestamps: np.ndarray        # (T,) seconds (may be NaN)
    success: np.ndarray           # (T,) bool
    controls: np.ndarray          # (T, M) muscles in MUSCLES order, lost rows held
    jaw: np.ndarray               # (T,)
    heads: np.ndarray | None      # (T, 4), lost rows held; None when absent
    fiducials: np.ndarray | None  # (T, 11, 2) image px; NaN when lost
    metadata: dict = field(default_factory=dict)
    table: pd.DataFrame | None = None
    folder: Path | None = None
    missing: tuple[str, ...] = ()

    @property
    def input_size(self) -> tuple[int, int] | None:
        size = (self.metadata.get("input") or {}).get("size")
        if size and len(size) == 2 and all(int(v) > 0 for v in size):
            return int(size[0]), int(size[1])
        return None

    @property
    def input_path(self) -> Path | None:
        p = (self.metadata.get("input") or {}).get("path")
        return Path(p) if p else None

    @property
    def neutral_row(self) -> int:
        """Row of the neutral frame (analysis.json's, else the first tracked row)."""
        nf = (self.metadata.get("parameters") or {}).get("neutral_frame")
        if nf is None:
            nf = (self.metadata.get("calibration") or {}).get("neutral_frame")
        if nf is not None:
            hits = np.flatnonzero(self.frames == int(nf))
            if hits.size and self.success[hits[0]]:
                return int(hits[0])
        if not self.success.any():
            raise ValueError("no tracked frame (success == 1) in the series")
        return int(np.argmax(self.success))

    def fps(self, override: float | None = None) -> float:
        if override is not None:
            return float(override)
        f = (self.metadata.get("input") or {}).get("fps")
        if f and np.isfinite(f) and f > 0:
            return float(f)
        ts = self.timestamps
        if ts.size > 1 and np.isfinite(ts).all():
            d = np.diff(ts) / np.maximum(np.diff(self.frames), 1)
            d = d[d > 0]
            if d.size:
                return float(1.0 / np.median(d))
        return _DEFAULT_FPS


def _label(frames, row: int) -> str:
    return f"line {row + 2} (frame {int(frames[row])})"


def _numeric_column(df: pd.DataFrame, column: str, where: str, frames) -> np.ndarray:
    raw = df[column]
    if pd.api.types.is_numeric_dtype(raw):
        return raw.to_numpy(dtype=float)
    converted = pd.to_numeric(raw, errors="coerce")
    blank = raw.isna() | (raw.astype(str).str.strip() == "")
    bad = converted.isna() & ~blank
    if bad.any():
        r = int(np.flatnonzero(bad.to_numpy())[0])
        raise ValueError(f"{where}: {_label(frames, r)}, column {column}: "
                         f"{str(raw.iloc[r])!r} is not a number")
    return converted.to_numpy(dtype=float)


def _series_from_table(df: pd.DataFrame, where: str, metadata: dict | None = None
                       ) -> _Series:
    """Validate a contractions table (complete or partial) into a :class:`_Series`."""
    from synth.model import MAX_JAW_ROTATION

    if not isinstance(df, pd.DataFrame):
        raise ValueError(f"{where}: expected a table, got {type(df).__name__}")
    if len(df) == 0:
        raise ValueError(f"{where}: the table has no rows")
    df = df.copy()
    df.columns = [str(c).strip() for c in df.columns]
    n = len(df)
    frames = np.arange(n)
    if "frame" in df.columns:
        frames = _numeric_column(df, "frame", where, frames)
        if not np.isfinite(frames).all() or (frames != np.round(frames)).any():
            r = int(np.flatnonzero(~np.isfinite(frames) | (frames != np.round(frames)))[0])
            raise ValueError(f"{where}: line {r + 2}, column frame: not an integer frame number")
        frames = frames.astype(np.int64)
        if n > 1 and (np.diff(frames) <= 0).any():
            r = int(np.flatnonzero(np.diff(frames) <= 0)[0]) + 1
            raise ValueError(f"{where}: {_label(frames, r)}, column frame: frame numbers must "
                             "increase")
    success = np.ones(n, bool)
    if "success" in df.columns:
        s = _numeric_column(df, "success", where, frames)
        bad = ~np.isin(s, (0.0, 1.0))
        if bad.any():
            r = int(np.flatnonzero(bad)[0])
            raise ValueError(f"{where}: {_label(frames, r)}, column success: {s[r]!r} is not "
                             "0 or 1")
        success = s == 1.0
    timestamps = np.full(n, np.nan)
    if "timestamp" in df.columns:
        timestamps = _numeric_column(df, "timestamp", where, frames)
    present = [m for m in MUSCLES if m in df.columns]
    if not present and JAW not in df.columns:
        raise ValueError(f"{where}: no muscle columns (e.g. {MUSCLES[0]}) and no {JAW} column")
    missing = tuple(m for m in MUSCLES if m not in df.columns)
    controls = np.zeros((n, len(MUSCLES)))
    jaw = np.zeros(n)
    for j, name in enumerate((*MUSCLES, JAW)):
        if name not in df.columns:
            continue
        v = _numeric_column(df, name, where, frames)
        hi = MAX_JAW_ROTATION if name == JAW else 1.0
        lost_nan = np.isnan(v) & ~success
        with np.errstate(invalid="ignore"):
            bad = ~lost_nan & (~np.isfinite(v) | (v < 0.0) | (v > hi))
        if bad.any():
            r = int(np.flatnonzero(bad)[0])
            problem = ("an empty cell in a tracked frame (success == 1)" if np.isnan(v[r])
                       else f"{v[r]:g} is outside [0, {hi:g}]")
            raise ValueError(f"{where}: {_label(frames, r)}, column {name}: {problem}")
        if name == JAW:
            jaw = v
        else:
            controls[:, j] = v
    # lost frames hold the last good value (rest before the first good one)
    controls, jaw = _hold(controls, success), _hold(jaw[:, None], success)[:, 0]
    heads = None
    if all(c in df.columns for c in HEAD_COLUMNS):
        h = np.stack([_numeric_column(df, c, where, frames) for c in HEAD_COLUMNS], axis=1)
        good = success & np.isfinite(h).all(axis=1) & (h[:, 2] > 0)
        if good.any():
            heads = _hold(h, good, first=h[int(np.argmax(good))])
    fiducials = None
    cols = [f"fid_{name}_{a}" for name in FIDUCIALS for a in "xy"]
    if all(c in df.columns for c in cols):
        fiducials = np.stack([_numeric_column(df, c, where, frames) for c in cols],
                             axis=1).reshape(n, len(FIDUCIALS), 2)
        fiducials[~success] = np.nan
    return _Series(frames=frames, timestamps=timestamps, success=success, controls=controls,
                   jaw=jaw, heads=heads, fiducials=fiducials, metadata=dict(metadata or {}),
                   table=df, missing=missing)


def _hold(values: np.ndarray, good: np.ndarray, first=None) -> np.ndarray:
    """Rows where ``good`` is false take the last good row (``first``, else 0, before any)."""
    out = np.array(values, dtype=float)
    idx = np.where(good, np.arange(len(good)), -1)
    idx = np.maximum.accumulate(idx)
    fill = np.zeros(out.shape[1]) if first is None else np.asarray(first, float)
    held = np.where((idx >= 0)[:, None], out[np.maximum(idx, 0)], fill[None, :])
    return held


def _read_metadata(path: Path) -> dict:
    if not path.is_file():
        return {}
    try:
        return json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        log.warning("ignoring unreadable %s (%s)", path, exc)
        return {}


def _load_series(source) -> _Series:
    """An Analysis, analysis folder, contractions CSV or DataFrame -> :class:`_Series`."""
    from faceanalysis.analysis.pipeline import Analysis

    if isinstance(source, Analysis):
        s = _series_from_table(source.table, "analysis", source.metadata)
        return s
    if isinstance(source, pd.DataFrame):
        return _series_from_table(source, "table")
    if not isinstance(source, (str, os.PathLike)):
        raise ValueError(f"source must be an Analysis, a DataFrame, a contractions.csv or an "
                         f"analysis folder, got {type(source).__name__}")
    path = Path(source)
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such file or folder")
    folder = path if path.is_dir() else path.parent
    csv = path / "contractions.csv" if path.is_dir() else path
    if not csv.is_file():
        raise FileNotFoundError(f"{csv}: no such file (expected an analysis folder or a "
                                "contractions.csv)")
    meta = _read_metadata(folder / "analysis.json")
    try:
        head = pd.read_csv(csv, nrows=0)
    except pd.errors.EmptyDataError:
        raise ValueError(f"{csv}: file is empty") from None
    except (pd.errors.ParserError, UnicodeDecodeError, ValueError):
        raise ValueError(f"{csv}: not a CSV table (expected contractions.csv or an analysis "
                         "folder)") from None
    from faceanalysis.io.table import contraction_columns, read_contractions

    if all(c in [str(h).strip() for h in head.columns] for c in contraction_columns()):
        df = read_contractions(csv)            # full table: validated, names row and column
    else:
        try:
            df = pd.read_csv(csv, keep_default_na=False, na_values=[""], low_memory=False)
        except pd.errors.EmptyDataError:
            raise ValueError(f"{csv}: file is empty") from None
        except (pd.errors.ParserError, UnicodeDecodeError) as exc:
            raise ValueError(f"{csv}: not a CSV table ({str(exc).strip()[:80]})") from None
    s = _series_from_table(df, str(csv), meta)
    s.folder = folder
    return s


# ----------------------------------------------------------------------------- framing
def _rot(theta: float) -> np.ndarray:
    c, s = math.cos(theta), math.sin(theta)
    return np.array([[c, -s], [s, c]])


@dataclass(frozen=True)
class Framing:
    """Model-to-image similarity of one frame: ``img = T + k R(roll) (x, -y)``.

    ``k`` in px/cm, ``roll`` in radians (clockwise on screen, the head frame's), ``T`` the
    image position (px) of the model origin.
    """

    k: float
    roll: float
    T: tuple

    def apply(self, points) -> np.ndarray:
        """Image positions (K, 2) of model points (K, 2 or 3) (orthographic)."""
        p = np.asarray(points, dtype=float)
        q = np.c_[p[:, 0], -p[:, 1]]
        return np.asarray(self.T) + self.k * q @ _rot(self.roll).T

    def invert(self, image_points) -> np.ndarray:
        """Model (x, y) of image points (K, 2)."""
        q = (np.asarray(image_points, dtype=float) - np.asarray(self.T)) @ _rot(self.roll)
        q = q / self.k
        return np.c_[q[:, 0], -q[:, 1]]

    def scaled(self, factor: float) -> Framing:
        """The same framing in an image resized by ``factor`` (pixel centres scale about
        -0.5)."""
        T = (np.asarray(self.T) + 0.5) * factor - 0.5
        return Framing(self.k * factor, self.roll, (float(T[0]), float(T[1])))

    def camera_pose(self, width: int, height: int):
        """A :class:`synth.render.Camera` and :class:`HeadPose` that render this framing."""
        from synth.render import Camera, HeadPose

        cx, cy = (width - 1) / 2.0, (height - 1) / 2.0
        lx = (cx - self.T[0]) / self.k
        ly = (self.T[1] - cy) / self.k
        cam = Camera(width=int(width), height=int(height), kind="orthographic", scale=self.k,
                     focal=self.k * 60.0, distance=60.0, look_at=(lx, ly, 0.0))
        pose = HeadPose(roll=math.degrees(self.roll), centre=(0.0, 0.0, 0.0))
        return cam, pose


def head_reference(mesh) -> tuple[np.ndarray, float]:
    """Model-space head-frame origin (x, y) and scale (cm, origin to nostrils) of ``mesh``."""
    from synth.personalize import head_frame_points

    origin, nose = head_frame_points(mesh)
    return origin[:2].copy(), float(np.hypot(*(nose[:2] - origin[:2])))


def framing_from_head(head, origin_cm, scale_cm) -> Framing:
    """The similarity that puts the model's head frame onto an image head frame (x, y, s, r)."""
    hx, hy, hs, hr = (float(v) for v in head)
    k = hs / scale_cm
    T = np.array([hx, hy]) - k * _rot(hr) @ np.array([origin_cm[0], -origin_cm[1]])
    return Framing(k, hr, (float(T[0]), float(T[1])))


def transfer_head_motion(heads, source_neutral, target_neutral) -> np.ndarray:
    """Head frames (T, 4) of a target that moves as the source moves from its neutral frame.

    Translation, scale ratio and roll change of each source head frame (x, y, scale, roll)
    relative to ``source_neutral`` are applied to ``target_neutral``; translations are
    rotated and scaled into the target's frame.

    Examples
    --------
    >>> h = np.array([[100.0, 80.0, 50.0, 0.0], [110.0, 80.0, 55.0, 0.1]])
    >>> transfer_head_motion(h, h[0], np.array([40.0, 30.0, 25.0, 0.0])).round(3).tolist()
    [[40.0, 30.0, 25.0, 0.0], [45.0, 30.0, 27.5, 0.1]]
    """
    h = np.asarray(heads, dtype=float)
    s0 = np.asarray(source_neutral, dtype=float)
    t0 = np.asarray(target_neutral, dtype=float)
    k = t0[2] / s0[2]
    d = (h[:, :2] - s0[:2]) @ _rot(t0[3] - s0[3]).T * k
    return np.c_[t0[:2] + d, t0[2] * h[:, 2] / s0[2], t0[3] + (h[:, 3] - s0[3])]


# ----------------------------------------------------------------------------- subject
@dataclass
class SubjectInfo:
    """A personalised model and how it was made.

    Attributes
    ----------
    model : FaceModel
        The warped model.
    warp : synth.personalize.LandmarkWarp
    framing : Framing
        Model-to-image similarity of the subject's neutral frame (input pixels).
    image : (H, W, 3) uint8 RGB
        The neutral frame (the texture).
    fiducials : (11, 2)
        Neutral fiducials (input px).
    neutral_frame : int
    reference : tuple
        ``(origin_cm, scale_cm)`` of the generic model's head frame.
    """

    model: object
    warp: object
    framing: Framing
    image: np.ndarray
    fiducials: np.ndarray
    neutral_frame: int
    reference: tuple
    source: str = ""
    head: np.ndarray | None = None

    def uv(self) -> tuple[np.ndarray, np.ndarray]:
        """Texture coordinates of the skin and inner vertices in the neutral frame."""
        H, W = self.image.shape[:2]
        mesh = self.model.mesh
        skin = self.framing.apply(np.asarray(mesh.vertices))
        inner = self.framing.apply(np.asarray(mesh.inner_vertices)) \
            if len(mesh.inner_vertices) else np.zeros((0, 2))
        size = np.array([W, H], float)
        return (skin + 0.5) / size, (inner + 0.5) / size


def _read_frame(path: Path, index: int) -> np.ndarray:
    """Frame ``index`` of a video (RGB uint8)."""
    import cv2

    from faceanalysis.io.video import open_video, to_bgr_uint8

    with open_video(path, start=int(index), end=int(index) + 1) as src:
        for frame in src:
            if frame.ok:
                return cv2.cvtColor(to_bgr_uint8(frame.image), cv2.COLOR_BGR2RGB)
    raise ValueError(f"{path}: frame {index} could not be read")


def personalize(subject, *, model=None, kernel: str = "linear") -> SubjectInfo:
    """Warp ``model`` (the generic face by default) to the subject's neutral frame.

    Parameters
    ----------
    subject : Analysis, path of an analysis folder, or path of a video
        A video is analysed first (its first frame is the neutral one).
    model : FaceModel, optional
    kernel : {'linear', 'gaussian'}
        Radial basis of the warp (:func:`synth.personalize.fit_landmark_warp`).

    Returns
    -------
    SubjectInfo

    Raises
    ------
    ValueError
        The subject has no tracked fiducials or head frame, its video cannot be found, or
        the landmarks fold the warp.
    """
    series, video = _subject_series(subject)
    return _personalize_series(series, video, model=model, kernel=kernel)


def _personalize_series(series: _Series, video, *, model=None, kernel: str = "linear"
                        ) -> SubjectInfo:
    from synth.personalize import head_frame_points, personalize_model

    if series.fiducials is None or series.heads is None:
        raise ValueError("the subject's table has no fiducials or head frame columns")
    if model is None:
        from synth.model import FaceModel

        model = FaceModel.default()
    k = series.neutral_row
    fid = series.fiducials[k]
    if not np.isfinite(fid).all():
        raise ValueError(f"the subject's neutral frame {series.frames[k]} has no fiducials")
    if video is None or not Path(video).exists():
        raise ValueError(f"the subject's video {video} cannot be found (needed for the "
                         "texture); pass the video itself as the subject")
    origin_cm, scale_cm = head_reference(model.mesh)
    framing = framing_from_head(series.heads[k], origin_cm, scale_cm)
    lm = model.landmark_positions()
    src = np.array([lm[n] for n in FIDUCIALS], dtype=float)
    xy = framing.invert(fid)
    # depth is not observed: the model's, scaled by the subject's overall size in the image
    # plane (keeping depth unscaled where the face is narrower would tilt short muscles
    # such as the corrugator into the skull)
    A, *_ = np.linalg.lstsq(np.c_[src[:, :2], np.ones(len(src))], xy, rcond=None)
    depth_scale = float(np.sqrt(abs(np.linalg.det(A[:2]))))
    o3, n3 = head_frame_points(model.mesh)         # pinned: they define the framing
    source = np.vstack([src, o3, n3])
    target = np.vstack([np.c_[xy, depth_scale * src[:, 2]],
                        [o3[0], o3[1], depth_scale * o3[2]],
                        [n3[0], n3[1], depth_scale * n3[2]]])
    # the best 3-D affine map of the landmarks: the fallback when the full warp cannot
    # make a valid model (a fold, or a muscle left without tissue to pull)
    B, *_ = np.linalg.lstsq(np.c_[source, np.ones(len(source))], target, rcond=None)
    affine = np.c_[source, np.ones(len(source))] @ B
    personal = warp = None
    for alpha in (1.0, 0.75, 0.5, 0.25, 0.0):
        try:
            personal, warp = personalize_model(model, source, affine + alpha * (target - affine),
                                               kernel=kernel)
        except ValueError as exc:
            log.warning("personalisation: the landmark warp at %.0f%% gives no valid model "
                        "(%s); trying a smoother one", 100 * alpha, exc)
            continue
        if alpha < 1.0:
            log.warning("personalisation: the model follows the subject's landmarks at %.0f%% "
                        "only (see the landmark error in the report)", 100 * alpha)
        break
    if personal is None:
        raise ValueError("the subject's neutral fiducials cannot be fitted by the face model "
                         "(every warp, down to an affine one, failed)")
    image = _read_frame(Path(video), int(series.frames[k]))
    return SubjectInfo(model=personal, warp=warp, framing=framing, image=image,
                       fiducials=fid, neutral_frame=int(series.frames[k]),
                       reference=(origin_cm, scale_cm), source=str(video),
                       head=np.array(series.heads[k], dtype=float))


def _subject_series(subject) -> tuple[_Series, Path | None]:
    from faceanalysis.analysis.pipeline import Analysis, analyze

    if isinstance(subject, Analysis):
        s = _series_from_table(subject.table, "subject", subject.metadata)
        return s, s.input_path
    path = Path(subject)
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such subject video or analysis folder")
    if path.is_dir() and (path / "contractions.csv").is_file():
        s = _load_series(path)
        return s, s.input_path
    log.info("analysing the subject's first frame in %s", path)
    a = analyze(path, end=1)
    return _series_from_table(a.table, str(path), a.metadata), path


# ----------------------------------------------------------------------------- drawing
class _Wireframe:
    """Wireframe of the skin with the muscles drawn over it (004, Fig. 4)."""

    def __init__(self, model):
        from synth.muscles import uv_to_surface

        mesh = model.mesh
        self.tris = np.asarray(mesh.triangles, dtype=np.int64)
        n = len(mesh.vertices)
        eye = np.eye(n)
        self.names = list(model.muscle_names)
        self.parts = []     # per muscle: (kind, weight matrix (k, N), fixed points or None)
        for m in model.muscles.muscles:
            p = m.params
            if m.type == "linear":
                uv = np.array([p["head"], p["tail"]], float)
                self.parts.append(("line", uv_to_surface(mesh, uv, values=eye)))
            elif m.type == "sphincter":
                a, b = p["semi_axes"]
                ang = math.radians(p.get("angle", 0.0))
                t = np.linspace(0, 2 * np.pi, 25)
                e = np.c_[a * np.cos(t), b * np.sin(t)] @ _rot(ang).T + np.asarray(p["centre"])
                self.parts.append(("loop", uv_to_surface(mesh, e, values=eye)))
            else:
                (a1, a2), (i1, i2) = p["attachment"], p["insertion"]
                uv = np.array([a1, a2, i2, i1, a1], float)
                self.parts.append(("loop", uv_to_surface(mesh, uv, values=eye)))

    def draw(self, xy_skin: np.ndarray, contractions: np.ndarray, size) -> np.ndarray:
        import cv2

        W, H = size
        img = np.empty((H, W, 3), np.uint8)
        img[:] = (18, 22, 30)
        p = xy_skin[self.tris]
        a = p[:, 1] - p[:, 0]
        b = p[:, 2] - p[:, 0]
        front = -(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]) > 0
        sh = 4
        pts = np.round(p[front] * (1 << sh)).astype(np.int32)
        cv2.polylines(img, list(pts), True, (120, 150, 140), 1, cv2.LINE_AA, sh)
        for (kind, Wm), c in zip(self.parts, contractions):
            q = np.round((Wm @ xy_skin) * (1 << sh)).astype(np.int32)
            colour = (int(110 + 145 * c), int(60 * (1 - c)), int(60 * (1 - c)))
            thick = 1 + int(round(2 * c))
            cv2.polylines(img, [q], kind == "loop", colour, thick, cv2.LINE_AA, sh)
            if kind == "line":
                cv2.circle(img, tuple(int(v) for v in q[0]), 2 << sh, colour, -1,
                           cv2.LINE_AA, sh)
        return img


class _PlotStrip:
    """The contraction plot under a side-by-side video, with a moving cursor."""

    def __init__(self, times, controls, jaw, width: int, height: int):
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure

        series = {MUSCLES[j]: controls[:, j] for j in range(controls.shape[1])}
        series[JAW + " (x2, rad)"] = 2 * jaw
        active = sorted(((float(np.nanmax(v)), k) for k, v in series.items()
                         if np.nanmax(v) > 0.02), reverse=True)[:6]
        dpi = 100
        fig = Figure(figsize=(width / dpi, height / dpi), dpi=dpi)
        FigureCanvasAgg(fig)      # an off-screen canvas: the global backend stays as it is
        ax = fig.add_axes((0.06, 0.26, 0.68, 0.68))
        for _, k in active:
            ax.plot(times, series[k], lw=1.2, label=k)
        ax.set_xlim(times[0], times[-1] if times[-1] > times[0] else times[0] + 1)
        ax.set_ylim(0, 1.02)
        ax.tick_params(labelsize=6)
        ax.set_xlabel("time (s)", fontsize=7, labelpad=1)
        if active:
            ax.legend(fontsize=6, loc="upper left", bbox_to_anchor=(1.01, 1.05), frameon=False,
                      labelspacing=0.2, handlelength=1.2)
        fig.canvas.draw()
        self.image = np.asarray(fig.canvas.buffer_rgba())[..., :3].copy()
        bbox = ax.get_window_extent()
        self.y0 = int(round(height - bbox.y1))
        self.y1 = int(round(height - bbox.y0))
        self.xs = ax.transData.transform(np.c_[times, np.zeros_like(times)])[:, 0]

    def frame(self, i: int) -> np.ndarray:
        import cv2

        img = self.image.copy()
        x = int(round(self.xs[i]))
        cv2.line(img, (x, self.y0), (x, self.y1), (200, 30, 30), 1)
        return img


# ----------------------------------------------------------------------------- main
@dataclass
class FrameState:
    """One resynthesised frame: the image and the geometry behind it."""

    row: int
    frame: int
    image: np.ndarray                 # (H, W, 3) uint8 RGB, the resynthesis
    output: np.ndarray                # what the video gets (side by side when asked)
    vertices: np.ndarray              # (N, 3) skin, model cm
    inner: np.ndarray                 # (P, 3)
    fiducials: np.ndarray             # (11, 2) projected, output px
    seconds: float                    # equilibrium + rendering time
    photometric_mae: float | None = None  # vs the input frame (personalised, side by side)


class Resynthesis:
    """A configured resynthesis: iterate for frames (RGB uint8), or :meth:`write` a video.

    Made by :func:`resynthesize`; see there for the parameters.

    Attributes
    ----------
    model : FaceModel
        The model driven (personalised when a subject was given).
    subject : SubjectInfo or None
    fps : float
    size : (width, height)
        Size of the resynthesised frames (the side-by-side video is wider and taller).
    missing : tuple of str
        Muscles absent from the table (driven at 0).
    report : dict
        Personalisation figures (landmark error, photometric comparison) and, after a run,
        timings.
    path : Path or None
        The video written (after :meth:`write`).
    """

    def __init__(self, series: _Series, *, model, subject: SubjectInfo | None, size, view,
                 shading, fps, side_by_side, input_video, tol):
        self.series = series
        self.subject = subject
        self.model = subject.model if subject is not None else model
        self.view = view
        self.shading = shading
        self.fps = series.fps(fps)
        self.side_by_side = side_by_side
        self.tol = float(tol)
        self.missing = series.missing
        self.path: Path | None = None
        self.report: dict = {}
        in_size = series.input_size
        if subject is not None:
            in_size = (subject.image.shape[1], subject.image.shape[0])
        self.input_size = in_size
        # output size
        if size is None:
            size = (in_size[0] if in_size is not None and view == "front" else 256)
        if isinstance(size, (int, np.integer)):
            if in_size is not None and view == "front":
                w = int(size)
                h = max(16, int(round(size * in_size[1] / in_size[0])))
            else:
                w = h = int(size)
        else:
            w, h = (int(v) for v in size)
        if w < 16 or h < 16:
            raise ValueError(f"size {w}x{h} must be at least 16x16")
        self.size = (w, h)
        # framing: from the head frames when we know the input's size
        self._framings = None
        if view == "front" and series.heads is not None and in_size is not None:
            heads = series.heads
            if subject is not None:
                origin_cm, scale_cm = subject.reference
                if subject.head is not None and series.success.any():
                    # the source's head motion, relative to its neutral frame, applied to
                    # the subject's neutral head frame (the identity when the subject is the
                    # source's own neutral frame; expression transfer otherwise)
                    heads = transfer_head_motion(heads, heads[series.neutral_row],
                                                 subject.head)
            else:
                origin_cm, scale_cm = head_reference(self.model.mesh)
            f = w / in_size[0]
            self._framings = [framing_from_head(h_, origin_cm, scale_cm).scaled(f)
                              for h_ in heads]
        self.input_video = input_video
        if side_by_side and self.input_video is None:
            self.input_video = (Path(subject.source) if subject is not None and subject.source
                                else series.input_path)
        if side_by_side and (self.input_video is None or not Path(self.input_video).exists()):
            raise ValueError("side_by_side needs the input video: pass input_video (--input) "
                             f"or a source whose analysis.json names it (got "
                             f"{self.input_video})")
        self._renderer = None
        self._wire = None
        self.texture_seed = 0
        self._order = [MUSCLES.index(m) for m in self.model.muscle_names]
        self._background = None
        if subject is not None:
            self.report["personalisation"] = self._personal_report()
            if shading == "textured" and self._framings is not None:
                # the rest of the subject's head (hair, ears, neck) and the scene: the
                # neutral frame, moved with the tracked head frame
                import cv2

                f = w / in_size[0]
                img = cv2.resize(subject.image, (w, h), interpolation=cv2.INTER_AREA)
                self._background = (img, subject.framing.scaled(f))

    # -------------------------------------------------------------- rendering setup
    def _fixed_camera(self):
        from synth.render import HeadPose, default_camera

        w, h = self.size
        cam = default_camera(w, h)
        pose = HeadPose(yaw=VIEWS[self.view], centre=(0.0, -1.6, -1.5))
        return cam, pose

    def _camera_pose(self, row: int):
        if self._framings is not None:
            return self._framings[row].camera_pose(*self.size)
        return self._fixed_camera()

    def _make_renderer(self):
        from synth.render import Renderer, Surface
        from synth.render.shading import Light

        mesh = self.model.mesh
        if self.shading == "wireframe":
            self._wire = _Wireframe(self.model)
            return None
        if self.shading == "plain":
            return Renderer(mesh, camera=self._fixed_camera()[0], supersample=1)
        if self.subject is not None:
            uv, inner_uv = self.subject.uv()
            surf = Surface(vertices=np.asarray(mesh.vertices), triangles=mesh.triangles,
                           uv=np.clip(uv, 0.0, 1.0), inner_vertices=mesh.inner_vertices,
                           inner_triangles=mesh.inner_triangles,
                           inner_material=mesh.inner_material,
                           inner_uv=np.clip(inner_uv, 0.0, 1.0))
            # the photograph already holds the light: render it unlit
            unlit = Light(colour=(1.0, 1.0, 1.0), ambient=1.0, specular_scale=0.0)
            return Renderer(surf, texture=self.subject.image, eye_tex=self.subject.image,
                            camera=self._fixed_camera()[0], light=unlit, supersample=1)
        from synth.render import paint_skin_texture

        tex = paint_skin_texture(mesh, self.texture_seed, size=512)
        return Renderer(mesh, texture=tex, camera=self._fixed_camera()[0], supersample=1)

    def _render(self, skin, inner, row: int, contractions):
        """(image, projected skin xy, skin mask or None) of one frame."""
        from synth.render.camera import project

        cam, pose = self._camera_pose(row)
        if self.shading == "wireframe":
            xy, _ = project(skin, cam, pose)
            return self._wire.draw(xy, contractions, self.size), xy, None
        self._renderer.camera = cam
        res = self._renderer.render(skin, inner, pose=pose)
        image = res.image
        if self._background is not None:
            image = np.where(res.mask[..., None], image, self._moved_background(row))
        return image, res.xy[: len(skin)], res.skin_mask

    def _moved_background(self, row: int) -> np.ndarray:
        """The subject's neutral frame moved by the head motion from neutral to ``row``."""
        import cv2

        img, f0 = self._background
        fi = self._framings[row]
        M = (fi.k / f0.k) * _rot(fi.roll) @ _rot(f0.roll).T
        t = np.asarray(fi.T) - M @ np.asarray(f0.T)
        w, h = self.size
        return cv2.warpAffine(img, np.c_[M, t], (w, h), flags=cv2.INTER_LINEAR,
                              borderMode=cv2.BORDER_REPLICATE)

    def _personal_report(self) -> dict:
        """Landmark error and photometric comparison of the personalised neutral frame."""
        import cv2

        subj = self.subject
        m = self.model
        m.reset()
        m.set_contractions(None)
        m.equilibrate()
        lm = m.landmark_positions()
        pred = subj.framing.apply(np.array([lm[n] for n in FIDUCIALS]))
        err = np.hypot(*(pred - subj.fiducials).T)
        from synth.render import Renderer, Surface
        from synth.render.shading import Light

        H, W = subj.image.shape[:2]
        cam, pose = subj.framing.camera_pose(W, H)
        uv, inner_uv = subj.uv()
        mesh = m.mesh
        surf = Surface(vertices=np.asarray(mesh.vertices), triangles=mesh.triangles,
                       uv=np.clip(uv, 0, 1), inner_vertices=mesh.inner_vertices,
                       inner_triangles=mesh.inner_triangles, inner_material=mesh.inner_material,
                       inner_uv=np.clip(inner_uv, 0, 1))
        r = Renderer(surf, texture=subj.image, eye_tex=subj.image, camera=cam,
                     light=Light(ambient=1.0, specular_scale=0.0))
        res = r.render(m.surface_vertices, m.inner_vertices(), pose=pose)
        mask = cv2.erode(res.skin_mask.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
        a = cv2.cvtColor(res.image, cv2.COLOR_RGB2GRAY).astype(float)[mask]
        b = cv2.cvtColor(subj.image, cv2.COLOR_RGB2GRAY).astype(float)[mask]
        ncc = float(np.corrcoef(a, b)[0, 1]) if a.size > 2 and a.std() > 0 and b.std() > 0 \
            else None
        m.reset()
        return {
            "neutral_frame": subj.neutral_frame,
            "landmark_error_px": {"mean": float(err.mean()), "max": float(err.max()),
                                  "by_point": {n: float(e) for n, e in zip(FIDUCIALS, err)}},
            "photometric": {"mask_pixels": int(mask.sum()),
                            "mae_grey": float(np.abs(a - b).mean()) if a.size else None,
                            "rmse_grey": float(np.sqrt(np.mean((a - b) ** 2))) if a.size
                            else None, "ncc": ncc},
            "warp": {"landmarks": len(subj.warp.source), "kernel": subj.warp.kernel},
        }

    # -------------------------------------------------------------- iteration
    def states(self, *, progress: bool = False):
        """Iterate :class:`FrameState` objects (equilibrium and rendering of every frame)."""
        s = self.series
        m = self.model
        if self._renderer is None and self._wire is None:
            self._renderer = self._make_renderer()
        m.reset()
        strip = None
        inputs = None
        if self.side_by_side:
            times = s.timestamps if np.isfinite(s.timestamps).all() else s.frames / self.fps
            w, h = self.size
            strip = _PlotStrip(times, s.controls, s.jaw, 2 * w, max(80, int(0.45 * h)))
            inputs = _input_frames(Path(self.input_video), s.frames, self.size)
        bar = None
        if progress:
            from tqdm import tqdm

            bar = tqdm(total=len(s.frames), desc="resynth", unit="frame", file=sys.stderr,
                       leave=False, dynamic_ncols=True)
        prev = None
        lm_idx = [m.mesh.landmarks[n] for n in FIDUCIALS]
        compare = (self.subject is not None and self.shading == "textured"
                   and self._framings is not None)
        try:
            for i in range(len(s.frames)):
                t0 = time.perf_counter()
                values = s.controls[i, self._order]
                jaw = float(s.jaw[i])
                key = (values.tobytes(), jaw)
                if key != prev:
                    m.set_contractions(values, jaw_rotation=jaw)
                    m.equilibrate(tol=self.tol)
                    prev = key
                skin = m.surface_vertices
                inner = m.inner_vertices()
                image, xy, mask = self._render(skin, inner, i, values)
                seconds = time.perf_counter() - t0
                out = image
                mae = None
                if self.side_by_side:
                    frame_in = next(inputs)
                    out = np.concatenate([np.concatenate([frame_in, image], axis=1),
                                          strip.frame(i)], axis=0)
                    if compare and s.success[i]:
                        mae = _masked_mae(frame_in, image, mask)
                if bar is not None:
                    bar.update(1)
                yield FrameState(row=i, frame=int(s.frames[i]), image=image, output=out,
                                 vertices=skin, inner=inner, fiducials=xy[lm_idx],
                                 seconds=seconds, photometric_mae=mae)
        finally:
            if bar is not None:
                bar.close()
            if inputs is not None:
                inputs.close()

    def __iter__(self):
        for st in self.states():
            yield st.output

    def __len__(self) -> int:
        return len(self.series.frames)

    def write(self, output, *, export_meshes=None, mesh_format: str = "obj",
              overwrite: bool = False, progress: bool = False) -> Path:
        """Write the video (atomically) and, optionally, the meshes; returns the video path.

        Raises
        ------
        FileExistsError
            ``output`` (or a non-empty ``export_meshes`` folder / file) exists and
            ``overwrite`` is false.
        """
        import cv2

        from faceanalysis.io.video_writer import VideoWriter

        output = Path(output)
        if output.exists() and not overwrite:
            raise FileExistsError(f"{output} exists; pass --overwrite to replace it")
        exporter = _MeshExporter(export_meshes, mesh_format, self.model, overwrite,
                                 self.subject) if export_meshes is not None else None
        t0 = time.perf_counter()
        times = []
        maes = []
        writer = None
        try:
            for st in self.states(progress=progress):
                if writer is None:
                    h, w = st.output.shape[:2]
                    writer = VideoWriter(output, self.fps, (w, h))
                writer.write(cv2.cvtColor(st.output, cv2.COLOR_RGB2BGR))
                times.append(st.seconds)
                if st.photometric_mae is not None:
                    maes.append(st.photometric_mae)
                if exporter is not None:
                    exporter.add(st, self.model)
            self.path = writer.close()
            writer = None
            if exporter is not None:
                self.report["meshes"] = str(exporter.finish(self.series))
        finally:
            if writer is not None:
                writer.abort()
            if exporter is not None:
                exporter.abort()
        if maes:
            self.report["frame_comparison"] = {
                "what": "mean absolute grey-level difference between the input frame and the "
                        "personalised resynthesis on the face mask, tracked frames",
                "frames": len(maes), "mean_mae_grey": float(np.mean(maes)),
                "max_mae_grey": float(np.max(maes))}
        self.report["timing"] = {"frames": len(times), "total_s": time.perf_counter() - t0,
                                 "median_frame_s": float(np.median(times)) if times else None,
                                 "frames_per_second": float(1.0 / np.median(times))
                                 if times else None}
        return self.path


def _masked_mae(a: np.ndarray, b: np.ndarray, mask) -> float | None:
    """Mean absolute grey difference of two RGB images on ``mask`` (eroded by one pixel)."""
    import cv2

    if mask is None:
        return None
    m = cv2.erode(mask.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
    if not m.any():
        return None
    ga = cv2.cvtColor(a, cv2.COLOR_RGB2GRAY).astype(float)
    gb = cv2.cvtColor(b, cv2.COLOR_RGB2GRAY).astype(float)
    return float(np.abs(ga - gb)[m].mean())


def _input_frames(path: Path, frames: np.ndarray, size):
    """Input frames (RGB, resized to ``size``) in step with the table's frame numbers."""
    import cv2

    from faceanalysis.io.video import open_video, to_bgr_uint8

    w, h = size
    blank = np.full((h, w, 3), 60, np.uint8)
    with open_video(path, start=int(frames[0]), end=int(frames[-1]) + 1) as src:
        it = iter(src)
        cur = next(it, None)
        for f in frames:
            while cur is not None and cur.index < f:
                cur = next(it, None)
            if cur is not None and cur.index == f and cur.ok:
                img = cv2.cvtColor(to_bgr_uint8(cur.image), cv2.COLOR_BGR2RGB)
                yield cv2.resize(img, (w, h), interpolation=cv2.INTER_AREA)
            else:
                yield blank


class _MeshExporter:
    """Per-frame OBJ/PLY files in a folder, or one ``.npz`` of vertex trajectories."""

    def __init__(self, target, fmt: str, model, overwrite: bool,
                 subject: SubjectInfo | None = None):
        if fmt not in MESH_FORMATS:
            raise ValueError(f"unknown mesh format {fmt!r}; choose from {', '.join(MESH_FORMATS)}")
        self.target = Path(target)
        self.npz = self.target.suffix.lower() == ".npz"
        self.fmt = fmt
        self.model_mesh = model.mesh
        self.written: list[Path] = []
        self.vertices: list[np.ndarray] = []
        self.inner: list[np.ndarray] = []
        self.frames: list[int] = []
        self.subject_uv = subject.uv()[0] if subject is not None else None
        if self.npz:
            if self.target.exists() and not overwrite:
                raise FileExistsError(f"{self.target} exists; pass --overwrite to replace it")
        else:
            from faceanalysis.io.outputs import prepare_output_dir

            prepare_output_dir(self.target, overwrite=overwrite)
            if subject is not None and fmt == "obj":
                self._write_material(subject)

    def _write_material(self, subject: SubjectInfo) -> None:
        """The subject's neutral frame as the texture of the OBJ files (``subject.mtl``)."""
        import cv2

        from faceanalysis.io.outputs import atomic_path, write_text_atomic

        with atomic_path(self.target / "subject_texture.png") as tmp:
            if not cv2.imwrite(str(tmp), cv2.cvtColor(subject.image, cv2.COLOR_RGB2BGR)):
                raise ValueError(f"could not write {self.target / 'subject_texture.png'}")
        write_text_atomic(self.target / "subject.mtl",
                          "newmtl skin\nKa 1 1 1\nKd 1 1 1\nKs 0 0 0\n"
                          "map_Kd subject_texture.png\n")

    def _write_obj(self, path: Path, vertices: np.ndarray) -> None:
        """OBJ of the skin with the subject's texture coordinates (neutral-frame projection)."""
        from faceanalysis.io.outputs import write_text_atomic

        mesh = self.model_mesh
        t = np.asarray(mesh.triangles) + 1
        uv = self.subject_uv
        lines = ["# faceanalysis resynthesis, personalised skin (cm; x = subject's left, "
                 "y = up, z = toward the viewer)", "mtllib subject.mtl"]
        lines += [f"v {a:.6f} {b:.6f} {c:.6f}" for a, b, c in vertices]
        lines += [f"vt {a:.6f} {1.0 - b:.6f}" for a, b in uv]
        lines.append("usemtl skin")
        lines += [f"f {a}/{a} {b}/{b} {c}/{c}" for a, b, c in t]
        write_text_atomic(path, "\n".join(lines) + "\n")

    def add(self, st: FrameState, model) -> None:
        self.frames.append(st.frame)
        if self.npz:
            self.vertices.append(st.vertices.astype(np.float32))
            self.inner.append(np.asarray(st.inner, np.float32))
            return
        path = self.target / f"frame_{st.frame:06d}.{self.fmt}"
        if self.fmt == "obj" and self.subject_uv is not None:
            self._write_obj(path, st.vertices)
        else:
            (model.to_obj if self.fmt == "obj" else model.to_ply)(path)
        self.written.append(path)

    def finish(self, series: _Series) -> Path:
        if not self.npz:
            return self.target
        from faceanalysis.io.outputs import atomic_path

        mesh = self.model_mesh
        with atomic_path(self.target) as tmp, open(tmp, "wb") as fh:
            np.savez_compressed(
                fh, vertices=np.stack(self.vertices), inner_vertices=np.stack(self.inner),
                triangles=np.asarray(mesh.triangles, np.int32),
                inner_triangles=np.asarray(mesh.inner_triangles, np.int32),
                uv=np.asarray(mesh.uv, np.float32), frames=np.asarray(self.frames),
                timestamps=series.timestamps[: len(self.frames)],
                units=np.array("cm; x = subject's left, y = up, z = toward the viewer"),
                **({} if self.subject_uv is None else
                   {"subject_uv": self.subject_uv.astype(np.float32)}))
        return self.target

    def abort(self) -> None:
        self.vertices.clear()
        self.inner.clear()


def resynthesize(source, *, model=None, subject=None, size=None, view: str = "front",
                 shading: str = "textured", fps: float | None = None,
                 side_by_side: bool = False, output=None, export_meshes=None,
                 mesh_format: str = "obj", input_video=None, overwrite: bool = False,
                 tol: float = 2e-3, texture_seed: int = 0, progress: bool = False
                 ) -> Resynthesis:
    """Drive the face model with a contraction time series and render it (004, Fig. 7c).

    Parameters
    ----------
    source : Analysis, DataFrame or path
        The time series: an :class:`~faceanalysis.analysis.pipeline.Analysis`, an analysis folder,
        a ``contractions.csv`` (all columns, validated by
        :func:`faceanalysis.io.table.read_contractions`, or a partial table holding some muscle
        columns and/or ``jaw_rotation``; missing muscles are driven at 0 with a warning
        that lists them), or a DataFrame of such columns. Rows with ``success == 0`` hold
        the last good contractions.
    model : FaceModel, optional
        Model to drive (default: the generic face).
    subject : Analysis or path, optional
        Personalise: warp the model to this subject's neutral frame (an analysis folder or
        a video) and texture it with that frame (see the module docstring).
    size : int or (width, height), optional
        Frame width (the height follows the input's aspect ratio in the input's framing),
        or an explicit size. Default: the input's size in the front view when the source
        knows it (the analysis's own scale), else 256.
    view : {'front', 'three-quarter', 'profile'}
    shading : {'textured', 'plain', 'wireframe'}
        ``wireframe`` draws the skin mesh and the muscles (004, Fig. 4), redder and thicker
        with contraction.
    fps : float, optional
        Output frame rate (default: the source's).
    side_by_side : bool
        Input frame and resynthesis side by side, the contraction plot with a cursor below.
    output : path, optional
        Write the video here (atomically) before returning.
    export_meshes : path, optional
        Folder for one mesh per frame (``mesh_format``), or a ``.npz`` file of vertex
        trajectories (``vertices`` (T, N, 3) cm, ``triangles``, ``uv``, ``frames``...).
    mesh_format : {'obj', 'ply'}
    input_video : path, optional
        The input video (side by side); default: the subject's video or the one named in
        ``analysis.json``.
    overwrite : bool
        Replace existing outputs.
    texture_seed : int
        Identity seed of the procedural skin texture (:func:`synth.render.paint_skin_texture`)
        of the ``textured`` shading without a subject.
    tol : float
        Equilibrium tolerance in cm (largest solver update; at 2e-3 cm the vertices of the
        256 px frontal view are within ~0.05 px of the converged equilibrium on average).
    progress : bool
        Progress bar on stderr.

    Returns
    -------
    Resynthesis
        Iterable of RGB ``uint8`` frames; ``.path`` is the video when ``output`` was given,
        ``.report`` holds personalisation figures and timings.

    Raises
    ------
    ValueError
        Bad options, a non-numeric cell or a value outside its range (row and column named).
    FileNotFoundError
        Missing source, subject or video.
    FileExistsError
        Outputs exist and ``overwrite`` is false.

    Examples
    --------
    >>> import pandas as pd
    >>> drive = pd.DataFrame({"zygomaticus_major_l": [0.0, 0.5], "zygomaticus_major_r": [0.0, 0.5]})
    >>> frames = list(resynthesize(drive, size=64, shading="plain"))
    >>> len(frames), frames[0].shape
    (2, (64, 64, 3))
    """
    if view not in VIEWS:
        raise ValueError(f"unknown view {view!r}; choose from {', '.join(VIEWS)}")
    if shading not in SHADINGS:
        raise ValueError(f"unknown shading {shading!r}; choose from {', '.join(SHADINGS)}")
    if mesh_format not in MESH_FORMATS:
        raise ValueError(f"unknown mesh format {mesh_format!r}; choose from "
                         f"{', '.join(MESH_FORMATS)}")
    if fps is not None and not (np.isfinite(fps) and fps > 0):
        raise ValueError(f"fps must be a positive number, got {fps!r}")
    if not (np.isfinite(tol) and tol > 0):
        raise ValueError(f"tol must be a positive number, got {tol!r}")
    if isinstance(texture_seed, bool) or not isinstance(texture_seed, (int, np.integer)) \
            or texture_seed < 0:
        raise ValueError(f"texture_seed must be a non-negative integer, got {texture_seed!r}")
    if output is not None and Path(output).exists() and not overwrite:
        raise FileExistsError(f"{output} exists; pass --overwrite to replace it")
    series = _load_series(source)
    if series.missing and len(series.missing) < len(MUSCLES):
        log.warning("muscles missing from the table, driven at 0: %s", ", ".join(series.missing))
    elif series.missing:
        log.warning("no muscle columns in the table: only %s drives the model", JAW)
    if model is None:
        from synth.model import FaceModel

        model = FaceModel.default()
    unknown = [m for m in model.muscle_names if m not in MUSCLES]
    if unknown:
        raise ValueError(f"the model has muscles the table format does not know: {unknown}")
    subj = None
    if isinstance(subject, SubjectInfo):
        subj = subject
    elif subject is not None:
        same = (isinstance(subject, (str, os.PathLike)) and Path(subject).is_file()
                and series.input_path is not None and series.input_path.exists()
                and series.input_path.resolve() == Path(subject).resolve())
        # the subject is the video the source analysed: its neutral frame is already tracked
        subj = (_personalize_series(series, Path(subject), model=model) if same
                else personalize(subject, model=model))
    res = Resynthesis(series, model=model, subject=subj, size=size, view=view, shading=shading,
                      fps=fps, side_by_side=side_by_side, input_video=input_video, tol=tol)
    res.texture_seed = int(texture_seed)
    if output is not None:
        res.write(output, export_meshes=export_meshes, mesh_format=mesh_format,
                  overwrite=overwrite, progress=progress)
    elif export_meshes is not None:
        exporter = _MeshExporter(export_meshes, mesh_format, res.model, overwrite, subj)
        for st in res.states(progress=progress):
            exporter.add(st, res.model)
        res.report["meshes"] = str(exporter.finish(series))
    return res


# ----------------------------------------------------------------------------- round trip
def round_trip(cases, *, frames: int = 30, size: int = 256, head_motion: float = 0.0,
               noise: float = 0.0, illumination: float = 0.0, personalised: bool = False,
               analysis_options: dict | None = None, workdir=None) -> pd.DataFrame:
    """Render known contractions, analyse, resynthesise; score the resynthesised fiducials.

    For every ``(identity, expression)``: the face of identity seed ``identity`` renders the
    expression (:func:`synth.render.synthesize`), the video is analysed
    (:func:`faceanalysis.analysis.pipeline.analyze`), and the estimated series drives the same
    identity's model (or, with ``personalised``, the generic model warped onto the neutral
    frame) framed by the tracked head frames. The score is the distance between the
    resynthesised fiducials and the ground-truth projected fiducials.

    Returns
    -------
    DataFrame
        One row per case: ``identity``, ``expression``, ``frames``,
        ``fiducial_error_px`` (mean over frames and the visible fiducials),
        ``fiducial_error_max_px``, ``apex_error_px`` (mean at the frame of largest motion).
    """
    import tempfile

    from faceanalysis.analysis.pipeline import analyze
    from synth.mesh import FaceShape
    from synth.model import FaceModel
    from synth.render.sequence import render_sequence

    options = ({"tracker_options": {"brow_mid": 0.556}} if analysis_options is None
               else dict(analysis_options))
    rows = []
    with tempfile.TemporaryDirectory(dir=workdir) as tmp:
        for identity, expression in cases:
            d = Path(tmp) / f"id{identity}_{expression}"
            kwargs = ({"expression": expression} if not str(expression)[:1].isdigit()
                      else {"au": expression})
            files = render_sequence(d, frames=frames, size=size, seed=int(identity),
                                    head_motion=head_motion, noise=noise,
                                    illumination=illumination, flow=False, **kwargs)
            truth = pd.read_csv(files["truth"])
            a = analyze(files["video"], **options)
            if personalised:
                res = resynthesize(a, subject=a, size=size, shading="wireframe")
            else:
                model = FaceModel.build(FaceShape.random(int(identity)))
                res = resynthesize(a, model=model, size=size, shading="wireframe",
                                   texture_seed=int(identity))
            err = []
            for st in res.states():
                row = truth.loc[truth["frame"] == st.frame]
                if row.empty or not a.table["success"].iloc[st.row]:
                    continue
                r = row.iloc[0]
                t = np.array([[r[f"fid_{n}_x"], r[f"fid_{n}_y"]] for n in FIDUCIALS])
                vis = np.array([bool(r.get(f"fid_{n}_visible", 1)) for n in FIDUCIALS])
                e = np.hypot(*(st.fiducials - t).T)
                err.append(np.where(vis, e, np.nan))
            err = np.array(err)
            truth_fid = np.stack([truth[[f"fid_{n}_x", f"fid_{n}_y"]].to_numpy(float)
                                  for n in FIDUCIALS], axis=1)
            motion = np.hypot(*(truth_fid - truth_fid[:1]).transpose(2, 0, 1)).mean(axis=1)
            apex = int(np.argmax(motion[: len(err)])) if len(err) else 0
            rows.append({"identity": int(identity), "expression": str(expression),
                         "frames": int(len(err)),
                         "fiducial_error_px": float(np.nanmean(err)) if len(err) else np.nan,
                         "fiducial_error_max_px": float(np.nanmax(err)) if len(err) else np.nan,
                         "apex_error_px": float(np.nanmean(err[apex])) if len(err) else np.nan,
                         "truth_motion_apex_px": float(motion[apex]),
                         **({"landmark_error_px": res.report["personalisation"]
                             ["landmark_error_px"]["mean"]}
                            if personalised and "personalisation" in res.report else {})})
    return pd.DataFrame(rows)
