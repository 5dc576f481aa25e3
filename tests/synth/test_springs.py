"""Biphasic springs (synth.springs): the Numba kernel agrees with the NumPy reference and
follows the piecewise-linear law of 004."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from synth.springs import spring_forces, spring_forces_numpy

from .physics_standin import _perturbed


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
