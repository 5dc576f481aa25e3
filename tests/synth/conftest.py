"""Fixtures shared by the tests of the face mesh and of the lattice's forces, whose
subjects are split over several modules (synth.mesh / synth.face_mesh, synth.forces /
synth.springs / synth.volume)."""

from __future__ import annotations

import pytest

from synth.face_mesh import FaceMesh
from synth.lattice import build_lattice
from synth.mesh import generate_face_mesh

from .physics_standin import make_standin_mesh


@pytest.fixture(scope="module")
def mesh() -> FaceMesh:
    return generate_face_mesh()


@pytest.fixture(scope="module")
def lattice():
    return build_lattice(make_standin_mesh(nx=9, ny=11))
