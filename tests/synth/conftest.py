"""Fixtures shared by the tests of the face mesh, whose subject is split over several
modules (synth.mesh / synth.face_mesh)."""

from __future__ import annotations

import pytest

from synth.face_mesh import FaceMesh
from synth.mesh import generate_face_mesh


@pytest.fixture(scope="module")
def mesh() -> FaceMesh:
    return generate_face_mesh()
