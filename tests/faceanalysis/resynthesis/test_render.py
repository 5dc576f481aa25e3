"""Rendering a resynthesis: views, shadings, video and mesh export."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from faceanalysis.resynthesis.pipeline import resynthesize
from tests.faceanalysis.resynthesis._series import _drive


def test_views_and_shadings(model):
    df = _drive(2)
    images = {}
    for view in ("front", "three-quarter", "profile"):
        for shading in ("textured", "plain", "wireframe"):
            frames = list(resynthesize(df, model=model, size=80, view=view, shading=shading))
            assert frames[1].shape == (80, 80, 3)
            images[view, shading] = frames[1]
    # every combination draws something different
    keys = list(images)
    for i, a in enumerate(keys):
        for b in keys[i + 1:]:
            assert np.abs(images[a].astype(int) - images[b]).mean() > 1.0, (a, b)
    # the wireframe draws the contracted muscles in red
    wire = images["front", "wireframe"].astype(int)
    assert ((wire[..., 0] > 180) & (wire[..., 1] < 60)).sum() > 20


def test_video_and_mesh_export(tmp_path, model):
    out = tmp_path / "resynth.mp4"
    res = resynthesize(_drive(3), model=model, size=64, shading="plain", output=out,
                       export_meshes=tmp_path / "meshes", fps=12)
    assert res.path.exists() and res.path.stat().st_size > 0
    cap = cv2.VideoCapture(str(res.path))
    assert int(cap.get(cv2.CAP_PROP_FRAME_COUNT)) == 3
    assert cap.get(cv2.CAP_PROP_FPS) == pytest.approx(12, abs=0.01)
    cap.release()
    objs = sorted((tmp_path / "meshes").glob("*.obj"))
    assert [p.name for p in objs] == [f"frame_{i:06d}.obj" for i in range(3)]
    assert sum(1 for line in objs[0].read_text().splitlines() if line.startswith("v ")) == \
        len(model.mesh.vertices)
    assert res.report["timing"]["frames"] == 3
    assert repr(res) == (f"<Resynthesis: 3 frames of 64x64 at 12 fps, front view, plain, on "
                         f"the generic face -> {out}>")
    with pytest.raises(FileExistsError):
        resynthesize(_drive(3), model=model, output=out)
    # one .npz of trajectories, equal to the states
    npz = tmp_path / "traj.npz"
    res = resynthesize(_drive(3), model=model, size=48, shading="wireframe",
                       export_meshes=npz, mesh_format="ply")
    z = np.load(npz)
    assert z["vertices"].shape == (3, len(model.mesh.vertices), 3)
    states = list(res.states())
    np.testing.assert_allclose(z["vertices"][2], states[2].vertices, atol=1e-5)
    np.testing.assert_array_equal(z["triangles"], model.mesh.triangles)
    ply = tmp_path / "ply"
    resynthesize(_drive(2), model=model, export_meshes=ply, mesh_format="ply")
    assert len(list(ply.glob("*.ply"))) == 2
