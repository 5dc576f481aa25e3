"""Synthetic face video with exact ground truth: contractions -> model -> renderer -> files.

:func:`synthesize` drives a face model with a contraction time series (an expression with
timing, an AU script or a ``contractions.csv``), moves the head, changes the light, adds
sensor blur and noise, and keeps everything the renderer knows. :func:`write_sequence`
stores it in an output folder:

- ``video.mp4`` (OpenCV ``mp4v``; ``video.avi``/MJPG when that codec is missing, noted in
  ``meta.json`` and logged);
- ``truth.csv``: one row per frame in the column names of ``contractions.csv``: ``frame,
  timestamp, success (=1), confidence (=1), head_x, head_y, head_scale, head_roll``,
  ``fid_<name>_x, fid_<name>_y, fid_<name>_visible`` for the 11 fiducials, one column per
  muscle, ``jaw_rotation`` and, where :mod:`synth.facs` offers ``muscles_to_aus``, the
  ``AUxx_r`` intensities;
- ``flow.npz`` (compressed, byte-for-byte deterministic): ``flow`` (T-1, H, W, 2) forward
  flow from frame t to t+1 in px, ``occluded`` (T-1, H, W) in frame t, ``disoccluded``
  (T-1, H, W) in frame t+1, ``mask`` (T, H, W) face pixels, ``skin_mask`` (T, H, W),
  ``depth`` (T, H, W) float32 cm from the camera plane (inf on the background);
- ``meta.json``: camera, identity (face shape, texture parameters), seed, source of the
  contractions, per-frame head poses and lights, degradations, versions.

The head reference frame of ``truth.csv`` is defined in :mod:`synth.render.groundtruth`
(rigid head: origin at the arc-length centroid of the hairline, scale = px from the origin
to the nostrils, roll in radians, clockwise on screen; as the trackers define it).
Everything is deterministic per seed: identity shape and texture, head motion,
illumination and sensor noise.
"""

from __future__ import annotations

import difflib
import io
import json
import logging
import math
import os
import re
import sys
import zipfile
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
import pandas as pd

from synth.files import prepare_output_dir, write_bytes_atomic, write_text_atomic
from synth.render.appearance import background_flow
from synth.render.camera import HeadPose, default_camera
from synth.render.groundtruth import FIDUCIALS, flow_and_occlusion, head_frame, project_landmarks
from synth.render.renderer import Renderer
from synth.render.shading import Light
from synth.render.texture import paint_skin_texture, texture_params
from synth.render.video import VideoWriter

__all__ = ["SyntheticSequence", "synthesize", "write_sequence", "render_sequence",
           "contraction_timeline", "parse_au_string", "head_motion_track",
           "illumination_track", "write_npz_deterministic"]

log = logging.getLogger(__name__)


# ---------------------------------------------------------------------------- timelines
def parse_au_string(text: str) -> dict[int, float]:
    """Parse an AU script ``"12:0.8,6:0.5"`` into ``{12: 0.8, 6: 0.5}``.

    Intensities are contraction-scale activations in [0, 1].

    Examples
    --------
    >>> parse_au_string("12:0.8, 6:0.5")
    {12: 0.8, 6: 0.5}
    """
    if not isinstance(text, str) or not text.strip():
        raise ValueError("AU script must be a non-empty string like '12:0.8,6:0.5'")
    out: dict[int, float] = {}
    for part in text.split(","):
        m = re.fullmatch(r"\s*(?:AU)?(\d+)\s*:\s*([-+0-9.eE]+)\s*", part)
        if not m:
            raise ValueError(f"AU script item {part.strip()!r} is not 'AU:intensity' "
                             "(e.g. '12:0.8')")
        au, val = int(m.group(1)), float(m.group(2))
        if not 0.0 <= val <= 1.0:
            raise ValueError(f"AU{au:02d} intensity {val} must be in [0, 1]")
        out[au] = val
    return out


