"""Biphasic springs, volume preservation, skull and lip penalties: forces are the exact
negative gradients of their energies, vanish at rest and do what the papers say."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from synth.forces import (
    TissueSystem,
    skull_forces,
    spring_forces,
    spring_forces_numpy,
    volume_forces,
)
from synth.lattice import build_lattice, prism_volumes

from .physics_standin import make_standin_mesh


@pytest.fixture(scope="module")
def lattice():
    return build_lattice(make_standin_mesh(nx=9, ny=11))


def _perturbed(lattice, rng, scale=0.1):
    x = lattice.rest + scale * rng.standard_normal(lattice.rest.shape)
    x[lattice.fixed] = lattice.rest[lattice.fixed]
    return x


def test_no_force_at_rest(lattice):
    f, e = spring_forces(lattice.rest, lattice)
    assert e == 0.0 and np.abs(f).max() < 1e-12
    f, e = volume_forces(lattice.rest, lattice)
    assert e == pytest.approx(0.0, abs=1e-20) and np.abs(f).max() < 1e-9
    f, e = skull_forces(lattice.rest, lattice)
    assert e == 0.0 and np.abs(f).max() == 0.0


@pytest.mark.parametrize("term", ["spring", "volume", "skull", "total"])
def test_forces_are_negative_energy_gradients(lattice, rng, term):
    x = _perturbed(lattice, rng, 0.15)
    system = TissueSystem(lattice)
    system.set_external(rng.standard_normal(lattice.rest.shape))
    fn = {
        "spring": lambda y: spring_forces(y, lattice),
        "volume": lambda y: volume_forces(y, lattice),
        "skull": lambda y: skull_forces(y, lattice),
        "total": lambda y: system.forces(y),
    }[term]
    f, _ = fn(x.copy())
    v = rng.standard_normal(x.shape)
    v[lattice.fixed] = 0.0
    eps = 1e-6
    de = (fn(x + eps * v)[1] - fn(x - eps * v)[1]) / (2 * eps)
    assert de == pytest.approx(-np.sum(f * v), rel=1e-5, abs=1e-8)


def test_numba_and_numpy_springs_agree(lattice, rng):
    x = _perturbed(lattice, rng, 0.2)
    f1, e1 = spring_forces(x, lattice)
    f2, e2 = spring_forces_numpy(x, lattice)
    assert np.allclose(f1, f2, atol=1e-10)
    assert e1 == pytest.approx(e2)


def _one_spring(k_low=2.0, k_high=10.0, strain=0.2):
    lat = SimpleNamespace(springs=np.array([[0, 1]], np.int32), rest_length=np.array([1.0]),
                          k_low=np.array([k_low]), k_high=np.array([k_high]),
                          switch=np.array([strain]))
    return lat


@pytest.mark.parametrize("length, expected", [
    (0.9, 2.0 * -0.1),                     # compression: small-strain stiffness
    (1.1, 2.0 * 0.1),                      # below the threshold
    (1.2, 2.0 * 0.2),                      # at the threshold (continuous)
    (1.5, 2.0 * 0.2 + 10.0 * 0.3),         # beyond: large-strain stiffness
    (0.7, -2.0 * 0.2 - 10.0 * 0.1),        # strong compression stiffens too
])
def test_biphasic_law(length, expected):
    lat = _one_spring()
    x = np.array([[0.0, 0.0, 0.0], [length, 0.0, 0.0]])
    f, _ = spring_forces(x, lat)
    # force on node 0 pulls it toward node 1 when stretched
    assert f[0, 0] == pytest.approx(expected)
    assert f[1, 0] == pytest.approx(-expected)


def test_volume_force_restores_volume(lattice):
    n = lattice.n_vertices
    x = lattice.rest.copy()
    # squash the dermis: push the epidermis inward along the extrusion direction
    x[:n] += 0.3 * lattice.inward * np.asarray(lattice.info["depth"])[:, None] * 0.25
    x[lattice.fixed] = lattice.rest[lattice.fixed]
    f, _ = volume_forces(x, lattice)
    v0 = prism_volumes(x, lattice.prisms).sum()
    v1 = prism_volumes(x + 1e-4 * f / np.abs(f).max(), lattice.prisms).sum()
    assert v0 < lattice.rest_volume.sum()
    assert v1 > v0


def test_skull_penalty_pushes_out(lattice):
    system = TissueSystem(lattice)
    x = lattice.rest.copy()
    q = 5
    node, bone = lattice.skull_nodes[q], lattice.skull_bone[q]
    x[node] = x[bone] - 0.05 * lattice.skull_normal[q]          # inside the skull
    f, _ = system.forces(x)
    assert f[node] @ lattice.skull_normal[q] > 0
    assert system.project_skull(x) >= 1
    assert system.skull_heights(x)[q] >= -1e-12


def test_lip_contact_penalty_separates_crossed_lips():
    lat = build_lattice(make_standin_mesh())
    system = TissueSystem(lat)
    assert len(lat.contact_pairs) > 0
    a, b = lat.contact_pairs[0]
    x = lat.rest.copy()
    x[a] -= 0.05 * lat.contact_normal[0]                        # upper lip below the lower
    f, e = system.forces(x)
    assert e > 0
    assert f[a] @ lat.contact_normal[0] > 0 and f[b] @ lat.contact_normal[0] < 0


def test_jaw_moves_mandible_bone_only():
    lat = build_lattice(make_standin_mesh())
    system = TissueSystem(lat)
    system.set_jaw(0.2)
    moved = np.linalg.norm(system.prescribed - lat.rest, axis=1) > 1e-9
    assert np.any(moved)
    assert np.all(lat.jaw_weight[moved] > 0)
    assert np.all(lat.fixed[moved])


def test_external_force_shape_checked(lattice):
    with pytest.raises(ValueError, match="f_ext"):
        TissueSystem(lattice).set_external(np.zeros((3, 3)))
