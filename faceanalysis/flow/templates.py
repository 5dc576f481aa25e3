"""Optical-flow templates made by the face model (seed 003, section 6; Essa & Pentland).

Zhang et al. propose that the model's own surface motion, seen as optical flow, serves as
templates that characterise each expression. :func:`make_templates` renders the face model
and turns its exact image-plane motion (the renderer's ground-truth flow, or the projected
node motion) into fields on the canonical :class:`~faceanalysis.flow.grid.FaceGrid`:

- one **per control** (each muscle and the jaw): the displacement from rest to the
  equilibrium under a contraction of ``level`` (default 1), divided by the level, so that a
  template is the motion per unit contraction (the jaw's, made at ``level *``
  :data:`JAW_TEMPLATE` radians, is per radian; its bound is :data:`JAW_MAX`);
- one **per primary expression** (:data:`synth.facs.EXPRESSIONS`): the spatio-temporal
  template of its onset, the displacement from rest at ``n_steps`` instants from neutral to
  apex (the timing of :func:`synth.facs.expression_timeline`), and the motion-energy map
  ``sum_t |d_t - d_{t-1}|^2`` of that onset (Essa & Pentland's spatio-temporal motion energy);
- **nuisance** motions: the four similarity motions of :func:`faceanalysis.flow.grid.rigid_basis`
  (tracker jitter of the head frame) and the model's own flow under one degree of yaw and of
  pitch (out-of-plane head rotation, which the 2-D head frame cannot remove).

Head frame of the model. The grid lives in the head frame of the trackers
(:mod:`trackers.fiducials`). To place the model's motion in the *same* frame as an analysed
video, the model's neutral render is tracked by the same tracker (automatic layout on the
render, then the tracker's head frame). If the tracker fails, or its frame disagrees with
the one built from the model's landmarks (origin = mean of the three hairline landmarks,
scale = distance to the nose tip, roll = image angle of the model's x axis; mapped to the
trackers' convention by two constants measured on several identities), the landmark frame
is used (``meta['head_source']`` says which).

Personalised templates: :func:`faceanalysis.flow.personalize.personalize` warps generic
templates onto a subject's face by a thin-plate spline of the grid driven by the 11
fiducials (model's at rest -> the subject's neutral fiducials, both in head coordinates),
the 2-D counterpart of the landmark-driven deformation of Kähler (001, ch. 8). A model
warped to the subject in 3-D (:func:`faceanalysis.resynthesis.personalize.personalize`) or
built for an identity (``make_templates(FaceModel.build(shape))``) works too.
"""

from __future__ import annotations

import hashlib
import json
import logging
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from faceanalysis.flow.grid import FaceGrid, grid_image_points, image_flow_to_grid, rigid_basis
from faceanalysis.io.table import FIDUCIALS

log = logging.getLogger(__name__)

__all__ = ["FlowTemplates", "ModelView", "make_templates", "default_templates", "write_templates",
           "preview_templates", "JAW_MAX", "JAW_TEMPLATE", "REGION_GROUPS", "EXPRESSION_NAMES"]

#: Upper bound of the jaw rotation (radians), that of :data:`synth.facs.MAX_JAW_ROTATION`.
JAW_MAX = 0.5
#: Jaw rotation (radians) at which the jaw template is made (times ``level``); the template
#: is the motion per radian.
JAW_TEMPLATE = 0.25
#: Expression classes in a fixed order (the six primaries of :mod:`synth.facs`).
EXPRESSION_NAMES = ("happiness", "sadness", "surprise", "fear", "anger", "disgust")
#: Reporting regions of the face grid: name -> synth.face_mesh.Region codes.
REGION_GROUPS = {
    "forehead": (0, 1, 2),       # scalp edge, forehead, temples
    "brows": (3,),
    "eyes": (4,),
    "nose": (5,),
    "cheeks": (6, 7, 11),        # cheeks, nasolabial band, jaw sides
    "mouth": (8, 9),
    "chin": (10,),
}


