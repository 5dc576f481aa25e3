"""Volume preservation (synth.volume): the force restores a squashed lattice's volume, and the
energy stiffens under compression so that no element collapses."""

from __future__ import annotations

import numpy as np

from synth.lattice import prism_volumes
from synth.volume import volume_forces


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


def _scaled(lattice, s):
    """Every node scaled by ``s`` about the lattice's centre: every element's J is s**3."""
    c = lattice.rest.mean(axis=0)
    return c + s * (lattice.rest - c)


def test_energy_is_quadratic_in_growth_and_resists_squeezing_harder(lattice):
    kv = lattice.bulk * lattice.rest_volume
    for J in (1.3, 0.9, 0.5, 0.1):
        _, e = volume_forces(_scaled(lattice, J ** (1 / 3)), lattice)
        quadratic = 0.5 * np.sum(kv) * (J - 1.0) ** 2
        expected = quadratic if J >= 1 else quadratic / J
        assert np.isclose(e, expected, rtol=1e-9), J
    # squeezed to a tenth, the energy is ten times 004's quadratic: no element collapses cheaply
    _, e = volume_forces(_scaled(lattice, 0.1 ** (1 / 3)), lattice)
    assert e > 9.9 * 0.5 * np.sum(kv) * 0.81


def test_force_is_the_energy_gradient_under_strong_compression(lattice):
    rng = np.random.default_rng(3)
    x = _scaled(lattice, 0.25 ** (1 / 3)) + 0.01 * rng.standard_normal(lattice.rest.shape)
    f, _ = volume_forces(x, lattice)
    d = rng.standard_normal(x.shape)
    d /= np.linalg.norm(d)
    h = 1e-6
    slope = (volume_forces(x + h * d, lattice)[1] - volume_forces(x - h * d, lattice)[1]) / (2 * h)
    assert np.isclose(-np.sum(f * d), slope, rtol=1e-5)


def test_energy_is_continuous_where_it_turns_quadratic(lattice):
    # below J = 0.02 the barrier continues as its quadratic expansion: no jump at the switch
    below = volume_forces(_scaled(lattice, (0.02 - 1e-9) ** (1 / 3)), lattice)[1]
    above = volume_forces(_scaled(lattice, (0.02 + 1e-9) ** (1 / 3)), lattice)[1]
    assert np.isclose(below, above, rtol=1e-6)
    # an inverted element (J < 0) still has a finite energy and force
    f, e = volume_forces(_scaled(lattice, -0.5), lattice)
    assert np.isfinite(e) and np.all(np.isfinite(f))
