"""The landmark tracker's face-mesh points as measurement points of the face model.

The landmark tracker (MediaPipe's 468-point face mesh) puts points all over the face:
along the brows, the nose, both borders of both lips, the cheeks and the chin. Read
through the face model, they tell apart muscles that the 16 contour points cannot (the
levators, risorius and zygomaticus pull the cheek and the upper lip differently), and
they do not move with the light as an edge does.

Two things make them measurement points:

* **where each one is on the model** (:func:`mesh_correspondence`): the generic face is
  rendered at rest, the landmark model is run on the render, and each landmark takes the
  skin point under it (a triangle and barycentric weights). Landmarks on the face's
  silhouette, on the eyelids (the model has no blink), in the mouth's opening or within
  :data:`SEAM_MARGIN` of the mouth line (where the upper and lower lip part, so that a
  point on the wrong side would read a jaw) are left out. The result is cached on disk.
* **how each one moved** (:func:`mesh_displacements`): the frame's landmarks are carried
  back onto the neutral frame's by the 3-D similarity that best superposes the face
  (robustly, from the eye corners and nose bridge) and by the horizontal stretch and shears
  of the image that the landmark model adds to a turning head (:func:`image_stretch`), so
  that a turned or bowed head leaves mostly the face's own motion, which is then taken into
  model units by the calibration.
"""

from __future__ import annotations

import functools
import logging

import numba
import numpy as np

from faceanalysis._version import __version__
from faceanalysis.io.cache import cache_dir, digest_of, source_digest
from faceanalysis.io.outputs import atomic_path
from trackers.landmarks.mesh import FACE_OVAL

log = logging.getLogger(__name__)

__all__ = ["MESH_POINT_PREFIX", "NAMED_POINTS", "SEAM_MARGIN", "head_alignment",
           "image_stretch", "mesh_correspondence", "mesh_displacements", "mesh_indices",
           "mesh_point_names", "similarity_3d", "surface_points", "to_model_units"]

#: Name of face-mesh landmark ``i`` as a measurement point: ``f"mesh_{i}"``.
MESH_POINT_PREFIX = "mesh_"

#: Landmarks closer than this to the model's mouth line (cm) are not used: the mouth
#: parts there, and a landmark put on the other lip would read the jaw backwards.
SEAM_MARGIN = 0.15

# the eyelid contours (the face model does not blink); the face oval (FACE_OVAL) is the
# silhouette, which slides over the surface as the head turns
_EYELIDS = (263, 249, 390, 373, 374, 380, 381, 382, 362, 466, 388, 387, 386, 385, 384, 398,
            33, 7, 163, 144, 145, 153, 154, 155, 133, 246, 161, 160, 159, 158, 157, 173)
_OFF_SILHOUETTE = np.setdiff1d(np.arange(468), FACE_OVAL)
#: The rigid points of the 3-D alignment: eye corners and the nose's bridge.
RIGID_3D = (33, 133, 362, 263, 168, 6, 197, 195, 5, 4)

#: Landmarks put on a named landmark of the model instead of the skin under them: the
#: mouth corners, which end the mouth line and so lie within :data:`SEAM_MARGIN` of it,
#: but move with neither lip alone. ``_l`` is the subject's left.
NAMED_POINTS = {61: "mouth_corner_r", 291: "mouth_corner_l"}

#: Reweighting rounds of the robust head alignment (:func:`head_alignment`; 0: the rigid
#: points alone).
ALIGN_ROUNDS = 4
#: Residual (a fraction of the face's RMS radius in the image) at which a landmark's
#: weight in the head alignment has halved.
ALIGN_SCALE = 0.02
#: Frames whose displacements :func:`mesh_displacements` works out at a time.
DISPLACEMENT_CHUNK = 256

#: Smallest |normal z| of a skin triangle a landmark may sit on (facing the camera).
_MIN_FACING = 0.5
_RENDER_SIZE = 640


