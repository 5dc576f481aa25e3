"""Ground truth that only the renderer knows: exact dense flow, fiducials, head frame.

Dense forward flow
------------------
For every pixel ``p`` of frame t the rasterizer knows which triangle is visible and the
barycentric coordinates ``b`` of the surface point under the pixel centre. The same
material point at frame t+1 is ``P' = sum_k b_k V_{t+1}[tri_k]``; the flow is
``project(P') - p`` (image px, x right, y down). Flags:

- ``occluded`` (frame t coordinates): the point leaves the image, its (skin) triangle turns
  back-facing, or it lies behind the surface visible at t+1 by more than ``eps`` cm (a
  triangle sharing a vertex with the source triangle never counts as occluding), or the
  pixel is background at t and face at t+1 (the static background gets covered).
- ``disoccluded`` (frame t+1 coordinates): the same test run backward, from t+1 to t:
  pixels visible at t+1 whose surface point was hidden (or outside the image) at t.

Background pixels have zero flow (the background is static).

Head reference frame
--------------------
Defined as the trackers define it (``trackers.fiducials.head_frame``; 004 V-D: "a head
reference frame from the average position of the hairline contour"), but measured on the
*rigid* head (the rest mesh moved by the head pose, so expressions never move the frame):

- ``head_x, head_y``: the arc-length centroid of the projected hairline curve (the
  ``hairline`` feature curve lifted from uv onto the rest surface), over its central part
  within +-0.76 inter-eye distances of the midline (:data:`HAIRLINE_HALF_SPAN`: the span
  of the trackers' hairline template; the painted hairline runs on down to the temples);
- ``head_scale``: the distance in px from that origin to the projected midpoint of the two
  nostril centroids (the trackers' nose-tip contour follows the dark nostrils); a length
  in pixels, not a physical unit (``px_per_cm`` is given separately);
- ``head_roll``: the in-plane rotation in radians, the image angle ``atan2(dy, dx)`` of the
  projected model x axis (subject's left): 0 upright, positive when the subject's left side
  is lower in the image (clockwise on screen, image y points down).

Meshes without feature curves fall back to the hairline landmarks (origin: their mean) and
the ``subnasale`` landmark.
"""

from __future__ import annotations

import math

import numpy as np

from synth.face_mesh import FIDUCIALS, locate_uv, resample_polyline_uv
from synth.render.camera import HeadPose, project
from synth.render.raster import _flow_kernel

__all__ = ["forward_flow", "flow_and_occlusion", "head_frame", "project_landmarks",
           "surface_points_from_uv",
           "warp_backward", "FIDUCIALS", "HAIRLINE_LANDMARKS"]

HAIRLINE_LANDMARKS = ("hairline_l", "hairline_centre", "hairline_r")


def _cam_params(cam) -> np.ndarray:
    cx, cy = cam.centre
    return np.array([cam.look_at[0], cam.look_at[1], cam.look_at[2], cam.distance,
                     cam.focal, cx, cy], dtype=np.float64)


def forward_flow(renderer, result_t, result_t1, *, eps: float = 0.1):
    """Exact forward flow from frame t to t+1 and its occlusion mask (frame t pixels).

    Parameters
    ----------
    renderer : Renderer
        The renderer that made both results (triangles, culling).
    result_t, result_t1 : RenderResult
        Frames t and t+1 (``shade=False`` suffices).
    eps : float
        Depth tolerance (cm) of the visibility test.

    Returns
    -------
    flow : (H, W, 2) float32
        Displacement (dx, dy) in px of the surface under each pixel.
    occluded : (H, W) bool
    """
    if result_t.triangle_id.shape != result_t1.triangle_id.shape:
        raise ValueError("both frames must have the same size")
    if eps < 0:
        raise ValueError(f"eps={eps} must be non-negative")
    H, W = result_t.triangle_id.shape
    flow = np.zeros((H, W, 2), dtype=np.float64)
    occ = np.zeros((H, W), dtype=np.bool_)
    cam = result_t1.camera
    _flow_kernel(result_t.triangle_id, result_t.barycentric, renderer.triangles,
                 renderer.cull, result_t1.world, result_t1.xy, result_t1.vertex_depth,
                 result_t1.depth, result_t1.triangle_id, cam.perspective, _cam_params(cam),
                 float(eps), flow, occ)
    return flow.astype(np.float32), occ