def _missing_message(path, df: pd.DataFrame, column: str, bad: np.ndarray) -> str:
    """One line naming the rows of ``column`` that are empty or not numbers; for an
    analysis's table, whose lost frames are empty, it names them as frames and points to
    ``resynth``, which renders an analysis and holds its lost frames."""
    rows = np.flatnonzero(bad)
    frames = pd.to_numeric(df["frame"], errors="coerce") if "frame" in df.columns else None
    lost = ("success" in df.columns
            and (pd.to_numeric(df["success"], errors="coerce").iloc[rows] == 0).all())
    if frames is not None and frames.iloc[rows].notna().all():
        where = "frame"
        shown = frames.iloc[rows].astype(int).tolist()
    else:
        where = "data row"
        shown = (rows + 1).tolist()
    listed = ", ".join(str(v) for v in shown[:5]) + (f" and {len(shown) - 5} more"
                                                     if len(shown) > 5 else "")
    text = (f"{path}: column {column} is empty or not a number on {len(rows)} "
            f"{where}{'s' if len(rows) != 1 else ''} ({listed}); every row is rendered")
    if lost:
        text += (" (these are an analysis's lost frames, success = 0: 'faceanalysis resynth' "
                 "renders an analysis, holding its lost frames)")
    return text


def _read_contractions_csv(path, muscle_names) -> pd.DataFrame:
    p = Path(path)
    if not p.is_file():
        raise FileNotFoundError(f"contractions file {p} does not exist")
    df = pd.read_csv(p)
    cols = [c for c in muscle_names if c in df.columns]
    known = {*muscle_names, "jaw_rotation"}
    for c in df.columns:
        # a misspelt muscle would be rendered at rest without a word; other columns (an
        # analysis's head, fiducials, AUs, notes) are not contractions and are left alone
        near = difflib.get_close_matches(str(c), sorted(known), n=1, cutoff=0.85)
        if c not in known and near:
            raise ValueError(f"{p}: column {c!r} is not a control of the face model (did you "
                             f"mean {near[0]!r}?)")
    if not cols and "jaw_rotation" not in df.columns:
        raise ValueError(f"{p}: no muscle columns (expected names like "
                         f"{', '.join(list(muscle_names)[:3])}, ...) and no jaw_rotation")
    out = pd.DataFrame(0.0, index=range(len(df)), columns=[*muscle_names, "jaw_rotation"])
    for c in [*cols, "jaw_rotation"]:
        if c in df.columns:
            v = pd.to_numeric(df[c], errors="coerce").to_numpy(float)
            if not np.all(np.isfinite(v)):
                raise ValueError(_missing_message(p, df, c, ~np.isfinite(v)))
            if c != "jaw_rotation" and (v.min() < 0 or v.max() > 1):
                raise ValueError(f"{p}: column {c} has contractions outside [0, 1]")
            out[c] = v
    if len(out) < 1:
        raise ValueError(f"{p} holds no rows")
    return out


