"""Framing: the model placed in the input's head frame."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from faceanalysis.io.table import FIDUCIALS
from faceanalysis.resynthesis.pipeline import resynthesize


@pytest.mark.slow
def test_framing_follows_the_head_frame(subject, model):
    """Resynthesised with its own identity, the neutral fiducials land on the truth."""
    from synth.face_shape import FaceShape
    from synth.model import FaceModel

    root, files = subject
    truth = pd.read_csv(files["truth"])
    res = resynthesize(root / "analysis", model=FaceModel.build(FaceShape.random(101)),
                       shading="wireframe")
    st = next(iter(res.states()))
    t = np.array([[truth.loc[0, f"fid_{n}_x"], truth.loc[0, f"fid_{n}_y"]] for n in FIDUCIALS])
    assert np.hypot(*(st.fiducials - t).T).mean() < 1.0


def test_framing_matches_the_camera_and_pose_it_makes():
    from faceanalysis.resynthesis.framing import Framing, framing_from_head
    from synth.render.camera import project

    f = Framing(k=9.5, roll=0.07, T=(120.3, 95.2))
    p = np.array([[0.0, 0.0, 0.0], [3.0, 2.0, 1.0], [-2.5, -7.0, 0.5]])
    cam, pose = f.camera_pose(256, 200)
    xy, _ = project(p, cam, pose)
    np.testing.assert_allclose(xy, f.apply(p), atol=1e-9)
    np.testing.assert_allclose(f.invert(f.apply(p)), p[:, :2], atol=1e-9)
    # positive roll turns the model's x axis clockwise on screen (y down)
    d = f.apply(p[:1] + [1.0, 0, 0]) - f.apply(p[:1])
    assert np.arctan2(d[0, 1], d[0, 0]) == pytest.approx(0.07)
    half = f.scaled(0.5)
    np.testing.assert_allclose(half.apply(p), (f.apply(p) + 0.5) * 0.5 - 0.5, atol=1e-9)
    # the model's head frame lands on the image head frame
    g = framing_from_head((100.0, 60.0, 40.0, -0.1), np.array([0.2, 7.5]), 9.0)
    np.testing.assert_allclose(g.apply(np.array([[0.2, 7.5]])), [[100.0, 60.0]], atol=1e-9)
    assert g.k == pytest.approx(40.0 / 9.0) and g.roll == -0.1
