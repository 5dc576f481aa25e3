"""Biphasic springs, volume preservation, skull and lip penalties: forces are the exact
negative gradients of their energies, vanish at rest and do what the papers say."""

from __future__ import annotations

import numpy as np
import pytest

from synth.forces import TissueSystem
from synth.lattice import build_lattice
from synth.skull import skull_forces
from synth.springs import spring_forces
from synth.volume import volume_forces

from .physics_standin import _perturbed, make_standin_mesh


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
