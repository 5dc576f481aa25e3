"""Tests of the identity parameters (synth.face_shape)."""

from __future__ import annotations

import numpy as np
import pytest

from synth.face_shape import FaceShape
from synth.mesh import generate_face_mesh


def test_random_shape_determinism_and_spread():
    assert FaceShape.random(3) == FaceShape.random(3)
    assert FaceShape.random(3) != FaceShape.random(4)
    assert FaceShape.random(3, spread=0.0) == FaceShape()
    wide = [FaceShape.random(s, spread=2.0).as_dict() for s in range(20)]
    narrow = [FaceShape.random(s, spread=0.5).as_dict() for s in range(20)]
    dev = lambda rows: np.mean([abs(v - 1) for r in rows for v in r.values()])  # noqa: E731
    assert dev(wide) > 2 * dev(narrow)


def test_bad_shape_parameters_raise():
    with pytest.raises(ValueError, match="nose_lenght"):
        FaceShape(nose_lenght=1.1)
    with pytest.raises(ValueError, match="face_width"):
        FaceShape(face_width=-1.0)
    with pytest.raises(ValueError, match="eye_size"):
        FaceShape(eye_size=float("nan"))
    with pytest.raises(ValueError, match="jaw_width"):
        FaceShape(jaw_width=5.0)
    with pytest.raises(ValueError, match="mouth"):
        generate_face_mesh({"mouth": 1.0})
    with pytest.raises(ValueError, match="shape"):
        generate_face_mesh("wide")
    with pytest.raises(ValueError, match="spread"):
        FaceShape.random(1, spread=-1)
    with pytest.raises(ValueError, match="seed"):
        FaceShape.random(1.5)
