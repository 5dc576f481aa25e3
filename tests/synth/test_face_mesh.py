"""Tests of the face mesh container (synth.face_mesh): its cached topology, mirror map,
landmark and feature-curve positions, and vertex normals."""

from __future__ import annotations

import numpy as np
import pytest

from synth.face_mesh import vertex_normals


def _pos(mesh, name):
    return mesh.vertices[mesh.landmarks[name]]


def test_mirror_index_fallback_matches_stored_map(mesh):
    import dataclasses

    bare = dataclasses.replace(mesh, mirror_map=None)
    np.testing.assert_array_equal(bare.mirror_index, mesh.mirror_index)


def test_vertex_normals_function():
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]], float)
    t = np.array([[0, 1, 2], [1, 3, 2]])
    np.testing.assert_allclose(vertex_normals(v, t), [[0, 0, 1]] * 4)
    with pytest.raises(ValueError, match="vertices"):
        vertex_normals(v[:, :2], t)
    with pytest.raises(ValueError, match="triangles"):
        vertex_normals(v, [[0, 1, 7]])


def test_curve_positions_are_material_points_of_the_surface(mesh):
    furrow = mesh.curve_positions("furrow_l")
    assert furrow.shape[1] == 3 and len(furrow) > 20 and np.isfinite(furrow).all()
    # the curve starts on the furrow_top landmark (same uv point) and runs down
    np.testing.assert_allclose(furrow[0], mesh.vertices[mesh.landmarks["furrow_top_l"]],
                               atol=1e-9)
    assert furrow[-1, 1] < furrow[0, 1]
    # it moves with the vertices: an affine map of the surface maps the curve alike
    a = np.array([[1.1, 0.2, 0.0], [-0.1, 0.9, 0.05], [0.0, 0.0, 1.0]])
    moved = mesh.curve_positions("furrow_l", mesh.vertices @ a.T + [1.0, -2.0, 0.5])
    np.testing.assert_allclose(moved, furrow @ a.T + [1.0, -2.0, 0.5], atol=1e-9)
    # mirror-symmetric mesh, mirror-symmetric curves
    np.testing.assert_allclose(mesh.curve_positions("furrow_r")[:, 0], -furrow[:, 0],
                               atol=1e-6)
    with pytest.raises(ValueError, match="unknown feature curve 'furrow'"):
        mesh.curve_positions("furrow")
    with pytest.raises(ValueError, match="vertices must have shape"):
        mesh.curve_positions("furrow_l", mesh.vertices[:10])


def test_cached_topology_helpers(mesh):
    e = mesh.edges
    assert e.shape[1] == 2 and np.all(e[:, 0] < e[:, 1])
    assert len(np.unique(e, axis=0)) == len(e)
    assert mesh.edges is mesh.edges  # cached
    v, t, f = mesh.n_vertices, mesh.n_triangles, len(e)
    # Euler characteristic of a disc with 3 holes (eyes, mouth slit): 2 - 2*0 - 4 = -2
    assert v - f + t == -2


def test_landmark_positions(mesh):
    pos = mesh.landmark_positions()
    np.testing.assert_array_equal(pos["chin"], _pos(mesh, "chin"))
    moved = mesh.vertices + 1.0
    assert np.allclose(mesh.landmark_positions(moved)["chin"], _pos(mesh, "chin") + 1.0)
    with pytest.raises(ValueError, match="shape"):
        mesh.landmark_positions(np.zeros((3, 3)))