@dataclass(eq=False)
class FlowTemplates:
    """Model-made flow templates on a face grid (all displacements in head units).

    Attributes
    ----------
    grid : FaceGrid
    controls : tuple of str
        Muscle names and ``jaw_rotation``.
    upper : ndarray (M,)
        Upper bound of each control (1 for muscles, :data:`JAW_MAX` for the jaw).
    control : ndarray (M, rows, cols, 2)
        Displacement per unit of each control.
    nuisance_names : tuple of str
    nuisance : ndarray (K, rows, cols, 2)
        Nuisance motions (similarity, yaw and pitch per degree).
    mask : ndarray (rows, cols) bool
        Grid cells on the face (skin, eyes, mouth), one cell in from the outline.
    region : ndarray (rows, cols) int8
        ``synth.face_mesh.Region`` code of the nearest skin vertex (-1 off the face).
    expressions : tuple of str
    expression : ndarray (E, S, rows, cols, 2)
        Displacement from rest at S instants from neutral to apex of each expression.
    energy : ndarray (E, rows, cols)
        Motion energy of each expression's onset.
    fiducials : ndarray (11, 2)
        The model's rest fiducials in head coordinates (for
        :func:`faceanalysis.flow.personalize.personalize`).
    head : ndarray (4,)
        Head frame of the model's render (px), for reference.
    meta : dict
    """

    grid: FaceGrid
    controls: tuple
    upper: np.ndarray
    control: np.ndarray
    nuisance_names: tuple
    nuisance: np.ndarray
    mask: np.ndarray
    region: np.ndarray
    expressions: tuple
    expression: np.ndarray
    energy: np.ndarray
    fiducials: np.ndarray
    head: np.ndarray
    meta: dict = field(default_factory=dict)

    def __repr__(self) -> str:
        # the fields are image-sized arrays
        return (f"<FlowTemplates: {len(self.controls)} controls, {len(self.expressions)} "
                f"expressions ({', '.join(self.expressions)}), on a {self.grid.rows}x"
                f"{self.grid.cols} face grid>")

    @property
    def apex(self) -> np.ndarray:
        """Apex displacement of each expression, (E, rows, cols, 2)."""
        return self.expression[:, -1]

    def region_masks(self) -> dict[str, np.ndarray]:
        """Name -> (rows, cols) bool for the groups of :data:`REGION_GROUPS` (on the mask)."""
        return {name: self.mask & np.isin(self.region, codes)
                for name, codes in REGION_GROUPS.items()}

    def save(self, path) -> Path:
        """Write to a ``.npz`` file (atomically)."""
        from faceanalysis.io.outputs import atomic_path

        path = Path(path)
        arrays = {"control": self.control.astype(np.float32),
                  "upper": self.upper, "nuisance": self.nuisance.astype(np.float32),
                  "mask": self.mask, "region": self.region,
                  "expression": self.expression.astype(np.float32),
                  "energy": self.energy.astype(np.float32), "fiducials": self.fiducials,
                  "head": self.head,
                  "controls": np.array(self.controls), "expressions": np.array(self.expressions),
                  "nuisance_names": np.array(self.nuisance_names),
                  "grid": np.array(json.dumps(self.grid.as_dict())),
                  "meta": np.array(json.dumps(self.meta, default=str))}
        with atomic_path(path) as tmp, open(tmp, "wb") as fh:
            np.savez_compressed(fh, **arrays)
        return path

    @classmethod
    def load(cls, path) -> FlowTemplates:
        """Read a file written by :meth:`save`."""
        path = Path(path)
        if not path.is_file():
            raise FileNotFoundError(f"{path}: no such templates file")
        what = "not a flow-templates file (the .npz that 'faceanalysis templates' writes)"
        try:
            z = np.load(path, allow_pickle=False)
        except (ValueError, OSError, EOFError):
            # NumPy says "pickled data" for any file that is neither .npz nor .npy
            raise ValueError(f"{path}: {what}: it is not an .npz archive") from None
        if not isinstance(z, np.lib.npyio.NpzFile):
            raise ValueError(f"{path}: {what}: it holds a single .npy array") from None
        needed = ("grid", "controls", "upper", "control", "nuisance_names", "nuisance", "mask",
                  "region", "expressions", "expression", "energy", "fiducials", "head", "meta")
        missing = [k for k in needed if k not in z.files]
        if missing:
            z.close()
            raise ValueError(f"{path}: {what}: it has no {', '.join(missing)} array")
        try:
            with z:
                return cls(grid=FaceGrid.from_dict(json.loads(str(z["grid"]))),
                           controls=tuple(str(s) for s in z["controls"]),
                           upper=z["upper"].astype(float),
                           control=z["control"].astype(np.float64),
                           nuisance_names=tuple(str(s) for s in z["nuisance_names"]),
                           nuisance=z["nuisance"].astype(np.float64), mask=z["mask"],
                           region=z["region"], expressions=tuple(str(s) for s in z["expressions"]),
                           expression=z["expression"].astype(np.float64),
                           energy=z["energy"].astype(np.float64),
                           fiducials=z["fiducials"], head=z["head"],
                           meta=json.loads(str(z["meta"])))
        except (KeyError, ValueError, OSError, EOFError) as exc:
            raise ValueError(f"{path}: {what}: {exc}") from None


