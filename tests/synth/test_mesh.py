"""Tests of the procedural generic face mesh (synth.mesh)."""

from __future__ import annotations

import numpy as np
import pytest

from synth.face_mesh import (
    FEATURE_CURVE_NAMES,
    FIDUCIALS,
    INNER_EYE,
    INNER_MOUTH,
    INNER_TEETH,
    LANDMARK_NAMES,
    Region,
)
from synth.face_shape import FaceShape
from synth.mesh import generate_face_mesh

MIRROR = np.array([-1.0, 1.0, 1.0])


def _pos(mesh, name):
    return mesh.vertices[mesh.landmarks[name]]


def _boundary_loops(mesh):
    """Closed loops of boundary edges (each a list of vertex indices)."""
    nxt = {int(a): int(b) for a, b in mesh.boundary_edges}
    loops, seen = [], set()
    for start in nxt:
        if start in seen:
            continue
        loop, v = [], start
        while v not in seen:
            seen.add(v)
            loop.append(v)
            v = nxt[v]
        loops.append(loop)
    return loops


# -- basic structure -----------------------------------------------------------------------


def test_default_mesh_arrays_and_dtypes(mesh):
    n, m = mesh.n_vertices, mesh.n_triangles
    assert 1000 <= n <= 2500
    assert mesh.vertices.shape == (n, 3) and mesh.vertices.dtype == np.float64
    assert mesh.triangles.shape == (m, 3) and mesh.triangles.dtype == np.int32
    assert mesh.uv.shape == (n, 2)
    assert mesh.region.shape == (n,) and mesh.region.dtype == np.int8
    assert mesh.tissue_thickness.shape == (n,)
    assert mesh.jaw_weight.shape == (n,)
    assert mesh.boundary.shape == (n,) and mesh.boundary.dtype == bool
    assert mesh.jaw_pivot.shape == (3,)
    assert mesh.mouth_seam.ndim == 2 and mesh.mouth_seam.shape[1] == 2
    p = len(mesh.inner_vertices)
    assert mesh.inner_triangles.shape[1] == 3
    assert mesh.inner_material.shape == (len(mesh.inner_triangles),)
    assert mesh.inner_uv.shape == (p, 2)
    assert mesh.inner_jaw_weight.shape == (p,)
    assert np.all(np.isfinite(mesh.vertices))
    assert set(np.unique(mesh.region)) <= {int(r) for r in Region}


def test_arrays_are_read_only(mesh):
    with pytest.raises(ValueError):
        mesh.vertices[0, 0] = 1.0


def test_every_vertex_used_and_manifold(mesh):
    used = np.zeros(mesh.n_vertices, dtype=bool)
    used[mesh.triangles.ravel()] = True
    assert used.all()
    t = mesh.triangles
    e = np.sort(np.concatenate([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]]), axis=1)
    _, counts = np.unique(e, axis=0, return_counts=True)
    assert counts.max() <= 2
    assert np.all(mesh.triangle_areas > 1e-6)


def test_boundary_has_outline_two_eyes_and_mouth(mesh):
    loops = _boundary_loops(mesh)
    # outline, two eye openings, and the closed slit around the mouth seam
    assert len(loops) == 4
    outline = max(loops, key=len)
    assert mesh.boundary[outline].all()
    others = [lp for lp in loops if lp is not outline]
    for lp in others:
        assert not mesh.boundary[lp].any()


def test_determinism():
    a = generate_face_mesh(FaceShape.random(5), resolution=0.7)
    b = generate_face_mesh(FaceShape(**FaceShape.random(5).as_dict()), resolution=0.7)
    np.testing.assert_array_equal(a.vertices, b.vertices)
    np.testing.assert_array_equal(a.triangles, b.triangles)
    assert a.landmarks == b.landmarks


# -- symmetry and orientation --------------------------------------------------------------


def test_exact_mirror_symmetry(mesh):
    mi = mesh.mirror_index
    assert mi.shape == (mesh.n_vertices,)
    np.testing.assert_array_equal(mi[mi], np.arange(mesh.n_vertices))
    np.testing.assert_array_equal(mesh.vertices[mi], mesh.vertices * MIRROR)
    np.testing.assert_array_equal(mesh.region[mi], mesh.region)
    np.testing.assert_allclose(mesh.uv[mi, 0], 1.0 - mesh.uv[:, 0], atol=1e-12)
    np.testing.assert_array_equal(mesh.tissue_thickness[mi], mesh.tissue_thickness)
    np.testing.assert_array_equal(mesh.jaw_weight[mi], mesh.jaw_weight)
    # triangles map to triangles (with reversed orientation)
    tri = {tuple(sorted(t)) for t in mesh.triangles.tolist()}
    mirrored = {tuple(sorted(t)) for t in mi[mesh.triangles].tolist()}
    assert tri == mirrored
    # left landmarks mirror right ones
    for name in mesh.landmarks:
        if name.endswith("_l"):
            assert mi[mesh.landmarks[name]] == mesh.landmarks[name[:-2] + "_r"]