def contraction_timeline(muscle_names, *, expression: str | None = None, au=None,
                         contractions=None, frames: int | None = 60, fps: float = 30.0,
                         intensity: float = 1.0) -> pd.DataFrame:
    """Contraction time series (one column per muscle + ``jaw_rotation``) from one source.

    Parameters
    ----------
    muscle_names : sequence of str
        The model's muscles (columns of the result, in order).
    expression : str, optional
        Name of an expression of :data:`synth.facs.EXPRESSIONS` (onset, apex, offset timing
        of :func:`synth.facs.expression_timeline`).
    au : str or dict, optional
        AU script (``"12:0.8,6:0.5"`` or ``{12: 0.8}``), timed like an expression.
    contractions : path or DataFrame, optional
        A table in the ``contractions.csv`` format; its rows are the frames.
    frames : int, optional
        Number of frames (ignored by ``contractions`` unless smaller than its rows).
    fps : float
    intensity : float
        Multiplier of the expression / AU intensities.

    Returns
    -------
    pandas.DataFrame
        Rows = frames.
    """
    sources = [s is not None for s in (expression, au, contractions)]
    if sum(sources) > 1:
        raise ValueError("give only one of expression, au, contractions")
    muscle_names = list(muscle_names)
    if frames is not None and (int(frames) != frames or frames < 1):
        raise ValueError(f"frames={frames} must be a positive integer")
    if contractions is not None:
        if isinstance(contractions, pd.DataFrame):
            df = pd.DataFrame(0.0, index=range(len(contractions)),
                              columns=[*muscle_names, "jaw_rotation"])
            for c in df.columns:
                if c in contractions.columns:
                    df[c] = contractions[c].to_numpy(float)
        else:
            df = _read_contractions_csv(contractions, muscle_names)
        if frames is not None and frames < len(df):
            df = df.iloc[:frames].reset_index(drop=True)
        return df
    n = 60 if frames is None else int(frames)
    if expression is None and au is None:
        return pd.DataFrame(0.0, index=range(n), columns=[*muscle_names, "jaw_rotation"])
    from synth.facs import ACTION_UNITS, EXPRESSIONS, au_timeline, expression_timeline

    if expression is not None:
        names = sorted(EXPRESSIONS)
        if expression not in EXPRESSIONS:
            raise ValueError(f"unknown expression {expression!r}; choose from "
                             f"{', '.join(names)}")
        tl = expression_timeline(expression, n, emphasis=intensity)
    else:
        aus = parse_au_string(au) if isinstance(au, str) else {int(k): float(v)
                                                              for k, v in dict(au).items()}
        unknown = sorted(set(aus) - set(ACTION_UNITS))
        if unknown:
            raise ValueError(f"unknown action unit(s) {unknown}; known: "
                             f"{sorted(ACTION_UNITS)}")
        tl = au_timeline(aus, n, emphasis=intensity)
    df = pd.DataFrame(0.0, index=range(n), columns=[*muscle_names, "jaw_rotation"])
    for c in df.columns:
        if c in tl.columns:
            df[c] = np.asarray(tl[c], dtype=float)[:n]
    return df


def _smooth_signal(rng, n: int, fps: float, amplitude: float) -> np.ndarray:
    """Sum of two slow sinusoids (0.1-0.6 Hz), ramped in so that frame 0 is exactly 0."""
    t = np.arange(n) / fps
    out = np.zeros(n)
    for _ in range(2):
        f = rng.uniform(0.1, 0.6)
        ph = rng.uniform(0, 2 * np.pi)
        out += np.sin(2 * np.pi * f * t + ph) - np.sin(ph)
    ramp = np.clip(t / 0.5, 0, 1)
    ramp = ramp * ramp * (3 - 2 * ramp)
    return amplitude * 0.5 * out * ramp


def head_motion_track(frames: int, seed: int, *, amplitude: float = 1.0, fps: float = 30.0,
                      out_of_plane: bool = True) -> list[HeadPose]:
    """Smooth random head motion, frontal at frame 0 (deterministic per seed).

    At ``amplitude=1``: translation up to ~0.6 cm, roll up to ~4 degrees, yaw and pitch up to
    ~3 degrees (``out_of_plane``).
    """
    if amplitude < 0:
        raise ValueError(f"head motion amplitude={amplitude} must be non-negative")
    rng = np.random.default_rng([int(seed), 0x4EAD])
    tx = _smooth_signal(rng, frames, fps, 0.6 * amplitude)
    ty = _smooth_signal(rng, frames, fps, 0.4 * amplitude)
    roll = _smooth_signal(rng, frames, fps, 4.0 * amplitude)
    yaw = _smooth_signal(rng, frames, fps, 3.0 * amplitude if out_of_plane else 0.0)
    pitch = _smooth_signal(rng, frames, fps, 2.0 * amplitude if out_of_plane else 0.0)
    return [HeadPose(roll=float(roll[i]), yaw=float(yaw[i]), pitch=float(pitch[i]),
                     translation=(float(tx[i]), float(ty[i]), 0.0)) for i in range(frames)]