# ---------------------------------------------------------------------------- model head frame
#: The trackers' head frame on model renders relative to the landmark one (measured on the
#: generic face and three random identities, spread ~1 %): reference length = this times
#: the hairline-to-nose-tip distance, origin this many (landmark) units higher.
_TRACKER_SCALE = 1.137
_TRACKER_RISE = 0.046


def _landmark_head(renderer, res, landmarks: dict) -> np.ndarray:
    """The model's head frame from its landmarks, in the trackers' convention: origin at the
    hairline landmarks' mean (raised by ``_TRACKER_RISE``), scale the hairline-to-nose-tip
    distance (times ``_TRACKER_SCALE``), roll the image angle of the model's x axis."""
    from synth.render.camera import project

    pts = np.array([landmarks[n] for n in ("hairline_l", "hairline_centre", "hairline_r",
                                           "nose_tip")])
    o3 = pts[:3].mean(axis=0)
    xy, _ = project(np.vstack([pts, o3, o3 + [1.0, 0, 0]]), res.camera, res.pose)
    origin = xy[4]
    d = xy[5] - xy[4]
    roll = math.atan2(d[1], d[0])
    length = float(np.hypot(*(xy[3] - origin)))
    up = np.array([math.sin(roll), -math.cos(roll)])          # head -y in the image
    origin = origin + _TRACKER_RISE * length * up
    return np.array([origin[0], origin[1], _TRACKER_SCALE * length, roll])


def _agrees(head: np.ndarray, guess: np.ndarray) -> bool:
    """Tracked and landmark head frames agree (origin within 0.05 units, scale within 8 %,
    roll within 0.05 rad)."""
    return bool(np.hypot(*(head[:2] - guess[:2])) < 0.05 * guess[2]
                and abs(head[2] / guess[2] - 1.0) < 0.08 and abs(head[3] - guess[3]) < 0.05)


def _tracked_head(image) -> np.ndarray | None:
    from trackers import Tracker, detect_layout

    try:
        lay = detect_layout(image, channel_order="rgb")
        tr = Tracker(lay, channel_order="rgb")
        res = None
        for _ in range(3):          # the same frame again: settle the contours
            res = tr.track(image)
    except ValueError as exc:
        log.warning("tracker found no face in the model render (%s)", exc)
        return None
    if res is None or not res.success:
        return None
    return np.array([res.head.x, res.head.y, res.head.scale, res.head.roll])


# ---------------------------------------------------------------------------- making templates
def _model_state(model, values=None, jaw=0.0):
    model.set_contractions(values, jaw_rotation=jaw)
    skin = np.asarray(model.equilibrate(), dtype=np.float64)
    inner = np.asarray(model.inner_vertices(), dtype=np.float64)
    return skin, inner


