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
Defined the way the trackers define it (004 V-D), on the rigid head: ``head_x, head_y``
is the image position of the mean of the three hairline landmarks (``hairline_l``,
``hairline_centre``, ``hairline_r``) of the *rest* mesh moved by the head pose (the hairline
sits on the skull: expressions do not move the frame); ``head_scale`` is the image scale in
px per cm of the model at that point; ``head_roll`` is the in-plane rotation in radians,
the image angle ``atan2(dy, dx)`` of the projected model x axis (subject's left), positive
clockwise on screen (image y points down).
"""

from __future__ import annotations

import math

import numpy as np

from synth.render.camera import HeadPose, project
from synth.render.raster import _flow_kernel

__all__ = ["forward_flow", "flow_and_occlusion", "head_frame", "project_landmarks",
           "warp_backward", "FIDUCIALS", "HAIRLINE_LANDMARKS"]

#: The 11 fiducial points of 004 V-D, in the order of DESIGN.md.
FIDUCIALS = ("brow_inner_l", "brow_mid_l", "brow_outer_l", "brow_inner_r", "brow_mid_r",
             "brow_outer_r", "mouth_corner_l", "mouth_corner_r", "furrow_top_l",
             "furrow_top_r", "chin")
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


def head_frame(rest_vertices: np.ndarray, landmarks: dict, camera, pose: HeadPose | None
               ) -> dict:
    """Head reference frame ground truth (see the module docstring).

    Returns
    -------
    dict with head_x, head_y (px), head_scale (px/cm), head_roll (radians)
    """
    pose = pose or HeadPose()
    missing = [n for n in HAIRLINE_LANDMARKS if n not in landmarks]
    if missing:
        raise ValueError(f"mesh landmarks lack {missing}")
    pts = np.asarray(rest_vertices, dtype=np.float64)[[landmarks[n] for n in
                                                       HAIRLINE_LANDMARKS]]
    origin = pts.mean(axis=0)
    probe = np.array([origin, origin + [1.0, 0.0, 0.0]])
    xy, depth = project(probe, camera, pose)
    dx, dy = xy[1] - xy[0]
    # px per cm: the length of a 1-cm segment parallel to the image plane at the origin
    scale = float(camera.px_per_cm(depth[0]))
    return {"head_x": float(xy[0, 0]), "head_y": float(xy[0, 1]), "head_scale": scale,
            "head_roll": float(math.atan2(dy, dx))}