def illumination_track(frames: int, seed: int, base: Light, *, amplitude: float = 1.0,
                       fps: float = 30.0) -> list[Light]:
    """Slowly swinging light direction (~15 degrees) and intensity (~10 %)."""
    rng = np.random.default_rng([int(seed), 0x11E7])
    az = _smooth_signal(rng, frames, fps, math.radians(15.0) * amplitude)
    gain = 1.0 + _smooth_signal(rng, frames, fps, 0.1 * amplitude)
    d = base.unit_direction
    out = []
    for i in range(frames):
        c, s = math.cos(az[i]), math.sin(az[i])
        di = (c * d[0] + s * d[2], d[1], -s * d[0] + c * d[2])
        out.append(Light(direction=di, colour=tuple(float(gain[i] * v) for v in base.colour),
                         ambient=base.ambient, shininess=base.shininess,
                         specular_scale=base.specular_scale))
    return out


# ---------------------------------------------------------------------------- synthesis
@dataclass(eq=False)
class SyntheticSequence:
    """A rendered sequence and its ground truth (see the module docstring for the arrays)."""

    images: np.ndarray                     # (T, H, W, 3) or (T, H, W) uint8, degraded
    truth: pd.DataFrame
    flow: np.ndarray | None                # (T-1, H, W, 2) float32
    occluded: np.ndarray | None            # (T-1, H, W) bool
    disoccluded: np.ndarray | None         # (T-1, H, W) bool
    mask: np.ndarray                       # (T, H, W) bool
    skin_mask: np.ndarray                  # (T, H, W) bool
    depth: np.ndarray                      # (T, H, W) float32
    meta: dict = field(default_factory=dict)
    clean_images: np.ndarray | None = None  # before blur/noise

    def __repr__(self) -> str:
        # the fields are the frames and their per-pixel truth
        t, h, w = self.images.shape[:3]
        fps, seed = self.meta.get("fps"), self.meta.get("seed")
        expression = (self.meta.get("source") or {}).get("expression")
        extras = [name for name in ("flow", "clean_images") if getattr(self, name) is not None]
        return (f"<SyntheticSequence: {t} frame{'' if t == 1 else 's'} of {w}x{h}"
                f"{f' at {fps:g} fps' if fps else ''}"
                f"{f', {expression}' if expression else ''}"
                f"{f', seed {seed}' if seed is not None else ''}"
                f"{'; with ' + ' and '.join(extras) if extras else ''}>")


def _model_for(seed: int, resolution: float, identity_spread: float):
    try:
        from synth.model import FaceModel
    except ImportError as exc:  # the physics model is a sibling module of synth
        raise ValueError("synth.model.FaceModel is not available; pass model=...") from exc
    from synth.face_shape import FaceShape

    shape = FaceShape.random(int(seed), spread=identity_spread)
    if resolution is None:
        return FaceModel.build(shape), shape
    return FaceModel.build(shape, resolution=resolution), shape


def _aus_of(df: pd.DataFrame):
    """AUxx_r columns (FACS 0..5 scale) estimated from the contractions by synth.facs."""
    try:
        from synth.facs import muscles_to_aus, to_facs_scale
    except ImportError:
        return None
    try:
        aus = muscles_to_aus(df.reset_index(drop=True))
    except (ValueError, KeyError, TypeError) as exc:
        log.warning("AU intensities not written: %s", exc)
        return None
    return pd.DataFrame({f"{c}_r": np.asarray(to_facs_scale(aus[c].to_numpy(float)), float)
                         for c in aus.columns})


def _progress_bar(total: int):
    from tqdm import tqdm

    return tqdm(total=total, desc="synth", unit="frame", file=sys.stderr, leave=False,
                dynamic_ncols=True)


