"""A small stand-in face surface with the FaceMesh contract fields, for physics tests.

A curved (cylindrical) grid patch, 14 cm wide and 18 cm tall, facing +z, with a mouth seam
(upper and lower lip rows that coincide but are not joined), a mandible region below the
mouth, the outline glued to the skull, and a few named landmarks.  Symmetric about x = 0.
Also ``_perturbed``: a lattice's rest positions with the free nodes moved at random.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True, eq=False)
class StandInMesh:
    vertices: np.ndarray
    triangles: np.ndarray
    uv: np.ndarray
    region: np.ndarray
    landmarks: dict
    tissue_thickness: np.ndarray
    jaw_weight: np.ndarray
    jaw_pivot: np.ndarray
    boundary: np.ndarray
    mouth_seam: np.ndarray
    feature_curves: dict = field(default_factory=dict)
    inner_vertices: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    inner_triangles: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), np.int32))
    inner_material: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int8))
    inner_uv: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    inner_jaw_weight: np.ndarray = field(default_factory=lambda: np.zeros(0))


def make_standin_mesh(nx: int = 15, ny: int = 19) -> StandInMesh:
    """Build the stand-in surface; nx must be odd so that x = 0 is a grid column."""
    width, height, radius = 14.0, 18.0, 9.0
    u = np.linspace(0.0, 1.0, nx)
    v_up = np.linspace(0.0, 1.0, ny)            # v = 0 top ... 1 bottom
    mouth_row = int(round(0.72 * (ny - 1)))     # seam row (v index)
    verts, uvs, ids = [], [], {}
    # rows 0..mouth_row (upper part incl. upper lip row), then a duplicate mouth row
    rows = list(range(ny)) + [mouth_row]
    for r_i, r in enumerate(rows):
        for c in range(nx):
            theta = (u[c] - 0.5) * width / radius
            x = radius * np.sin(theta)
            z = radius * np.cos(theta) - radius
            y = 4.0 - v_up[r] * height
            verts.append((x, y, z))
            uvs.append((u[c], v_up[r]))
            ids[(r_i, c)] = len(verts) - 1
    verts = np.array(verts)
    lower_row_index = ny            # the duplicate row acts as the lower lip
    mouth_c0, mouth_c1 = nx // 2 - 3, nx // 2 + 3

    def vid(r, c, below_mouth):
        if r == mouth_row and below_mouth and mouth_c0 <= c <= mouth_c1:
            return ids[(lower_row_index, c)]
        return ids[(r, c)]

    tris = []
    for r in range(ny - 1):
        below = r >= mouth_row
        for c in range(nx - 1):
            a, b = vid(r, c, below), vid(r, c + 1, below)
            cc, d = vid(r + 1, c, below), vid(r + 1, c + 1, below)
            # counter-clockwise seen from +z (y up, x right as seen by the viewer = -x?)
            tris.append((a, cc, b))
            tris.append((b, cc, d))
    tris = np.array(tris, dtype=np.int32)
    used = np.unique(tris)
    # drop unused duplicates (lower-lip copies outside the mouth)
    remap = -np.ones(len(verts), int)
    remap[used] = np.arange(len(used))
    verts, uvs = verts[used], np.array(uvs)[used]
    tris = remap[tris].astype(np.int32)
    # orientation: make normals point toward +z
    n = np.cross(verts[tris[:, 1]] - verts[tris[:, 0]], verts[tris[:, 2]] - verts[tris[:, 0]])
    if n[:, 2].mean() < 0:
        tris = tris[:, [0, 2, 1]]
    seam = np.array([(remap[ids[(mouth_row, c)]], remap[ids[(lower_row_index, c)]])
                     for c in range(mouth_c0 + 1, mouth_c1)])
    n_v = len(verts)
    boundary = np.zeros(n_v, bool)
    boundary[(uvs[:, 0] < 1e-9) | (uvs[:, 0] > 1 - 1e-9) | (uvs[:, 1] < 1e-9)
             | (uvs[:, 1] > 1 - 1e-9)] = True
    thickness = 0.6 + 0.6 * np.exp(-((uvs[:, 0] - 0.5) ** 2) / 0.05)
    mouth_y = 4.0 - v_up[mouth_row] * height
    jaw = np.clip((mouth_y - verts[:, 1] + 0.3) / 0.6, 0.0, 1.0)
    jaw[seam[:, 0]] = 0.0
    jaw[seam[:, 1]] = 1.0
    def nearest(p):
        return int(np.argmin(np.linalg.norm(uvs - np.asarray(p), axis=1)))
    corner_l = remap[ids[(mouth_row, mouth_c1)]]
    corner_r = remap[ids[(mouth_row, mouth_c0)]]
    landmarks = {
        "mouth_corner_l": int(corner_l), "mouth_corner_r": int(corner_r),
        "brow_mid_l": nearest((0.70, 0.25)), "brow_mid_r": nearest((0.30, 0.25)),
        "chin": nearest((0.5, 0.9)), "lip_upper_centre": int(seam[len(seam) // 2, 0]),
        "lip_lower_centre": int(seam[len(seam) // 2, 1]),
    }
    return StandInMesh(
        vertices=verts, triangles=tris, uv=uvs, region=np.zeros(n_v, np.int8),
        landmarks=landmarks, tissue_thickness=thickness, jaw_weight=jaw,
        jaw_pivot=np.array([0.0, mouth_y + 2.0, -9.0]), boundary=boundary, mouth_seam=seam,
    )


def _perturbed(lattice, rng, scale=0.1):
    x = lattice.rest + scale * rng.standard_normal(lattice.rest.shape)
    x[lattice.fixed] = lattice.rest[lattice.fixed]
    return x
