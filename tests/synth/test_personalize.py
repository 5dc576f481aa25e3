"""Landmark-driven personalisation of the face model (Kähler 001, ch. 8)."""

from __future__ import annotations

import numpy as np
import pytest

from synth.personalize import (
    check_warp,
    fit_landmark_warp,
    head_frame_points,
    personalize_in_plane,
    personalize_model,
    warp_mesh,
)

NAMES = ("brow_inner_l", "brow_mid_l", "brow_outer_l", "brow_inner_r", "brow_mid_r",
         "brow_outer_r", "mouth_corner_l", "mouth_corner_r", "furrow_top_l", "furrow_top_r",
         "chin")


@pytest.fixture(scope="module")
def generic():
    from synth.model import FaceModel

    return FaceModel.default()


@pytest.fixture(scope="module")
def landmarks(generic):
    lm = generic.landmark_positions()
    o, n = head_frame_points(generic.mesh)
    return np.array([lm[k] for k in NAMES] + [o, n])


def test_warp_interpolates_and_reproduces_affine_maps(rng):
    p = rng.normal(0, 3, (12, 3))
    q = p + rng.normal(0, 0.3, p.shape)
    for kernel in ("linear", "gaussian"):
        w = fit_landmark_warp(p, q, kernel=kernel)
        np.testing.assert_allclose(w(p), q, atol=1e-9)
    A = np.array([[1.1, 0.1, 0.0], [-0.05, 0.95, 0.02], [0.0, 0.03, 1.0]])
    t = np.array([0.4, -0.2, 0.1])
    w = fit_landmark_warp(p, p @ A.T + t)
    x = rng.normal(0, 4, (50, 3))
    np.testing.assert_allclose(w(x), x @ A.T + t, atol=1e-9)
    np.testing.assert_allclose(w.weights, 0.0, atol=1e-9)
    np.testing.assert_allclose(w.jacobian(x[:3]), np.broadcast_to(A, (3, 3, 3)), atol=1e-6)


@pytest.mark.parametrize("source, target, match", [
    (np.zeros((3, 3)), np.zeros((3, 3)), "at least 4"),
    (np.c_[np.random.default_rng(0).normal(size=(6, 2)), np.zeros(6)],
     np.c_[np.random.default_rng(1).normal(size=(6, 2)), np.zeros(6)], "coplanar"),
    (np.ones((5, 3)), np.ones((4, 3)), "shape"),
    (np.r_[np.eye(3), [[np.nan, 0, 0]], [[1, 1, 1.0]]], np.ones((5, 3)), "finite"),
])
def test_warp_rejects_bad_landmarks(source, target, match):
    with pytest.raises(ValueError, match=match):
        fit_landmark_warp(source, target)


def test_warp_rejects_unknown_kernel():
    with pytest.raises(ValueError, match="kernel"):
        fit_landmark_warp(np.eye(4), np.eye(4), kernel="cubic")


def test_identity_warp_leaves_the_model_unchanged(generic, landmarks):
    model, warp = personalize_model(generic, landmarks, landmarks)
    np.testing.assert_allclose(model.mesh.vertices, generic.mesh.vertices, atol=1e-9)
    np.testing.assert_allclose(model.lattice.rest, generic.lattice.rest, atol=1e-6)
    assert check_warp(warp, generic.mesh.vertices) == pytest.approx(1.0, abs=1e-6)


def test_personalised_model_hits_targets_and_stays_animatable(generic, landmarks):
    target = landmarks.copy()
    target[6, 0] += 0.35            # wider mouth
    target[7, 0] -= 0.35
    target[10, 1] -= 0.6            # longer chin
    target[:3, 1] += 0.25           # higher left brow
    model, warp = personalize_model(generic, landmarks, target)
    lm = model.landmark_positions()
    for j, name in enumerate(NAMES):
        np.testing.assert_allclose(lm[name], target[j], atol=1e-9)
    # depth is untouched by image-plane targets
    np.testing.assert_allclose(model.mesh.vertices[:, 2], generic.mesh.vertices[:, 2],
                               atol=1e-9)
    # the whole structure moved: bone layer close to the warped generic bone
    n = model.lattice.n_vertices
    bone = model.lattice.rest[3 * n:]
    dev = np.linalg.norm(bone - warp(generic.lattice.rest[3 * n:]), axis=1)
    assert dev.mean() < 0.08 and dev.max() < 0.3
    # inner parts and the jaw hinge follow the warp
    np.testing.assert_allclose(model.mesh.inner_vertices, warp(generic.mesh.inner_vertices))
    # the warped model is animatable: a smile pulls the mouth corners up and out as on the
    # generic model, and the solution is finite
    pull = {"zygomaticus_major_l": 1.0, "zygomaticus_major_r": 1.0}
    moves = []
    for m in (generic, model):
        m.reset()
        rest = m.landmark_positions()["mouth_corner_l"]
        m.set_contractions(pull)
        skin = m.equilibrate()
        assert np.isfinite(skin).all()
        moves.append(m.landmark_positions()["mouth_corner_l"] - rest)
        m.reset()
    assert moves[1][1] > 0.2 and moves[1][0] > 0.05
    cos = moves[0] @ moves[1] / np.linalg.norm(moves[0]) / np.linalg.norm(moves[1])
    assert cos > 0.95
    assert 0.8 < np.linalg.norm(moves[1]) / np.linalg.norm(moves[0]) < 1.25


def test_folding_warp_is_refused(generic, landmarks):
    target = landmarks.copy()
    target[6, 0], target[7, 0] = landmarks[7, 0], landmarks[6, 0]   # mirrored mouth corners
    with pytest.raises(ValueError, match="folds"):
        personalize_model(generic, landmarks, target)


def test_warp_mesh_keeps_topology_and_uv(generic, landmarks):
    target = landmarks * np.array([1.05, 0.97, 1.0])
    mesh = warp_mesh(generic.mesh, fit_landmark_warp(landmarks, target))
    assert mesh.vertices.shape == generic.mesh.vertices.shape
    np.testing.assert_array_equal(mesh.triangles, generic.mesh.triangles)
    np.testing.assert_array_equal(mesh.uv, generic.mesh.uv)
    assert np.all(mesh.tissue_thickness > 0)


def test_in_plane_a_folding_warp_falls_back_toward_its_affine_part(generic, landmarks):
    points = landmarks[:-2]                           # (the head frame's are added)
    xy = points[:, :2].copy()
    xy[[6, 7], 0] = xy[[7, 6], 0]                    # mirrored mouth corners: a fold
    personal, _, blend = personalize_in_plane(generic, points, xy)
    assert blend < 1.0
    assert np.isfinite(personal.surface_vertices).all()
    # where nothing folds, the whole warp is kept and the points land where asked
    wider = points[:, :2] * [1.08, 1.0]
    personal, _, blend = personalize_in_plane(generic, points, wider)
    assert blend == 1.0
    moved = personal.landmark_positions()
    np.testing.assert_allclose([moved[n][:2] for n in NAMES], wider, atol=1e-6)
    with pytest.raises(ValueError, match="xy"):
        personalize_in_plane(generic, points, wider[:3])