def mesh_point_names(indices) -> tuple[str, ...]:
    """Measurement-point names of face-mesh landmarks ``indices``."""
    return tuple(f"{MESH_POINT_PREFIX}{int(i)}" for i in indices)


def _key(model) -> str:
    from trackers.landmarks.models import FACE_MODEL_FILES

    return digest_of([
        __version__.encode(),
        np.ascontiguousarray(model.mesh.vertices, dtype=np.float64).tobytes(),
        np.ascontiguousarray(model.mesh.triangles).tobytes(),
        repr(sorted(FACE_MODEL_FILES.items())).encode(),
        repr((SEAM_MARGIN, FACE_OVAL, _EYELIDS, _MIN_FACING, _RENDER_SIZE, NAMED_POINTS))
        .encode(),
        source_digest(("synth", "trackers"), ("faceanalysis.estimation.mesh_points",)).encode(),
    ])


def _renderer(model):
    from synth.render.camera import default_camera
    from synth.render.renderer import Renderer
    from synth.render.texture import paint_skin_texture

    mesh = model.mesh
    cam = default_camera(_RENDER_SIZE, _RENDER_SIZE)
    return Renderer(mesh, texture=paint_skin_texture(mesh, 0, size=1024), camera=cam)


def _compute_correspondence(model) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    from trackers.landmarks import LandmarkTracker

    mesh = model.mesh
    renderer = _renderer(model)
    rest = np.asarray(mesh.vertices, dtype=float)
    frame = renderer.render(rest)
    lm = LandmarkTracker(channel_order="rgb").track(frame.image)
    if lm is None:
        raise RuntimeError("the landmark model found no face on the rendered generic face")
    tris = np.asarray(mesh.triangles)
    v = rest[tris]                                                 # (M, 3, 3)
    normal = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
    facing = np.abs(normal[:, 2]) / np.maximum(np.linalg.norm(normal, axis=1), 1e-12)
    mouth = np.asarray(mesh.curve_positions("mouth_line", rest))[:, :2]
    excluded = set(FACE_OVAL) | set(_EYELIDS)
    out: dict[int, tuple[np.ndarray, np.ndarray]] = {
        i: (np.full(3, mesh.landmarks[name], dtype=np.intp), np.array([1.0, 0.0, 0.0]))
        for i, name in NAMED_POINTS.items()}
    h, w = frame.triangle_id.shape
    for i, (x, y) in enumerate(np.asarray(lm.points, dtype=float)):
        if i in excluded or i in out:
            continue
        col, row = int(round(x)), int(round(y))
        if not (0 <= row < h and 0 <= col < w) or not frame.skin_mask[row, col]:
            continue
        t = int(frame.triangle_id[row, col])
        if facing[t] < _MIN_FACING:
            continue
        # barycentric weights of the landmark itself (not the pixel centre) in the
        # triangle's projection
        xy = frame.xy[tris[t]]
        a = np.column_stack([xy[1] - xy[0], xy[2] - xy[0]])
        try:
            uv = np.linalg.solve(a, np.array([x, y]) - xy[0])
        except np.linalg.LinAlgError:
            continue
        bary = np.clip(np.array([1.0 - uv.sum(), uv[0], uv[1]]), 0.0, 1.0)
        bary /= bary.sum()
        point = bary @ v[t]
        seam = np.min(np.hypot(*(mouth - point[:2]).T))
        if seam < SEAM_MARGIN:
            continue
        out[i] = (tris[t].astype(np.intp), bary)
    return out