def _nodes_to_grid(res0, res1, n_skin, head, grid, mask):
    """Projected node motion interpolated (linearly, over the rest projection) to the grid."""
    from scipy.interpolate import LinearNDInterpolator

    xy0, xy1 = res0.xy[:n_skin], res1.xy[:n_skin]
    H, W = res0.depth.shape
    r = np.clip(np.round(xy0[:, 1]).astype(int), 0, H - 1)
    c = np.clip(np.round(xy0[:, 0]).astype(int), 0, W - 1)
    vis = res0.vertex_depth[:n_skin] <= res0.depth[r, c] + 0.15
    interp = LinearNDInterpolator(xy0[vis], (xy1 - xy0)[vis])
    pts = grid_image_points(grid, head)
    d = interp(pts.reshape(-1, 2)).reshape(*grid.shape, 2)
    from faceanalysis.flow.grid import vectors_to_head

    out = vectors_to_head(d, head)
    out[~mask] = 0.0
    return np.nan_to_num(out)


class ModelView:
    """The face model at rest, rendered, with its head frame and face mask on the grid.

    Turns any later state of the model into its displacement field on the grid (head
    units, from rest), from the renderer's exact flow (``source='exact'``; occluded pixels
    left out) or from the projected node motion (``'nodes'``). Used for the templates and
    for the resynthesis flow of :mod:`faceanalysis.evaluation.validation`.

    Parameters
    ----------
    model : FaceModel-like
    grid : FaceGrid, optional
    size : int
        Square render size, px (orthographic default camera).
    texture_seed : int
    source : {'exact', 'nodes'}
    """

    def __init__(self, model, *, grid: FaceGrid | None = None, size: int = 256,
                 texture_seed: int = 0, source: str = "exact"):
        import cv2
        from scipy.spatial import cKDTree

        from faceanalysis.tracking import to_head_frame
        from synth.render import Renderer, default_camera, paint_skin_texture
        from synth.render.camera import project

        if source not in ("exact", "nodes"):
            raise ValueError(f"source={source!r} must be 'exact' or 'nodes'")
        self.model = model
        self.grid = grid = grid or FaceGrid()
        self.source = source
        self.mesh = mesh = model.mesh
        cam = default_camera(int(size), int(size))
        self.renderer = Renderer(mesh, texture=paint_skin_texture(mesh, int(texture_seed),
                                                                  size=512),
                                 camera=cam, supersample=2)
        self.n_skin = self.renderer.n_skin
        if hasattr(model, "reset"):
            model.reset()
        self.skin0, self.inner0 = _model_state(model)
        self.rest = res0 = self.renderer.render(self.skin0, self.inner0)
        lm = (model.landmark_positions() if hasattr(model, "landmark_positions")
              else mesh.landmark_positions(self.skin0))
        guess = _landmark_head(self.renderer, res0, lm)
        head = _tracked_head(res0.image)
        self.head_source = "tracker"
        if head is None or not _agrees(head, guess):
            # the tracker failed or locked onto other features on this render
            head = guess
            self.head_source = "landmarks"
        self.head = head
        pts = grid_image_points(grid, head).astype(np.float32)
        fm = cv2.remap(res0.mask.astype(np.float32), pts[..., 0], pts[..., 1],
                       cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0.0)
        # face cells: the whole neighbourhood on the face
        self.mask = cv2.erode((fm > 0.99).astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
        _, near = cKDTree(res0.xy[:self.n_skin]).query(pts.reshape(-1, 2))
        region = np.asarray(mesh.region)[near].reshape(grid.shape).astype(np.int8)
        region[~self.mask] = -1
        self.region = region
        fid_xy, _ = project(np.array([lm[n] for n in FIDUCIALS]), cam)
        self.fiducials = to_head_frame(fid_xy, head)

    def to_grid(self, result) -> np.ndarray:
        """Displacement field (rows, cols, 2) from rest to the render ``result``."""
        from synth.render import forward_flow

        if self.source == "exact":
            flow, occ = forward_flow(self.renderer, self.rest, result)
            d = image_flow_to_grid(flow, self.head, self.grid, valid=self.rest.mask & ~occ)
            d[~self.mask] = 0.0
            return np.nan_to_num(d)
        return _nodes_to_grid(self.rest, result, self.n_skin, self.head, self.grid, self.mask)

    def nuisance(self) -> tuple[list, np.ndarray]:
        """Names and fields (K, rows, cols, 2) of the nuisance motions: the four similarity
        motions and the model's own flow under one degree of yaw and of pitch."""
        from synth.render.camera import HeadPose

        fields = [*rigid_basis(self.grid)]
        names = ["translate_u", "translate_v", "rotate", "scale"]
        for axis in ("yaw", "pitch"):
            res1 = self.renderer.render(self.skin0, self.inner0, pose=HeadPose(**{axis: 1.0}),
                                        shade=False)
            fields.append(self.to_grid(res1))
            names.append(axis)
        out = np.array(fields)
        out[:, ~self.mask] = 0.0
        return names, out

    def templates(self) -> FlowTemplates:
        """Templates holding only this view's mask, regions and nuisance motions (no control
        or expression templates): what :func:`faceanalysis.evaluation.validation.flow_agreement`
        needs for a model of its own (e.g. a personalised one)."""
        names, nuisance = self.nuisance()
        g = self.grid
        return FlowTemplates(grid=g, controls=(), upper=np.zeros(0),
                             control=np.zeros((0, *g.shape, 2)), nuisance_names=tuple(names),
                             nuisance=nuisance, mask=self.mask, region=self.region,
                             expressions=(), expression=np.zeros((0, 1, *g.shape, 2)),
                             energy=np.zeros((0, *g.shape)), fiducials=self.fiducials,
                             head=self.head, meta={"head_source": self.head_source,
                                                   "personalised": False})

    def displacement(self, values=None, jaw_rotation: float = 0.0, *, pose=None
                     ) -> np.ndarray:
        """Equilibrate the model at ``values`` (dict or None) and return its displacement
        field from rest (optionally with a head pose)."""
        skin, inner = _model_state(self.model, values, jaw_rotation)
        return self.to_grid(self.renderer.render(skin, inner, pose=pose, shade=False))


def make_templates(model=None, *, grid: FaceGrid | None = None, size: int = 256,
                   level: float = 1.0, controls=None, expressions=EXPRESSION_NAMES,
                   n_steps: int = 6, source: str = "exact", texture_seed: int = 0,
                   progress=None) -> FlowTemplates:
    """Render the face model and make its flow templates (see the module docstring).

    Parameters
    ----------
    model : synth.FaceModel-like, optional
        Needs ``mesh``, ``muscle_names``, ``set_contractions``, ``equilibrate``,
        ``inner_vertices`` (``reset`` and ``landmark_positions`` are used when present).
        Default: the generic face, ``FaceModel.default()``.
    grid : FaceGrid, optional
    size : int
        Render size in px (square, orthographic camera, face filling 75 %).
    level : float
        Contraction at which the per-control templates are made (jaw: ``level * JAW_MAX``).
    controls : sequence of str, optional
        Default: all the model's muscles and ``jaw_rotation``.
    expressions : sequence of str
        Expressions of :data:`synth.facs.EXPRESSIONS` to make templates of.
    n_steps : int
        Instants from neutral to apex in an expression template.
    source : {'exact', 'nodes'}
        ``exact``: the renderer's exact dense flow (occluded pixels left out);
        ``nodes``: projected node motion interpolated between the vertices.
    texture_seed : int
        Skin texture of the render the tracker sees.
    progress : callable(done, total), optional

    Returns
    -------
    FlowTemplates
    """
    from synth import facs

    if source not in ("exact", "nodes"):
        raise ValueError(f"source={source!r} must be 'exact' or 'nodes'")
    if not 0 < level <= 1:
        raise ValueError(f"level={level} must be in (0, 1]")
    if int(n_steps) != n_steps or n_steps < 2:
        raise ValueError(f"n_steps={n_steps} must be an integer >= 2")
    if int(size) != size or size < 96:
        raise ValueError(f"size={size} must be an integer >= 96")
    unknown = [e for e in expressions if e not in facs.EXPRESSIONS]
    if unknown:
        raise ValueError(f"unknown expressions {unknown}; choose from "
                         f"{', '.join(sorted(facs.EXPRESSIONS))}")
    if model is None:
        from synth.model import FaceModel

        model = FaceModel.default()
    grid = grid or FaceGrid()
    muscles = tuple(model.muscle_names)
    controls = tuple(controls) if controls is not None else (*muscles, "jaw_rotation")
    bad = [c for c in controls if c != "jaw_rotation" and c not in muscles]
    if bad:
        raise ValueError(f"unknown controls {bad}; the model has {', '.join(muscles)}")
    view = ModelView(model, grid=grid, size=size, texture_seed=texture_seed, source=source)
    mesh, renderer, head, mask = view.mesh, view.renderer, view.head, view.mask
    cam = renderer.camera
    to_grid = view.to_grid

    total = len(controls) + 2 + len(expressions) * n_steps
    done = 0

    def tick():
        nonlocal done
        done += 1
        if progress is not None:
            progress(done, total)

    control = np.zeros((len(controls), *grid.shape, 2))
    upper = np.array([JAW_MAX if c == "jaw_rotation" else 1.0 for c in controls])
    for m, name in enumerate(controls):
        if name == "jaw_rotation":
            amount = level * JAW_TEMPLATE
            skin, inner = _model_state(model, None, amount)
        else:
            amount = level
            skin, inner = _model_state(model, {name: level})
        control[m] = to_grid(renderer.render(skin, inner, shade=False)) / amount
        tick()
    names, nuisance = view.nuisance()
    tick()
    tick()
    # expressions: onset of the timeline, neutral -> apex
    expr = np.zeros((len(expressions), n_steps, *grid.shape, 2))
    energy = np.zeros((len(expressions), *grid.shape))
    for e, name in enumerate(expressions):
        n_frames = 100
        tl = facs.expression_timeline(name, n_frames)
        total_act = tl.drop(columns=[c for c in tl.columns if c not in (*muscles, "jaw_rotation")]
                            ).abs().sum(axis=1).to_numpy()
        apex_at = int(np.argmax(total_act >= total_act.max() - 1e-9))
        idx = np.linspace(0, apex_at, n_steps + 1).round().astype(int)[1:]
        prev = np.zeros((*grid.shape, 2))
        for s, t in enumerate(idx):
            row = tl.iloc[t]
            vals = {m: float(row[m]) for m in muscles if m in tl.columns}
            jaw = float(row["jaw_rotation"]) if "jaw_rotation" in tl.columns else 0.0
            skin, inner = _model_state(model, vals, jaw)
            d = to_grid(renderer.render(skin, inner, shade=False))
            expr[e, s] = d
            energy[e] += np.sum((d - prev) ** 2, axis=-1)
            prev = d
            tick()
    if hasattr(model, "reset"):
        model.reset()
    meta = {"source": source, "level": float(level), "size": int(size),
            "n_steps": int(n_steps), "head_source": view.head_source,
            "model_vertices": int(len(mesh.vertices)), "personalised": False,
            "camera": cam.as_dict(), "texture_seed": int(texture_seed)}
    return FlowTemplates(grid=grid, controls=controls, upper=upper, control=control,
                         nuisance_names=tuple(names), nuisance=nuisance, mask=mask,
                         region=view.region, expressions=tuple(expressions), expression=expr,
                         energy=energy, fiducials=view.fiducials, head=head, meta=meta)


# ---------------------------------------------------------------------------- cache + files
def _model_key(model, grid: FaceGrid, extra) -> str:
    from faceanalysis._version import __version__
    from faceanalysis.io.cache import source_digest

    h = hashlib.sha1()
    h.update(__version__.encode())
    h.update(np.ascontiguousarray(model.mesh.vertices, dtype=np.float64).tobytes())
    h.update(repr(getattr(model, "parameters_digest", lambda: "")()).encode())
    h.update(repr((tuple(model.muscle_names), grid.as_dict(), extra)).encode())
    h.update(source_digest(("synth", "trackers"), ("faceanalysis.flow.templates",
                                                   "faceanalysis.flow.dense",
                                                   "faceanalysis.flow.grid")).encode())
    return h.hexdigest()[:16]


def default_templates(model=None, *, grid: FaceGrid | None = None, use_cache: bool = True,
                      **kwargs) -> FlowTemplates:
    """Templates of ``model`` (default: the generic face), cached on disk like the fiducial
    response (``$FACEANALYSIS_CACHE`` or ``~/.cache/faceanalysis``)."""
    from faceanalysis.io.cache import cache_dir

    if model is None:
        from synth.model import FaceModel

        model = FaceModel.default()
    grid = grid or FaceGrid()
    key = _model_key(model, grid, tuple(sorted(kwargs.items())))
    path = cache_dir() / f"flow-templates-{key}.npz"
    if use_cache and path.is_file():
        try:
            return FlowTemplates.load(path)
        except (OSError, ValueError) as exc:
            log.warning("ignoring unreadable templates cache %s (%s)", path, exc)
    tpl = make_templates(model, grid=grid, **kwargs)
    if use_cache:
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            tpl.save(path)
        except OSError as exc:
            log.debug("could not cache the templates: %s", exc)
    return tpl


def _arrows(ax, d, grid, mask, step=4, scale=None):
    p = grid.points
    sl = (slice(step // 2, None, step), slice(step // 2, None, step))
    m = mask[sl]
    ax.quiver(p[sl][..., 0][m], p[sl][..., 1][m], d[sl][..., 0][m], d[sl][..., 1][m],
              angles="xy", scale_units="xy", scale=scale, color="k", width=0.004)


def preview_templates(templates: FlowTemplates, path, *, which: str = "controls",
                      exaggerate: float = 3.0) -> Path:
    """A PNG sheet of templates: colour wheel (hue = direction) with arrows on the face.

    Parameters
    ----------
    which : {'controls', 'expressions', 'energy'}
    exaggerate : float
        Arrow length multiplier.
    """
    from matplotlib.figure import Figure

    from faceanalysis.flow.dense import flow_to_colour

    if which not in ("controls", "expressions", "energy"):
        raise ValueError(f"which={which!r} must be 'controls', 'expressions' or 'energy'")
    grid = templates.grid
    if which == "controls":
        names, fields = templates.controls, templates.control * templates.upper[:, None, None,
                                                                                 None]
    elif which == "expressions":
        names, fields = templates.expressions, templates.apex
    else:
        names, fields = templates.expressions, templates.energy
    n = len(names)
    ncol = min(6, n)
    nrow = int(math.ceil(n / ncol))
    fig = Figure(figsize=(2.0 * ncol, 2.5 * nrow))
    axes = fig.subplots(nrow, ncol, squeeze=False)
    ext = (grid.u[0], grid.u[1], grid.v[1], grid.v[0])
    for k, ax in enumerate(axes.ravel()):
        ax.set_axis_off()
        if k >= n:
            continue
        f = fields[k]
        if which == "energy":
            ax.imshow(np.where(templates.mask, f, np.nan), extent=ext, cmap="magma")
        else:
            img = flow_to_colour(np.where(templates.mask[..., None], f, np.nan),
                                 max_magnitude=max(float(np.abs(f).max()), 1e-9))
            ax.imshow(img, extent=ext)
            _arrows(ax, f * exaggerate, grid, templates.mask, scale=1.0)
        ax.set_title(names[k].replace("_", " "), fontsize=7)
    fig.suptitle(f"flow templates ({which}); "
                 f"{'personalised' if templates.meta.get('personalised') else 'generic'} face",
                 fontsize=9)
    fig.tight_layout()
    from faceanalysis.io.outputs import atomic_path

    path = Path(path)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    return path


def write_templates(templates: FlowTemplates, out_dir, *, name: str = "generic",
                    previews: bool = True) -> dict[str, Path]:
    """Write ``<name>.npz`` and preview PNGs (``<name>_controls.png``,
    ``<name>_expressions.png``, ``<name>_energy.png``) into ``out_dir``."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = {"templates": templates.save(out / f"{name}.npz")}
    if previews:
        for which in ("controls", "expressions", "energy"):
            paths[which] = preview_templates(templates, out / f"{name}_{which}.png", which=which)
    return paths