def _size_pair(size) -> tuple[int, int]:
    if isinstance(size, (int, np.integer)):
        return int(size), int(size)
    width, height = (int(v) for v in size)
    return width, height


def synthesize(*, model=None, expression: str | None = None, au=None, contractions=None,
               frames: int | None = 60, fps: float = 30.0, size=None, seed: int = 0,
               head_motion: float = 0.0, out_of_plane: bool = True,
               illumination: float = 0.0, noise: float = 0.0, blur: float = 0.0,
               camera: str = "orthographic", supersample: int = 2, grey: bool = False,
               flow: bool = True, intensity: float = 1.0, resolution: float | None = None,
               identity_spread: float = 1.0, texture_size: int = 1024,
               appearance=None, progress=None) -> SyntheticSequence:
    """Render a synthetic sequence with exact ground truth (in memory).

    Parameters
    ----------
    model : FaceModel-like, optional
        Needs ``mesh``, ``muscle_names``, ``set_contractions(values, jaw_rotation=)``,
        ``equilibrate()`` (returns the skin vertices) and ``inner_vertices()``; default
        ``FaceModel.build(FaceShape.random(seed))``.
    expression, au, contractions : one source of contractions, or none (neutral)
        See :func:`contraction_timeline`.
    frames : int, optional
    fps : float
    size : int or (width, height), optional
        Default 256, or the size of ``appearance``'s camera.
    seed : int
        Identity (shape, texture; not with ``appearance``), head motion, illumination
        and noise.
    head_motion : float
        Amplitude of the head motion (0 = still; 1 = ~0.6 cm, ~4 degrees roll).
    out_of_plane : bool
        Include yaw and pitch in the head motion.
    illumination : float
        Amplitude of the light change (0 = constant).
    noise : float
        Standard deviation of additive Gaussian sensor noise, grey levels (0-255).
    blur : float
        Gaussian blur sigma in px (0 = none).
    camera : {'orthographic', 'perspective'}
    supersample : int
        Anti-aliasing factor.
    grey : bool
    flow : bool
        Compute the flow ground truth.
    intensity : float
        Multiplier of expression / AU intensities.
    resolution : float, optional
        Mesh resolution of the default model (default: the model's own default).
    identity_spread : float
        Identity variation of the default model (``FaceShape.random`` spread).
    texture_size : int
    appearance : synth.render.appearance.PhotoAppearance, optional
        Render ``model`` with the look of the photograph it was fitted to (its texture,
        camera, pose and background; see :mod:`synth.render.appearance`) instead of a
        procedural texture. Needs ``model``; the camera is the appearance's (orthographic),
        head motion moves the head from the photograph's pose, and illumination changes
        relight the photograph by ratio.
    progress : bool or callable(int, int), optional
        True: a progress bar on stderr; a callable is called after each frame with
        (done, total).

    Returns
    -------
    SyntheticSequence
    """
    if appearance is not None:
        if model is None:
            raise ValueError("appearance= needs the model it was fitted with (model=)")
        if camera != "orthographic":
            raise ValueError(f"camera={camera!r}: a photographed face renders through its "
                             "own orthographic camera")
        look_size = (appearance.camera.width, appearance.camera.height)
        if size is not None and _size_pair(size) != look_size:
            raise ValueError(f"size {size} differs from the appearance's camera "
                             f"{look_size[0]}x{look_size[1]}")
        size = look_size
    width, height = _size_pair(256 if size is None else size)
    if width < 16 or height < 16:
        raise ValueError(f"size {width}x{height} must be at least 16x16")
    if fps <= 0:
        raise ValueError(f"fps={fps} must be positive")
    for name, v in (("noise", noise), ("blur", blur), ("head_motion", head_motion),
                    ("illumination", illumination)):
        if not (math.isfinite(v) and v >= 0):
            raise ValueError(f"{name}={v} must be a non-negative number")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed={seed!r} must be a non-negative integer")
    if frames is not None and frames < 1:
        raise ValueError(f"frames={frames} must be at least 1")
    if not (math.isfinite(intensity) and 0 <= intensity <= 2):
        raise ValueError(f"intensity={intensity} must be in [0, 2]")
    shape = None
    if model is None:
        model, shape = _model_for(seed, resolution, identity_spread)
    mesh = model.mesh
    muscles = list(model.muscle_names)
    df = contraction_timeline(muscles, expression=expression, au=au, contractions=contractions,
                              frames=frames, fps=fps, intensity=intensity)
    T = len(df)
    motions = (head_motion_track(T, seed, amplitude=head_motion, fps=fps,
                                 out_of_plane=out_of_plane) if head_motion > 0
               else [HeadPose()] * T)
    if appearance is None:
        cam = default_camera(width, height, kind=camera)
        tparams = texture_params(int(seed))
        tex = paint_skin_texture(mesh, int(seed), size=texture_size)
        light0 = Light()
        renderer = Renderer(mesh, texture=tex, camera=cam, light=light0,
                            supersample=supersample, grey=grey)
        poses = motions
    else:
        cam = appearance.camera
        tparams = None
        light0 = appearance.light
        renderer = appearance.renderer(mesh, supersample=supersample, grey=grey)
        poses = [appearance.head_pose(m) for m in motions]
    lights = (illumination_track(T, seed, light0, amplitude=illumination, fps=fps)
              if illumination > 0 else [light0] * T)
    if appearance is not None:
        lights = [appearance.light_for(lt) for lt in lights]
    rng = np.random.default_rng([int(seed), 0x5E75])
    shp = (T, height, width) if grey else (T, height, width, 3)
    images = np.empty(shp, np.uint8)
    clean = np.empty(shp, np.uint8)
    mask = np.empty((T, height, width), bool)
    skin_mask = np.empty((T, height, width), bool)
    depth = np.empty((T, height, width), np.float32)
    flows = np.empty((max(T - 1, 0), height, width, 2), np.float32) if flow else None
    occ = np.empty((max(T - 1, 0), height, width), bool) if flow else None
    dis = np.empty((max(T - 1, 0), height, width), bool) if flow else None
    rows = []
    px_per_cm = []
    rest = np.asarray(mesh.vertices)
    # a photographed head's background (hair, ears, neck) moves with the head
    scene_motion = (np.empty((T, 2, 3)) if appearance is not None and head_motion > 0
                    else None)
    prev = None
    bar = _progress_bar(T) if progress is True else None
    try:
        for t in range(T):
            row = df.iloc[t]
            values = {m: float(row[m]) for m in muscles}
            model.set_contractions(values, jaw_rotation=float(row["jaw_rotation"]))
            skin = np.asarray(model.equilibrate(), dtype=np.float64)
            inner = np.asarray(model.inner_vertices(), dtype=np.float64)
            if scene_motion is not None:
                scene_motion[t] = appearance.scene_motion(rest, poses[t])
                renderer.set_background(appearance.scene(scene_motion[t]))
            res = renderer.render(skin, inner, pose=poses[t], light=lights[t])
            img = res.image.astype(np.float32)
            clean[t] = res.image
            if blur > 0:
                img = cv2.GaussianBlur(img, (0, 0), blur)
            if noise > 0:
                img = img + rng.normal(0.0, noise, img.shape).astype(np.float32)
            images[t] = np.clip(img + 0.5, 0, 255).astype(np.uint8) if (blur or noise) \
                else res.image
            mask[t] = res.mask
            skin_mask[t] = res.skin_mask
            depth[t] = res.depth
            if flow and prev is not None:
                flows[t - 1], occ[t - 1], dis[t - 1] = flow_and_occlusion(renderer, prev, res)
                if scene_motion is not None:
                    scene = background_flow(scene_motion[t - 1], scene_motion[t], width,
                                            height)
                    flows[t - 1][~prev.mask] = scene[~prev.mask]
            prev = res
            lm = _landmark_positions(model, mesh, skin)
            fids = project_landmarks({k: lm[k] for k in FIDUCIALS if k in lm}, renderer, res)
            hf = head_frame(mesh, cam, poses[t])
            px_per_cm.append(hf.pop("px_per_cm"))
            rec = {"frame": t, "timestamp": t / fps, "success": 1, "confidence": 1.0, **hf}
            for name in FIDUCIALS:
                x, y, vis = fids.get(name, (np.nan, np.nan, False))
                rec[f"fid_{name}_x"] = x
                rec[f"fid_{name}_y"] = y
                rec[f"fid_{name}_visible"] = int(vis)
            rec.update(values)
            rec["jaw_rotation"] = float(row["jaw_rotation"])
            rows.append(rec)
            if bar is not None:
                bar.update(1)
            elif progress:
                progress(t + 1, T)
    finally:
        if bar is not None:
            bar.close()
    truth = pd.DataFrame(rows)
    aus = _aus_of(df)
    if aus is not None and len(aus) == T:
        for c in aus.columns:
            truth[c] = np.asarray(aus[c], dtype=float)
    source = ({"expression": expression, "intensity": intensity} if expression is not None
              else {"au": au if isinstance(au, str) else {str(k): v for k, v in au.items()},
                    "intensity": intensity} if au is not None
              else {"contractions": str(contractions) if not isinstance(
                  contractions, pd.DataFrame) else "DataFrame"} if contractions is not None
              else {"neutral": True})
    meta = {
        "generator": "synth.render.sequence",
        "seed": int(seed), "frames": int(T), "fps": float(fps),
        "size": [width, height], "grey": bool(grey), "supersample": int(supersample),
        "camera": cam.as_dict(),
        "identity": {"shape": shape.as_dict() if shape is not None else None,
                     "identity_spread": float(identity_spread),
                     "resolution": getattr(mesh, "resolution", None),
                     "texture": (tparams.as_dict() if tparams is not None
                                 else {"photo": appearance.source}),
                     "texture_size": int(texture_size) if tparams is not None else None,
                     "mesh_vertices": int(len(rest))},
        "source": source,
        "head_motion": {"amplitude": float(head_motion), "out_of_plane": bool(out_of_plane),
                        "poses": [p.as_dict() for p in poses]},
        "illumination": {"amplitude": float(illumination),
                         "lights": [lt.as_dict() for lt in lights]},
        "degradation": {"noise_std": float(noise), "blur_sigma": float(blur)},
        "muscles": muscles,
        "head_frame": ("rigid head: origin = arc-length centroid of the projected hairline "
                       "curve (px); scale = px from the origin to the nostrils' midpoint; "
                       "roll = radians, positive clockwise on screen (trackers' convention)"),
        "px_per_cm": px_per_cm,
        "versions": _versions(),
    }
    return SyntheticSequence(images=images, truth=truth, flow=flows, occluded=occ,
                             disoccluded=dis, mask=mask, skin_mask=skin_mask, depth=depth,
                             meta=meta, clean_images=clean)