@functools.lru_cache(maxsize=4)
def _cached(key: str, model) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    path = cache_dir() / f"mesh-points-{key}.npz"
    if path.is_file():
        try:
            with np.load(path) as z:
                return {int(i): (t, b) for i, t, b in zip(z["index"], z["vertices"], z["bary"])}
        except (OSError, ValueError, KeyError) as exc:
            log.warning("ignoring unreadable mesh-point cache %s (%s)", path, exc)
    corr = _compute_correspondence(model)
    try:
        idx = np.array(sorted(corr), dtype=np.intp)
        with atomic_path(path) as tmp, open(tmp, "wb") as fh:
            np.savez(fh, index=idx, vertices=np.array([corr[i][0] for i in idx]),
                     bary=np.array([corr[i][1] for i in idx]))
    except OSError as exc:                                # read-only home: run uncached
        log.debug("could not cache the mesh points: %s", exc)
    return corr


def mesh_correspondence(model=None) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """Where each usable face-mesh landmark lies on ``model``'s skin (default: the generic
    face), cached on disk.

    Returns
    -------
    dict
        Landmark index -> (vertex indices, shape (3,); barycentric weights, shape (3,)) of
        the skin point under it on the rendered rest face.

    Raises
    ------
    RuntimeError
        When the landmark model finds no face on the render.
    """
    if model is None:
        from synth import FaceModel

        model = FaceModel.default()
    return _cached(_key(model), model)


@functools.lru_cache(maxsize=1)
def _default_correspondence() -> dict[int, tuple[np.ndarray, np.ndarray]]:
    # once per process: building the generic model and hashing it costs 60 ms, and a
    # response table reads the points at every one of its ~600 equilibria
    return mesh_correspondence()


def surface_points(names) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """The skin point of each face-mesh measurement point ``mesh_<i>`` in ``names``: vertex
    indices and barycentric weights on the generic face (:func:`mesh_correspondence`),
    which hold on any model of the same topology (a personalised one).

    Raises
    ------
    ValueError
        For a name that is not a usable face-mesh landmark (the message says which).
    """
    corr = _default_correspondence()
    out = {}
    for name in names:
        try:
            i = int(str(name).removeprefix(MESH_POINT_PREFIX))
        except ValueError:
            raise ValueError(f"{name!r} is not a face-mesh point ({MESH_POINT_PREFIX}<index>)"
                             ) from None
        if i not in corr:
            raise ValueError(f"face-mesh landmark {i} has no place on the face model (on the "
                             "silhouette, an eyelid or the mouth line); usable ones: "
                             "mesh_correspondence()")
        out[name] = corr[i]
    return out


