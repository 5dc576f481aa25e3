"""Numba kernels of the renderer: z-buffered triangles, normals, shading, exact flow.

All kernels take image coordinates (x right, y down, origin at the top-left pixel's
centre) and write into arrays the caller allocates; ``rasterize`` is the public, validated
entry point. Pixel ``(row, col)`` covers the point ``(x=col, y=row)``.

Front faces: the mesh's triangles are counter-clockwise seen from outside in model space
(y up); in image space (y down) a front-facing triangle has a *negative* signed area.
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["rasterize", "vertex_normals_fast", "BACKGROUND"]

#: triangle id of pixels that no triangle covers
BACKGROUND = -1


@numba.njit(cache=True, nogil=True)
def _raster_kernel(xy, depth, tris, cull, perspective, zbuf, tri_id, bary):
    H, W = zbuf.shape
    for t in range(tris.shape[0]):
        i0 = tris[t, 0]
        i1 = tris[t, 1]
        i2 = tris[t, 2]
        x0 = xy[i0, 0]
        y0 = xy[i0, 1]
        x1 = xy[i1, 0]
        y1 = xy[i1, 1]
        x2 = xy[i2, 0]
        y2 = xy[i2, 1]
        area = (x1 - x0) * (y2 - y0) - (x2 - x0) * (y1 - y0)
        if area == 0.0 or area != area:
            continue
        if cull[t] and area > 0.0:
            continue
        xmin = min(x0, min(x1, x2))
        xmax = max(x0, max(x1, x2))
        ymin = min(y0, min(y1, y2))
        ymax = max(y0, max(y1, y2))
        c0 = max(0, int(np.ceil(xmin)))
        c1 = min(W - 1, int(np.floor(xmax)))
        r0 = max(0, int(np.ceil(ymin)))
        r1 = min(H - 1, int(np.floor(ymax)))
        if c0 > c1 or r0 > r1:
            continue
        inv = 1.0 / area
        d0 = depth[i0]
        d1 = depth[i1]
        d2 = depth[i2]
        tol = -1e-9
        for r in range(r0, r1 + 1):
            py = float(r)
            for c in range(c0, c1 + 1):
                px = float(c)
                w0 = ((x1 - px) * (y2 - py) - (x2 - px) * (y1 - py)) * inv
                if w0 < tol:
                    continue
                w1 = ((x2 - px) * (y0 - py) - (x0 - px) * (y2 - py)) * inv
                if w1 < tol:
                    continue
                w2 = 1.0 - w0 - w1
                if w2 < tol:
                    continue
                w0 = max(w0, 0.0)
                w1 = max(w1, 0.0)
                w2 = max(w2, 0.0)
                s = w0 + w1 + w2
                w0 /= s
                w1 /= s
                w2 /= s
                if perspective:
                    q0 = w0 / d0
                    q1 = w1 / d1
                    q2 = w2 / d2
                    qs = q0 + q1 + q2
                    z = 1.0 / qs
                    b0 = q0 * z
                    b1 = q1 * z
                    b2 = q2 * z
                else:
                    z = w0 * d0 + w1 * d1 + w2 * d2
                    b0 = w0
                    b1 = w1
                    b2 = w2
                if z < zbuf[r, c]:
                    zbuf[r, c] = z
                    tri_id[r, c] = t
                    bary[r, c, 0] = b0
                    bary[r, c, 1] = b1
                    bary[r, c, 2] = b2


def rasterize(xy, depth, triangles, width, height, *, cull=None, perspective=False):
    """Z-buffer triangles into per-pixel triangle ids and barycentric coordinates.

    Parameters
    ----------
    xy : (N, 2) array_like
        Projected vertices in image coordinates (px).
    depth : (N,) array_like
        Vertex depth (distance from the camera plane, larger = farther).
    triangles : (M, 3) array_like of int
        Vertex indices.
    width, height : int
        Image size.
    cull : (M,) array_like of bool, optional
        Triangles to drop when back-facing (positive signed area in image space).
        Default: none culled.
    perspective : bool
        Interpolate perspective-correctly (1/depth is linear in the image).

    Returns
    -------
    zbuf : (H, W) float64
        Depth of the visible surface (inf on the background).
    tri_id : (H, W) int32
        Visible triangle (-1 on the background).
    bary : (H, W, 3) float64
        Barycentric coordinates of the visible surface point in its 3-D triangle.

    Examples
    --------
    >>> xy = np.array([[0.0, 0.0], [0.0, 3.0], [3.0, 0.0]])
    >>> z, tid, b = rasterize(xy, np.ones(3), [[0, 1, 2]], 4, 4)
    >>> tid.tolist()
    [[0, 0, 0, 0], [0, 0, 0, -1], [0, 0, -1, -1], [0, -1, -1, -1]]
    """
    xy = np.ascontiguousarray(xy, dtype=np.float64)
    depth = np.ascontiguousarray(depth, dtype=np.float64)
    tris = np.ascontiguousarray(triangles, dtype=np.int32)
    if xy.ndim != 2 or xy.shape[1] != 2:
        raise ValueError(f"xy must have shape (N, 2), got {xy.shape}")
    if depth.shape != (xy.shape[0],):
        raise ValueError(f"depth must have shape ({xy.shape[0]},), got {depth.shape}")
    if tris.ndim != 2 or tris.shape[1] != 3:
        raise ValueError(f"triangles must have shape (M, 3), got {tris.shape}")
    if tris.size and (tris.min() < 0 or tris.max() >= xy.shape[0]):
        raise ValueError("triangles index vertices out of range")
    width, height = int(width), int(height)
    if width < 1 or height < 1:
        raise ValueError(f"image size {width}x{height} must be positive")
    if cull is None:
        cull_arr = np.zeros(tris.shape[0], dtype=np.bool_)
    else:
        cull_arr = np.ascontiguousarray(cull, dtype=np.bool_)
        if cull_arr.shape != (tris.shape[0],):
            raise ValueError(f"cull must have shape ({tris.shape[0]},), got {cull_arr.shape}")
    zbuf = np.full((height, width), np.inf)
    tri_id = np.full((height, width), BACKGROUND, dtype=np.int32)
    bary = np.zeros((height, width, 3))
    _raster_kernel(xy, depth, tris, cull_arr, bool(perspective), zbuf, tri_id, bary)
    return zbuf, tri_id, bary


@numba.njit(cache=True, nogil=True)
def _normals_kernel(v, tris, out):
    out[:] = 0.0
    for t in range(tris.shape[0]):
        a = tris[t, 0]
        b = tris[t, 1]
        c = tris[t, 2]
        e1x = v[b, 0] - v[a, 0]
        e1y = v[b, 1] - v[a, 1]
        e1z = v[b, 2] - v[a, 2]
        e2x = v[c, 0] - v[a, 0]
        e2y = v[c, 1] - v[a, 1]
        e2z = v[c, 2] - v[a, 2]
        nx = e1y * e2z - e1z * e2y
        ny = e1z * e2x - e1x * e2z
        nz = e1x * e2y - e1y * e2x
        for k in range(3):
            i = tris[t, k]
            out[i, 0] += nx
            out[i, 1] += ny
            out[i, 2] += nz
    for i in range(out.shape[0]):
        n = np.sqrt(out[i, 0] ** 2 + out[i, 1] ** 2 + out[i, 2] ** 2)
        if n > 0:
            out[i, 0] /= n
            out[i, 1] /= n
            out[i, 2] /= n
        else:
            out[i, 2] = 1.0


def vertex_normals_fast(vertices, triangles):
    """Area-weighted unit vertex normals (N, 3) of a triangle mesh (Numba).

    Examples
    --------
    >>> v = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]])
    >>> vertex_normals_fast(v, [[0, 1, 2]])[0].tolist()
    [0.0, 0.0, 1.0]
    """
    v = np.ascontiguousarray(vertices, dtype=np.float64)
    t = np.ascontiguousarray(triangles, dtype=np.int32)
    out = np.empty_like(v)
    _normals_kernel(v, t, out)
    return out


@numba.njit(cache=True, nogil=True, fastmath=True)
def _sample_bilinear(tex, x, y, out):
    """Bilinear sample of tex (H, W, C) at pixel coordinates (x, y) (clamped) into out."""
    H = tex.shape[0]
    W = tex.shape[1]
    if x < 0.0:
        x = 0.0
    if y < 0.0:
        y = 0.0
    if x > W - 1.0:
        x = W - 1.0
    if y > H - 1.0:
        y = H - 1.0
    x0 = int(x)
    y0 = int(y)
    x1 = min(x0 + 1, W - 1)
    y1 = min(y0 + 1, H - 1)
    fx = x - x0
    fy = y - y0
    for ch in range(tex.shape[2]):
        a = tex[y0, x0, ch] * (1.0 - fx) + tex[y0, x1, ch] * fx
        b = tex[y1, x0, ch] * (1.0 - fx) + tex[y1, x1, ch] * fx
        out[ch] = a * (1.0 - fy) + b * fy


@numba.njit(cache=True, nogil=True, fastmath=True)
def _shade_kernel(tri_id, bary, tris, material, uv, normals, wpos, tex, eye_tex, flat_colours,
                  light_dir, light_rgb, ambient, specular, shininess, view_persp, eye_pos,
                  image, out_scale, out_offset, out_max):
    """Lambert + Blinn-Phong shading with texture lookup; writes RGB into image.

    material: 0 = skin (tex by uv), 1 = eye (eye_tex by uv), 2.. = flat colour
    flat_colours[material]. Values are written as ``min(max(v * out_scale + out_offset,
    0), out_max)`` (image may be float, or uint8 with scale 255, offset 0.5, max 255).
    """
    H, W = tri_id.shape
    th = tex.shape[0]
    tw = tex.shape[1]
    eh = eye_tex.shape[0]
    ew = eye_tex.shape[1]
    albedo = np.empty(3)
    for r in range(H):
        for c in range(W):
            t = tri_id[r, c]
            if t < 0:
                continue
            i0 = tris[t, 0]
            i1 = tris[t, 1]
            i2 = tris[t, 2]
            b0 = bary[r, c, 0]
            b1 = bary[r, c, 1]
            b2 = bary[r, c, 2]
            m = material[t]
            u = b0 * uv[i0, 0] + b1 * uv[i1, 0] + b2 * uv[i2, 0]
            v = b0 * uv[i0, 1] + b1 * uv[i1, 1] + b2 * uv[i2, 1]
            if m == 0:
                _sample_bilinear(tex, u * tw - 0.5, v * th - 0.5, albedo)
            elif m == 1:
                _sample_bilinear(eye_tex, u * ew - 0.5, v * eh - 0.5, albedo)
            else:
                albedo[0] = flat_colours[m, 0]
                albedo[1] = flat_colours[m, 1]
                albedo[2] = flat_colours[m, 2]
            nx = b0 * normals[i0, 0] + b1 * normals[i1, 0] + b2 * normals[i2, 0]
            ny = b0 * normals[i0, 1] + b1 * normals[i1, 1] + b2 * normals[i2, 1]
            nz = b0 * normals[i0, 2] + b1 * normals[i1, 2] + b2 * normals[i2, 2]
            nn = np.sqrt(nx * nx + ny * ny + nz * nz)
            if nn > 0:
                nx /= nn
                ny /= nn
                nz /= nn
            # view direction
            if view_persp:
                px = b0 * wpos[i0, 0] + b1 * wpos[i1, 0] + b2 * wpos[i2, 0]
                py = b0 * wpos[i0, 1] + b1 * wpos[i1, 1] + b2 * wpos[i2, 1]
                pz = b0 * wpos[i0, 2] + b1 * wpos[i1, 2] + b2 * wpos[i2, 2]
                vx = eye_pos[0] - px
                vy = eye_pos[1] - py
                vz = eye_pos[2] - pz
                vn = np.sqrt(vx * vx + vy * vy + vz * vz)
                vx /= vn
                vy /= vn
                vz /= vn
            else:
                vx = 0.0
                vy = 0.0
                vz = 1.0
            ndv = nx * vx + ny * vy + nz * vz
            if ndv < 0.0:   # two-sided lighting for the inner parts
                nx = -nx
                ny = -ny
                nz = -nz
            ndl = nx * light_dir[0] + ny * light_dir[1] + nz * light_dir[2]
            if ndl < 0.0:
                ndl = 0.0
            hx = light_dir[0] + vx
            hy = light_dir[1] + vy
            hz = light_dir[2] + vz
            hn = np.sqrt(hx * hx + hy * hy + hz * hz)
            spec = 0.0
            if hn > 0 and ndl > 0.0:
                ndh = (nx * hx + ny * hy + nz * hz) / hn
                if ndh > 0.0:
                    spec = specular[m] * ndh ** shininess
            for ch in range(3):
                val = ((albedo[ch] * (ambient + (1.0 - ambient) * ndl) + spec) * light_rgb[ch]
                       * out_scale + out_offset)
                image[r, c, ch] = min(max(val, 0.0), out_max)


@numba.njit(cache=True, nogil=True)
def _flow_kernel(tri_id, bary, tris, cull, wpos1, xy1, depth1, zbuf1, tri_id1, perspective,
                 eye_pos, eps, flow, occluded):
    """Forward flow of the surface under each pixel to the next frame.

    wpos1/xy1/depth1: posed world positions, image positions and depths of the vertices at
    the next frame; zbuf1/tri_id1: that frame's z-buffer. occluded is set where the point
    leaves the image, turns back-facing or hides behind another surface.
    """
    H, W = tri_id.shape
    for r in range(H):
        for c in range(W):
            t = tri_id[r, c]
            if t < 0:
                # static background: covered at the next frame -> occluded
                if tri_id1[r, c] >= 0:
                    occluded[r, c] = True
                continue
            i0 = tris[t, 0]
            i1 = tris[t, 1]
            i2 = tris[t, 2]
            b0 = bary[r, c, 0]
            b1 = bary[r, c, 1]
            b2 = bary[r, c, 2]
            if perspective:
                # project the 3-D point itself (projection is not affine)
                px = b0 * wpos1[i0, 0] + b1 * wpos1[i1, 0] + b2 * wpos1[i2, 0]
                py = b0 * wpos1[i0, 1] + b1 * wpos1[i1, 1] + b2 * wpos1[i2, 1]
                pz = b0 * wpos1[i0, 2] + b1 * wpos1[i1, 2] + b2 * wpos1[i2, 2]
                d = eye_pos[3] - (pz - eye_pos[2])
                f = eye_pos[4] / d
                x = eye_pos[5] + f * (px - eye_pos[0])
                y = eye_pos[6] - f * (py - eye_pos[1])
            else:
                x = b0 * xy1[i0, 0] + b1 * xy1[i1, 0] + b2 * xy1[i2, 0]
                y = b0 * xy1[i0, 1] + b1 * xy1[i1, 1] + b2 * xy1[i2, 1]
                d = b0 * depth1[i0] + b1 * depth1[i1] + b2 * depth1[i2]
            flow[r, c, 0] = x - c
            flow[r, c, 1] = y - r
            occ = False
            if cull[t]:
                x0 = xy1[i0, 0]
                y0 = xy1[i0, 1]
                area = ((xy1[i1, 0] - x0) * (xy1[i2, 1] - y0)
                        - (xy1[i2, 0] - x0) * (xy1[i1, 1] - y0))
                if area >= 0.0:
                    occ = True
            rr = int(np.floor(y + 0.5))
            cc = int(np.floor(x + 0.5))
            if rr < 0 or rr >= H or cc < 0 or cc >= W:
                occ = True
            elif not occ:
                t1 = tri_id1[rr, cc]
                if t1 < 0:
                    # lands on background at the pixel centre: the silhouette moved by a
                    # fraction of a pixel; the point itself is still in view
                    occ = False
                elif t1 != t:
                    shared = False
                    for a in range(3):
                        for b in range(3):
                            if tris[t1, a] == tris[t, b]:
                                shared = True
                    if not shared and d > zbuf1[rr, cc] + eps:
                        occ = True
            occluded[r, c] = occ