def test_normals_point_out_of_the_face(mesh):
    n = mesh.vertex_normals
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-9)
    front = np.abs(mesh.vertices[:, 0]) < 4.0
    assert np.all(n[front, 2] > 0.0)
    assert np.mean(mesh.face_normals[:, 2] > 0) > 0.99
    # sides face outward sideways too
    left = mesh.vertices[:, 0] > 5.0
    assert np.all(n[left, 0] > 0)


# -- mouth seam and eyes -------------------------------------------------------------------


def test_mouth_seam_coincides_and_is_not_bridged(mesh):
    seam = mesh.mouth_seam
    assert len(seam) >= 9
    up, lo = seam[:, 0], seam[:, 1]
    np.testing.assert_array_equal(mesh.vertices[up], mesh.vertices[lo])
    assert len(np.intersect1d(up, lo)) == 0
    s_up, s_lo = set(up.tolist()), set(lo.tolist())
    for t in mesh.triangles.tolist():
        assert not (s_up & set(t) and s_lo & set(t))
    # upper copies are used only by triangles above the mouth line, lower copies below
    cen = mesh.vertices[mesh.triangles].mean(axis=1)
    uses_up = np.isin(mesh.triangles, up).any(axis=1)
    uses_lo = np.isin(mesh.triangles, lo).any(axis=1)
    y_seam = mesh.vertices[up, 1].min()
    assert np.all(cen[uses_up, 1] > y_seam - 0.05)
    assert np.all(cen[uses_lo, 1] < mesh.vertices[up, 1].max() + 0.05)
    assert np.all(mesh.region[up] == Region.UPPER_LIP)
    assert np.all(mesh.region[lo] == Region.LOWER_LIP)
    assert np.all(mesh.jaw_weight[lo] > mesh.jaw_weight[up])
    # the seam spans the mouth between the corners
    xs = mesh.vertices[up, 0]
    cl, cr = _pos(mesh, "mouth_corner_l"), _pos(mesh, "mouth_corner_r")
    assert xs.min() > cr[0] and xs.max() < cl[0]


def test_eye_holes_and_eyeballs(mesh):
    loops = _boundary_loops(mesh)
    holes = [lp for lp in loops if not mesh.boundary[lp].any()]
    eye_loops = [lp for lp in holes if not np.isin(lp, mesh.mouth_seam).any()]
    assert len(eye_loops) == 2
    for lp, side, sign in zip(sorted(eye_loops, key=lambda lp: -mesh.vertices[lp, 0].mean()),
                              ("l", "r"), (1, -1)):
        pts = mesh.vertices[lp]
        assert np.sign(pts[:, 0].mean()) == sign
        assert mesh.landmarks[f"eye_inner_{side}"] in lp
        assert mesh.landmarks[f"eye_outer_{side}"] in lp
        assert mesh.landmarks[f"eye_centre_{side}"] in lp
        assert np.all(mesh.region[lp] == Region.EYELID)
        # the eyeball is behind the lid margin: the sphere's front surface under each margin
        # vertex is behind that vertex
        c = mesh.eyeball_centres[0 if side == "l" else 1]
        r = mesh.eyeball_radius
        rho2 = (pts[:, 0] - c[0]) ** 2 + (pts[:, 1] - c[1]) ** 2
        inside = rho2 < r**2
        assert inside.mean() > 0.8
        z_ball = c[2] + np.sqrt(r**2 - rho2[inside])
        assert np.all(z_ball < pts[inside, 2])
        assert np.all(z_ball > pts[inside, 2] - 0.6)  # but close: no gap to look through
    eye = mesh.inner_material == INNER_EYE
    assert eye.sum() > 0 and (mesh.inner_material == INNER_MOUTH).sum() > 0
    assert (mesh.inner_material == INNER_TEETH).sum() > 0
    ev = np.unique(mesh.inner_triangles[eye])
    np.testing.assert_array_equal(mesh.inner_jaw_weight[ev], 0.0)
    assert np.all((mesh.inner_uv >= 0) & (mesh.inner_uv <= 1))
    # the iris (inner_uv near the centre) faces the viewer
    front = ev[np.linalg.norm(mesh.inner_uv[ev] - 0.5, axis=1) < 0.05]
    assert len(front) > 0
    d = mesh.inner_vertices[front] - mesh.eyeball_centres[
        (mesh.inner_vertices[front, 0] < 0).astype(int)]
    assert np.all(d[:, 2] > 0.9 * mesh.eyeball_radius)


