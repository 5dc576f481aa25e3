"""The muscle file and the muscle force fields."""

from __future__ import annotations

import json

import numpy as np
import pytest

from synth.lattice import build_lattice
from synth.mesh import generate_face_mesh
from synth.muscles import (
    default_muscle_file,
    load_muscles,
    muscle_force_basis,
    uv_to_surface,
)

DESIGN_PAIRED = ("frontalis_inner", "frontalis_major", "frontalis_outer", "corrugator",
                 "zygomaticus_major", "zygomaticus_minor", "levator_labii_nasi",
                 "levator_labii", "depressor_anguli", "depressor_labii", "mentalis",
                 "buccinator", "risorius")


@pytest.fixture(scope="module")
def face():
    mesh = generate_face_mesh(resolution=0.4)
    return mesh, build_lattice(mesh)


@pytest.fixture(scope="module")
def basis(face):
    mesh, lat = face
    ms = load_muscles()
    nodes, b = muscle_force_basis(ms, mesh, lat)
    return ms, nodes, b


def test_default_file_has_design_muscles():
    ms = load_muscles()
    names = set(ms.names)
    for m in DESIGN_PAIRED:
        assert {f"{m}_l", f"{m}_r"} <= names
    assert {"orbicularis_oris", "orbicularis_oculi_l", "orbicularis_oculi_r"} <= names
    assert {m.type for m in ms.muscles} == {"linear", "sphincter", "sheet"}
    assert ms["frontalis_major_l"].type == "sheet"
    assert ms["orbicularis_oris"].type == "sphincter"
    assert ms["zygomaticus_major_r"].type == "linear"
    assert default_muscle_file().suffix == ".toml"


def test_order_matches_facs():
    facs = pytest.importorskip("synth.facs")
    assert load_muscles().names == tuple(facs.MUSCLE_NAMES)


def test_right_side_is_the_mirror_of_the_left():
    ms = load_muscles()
    left, right = ms["zygomaticus_major_l"], ms["zygomaticus_major_r"]
    assert right.params["head"] == pytest.approx((1 - left.params["head"][0],
                                                  left.params["head"][1]))


def test_every_muscle_acts_and_pulls_with_its_force(basis):
    ms, nodes, b = basis
    for k, m in enumerate(ms.muscles):
        f = b[k]
        active = np.linalg.norm(f, axis=1) > 0
        assert active.sum() >= 1, m.name
        # magnitudes add up to the muscle force (tangential projection can only shrink them)
        total = np.linalg.norm(f, axis=1).sum()
        assert 0.3 * m.force <= total <= m.force + 1e-9, m.name


def test_basis_is_mirror_symmetric(face, basis):
    mesh, lat = face
    ms, nodes, b = basis
    n = lat.n_vertices
    pos = {v: i for i, v in enumerate(nodes)}
    perm = np.array([pos[2 * n + mesh.mirror_index[v - 2 * n]] for v in nodes])
    for k, name in enumerate(ms.names):
        if name.endswith("_l"):
            r = ms.names.index(name[:-2] + "_r")
            assert np.allclose(b[r][perm] * [-1, 1, 1], b[k], atol=1e-9), name


def test_linear_muscle_pulls_toward_its_head(face, basis):
    mesh, lat = face
    ms, nodes, b = basis
    k = ms.names.index("zygomaticus_major_l")
    head = uv_to_surface(mesh, [ms.muscles[k].params["head"]])[0]
    f = b[k]
    active = np.linalg.norm(f, axis=1) > 1e-9
    to_head = head - lat.rest[nodes[active]]
    assert np.all(np.einsum("ij,ij->i", f[active], to_head) > 0)


def test_sheet_pulls_up_and_sphincter_pulls_inward(face, basis):
    mesh, lat = face
    ms, nodes, b = basis
    fr = b[ms.names.index("frontalis_major_l")]
    assert fr[:, 1].sum() > 0.8 * np.linalg.norm(fr, axis=1).sum()
    oris = b[ms.names.index("orbicularis_oris")]
    centre = uv_to_surface(mesh, [ms["orbicularis_oris"].params["centre"]])[0]
    mag = np.linalg.norm(oris, axis=1)
    active = mag > 0.05 * mag.max()            # nodes near the centre carry ~no force
    rel = lat.rest[nodes[active]] - centre
    fxy, rxy = oris[active][:, :2], rel[:, :2]
    cos = np.einsum("ij,ij->i", fxy, rxy) / (np.linalg.norm(fxy, axis=1)
                                             * np.linalg.norm(rxy, axis=1))
    assert np.all(cos < 0.05)           # toward the centre (or across it, never away)
    assert np.median(cos) < -0.5


