"""Simple meshes for renderer tests (planes, spheres) built here, not from synth.mesh."""

import numpy as np

from synth.render.renderer import Surface


def plane(n=40, size=16.0, z=0.0, centre=(0.0, -2.0)):
    """A square grid in the z plane facing +z, uv spanning [0, 1]."""
    t = np.linspace(-0.5, 0.5, n)
    X, Y = np.meshgrid(t * size + centre[0], -t * size + centre[1])
    V = np.stack([X.ravel(), Y.ravel(), np.full(X.size, z)], axis=1)
    U = np.stack([(t[None, :] + 0.5).repeat(n, 0).ravel(),
                  (t[:, None] + 0.5).repeat(n, 1).ravel()], axis=1)
    idx = np.arange(n * n).reshape(n, n)
    a, b, c, d = idx[:-1, :-1], idx[:-1, 1:], idx[1:, :-1], idx[1:, 1:]
    # rows go downward in y (model), so (a, c, b) is counter-clockwise seen from +z
    tris = np.concatenate([np.stack([a, c, b], -1).reshape(-1, 3),
                           np.stack([b, c, d], -1).reshape(-1, 3)])
    return Surface(vertices=V, triangles=tris.astype(np.int32), uv=U)


def sphere(n_lat=40, n_lon=80, radius=7.0, centre=(0.0, -2.0, -7.0)):
    """A UV sphere, triangles counter-clockwise seen from outside."""
    lat = np.linspace(0, np.pi, n_lat)
    lon = np.linspace(0, 2 * np.pi, n_lon, endpoint=False)
    th, ph = np.meshgrid(lat, lon, indexing="ij")
    # longitude 0 (the uv seam) at the back, away from the camera
    V = np.stack([-np.sin(th) * np.sin(ph), np.cos(th), -np.sin(th) * np.cos(ph)], -1)
    V = V.reshape(-1, 3) * radius + np.asarray(centre)
    U = np.stack([(ph / (2 * np.pi)).ravel(), (th / np.pi).ravel()], 1)
    idx = np.arange(n_lat * n_lon).reshape(n_lat, n_lon)
    nxt = np.roll(idx, -1, axis=1)
    a, b, c, d = idx[:-1], nxt[:-1], idx[1:], nxt[1:]
    tris = np.concatenate([np.stack([a, c, b], -1).reshape(-1, 3),
                           np.stack([b, c, d], -1).reshape(-1, 3)]).astype(np.int32)
    # orient outward
    v = V[tris]
    nrm = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
    out = (v.mean(1) - np.asarray(centre))
    flip = (nrm * out).sum(1) < 0
    tris[flip] = tris[flip][:, [0, 2, 1]]
    area = np.linalg.norm(nrm, axis=1)
    tris = tris[area > 1e-12]
    return Surface(vertices=V, triangles=tris, uv=U)


def noise_texture(size=512, seed=0):
    rng = np.random.default_rng(seed)
    import cv2
    tex = np.zeros((size, size), np.float32)
    for k, amp in ((6, 0.25), (16, 0.2), (40, 0.2)):
        g = rng.random((k, k)).astype(np.float32)
        tex += amp * cv2.resize(g, (size, size), interpolation=cv2.INTER_CUBIC)
    tex = (tex - tex.min()) / (tex.max() - tex.min())
    return np.stack([0.3 + 0.6 * tex, 0.25 + 0.5 * tex, 0.2 + 0.4 * tex], -1)