def test_mouth_cavity_lower_half_moves_with_jaw(mesh):
    mouth = np.unique(mesh.inner_triangles[mesh.inner_material == INNER_MOUTH])
    y = mesh.inner_vertices[mouth, 1]
    w = mesh.inner_jaw_weight[mouth]
    y_mouth = _pos(mesh, "mouth_corner_l")[1]
    assert np.all(w[y < y_mouth - 0.3] == 1.0)
    assert np.all(w[y > y_mouth + 0.3] == 0.0)
    # the cavity lies behind the lips
    lips = mesh.region_mask(Region.UPPER_LIP, Region.LOWER_LIP)
    assert mesh.inner_vertices[mouth, 2].max() < mesh.vertices[lips, 2].max()


# -- landmarks -----------------------------------------------------------------------------


def test_landmark_names_and_fiducials(mesh):
    assert set(mesh.landmarks) == set(LANDMARK_NAMES)
    assert set(FIDUCIALS) <= set(mesh.landmarks)
    assert len(FIDUCIALS) == 11
    idx = list(mesh.landmarks.values())
    assert len(set(idx)) == len(idx)
    assert all(0 <= i < mesh.n_vertices for i in idx)


def test_landmarks_are_in_sensible_places(mesh):
    p = {name: _pos(mesh, name) for name in mesh.landmarks}
    for name, q in p.items():
        if name.endswith("_l"):
            assert q[0] > 0.3, name
        elif name.endswith("_r"):
            assert q[0] < -0.3, name
        else:
            assert q[0] == 0.0, name
    for s in ("l", "r"):
        # brows above the eyes, ordered inner -> outer away from the midline
        assert p[f"brow_mid_{s}"][1] > p[f"eye_centre_{s}"][1] + 1.0
        assert (abs(p[f"brow_inner_{s}"][0]) < abs(p[f"brow_mid_{s}"][0])
                < abs(p[f"brow_outer_{s}"][0]))
        assert abs(p[f"eye_inner_{s}"][0]) < abs(p[f"eye_outer_{s}"][0])
        # the furrow top sits beside the alar wing, above the mouth corner
        assert abs(p[f"furrow_top_{s}"][0]) > abs(p[f"alar_{s}"][0]) - 0.3
        assert p[f"mouth_corner_{s}"][1] < p[f"furrow_top_{s}"][1] - 1.5
        assert p[f"jaw_angle_{s}"][1] < p[f"alar_{s}"][1]
        assert mesh.boundary[mesh.landmarks[f"jaw_angle_{s}"]]
        assert mesh.region[mesh.landmarks[f"brow_mid_{s}"]] == Region.BROW
        assert mesh.region[mesh.landmarks[f"mouth_corner_{s}"]] == Region.UPPER_LIP
    # vertical order on the midline
    ys = [p[n][1] for n in ("hairline_centre", "nasion", "nose_tip", "subnasale",
                            "lip_upper_centre", "lip_lower_centre", "chin")]
    assert ys == sorted(ys, reverse=True)
    # the nose tip is the most forward point, the eye-centre midpoint is the origin
    assert p["nose_tip"][2] == mesh.vertices[:, 2].max()
    np.testing.assert_allclose(mesh.eyeball_centres[:, :2].mean(axis=0), 0.0, atol=1e-9)
    assert abs(p["eye_centre_l"][1]) < 1.0
    # overall size: ~14 cm wide, hairline to chin ~18 cm
    width = np.ptp(mesh.vertices[:, 0])
    assert 12.0 < width < 16.0
    assert 16.0 < p["hairline_centre"][1] - mesh.vertices[:, 1].min() < 20.0
    assert mesh.region[mesh.landmarks["chin"]] == Region.CHIN
    assert mesh.region[mesh.landmarks["nose_tip"]] == Region.NOSE
    # the mouth corners are the ends of the seam
    seam_x = mesh.vertices[mesh.mouth_seam[:, 0], 0]
    gap = np.diff(np.sort(np.abs(seam_x))).max()
    assert p["mouth_corner_l"][0] - seam_x.max() < 2 * gap + 1e-9