def flow_and_occlusion(renderer, result_t, result_t1, *, eps: float = 0.1):
    """Forward flow, occlusion (frame t) and disocclusion (frame t+1) masks.

    Returns
    -------
    flow : (H, W, 2) float32
    occluded : (H, W) bool, in frame t
    disoccluded : (H, W) bool, in frame t+1

    Examples
    --------
    >>> from synth.render.renderer import Renderer, Surface
    >>> surf = Surface(vertices=np.array([[-5.0, -5, 0], [5, -5, 0], [0, 5, 0]]),
    ...                triangles=np.array([[0, 1, 2]]), uv=np.zeros((3, 2)))
    >>> r = Renderer(surf)
    >>> a = r.render(surf.vertices, shade=False)
    >>> b = r.render(surf.vertices + [0.1, 0, 0], shade=False)
    >>> flow, occ, dis = flow_and_occlusion(r, a, b)
    >>> round(float(flow[128, 128, 0]), 3)     # 0.1 cm at 10.67 px/cm
    1.067
    """
    flow, occ = forward_flow(renderer, result_t, result_t1, eps=eps)
    _, back_occ = forward_flow(renderer, result_t1, result_t, eps=eps)
    # backward "occluded" on face pixels of t+1 = disoccluded; background pixels of t+1
    # that were face at t are uncovered background, also disoccluded
    return flow, occ, back_occ


def warp_backward(image_t1: np.ndarray, flow: np.ndarray) -> np.ndarray:
    """Sample frame t+1 at ``p + flow(p)``: the reconstruction of frame t (bilinear).

    Examples
    --------
    >>> img = np.arange(16, dtype=np.float32).reshape(4, 4)
    >>> fl = np.zeros((4, 4, 2), np.float32); fl[..., 0] = 1
    >>> warp_backward(img, fl)[0].tolist()
    [1.0, 2.0, 3.0, 3.0]
    """
    import cv2

    flow = np.asarray(flow, dtype=np.float32)
    H, W = flow.shape[:2]
    gx, gy = np.meshgrid(np.arange(W, dtype=np.float32), np.arange(H, dtype=np.float32))
    return cv2.remap(np.asarray(image_t1), gx + flow[..., 0], gy + flow[..., 1],
                     interpolation=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)


def project_landmarks(points: dict, renderer, result) -> dict:
    """Project named model-space points (already deformed) with the frame's camera and pose.

    Parameters
    ----------
    points : dict name -> (3,) array
        Current positions (cm, model space, before the head pose).
    renderer : Renderer
    result : RenderResult
        The frame (its camera, pose and z-buffer decide visibility).

    Returns
    -------
    dict name -> (x, y, visible)
        ``visible`` is False when the point falls outside the image or lies behind the
        visible surface by more than 0.15 cm.
    """
    names = list(points)
    if not names:
        return {}
    P = np.array([np.asarray(points[n], dtype=np.float64) for n in names])
    xy, depth = project(P, result.camera, result.pose)
    H, W = result.depth.shape
    out = {}
    for i, n in enumerate(names):
        x, y = float(xy[i, 0]), float(xy[i, 1])
        r, c = int(math.floor(y + 0.5)), int(math.floor(x + 0.5))
        visible = 0 <= r < H and 0 <= c < W
        if visible:
            z = result.depth[r - 1 if r > 0 else r: r + 2, c - 1 if c > 0 else c: c + 2]
            zmax = np.max(np.where(np.isfinite(z), z, -np.inf))
            visible = bool(depth[i] <= zmax + 0.15)
        out[n] = (x, y, visible)
    return out


def surface_points_from_uv(mesh, uv_points) -> np.ndarray:
    """Lift uv points onto the rest surface: (K, 2) uv -> (K, 3) model-space points.

    Each point is located in the mesh's uv triangulation and interpolated barycentrically;
    points outside every triangle get NaN.

    Examples
    --------
    >>> from synth.render.renderer import Surface
    >>> s = Surface(vertices=np.array([[0.0, 0, 0], [2, 0, 0], [0, 2, 1]]),
    ...             triangles=np.array([[0, 1, 2]]), uv=np.array([[0, 0], [1, 0], [0, 1.0]]))
    >>> surface_points_from_uv(s, [[0.5, 0.5], [0.9, 0.9]]).round(3).tolist()
    [[1.0, 1.0, 0.5], [nan, nan, nan]]
    """
    V = np.asarray(mesh.vertices, dtype=np.float64)
    T = np.asarray(mesh.triangles)
    tri, bary = locate_uv(uv_points, mesh.uv, T)
    out = np.full((len(tri), 3), np.nan)
    found = tri >= 0
    out[found] = np.einsum("kj,kjd->kd", bary[found], V[T[tri[found]]])
    return out


