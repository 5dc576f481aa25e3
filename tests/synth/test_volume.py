"""Volume preservation (synth.volume): the force restores a squashed lattice's volume."""

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