def test_uv_lookup_is_exact_on_vertices(face):
    mesh, _ = face
    idx = [mesh.landmarks["chin"], mesh.landmarks["nose_tip"], mesh.landmarks["brow_mid_l"]]
    assert np.allclose(uv_to_surface(mesh, mesh.uv[idx]), mesh.vertices[idx])


def _write(tmp_path, text, name="m.toml"):
    p = tmp_path / name
    p.write_text(text)
    return p


GOOD = """
[[muscle]]
name = "zyg"
type = "linear"
sides = ["l", "r"]
head = [0.8, 0.5]
tail = [0.65, 0.78]
force = 10.0
"""


def test_custom_file_and_json(tmp_path):
    ms = load_muscles(_write(tmp_path, GOOD))
    assert ms.names == ("zyg_l", "zyg_r")
    data = {"muscle": [{"name": "ring", "type": "sphincter", "centre": [0.5, 0.79],
                        "semi_axes": [0.15, 0.07], "force": 5.0}]}
    p = tmp_path / "m.json"
    p.write_text(json.dumps(data))
    assert load_muscles(p).names == ("ring",)


@pytest.mark.parametrize("edit, match", [
    (lambda s: s.replace('type = "linear"', 'type = "ring"'), "type"),
    (lambda s: s.replace("force = 10.0", "force = 10.0\nstrength = 2"), "strength"),
    (lambda s: s.replace("head = [0.8, 0.5]\n", ""), "head"),
    (lambda s: s.replace("force = 10.0", "force = -1.0"), "force"),
    (lambda s: s.replace('sides = ["l", "r"]', 'sides = ["left"]'), "sides"),
    (lambda s: s + GOOD, "duplicate"),
    (lambda s: s.replace("[0.8, 0.5]", "[0.8]"), "head"),
])
def test_malformed_files_raise_naming_the_problem(tmp_path, edit, match):
    with pytest.raises(ValueError, match=match):
        load_muscles(_write(tmp_path, edit(GOOD)))


def test_missing_file(tmp_path):
    with pytest.raises(FileNotFoundError):
        load_muscles(tmp_path / "nope.toml")


def test_muscle_off_the_face_raises(tmp_path, face):
    mesh, lat = face
    text = GOOD.replace("head = [0.8, 0.5]", "head = [5.0, 5.0]").replace(
        "tail = [0.65, 0.78]", "tail = [5.1, 5.1]")
    with pytest.raises(ValueError, match="zyg_l"):
        muscle_force_basis(load_muscles(_write(tmp_path, text)), mesh, lat)


def test_a_muscle_whose_narrow_zone_holds_no_node_acts_on_the_nodes_nearest_its_axis(
        tmp_path, face, monkeypatch):
    # a short muscle with a narrow cone falls between the fascia nodes (as a corrugator
    # does on a mesh a landmark warp has stretched): its zone is widened until it reaches
    # some, and it still pulls toward its head with its whole force
    import synth.muscles

    mesh, lat = face
    text = GOOD.replace("head = [0.8, 0.5]", "head = [0.70, 0.60]").replace(
        "tail = [0.65, 0.78]", "tail = [0.66, 0.64]") + "zone_angle = 10.0\n"
    ms = load_muscles(_write(tmp_path, text))
    nodes, b = muscle_force_basis(ms, mesh, lat)
    pull = b[0]
    acting = np.linalg.norm(pull, axis=1) > 0
    assert 0 < acting.sum() < 10
    np.testing.assert_allclose(np.linalg.norm(pull, axis=1).sum(), 10.0, rtol=1e-9)
    head = uv_to_surface(mesh, np.array([[0.70, 0.60]]))[0]
    towards = np.einsum("ij,ij->i", pull[acting], head - lat.rest[nodes[acting]])
    assert (towards > 0).all()
    monkeypatch.setattr(synth.muscles, "_MAX_WIDENINGS", 0)      # the case needs widening
    with pytest.raises(ValueError, match="zyg_l"):
        muscle_force_basis(ms, mesh, lat)