_FRAME_CACHE: dict = {}
#: Half-width of the hairline part that defines the head frame, in inter-eye distances (the
#: span of the trackers' hairline template, trackers.layout.TEMPLATE['hairline']).
HAIRLINE_HALF_SPAN = 0.76


def _frame_points(mesh):
    """Rest-surface hairline polyline (K, 3) and nose point (3,) of ``mesh`` (cached)."""
    key = id(mesh)
    hit = _FRAME_CACHE.get(key)
    if hit is not None and hit[0] is mesh:
        return hit[1], hit[2]
    curves = getattr(mesh, "feature_curves", None) or {}
    lm = getattr(mesh, "landmarks", {}) or {}
    V = np.asarray(mesh.vertices, dtype=np.float64)
    hair = None
    if "hairline" in curves:
        h = surface_points_from_uv(mesh, resample_polyline_uv(curves["hairline"]))
        h = h[np.all(np.isfinite(h), axis=1)]
        if "eye_centre_l" in lm and "eye_centre_r" in lm and len(h) >= 2:
            # the central part that the trackers' hairline contour spans
            el, er = V[lm["eye_centre_l"]], V[lm["eye_centre_r"]]
            half = HAIRLINE_HALF_SPAN * abs(el[0] - er[0])
            h = h[np.abs(h[:, 0] - 0.5 * (el[0] + er[0])) <= half]
        if len(h) >= 2:
            hair = h
    if hair is None:
        missing = [n for n in HAIRLINE_LANDMARKS if n not in lm]
        if missing:
            raise ValueError(f"mesh has no hairline curve and its landmarks lack {missing}")
        hair = V[[lm[n] for n in HAIRLINE_LANDMARKS]]
        hair = np.vstack([hair.mean(axis=0), hair.mean(axis=0)])   # centroid = their mean
    nose = None
    if "nostril_l" in curves and "nostril_r" in curves:
        cs = []
        for name in ("nostril_l", "nostril_r"):
            p = surface_points_from_uv(mesh, np.asarray(curves[name])[:-1])
            p = p[np.all(np.isfinite(p), axis=1)]
            if len(p):
                cs.append(p.mean(axis=0))
        if len(cs) == 2:
            nose = 0.5 * (cs[0] + cs[1])
    if nose is None:
        if "subnasale" not in lm:
            raise ValueError("mesh has no nostril curves and no subnasale landmark")
        nose = V[lm["subnasale"]]
    if len(_FRAME_CACHE) > 16:
        _FRAME_CACHE.clear()
    _FRAME_CACHE[key] = (mesh, hair, nose)
    return hair, nose


def head_frame(mesh, camera, pose: HeadPose | None = None) -> dict:
    """Head reference frame ground truth of the rigid head (see the module docstring).

    Parameters
    ----------
    mesh : FaceMesh
        Rest mesh (``vertices``, ``triangles``, ``uv``, ``feature_curves``, ``landmarks``).
    camera : Camera
    pose : HeadPose, optional

    Returns
    -------
    dict with head_x, head_y (px), head_scale (px, origin to nostrils), head_roll
    (radians) and px_per_cm (image scale at the origin)
    """
    pose = pose or HeadPose()
    hair, nose = _frame_points(mesh)
    xy, depth = project(np.vstack([hair, nose[None, :]]), camera, pose)
    hxy = xy[:-1]
    seg = np.hypot(*np.diff(hxy, axis=0).T)
    if seg.sum() > 1e-12:
        mid = 0.5 * (hxy[1:] + hxy[:-1])
        origin = (mid * seg[:, None]).sum(axis=0) / seg.sum()
    else:
        origin = hxy.mean(axis=0)
    # 3-D point under the origin (for the roll probe and the px/cm scale)
    w = np.r_[seg, 0.0] * 0.5 + np.r_[0.0, seg] * 0.5
    o3 = (hair * w[:, None]).sum(axis=0) / w.sum() if w.sum() > 0 else hair.mean(axis=0)
    probe, pdepth = project(np.array([o3, o3 + [1.0, 0.0, 0.0]]), camera, pose)
    dx, dy = probe[1] - probe[0]
    scale = float(np.hypot(*(xy[-1] - origin)))
    return {"head_x": float(origin[0]), "head_y": float(origin[1]), "head_scale": scale,
            "head_roll": float(math.atan2(dy, dx)),
            "px_per_cm": float(camera.px_per_cm(pdepth[0]))}
