"""Tissue lattice assembly (004 III-D): structure, sizes, validation."""

from __future__ import annotations

import numpy as np
import pytest

from synth.lattice import (
    LAYER_NAMES,
    build_lattice,
    prism_volumes,
    rotate_about_jaw,
)

from .physics_standin import make_standin_mesh


@pytest.fixture(scope="module")
def standin():
    return make_standin_mesh()


@pytest.fixture(scope="module")
def lattice(standin):
    return build_lattice(standin)


def test_prism_volume_is_exact_and_labelling_free(rng):
    top = np.array([[0.0, 0.0, 0.0], [2.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    x = np.concatenate([top, top - [0.0, 0.0, 0.5]])
    assert prism_volumes(x, np.arange(6)[None])[0] == pytest.approx(1.0 * 0.5)
    # a warped prism: same volume whatever vertex the labelling starts from, and its mirror
    # image (reversed orientation) has the same volume too
    y = x + 0.2 * rng.standard_normal(x.shape)
    v = prism_volumes(y, np.arange(6)[None])[0]
    rot = np.array([[1, 2, 0, 4, 5, 3]])
    assert prism_volumes(y, rot)[0] == pytest.approx(v, rel=1e-12)
    mirrored = y * [-1.0, 1.0, 1.0]
    assert prism_volumes(mirrored, np.array([[0, 2, 1, 3, 5, 4]]))[0] == pytest.approx(
        v, rel=1e-12)
    # divergence theorem against a fine numerical integration of the bilinear-sided prism
    assert v == pytest.approx(_numeric_prism_volume(y), rel=1e-6)


def _numeric_prism_volume(y, n=8):
    """Volume of the prism x(s, t, h) = (1 - h) top(s, t) + h bottom(s, t) by quadrature."""
    g, w = np.polynomial.legendre.leggauss(n)
    g, w = (g + 1) / 2, w / 2
    vol = 0.0
    for s, ws in zip(g, w):
        for t, wt in zip(g, w):
            # map the unit square to the triangle: (s, t) -> (s, (1 - s) t), Jacobian (1 - s)
            a, b = s, (1 - s) * t
            for h, wh in zip(g, w):
                def point(a, b, h):
                    top = y[0] + a * (y[1] - y[0]) + b * (y[2] - y[0])
                    bot = y[3] + a * (y[4] - y[3]) + b * (y[5] - y[3])
                    return (1 - h) * top + h * bot
                e = 1e-6
                ja = (point(a + e, b, h) - point(a - e, b, h)) / (2 * e)
                jb = (point(a, b + e, h) - point(a, b - e, h)) / (2 * e)
                jh = (point(a, b, h + e) - point(a, b, h - e)) / (2 * e)
                vol += ws * wt * wh * (1 - s) * abs(np.linalg.det(np.stack([ja, jb, jh])))
    return vol


def test_layers_and_node_indexing(standin, lattice):
    n = len(standin.vertices)
    assert lattice.n_nodes == 4 * n
    assert np.array_equal(lattice.rest[:n], standin.vertices)
    for l, name in enumerate(LAYER_NAMES):
        nodes = lattice.layer_nodes(name)
        assert np.all(lattice.layer[nodes] == l)
    # bone is fixed, so is every layer under the glued outline
    assert np.all(lattice.fixed[lattice.layer_nodes("bone")])
    b = np.flatnonzero(standin.boundary)
    for l in range(3):
        assert np.all(lattice.fixed[l * n + b])
    # inner layers lie inward (below the skin along the surface normal)
    depth = np.einsum("ij,ij->i", standin.vertices - lattice.rest[2 * n:3 * n], -lattice.inward)
    assert np.all(depth > 0)


def test_three_prisms_per_triangle_positive_volumes(standin, lattice):
    assert lattice.n_elements == 3 * len(standin.triangles)
    assert np.all(lattice.rest_volume > 0)
    assert np.allclose(prism_volumes(lattice.rest, lattice.prisms), lattice.rest_volume)


def test_springs(standin, lattice):
    s = lattice.springs
    assert np.all(lattice.rest_length > 0)
    assert np.all(lattice.k_high >= lattice.k_low) and np.all(lattice.k_low > 0)
    assert not np.any(lattice.fixed[s[:, 0]] & lattice.fixed[s[:, 1]])
    assert len(np.unique(np.sort(s, axis=1), axis=0)) == len(s)
    # every layer pair is connected vertically
    n = lattice.n_vertices
    pairs = {tuple(p) for p in np.sort(s, axis=1)}
    free_v = np.flatnonzero(~standin.boundary)
    v = int(free_v[0])
    for l in range(3):
        assert (l * n + v, (l + 1) * n + v) in pairs


def test_mouth_seam_is_not_joined(standin, lattice):
    n = lattice.n_vertices
    pairs = {tuple(p) for p in np.sort(lattice.springs % n, axis=1)}
    for a, b in standin.mouth_seam:
        assert (min(a, b), max(a, b)) not in pairs


def test_default_model_is_at_least_paper_size():
    from synth.mesh import generate_face_mesh
    from synth.model import DEFAULT_RESOLUTION

    lat = build_lattice(generate_face_mesh(resolution=DEFAULT_RESOLUTION))
    assert lat.n_elements >= 960
    assert lat.n_springs >= 6500


def test_finer_mesh_gives_more_springs():
    from synth.mesh import generate_face_mesh

    a = build_lattice(generate_face_mesh(resolution=0.35))
    b = build_lattice(generate_face_mesh(resolution=0.6))
    assert b.n_springs > 1.5 * a.n_springs


def test_stiffness_is_resolution_consistent():
    """Springs are calibrated from element volumes: total stiffness x length^2 (a proxy of
    the stored energy per unit strain) stays about constant when the mesh is refined."""
    from synth.mesh import generate_face_mesh

    e = []
    for r in (0.35, 0.7):
        lat = build_lattice(generate_face_mesh(resolution=r))
        e.append(np.sum(lat.k_low * lat.rest_length**2))
    assert e[1] == pytest.approx(e[0], rel=0.25)


def test_jaw_rotation_opens_downward():
    p = np.array([[0.0, -10.0, 2.0]])
    q = rotate_about_jaw(p, np.array([1.0]), np.array([0.0, -2.6, -8.2]), 0.2)
    assert q[0, 1] < p[0, 1] and q[0, 2] < p[0, 2]
    assert np.allclose(rotate_about_jaw(p, np.array([0.0]), np.zeros(3), 0.3), p)


@pytest.mark.parametrize("kwargs, match", [
    ({"layer_depths": (0.0, 0.5, 0.4, 1.0)}, "layer_depths"),
    ({"stiffness": {"gristle": (1, 2, 0.1)}}, "gristle"),
    ({"stiffness": {"dermis": (10, 5, 0.1)}}, "dermis"),
    ({"bulk_modulus": -1.0}, "bulk_modulus"),
    ({"skull_margin": 1.5}, "skull_margin"),
])
def test_bad_parameters(standin, kwargs, match):
    with pytest.raises(ValueError, match=match):
        build_lattice(standin, **kwargs)


def test_bad_thickness(standin):
    from dataclasses import replace

    thick = np.array(standin.tissue_thickness)
    thick[3] = 0.0
    with pytest.raises(ValueError, match="tissue_thickness"):
        build_lattice(replace(standin, tissue_thickness=thick))


def test_lattice_prints_its_size_not_its_arrays(lattice):
    assert repr(lattice) == (f"<Lattice: {lattice.n_nodes} nodes ({lattice.n_vertices} a "
                             f"layer), {lattice.n_springs} springs, {lattice.n_elements} "
                             "elements>")
    assert lattice.n_nodes == 4 * lattice.n_vertices