def _landmark_positions(model, mesh, skin) -> dict:
    fn = getattr(model, "landmark_positions", None)
    if fn is not None:
        try:
            return {k: np.asarray(v, float) for k, v in fn().items()}
        except TypeError:
            pass
    return {k: skin[i] for k, i in mesh.landmarks.items()}


def _versions() -> dict:
    import numba

    out = {"numpy": np.__version__, "opencv": cv2.__version__, "numba": numba.__version__,
           "pandas": pd.__version__}
    try:
        from importlib.metadata import version

        out["faceanalysis"] = version("faceanalysis")
    except Exception:  # noqa: BLE001 - not installed as a distribution
        out["faceanalysis"] = None
    return out


# ---------------------------------------------------------------------------- files
def write_npz_deterministic(path, arrays: dict, *, compress: bool = True) -> Path:
    """Like ``numpy.savez_compressed`` but byte-for-byte reproducible (fixed zip dates),
    written atomically."""
    buf = io.BytesIO()
    method = zipfile.ZIP_DEFLATED if compress else zipfile.ZIP_STORED
    with zipfile.ZipFile(buf, "w", compression=method) as zf:
        for name, arr in arrays.items():
            a = io.BytesIO()
            np.lib.format.write_array(a, np.asanyarray(arr), allow_pickle=False)
            info = zipfile.ZipInfo(f"{name}.npy", date_time=(1980, 1, 1, 0, 0, 0))
            info.compress_type = method
            info.external_attr = 0o644 << 16
            zf.writestr(info, a.getvalue())
    return write_bytes_atomic(path, buf.getvalue())