def test_feature_curves_match_landmarks(mesh):
    assert set(mesh.feature_curves) == set(FEATURE_CURVE_NAMES)
    for name, curve in mesh.feature_curves.items():
        assert curve.ndim == 2 and curve.shape[1] == 2 and len(curve) >= 5, name
        assert np.all((curve >= 0) & (curve <= 1)), name
    uv = mesh.uv

    def near(curve, name, tol):
        d = np.linalg.norm(mesh.feature_curves[curve] - uv[mesh.landmarks[name]], axis=1)
        assert d.min() < tol, (curve, name, d.min())

    for s in ("l", "r"):
        near(f"brow_{s}", f"brow_inner_{s}", 1e-9)
        near(f"brow_{s}", f"brow_mid_{s}", 0.01)
        near(f"brow_{s}", f"brow_outer_{s}", 1e-9)
        near(f"furrow_{s}", f"furrow_top_{s}", 1e-9)
        near(f"eye_{s}", f"eye_inner_{s}", 0.01)
        near("mouth_line", f"mouth_corner_{s}", 1e-9)
    near("hairline", "hairline_centre", 0.01)
    near("chin_boss", "chin", 0.06)
    # left features on the right half of the texture (u > 0.5)
    assert mesh.feature_curves["brow_l"][:, 0].min() > 0.5
    assert mesh.feature_curves["eye_r"][:, 0].max() < 0.5
    # upper lip outline above the lower one (v grows downwards)
    curves = mesh.feature_curves
    assert curves["upper_lip"][:, 1].min() < curves["lower_lip"][:, 1].min()


def test_regions_cover_the_face(mesh):
    counts = np.bincount(mesh.region, minlength=len(Region))
    for r in (Region.FOREHEAD, Region.BROW, Region.EYELID, Region.NOSE, Region.CHEEK,
              Region.NASOLABIAL, Region.UPPER_LIP, Region.LOWER_LIP, Region.CHIN, Region.JAW,
              Region.SCALP):
        assert counts[r] > 5, r
    # densest where the face is most articulate: eyes and mouth
    area = np.zeros(mesh.n_vertices)
    np.add.at(area, mesh.triangles.ravel(), np.repeat(mesh.triangle_areas, 3) / 3)
    eyelid = area[mesh.region == Region.EYELID].mean()
    lips = area[mesh.region_mask(Region.UPPER_LIP, Region.LOWER_LIP)].mean()
    forehead = area[mesh.region == Region.FOREHEAD].mean()
    assert eyelid < 0.6 * forehead and lips < 0.6 * forehead


def test_tissue_thickness_and_jaw_weight(mesh):
    t = mesh.tissue_thickness
    assert np.all(t > 0.1) and np.all(t < 3.0)
    cheek = t[mesh.region == Region.CHEEK].mean()
    forehead = t[mesh.region == Region.FOREHEAD].mean()
    assert cheek > 1.5 * forehead
    assert t[mesh.landmarks["nasion"]] < cheek
    jw = mesh.jaw_weight
    assert np.all((jw >= 0) & (jw <= 1))
    assert jw[mesh.landmarks["chin"]] == 1.0
    assert jw[mesh.landmarks["lip_lower_centre"]] == 1.0
    assert jw[mesh.landmarks["lip_upper_centre"]] == 0.0
    assert jw[mesh.landmarks["nose_tip"]] == 0.0
    assert np.all(jw[mesh.region == Region.FOREHEAD] == 0.0)
    # the pivot lies behind the face, below the eyes
    assert mesh.jaw_pivot[2] < mesh.vertices[:, 2].min()
    assert mesh.jaw_pivot[1] < 0
    # positive rotation about +x through the pivot moves the chin down and back
    theta = 0.2
    rel = _pos(mesh, "chin") - mesh.jaw_pivot
    y = rel[1] * np.cos(theta) - rel[2] * np.sin(theta)
    z = rel[1] * np.sin(theta) + rel[2] * np.cos(theta)
    assert y < rel[1] and z < rel[2]


def test_uv_is_canonical_and_in_unit_square(mesh):
    assert np.all((mesh.uv >= 0) & (mesh.uv <= 1))
    other = generate_face_mesh(FaceShape.random(11))
    np.testing.assert_array_equal(other.uv, mesh.uv)
    np.testing.assert_array_equal(other.triangles, mesh.triangles)
    assert other.landmarks == mesh.landmarks
    # u increases with x (subject's left on the image's right), v increases downwards
    assert np.corrcoef(mesh.uv[:, 0], mesh.vertices[:, 0])[0, 1] > 0.99
    assert np.corrcoef(mesh.uv[:, 1], -mesh.vertices[:, 1])[0, 1] > 0.99


# -- resolution and identities -------------------------------------------------------------