def similarity_3d(src: np.ndarray, dst: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """Least-squares similarity ``x -> s R x + t`` carrying 3-D ``src`` onto ``dst``
    (Umeyama 1991).

    Examples
    --------
    >>> p = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1.0]])
    >>> s, R, t = similarity_3d(p, 2 * p + 1)
    >>> round(s, 6), np.allclose(R, np.eye(3)), t.round(6).tolist()
    (2.0, True, [1.0, 1.0, 1.0])
    """
    a = np.asarray(src, dtype=float)
    if np.mean(np.sum((a - a.mean(axis=0)) ** 2, axis=1)) < 1e-12:
        raise ValueError("the source points coincide")
    s, rot, t = _weighted_similarity(a, np.asarray(dst, dtype=float)[None],
                                     np.ones((1, len(a))))
    return float(s[0]), rot[0], t[0]


def _weighted_similarity(src, dst, w):
    """:func:`similarity_3d` of ``src`` onto each of the ``dst`` with weights ``w``, for a
    stack of frames: ``dst`` (T, N, 3), ``w`` (T, N); returns scales (T,), rotations
    (T, 3, 3) and translations (T, 3)."""
    n_t = len(dst)
    ma, mb = np.empty((n_t, 3)), np.empty((n_t, 3))
    var, cov = np.empty(n_t), np.empty((n_t, 3, 3))
    _moments_nb(np.ascontiguousarray(src, dtype=float), np.ascontiguousarray(dst, dtype=float),
                np.ascontiguousarray(w, dtype=float), ma, mb, var, cov)
    u, sv, vt = np.linalg.svd(cov)
    sign = np.sign(np.linalg.det(u @ vt))
    d = np.ones((n_t, 3))
    d[:, 2] = sign
    rot = u @ (d[:, :, None] * vt)
    s = np.sum(sv * d, axis=1) / np.maximum(var, 1e-12)
    return s, rot, mb - s[:, None] * np.einsum("tij,tj->ti", rot, ma)


# The weighted moments and the residual weights loop over every frame's hundreds of points in
# compiled code (a dozen array operations on (T, N, 3) stacks cost more than their arithmetic);
# the 3x3 SVDs stay batched in NumPy, whose compiled-linear-algebra counterpart takes Numba
# tens of seconds to compile on first use.
@numba.njit(cache=True, nogil=True)
def _moments_nb(src, dst, w, ma, mb, var, cov):
    n_t, n = w.shape
    for t in range(n_t):
        tot = 0.0
        for i in range(n):
            tot += w[t, i]
        inv = 1.0 / tot
        for k in range(3):
            sa = 0.0
            sb = 0.0
            for i in range(n):
                sa += w[t, i] * src[i, k]
                sb += w[t, i] * dst[t, i, k]
            ma[t, k] = sa * inv
            mb[t, k] = sb * inv
        v = 0.0
        for j in range(3):
            for k in range(3):
                cov[t, j, k] = 0.0
        for i in range(n):
            wi = w[t, i] * inv
            a0 = src[i, 0] - ma[t, 0]
            a1 = src[i, 1] - ma[t, 1]
            a2 = src[i, 2] - ma[t, 2]
            v += wi * (a0 * a0 + a1 * a1 + a2 * a2)
            for j in range(3):
                b = wi * (dst[t, i, j] - mb[t, j])
                cov[t, j, 0] += b * a0
                cov[t, j, 1] += b * a1
                cov[t, j, 2] += b * a2
        var[t] = v


@numba.njit(cache=True, nogil=True)
def _cauchy_weights_nb(ref, p, s, rot, tr, scale, w):
    # 1 / (1 + (r / scale)^2) of each point's residual r from the similarity's prediction
    n_t, n = w.shape
    for t in range(n_t):
        for i in range(n):
            r2 = 0.0
            for j in range(3):
                m = s[t] * (rot[t, j, 0] * ref[i, 0] + rot[t, j, 1] * ref[i, 1]
                            + rot[t, j, 2] * ref[i, 2]) + tr[t, j] - p[t, i, j]
                r2 += m * m
            w[t, i] = 1.0 / (1.0 + r2 / (scale * scale))


def head_alignment(neutral, points, *, rigid=RIGID_3D, rounds: int = ALIGN_ROUNDS):
    """The 3-D similarities carrying the neutral frame's face-mesh landmarks onto each frame's,
    robust to the face's own motion.

    Each starts from the ``rigid`` points and is refitted ``rounds`` times on every landmark
    off the silhouette with Cauchy weights ``1 / (1 + (r / s)^2)`` of each landmark's
    residual ``r``, ``s`` being :data:`ALIGN_SCALE` times the face's size: the landmarks
    an expression moves (a jaw drops a third of the face) weigh little, and the many it
    leaves still (forehead, temples, nose, upper cheeks) hold the head. The eye corners and
    nose bridge alone move with a smile or an open jaw in the landmark model's output.

    Parameters
    ----------
    neutral : ndarray, shape (468, 3)
    points : ndarray, shape (T, 468, 3)
        The frames' landmarks.

    Returns
    -------
    (ndarray (T,), ndarray (T, 3, 3), ndarray (T, 3))
        Scales, rotations and translations.
    """
    ref = np.asarray(neutral, dtype=float)
    p = np.asarray(points, dtype=float)
    rig = np.asarray(rigid, dtype=np.intp)
    use = _OFF_SILHOUETTE
    size = float(np.sqrt(np.mean(np.sum((ref[use, :2] - ref[use, :2].mean(0)) ** 2, axis=1))))
    scale = ALIGN_SCALE * max(size, 1e-9)
    s, rot, tr = _weighted_similarity(ref[rig], p[:, rig], np.ones((len(p), len(rig))))
    ref_use = np.ascontiguousarray(ref[use])
    p_use = np.ascontiguousarray(p[:, use])
    w = np.empty((len(p), len(use)))
    for _ in range(rounds):
        _cauchy_weights_nb(ref_use, p_use, s, rot, tr, float(scale), w)
        s, rot, tr = _weighted_similarity(ref_use, p_use, w)
    return s, rot, tr


def image_stretch(predicted, observed, *, rounds: int = ALIGN_ROUNDS):
    """The small linear map of the image that the 3-D similarity leaves: a horizontal
    stretch and the two shears, about the face's centre, fitted robustly per frame.

    A rigid head seen by the landmark model does not move its points by a similarity
    alone: its depths are a guess (their scale most of all) and a real camera is not
    orthographic, so a turned or moving head also stretches the face sideways and shears
    it in the model's output. The map ``observed ~ centre + M (predicted - centre) +
    shift`` has ``M = I + [[a, b], [c, 0]]``: the vertical stretch is left out because
    an opening jaw and raised brows stretch the face vertically themselves (with it, the
    jaw of rendered faces read 2.0 degrees off instead of 1.5). Each point weighs
    ``1 / (1 + (r / s)^2)`` of its residual, as in :func:`head_alignment`.

    Parameters
    ----------
    predicted : ndarray, shape (T, 468, 2)
        Where the similarity puts the neutral frame's landmarks in each frame's image.
    observed : ndarray, shape (T, 468, 2)
        Where the landmark model put them.
    rounds : int, keyword-only
        Reweighting rounds.

    Returns
    -------
    (ndarray (T, 2, 2), ndarray (T, 2), ndarray (T, 2))
        ``M``, the centre (the predicted points' mean off the silhouette) and the shift.

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> pred = rng.normal(0.0, 50.0, (1, 468, 2))
    >>> m_true = np.array([[1.03, 0.01], [-0.02, 1.0]])
    >>> c = pred[0, _OFF_SILHOUETTE].mean(axis=0)
    >>> obs = c + (pred - c) @ m_true.T + [2.0, -1.0]
    >>> m, centre, shift = image_stretch(pred, obs)
    >>> np.allclose(m[0], m_true), np.allclose(shift[0], [2.0, -1.0])
    (True, True)
    """
    pred = np.ascontiguousarray(predicted, dtype=float)
    obs = np.ascontiguousarray(observed, dtype=float)
    if pred.shape != obs.shape or pred.ndim != 3 or pred.shape[1:] != (468, 2):
        raise ValueError(f"predicted and observed must both have shape (T, 468, 2), got "
                         f"{pred.shape} and {obs.shape}")
    n_t = len(pred)
    m, centre, shift = np.empty((n_t, 2, 2)), np.empty((n_t, 2)), np.empty((n_t, 2))
    _stretch_nb(pred, obs, _OFF_SILHOUETTE.astype(np.intp), max(int(rounds), 1),
                float(ALIGN_SCALE), m, centre, shift)
    return m, centre, shift


@numba.njit(cache=True, nogil=True)
def _solve3(g, h):
    # Cramer's rule: numba's own linear algebra costs seconds of compilation on first use
    d = (g[0, 0] * (g[1, 1] * g[2, 2] - g[1, 2] * g[2, 1])
         - g[0, 1] * (g[1, 0] * g[2, 2] - g[1, 2] * g[2, 0])
         + g[0, 2] * (g[1, 0] * g[2, 1] - g[1, 1] * g[2, 0]))
    x0 = (h[0] * (g[1, 1] * g[2, 2] - g[1, 2] * g[2, 1])
          - g[0, 1] * (h[1] * g[2, 2] - g[1, 2] * h[2])
          + g[0, 2] * (h[1] * g[2, 1] - g[1, 1] * h[2])) / d
    x1 = (g[0, 0] * (h[1] * g[2, 2] - g[1, 2] * h[2])
          - h[0] * (g[1, 0] * g[2, 2] - g[1, 2] * g[2, 0])
          + g[0, 2] * (g[1, 0] * h[2] - h[1] * g[2, 0])) / d
    x2 = (g[0, 0] * (g[1, 1] * h[2] - h[1] * g[2, 1])
          - g[0, 1] * (g[1, 0] * h[2] - h[1] * g[2, 0])
          + h[0] * (g[1, 0] * g[2, 1] - g[1, 1] * g[2, 0])) / d
    return x0, x1, x2


@numba.njit(cache=True, nogil=True)
def _stretch_nb(pred, obs, use, rounds, rel_scale, m, centre, shift):
    # per frame: x residual = a u + b v + sx, y residual = c u + sy, (u, v) the predicted
    # point about the centre over the face's RMS radius; Cauchy-reweighted least squares
    n = use.shape[0]
    for t in range(pred.shape[0]):
        cx = 0.0
        cy = 0.0
        for i in range(n):
            cx += pred[t, use[i], 0]
            cy += pred[t, use[i], 1]
        cx /= n
        cy /= n
        size = 0.0
        for i in range(n):
            du = pred[t, use[i], 0] - cx
            dv = pred[t, use[i], 1] - cy
            size += du * du + dv * dv
        size = max(np.sqrt(size / n), 1e-9)
        s2 = (rel_scale * size) ** 2
        a = b = c = sx = sy = 0.0
        gx = np.empty((3, 3))
        hx = np.empty(3)
        for _ in range(rounds):
            gx[:] = 0.0
            hx[:] = 0.0
            g00 = g01 = g11 = h0 = h1 = 0.0
            for i in range(n):
                k = use[i]
                u = (pred[t, k, 0] - cx) / size
                v = (pred[t, k, 1] - cy) / size
                rx = obs[t, k, 0] - pred[t, k, 0]
                ry = obs[t, k, 1] - pred[t, k, 1]
                ex = rx - (a * u + b * v + sx)
                ey = ry - (c * u + sy)
                w = 1.0 / (1.0 + (ex * ex + ey * ey) / s2)
                gx[0, 0] += w * u * u
                gx[0, 1] += w * u * v
                gx[0, 2] += w * u
                gx[1, 1] += w * v * v
                gx[1, 2] += w * v
                gx[2, 2] += w
                hx[0] += w * u * rx
                hx[1] += w * v * rx
                hx[2] += w * rx
                g00 += w * u * u
                g01 += w * u
                g11 += w
                h0 += w * u * ry
                h1 += w * ry
            gx[1, 0] = gx[0, 1]
            gx[2, 0] = gx[0, 2]
            gx[2, 1] = gx[1, 2]
            a, b, sx = _solve3(gx, hx)
            det = g00 * g11 - g01 * g01
            c = (g11 * h0 - g01 * h1) / det
            sy = (g00 * h1 - g01 * h0) / det
        m[t, 0, 0] = 1.0 + a / size
        m[t, 0, 1] = b / size
        m[t, 1, 0] = c / size
        m[t, 1, 1] = 1.0
        centre[t, 0] = cx
        centre[t, 1] = cy
        shift[t, 0] = sx
        shift[t, 1] = sy


def mesh_displacements(landmarks, neutral: int, indices, *, rigid=RIGID_3D,
                       rounds: int = ALIGN_ROUNDS, stretch: bool = True) -> np.ndarray:
    """Motion of face-mesh landmarks since the neutral frame, with the head's taken out.

    Each frame's 468 landmarks (x, y, z; pixels) are carried onto the neutral frame's by
    the inverse of the 3-D similarity that carries the neutral frame's landmarks onto the
    frame's (:func:`head_alignment`), so what is left is the face's own motion, expressed
    in the neutral frame's image (pixels, x right, y down). With ``stretch`` (the default),
    the horizontal stretch and shears that the similarity leaves in the frame's image
    (:func:`image_stretch`) are taken out as well, and what is left of each point's image
    motion is taken back through the similarity's in-plane part.

    Parameters
    ----------
    landmarks : sequence of (468, 3) arrays or None
        The landmark tracker's points per frame (``Tracks.landmarks``); None: lost.
    neutral : int
        Row of the neutral frame.
    indices : sequence of int
        Landmarks to return.
    rigid, rounds
        See :func:`head_alignment`.
    stretch : bool, keyword-only
        Take out the image's horizontal stretch and shears as well (:func:`image_stretch`).

    Returns
    -------
    ndarray, shape (T, len(indices), 2)
        Displacement in the neutral frame's pixels; NaN on frames without landmarks.
    """
    if landmarks[neutral] is None:
        raise ValueError(f"the neutral frame (row {neutral}) has no face-mesh landmarks")
    idx = np.asarray(indices, dtype=np.intp)
    ref = np.asarray(landmarks[neutral], dtype=float)
    out = np.full((len(landmarks), len(idx), 2), np.nan)
    seen = np.array([t for t, pts in enumerate(landmarks) if pts is not None], np.intp)
    # frames are independent: a chunk at a time, the working arrays (some 50 kB a frame)
    # stay the size of a chunk however long the video is
    for a in range(0, len(seen), DISPLACEMENT_CHUNK):
        rows = seen[a:a + DISPLACEMENT_CHUNK]
        p = np.stack([np.asarray(landmarks[t], dtype=float) for t in rows])
        out[rows] = _displacements(ref, p, idx, rigid, rounds, stretch)
    return out


def _displacements(ref, p, idx, rigid, rounds, stretch):
    """:func:`mesh_displacements` of the frames ``p`` (T, 468, 3), all with landmarks."""
    s, rot, tr = head_alignment(ref, p, rigid=rigid, rounds=rounds)
    if not stretch:
        # into the neutral pose: R^T (p - t) / s
        back = (p[:, idx] - tr[:, None]) @ rot / s[:, None, None]
        return back[..., :2] - ref[idx, :2]
    # (matrix products, not einsum: these are the estimation's largest array operations)
    predicted = ref @ np.swapaxes(s[:, None, None] * rot[:, :2], 1, 2) + tr[:, None, :2]
    m, centre, shift = image_stretch(predicted, p[..., :2], rounds=rounds)
    expected = ((predicted[:, idx] - centre[:, None]) @ np.swapaxes(m, 1, 2)
                + (centre + shift)[:, None])
    # what is left, seen in the image, taken back into the neutral frame's: the image moves
    # m s R_xy per unit of a neutral displacement in the face's plane
    jac = m @ (s[:, None, None] * rot[:, :2, :2])
    return (p[:, idx, :2] - expected) @ np.swapaxes(np.linalg.inv(jac), 1, 2)


def mesh_indices() -> tuple[int, ...]:
    """The face-mesh landmarks that are measurement points, in index order."""
    return tuple(sorted(_default_correspondence()))


def to_model_units(displacements: np.ndarray, reference: np.ndarray, head: np.ndarray,
                   calibration) -> np.ndarray:
    """Image displacements (pixels) of points at ``reference`` (pixels) on the neutral frame
    whose head frame is ``head``, in model cm through ``calibration``
    (:class:`~faceanalysis.estimation.calibration.Calibration`)."""
    from faceanalysis.tracking import to_head_frame

    q1 = to_head_frame(np.asarray(reference, float) + displacements, head)
    q0 = to_head_frame(np.asarray(reference, float), head)
    return (q1 - q0) @ np.linalg.inv(calibration.matrix).T