def write_sequence(seq: SyntheticSequence, out_dir, *, overwrite: bool = False,
                   video_name: str = "video.mp4", flow_dtype: str = "float32") -> dict:
    """Write a :class:`SyntheticSequence` to ``out_dir`` (see the module docstring).

    ``flow_dtype`` 'float16' halves ``flow.npz`` (about 0.01 px resolution at 10 px).

    Raises
    ------
    FileExistsError
        ``out_dir`` is a non-empty folder (or a file) and ``overwrite`` is false.

    Returns
    -------
    dict name -> Path of the files written (``video``, ``truth``, ``flow``, ``meta``).
    """
    if flow_dtype not in ("float32", "float16"):
        raise ValueError(f"flow_dtype={flow_dtype!r} is not one of 'float32', 'float16'")
    out = prepare_output_dir(out_dir, overwrite=overwrite)
    T = seq.images.shape[0]
    H, W = seq.images.shape[1:3]
    with VideoWriter(out / video_name, seq.meta.get("fps", 30.0), (W, H)) as vw:
        for t in range(T):
            vw.write(seq.images[t])
    meta = dict(seq.meta)
    meta["video"] = vw.path.name
    meta["video_note"] = vw.note
    csv = seq.truth.to_csv(index=False, float_format="%.6f", lineterminator="\n")
    truth_path = write_text_atomic(out / "truth.csv", csv)
    arrays = {"mask": seq.mask, "skin_mask": seq.skin_mask, "depth": seq.depth}
    if seq.flow is not None:
        arrays.update(flow=seq.flow.astype(flow_dtype), occluded=seq.occluded,
                      disoccluded=seq.disoccluded)
    flow_path = write_npz_deterministic(out / "flow.npz", arrays)
    meta["files"] = {"video": vw.path.name, "truth": "truth.csv", "flow": "flow.npz"}
    meta_path = write_text_atomic(out / "meta.json",
                                  json.dumps(meta, indent=1, sort_keys=True) + "\n")
    # remove a stale video of the other container from an earlier run
    for other in (".mp4", ".avi"):
        p = (out / video_name).with_suffix(other)
        if p != vw.path and p.exists() and overwrite:
            os.remove(p)
    return {"video": vw.path, "truth": truth_path, "flow": flow_path, "meta": meta_path,
            "note": vw.note}


def render_sequence(out_dir, *, overwrite: bool = False, flow_dtype: str = "float32",
                    **kwargs) -> dict:
    """Synthesize a sequence and write it to ``out_dir``; see :func:`synthesize` for options.

    Returns
    -------
    dict name -> Path (``video``, ``truth``, ``flow``, ``meta``) plus ``note`` (codec
    fallback message or None).
    """
    if flow_dtype not in ("float32", "float16"):
        raise ValueError(f"flow_dtype={flow_dtype!r} is not one of 'float32', 'float16'")
    out = prepare_output_dir(out_dir, overwrite=overwrite)   # fail before the long render
    seq = synthesize(**kwargs)
    return write_sequence(seq, out, overwrite=overwrite, flow_dtype=flow_dtype)