def test_resolution_scaling():
    n = {r: generate_face_mesh(resolution=r).n_vertices for r in (0.5, 1.0, 2.0)}
    assert 2.8 < n[1.0] / n[0.5] < 5.0
    assert 2.8 < n[2.0] / n[1.0] < 5.0
    coarse = generate_face_mesh(resolution=0.5)
    assert set(coarse.landmarks) == set(LANDMARK_NAMES)
    np.testing.assert_array_equal(coarse.vertices[coarse.mirror_index],
                                  coarse.vertices * MIRROR)


def test_fine_mesh_for_large_lattices():
    fine = generate_face_mesh(resolution=4.0)
    assert fine.n_vertices > 15000
    np.testing.assert_array_equal(fine.vertices[fine.mirror_index], fine.vertices * MIRROR)
    assert np.all(fine.vertex_normals[np.abs(fine.vertices[:, 0]) < 4, 2] > 0)


def test_landmarks_stay_put_across_resolutions():
    a, b = generate_face_mesh(resolution=0.6), generate_face_mesh(resolution=1.5)
    for name in FIDUCIALS:
        assert np.linalg.norm(_pos(a, name) - _pos(b, name)) < 0.15, name


def test_identities_differ_and_parameters_act():
    base = generate_face_mesh()
    a, b = generate_face_mesh(FaceShape.random(1)), generate_face_mesh(FaceShape.random(2))
    assert np.abs(a.vertices - b.vertices).max() > 0.3
    assert np.abs(a.vertices - base.vertices).max() > 0.3

    def lm(shape, name):
        m = generate_face_mesh(shape)
        return m.vertices[m.landmarks[name]]

    wide = FaceShape(face_width=1.15)
    assert np.ptp(generate_face_mesh(wide).vertices[:, 0]) > np.ptp(base.vertices[:, 0]) * 1.1
    assert lm(FaceShape(eye_spacing=1.15), "eye_outer_l")[0] > _pos(base, "eye_outer_l")[0] + 0.2
    assert lm(FaceShape(mouth_width=1.15), "mouth_corner_l")[0] > (
        _pos(base, "mouth_corner_l")[0] + 0.2)
    assert lm(FaceShape(nose_protrusion=1.2), "nose_tip")[2] > _pos(base, "nose_tip")[2] + 0.2
    assert lm(FaceShape(chin_height=1.15), "chin")[1] < _pos(base, "chin")[1] - 0.2
    assert lm(FaceShape(nose_length=1.15), "nose_tip")[1] < _pos(base, "nose_tip")[1] - 0.2
    assert lm(FaceShape(brow_height=1.2), "brow_mid_l")[1] > _pos(base, "brow_mid_l")[1] + 0.2
    assert lm(FaceShape(brow_prominence=1.3), "brow_mid_l")[2] > _pos(base, "brow_mid_l")[2] + .1
    thick = generate_face_mesh(FaceShape(upper_lip_thickness=1.3))
    d0 = _pos(base, "lip_upper_centre")[1] - base.vertices[base.mouth_seam[:, 0], 1].max()
    d1 = (thick.vertices[thick.landmarks["lip_upper_centre"], 1]
          - thick.vertices[thick.mouth_seam[:, 0], 1].max())
    assert d1 > d0 + 0.1


@pytest.mark.parametrize("seed", [0, 1, 2, 3, 4, 5, 6, 7])
def test_random_identities_are_valid_meshes(seed):
    shape = FaceShape.random(seed)
    assert all(0.85 <= v <= 1.15 for v in shape.as_dict().values())
    m = generate_face_mesh(shape)
    np.testing.assert_array_equal(m.vertices[m.mirror_index], m.vertices * MIRROR)
    assert np.all(m.triangle_areas > 1e-5)
    # no fold-overs: the frontal projection keeps every triangle's orientation
    v, t = m.vertices, m.triangles
    front = np.abs(v[t].mean(axis=1)[:, 0]) < 4.5
    a = v[t[:, 1]] - v[t[:, 0]]
    b = v[t[:, 2]] - v[t[:, 0]]
    cross_z = a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]
    assert np.all(cross_z[front] > 0)
    np.testing.assert_array_equal(m.vertices[m.mouth_seam[:, 0]], m.vertices[m.mouth_seam[:, 1]])


# -- validation ----------------------------------------------------------------------------


@pytest.mark.parametrize("bad", [0, -1.0, float("nan"), float("inf"), 1e6, "fine", True])
def test_bad_resolution_raises(bad):
    with pytest.raises(ValueError, match="resolution"):
        generate_face_mesh(resolution=bad)


def test_shape_dict_accepted():
    a = generate_face_mesh({"nose_width": 1.1})
    b = generate_face_mesh(FaceShape(nose_width=1.1))
    assert a is b
