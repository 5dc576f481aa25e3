"""Personalisation: the face model deformed to the analysed subject."""

from __future__ import annotations

import logging

import cv2
import numpy as np
import pandas as pd
import pytest

from faceanalysis.io.table import write_contractions
from faceanalysis.resynthesis.pipeline import resynthesize
from tests.faceanalysis.resynthesis._series import SMILE


@pytest.mark.slow
def test_personalisation_on_synthetic_subject(subject, tmp_path):
    from faceanalysis.resynthesis.personalize import personalize

    root, files = subject
    info = personalize(root / "analysis")
    res = resynthesize(root / "analysis", subject=info, side_by_side=True,
                       output=tmp_path / "sbs.mp4", export_meshes=tmp_path / "meshes")
    p = res.report["personalisation"]
    # the warped model's projected landmarks sit on the subject's neutral fiducials
    assert p["landmark_error_px"]["max"] < 1.0
    # the neutral resynthesis reproduces the neutral frame on the face mask
    assert p["photometric"]["mask_pixels"] > 10000
    assert p["photometric"]["mae_grey"] < 2.0 and p["photometric"]["ncc"] > 0.98
    # ...and the whole sequence stays close to the input, frame by frame
    assert res.report["frame_comparison"]["mean_mae_grey"] < 12.0
    # side by side: input | resynthesis, plot strip underneath
    cap = cv2.VideoCapture(str(res.path))
    ok, frame = cap.read()
    cap.release()
    assert ok and frame.shape[1] == 512 and frame.shape[0] > 256 + 80
    # exported meshes carry the subject's texture (the neutral frame, projected)
    assert (tmp_path / "meshes" / "subject.mtl").is_file()
    assert cv2.imread(str(tmp_path / "meshes" / "subject_texture.png")).shape == (256, 256, 3)
    obj = (tmp_path / "meshes" / "frame_000005.obj").read_text().splitlines()
    assert obj[1] == "mtllib subject.mtl"
    vt = np.array([[float(x) for x in line.split()[1:]] for line in obj
                   if line.startswith("vt ")])
    assert vt.shape == (len(info.model.mesh.vertices), 2)
    np.testing.assert_allclose(vt[:, 0], info.uv()[0][:, 0], atol=1e-5)
    # the personalised model is still a working model with the generic muscles
    m = info.model
    m.reset()
    m.set_contractions({SMILE[0]: 1.0})
    assert np.isfinite(m.equilibrate()).all()
    m.reset()


@pytest.mark.slow
def test_personalise_from_the_video_itself(subject):
    from faceanalysis.resynthesis.personalize import personalize

    root, files = subject
    info = personalize(files["video"])          # analyses the first frame
    assert info.neutral_frame == 0 and info.image.shape == (256, 256, 3)
    res = resynthesize(root / "analysis", subject=files["video"], shading="wireframe")
    assert res.report["personalisation"]["landmark_error_px"]["max"] < 1.0
    assert len(list(res)) == 12


@pytest.mark.slow
def test_personalisation_falls_back_when_the_warp_is_invalid(subject, tmp_path, caplog):
    """Crossed mouth corners would fold the face: the warp is softened, and says so."""
    import shutil

    from faceanalysis.resynthesis.personalize import personalize

    root, _ = subject
    bad = tmp_path / "bad"
    shutil.copytree(root / "analysis", bad)
    table = pd.read_csv(bad / "contractions.csv")
    table.loc[0, ["fid_mouth_corner_l_x", "fid_mouth_corner_r_x"]] = \
        table.loc[0, ["fid_mouth_corner_r_x", "fid_mouth_corner_l_x"]].to_numpy()
    write_contractions(table, bad / "contractions.csv")
    with caplog.at_level(logging.WARNING, logger="faceanalysis.resynthesis.personalize"):
        info = personalize(bad)
    assert "follows the subject's landmarks at" in caplog.text
    assert np.isfinite(info.model.mesh.vertices).all()
    res = resynthesize(bad, subject=info, shading="wireframe")
    assert res.report["personalisation"]["landmark_error_px"]["max"] > 1.0   # honest cost
    assert len(list(res)) == 12


@pytest.mark.slow
def test_expression_transfer_to_another_subject(subject, tmp_path):
    """Another face's series drives the subject's model in the subject's own framing."""
    from faceanalysis.analysis.pipeline import analyze
    from faceanalysis.resynthesis.personalize import personalize
    from synth.render.sequence import render_sequence

    root, _ = subject
    files = render_sequence(tmp_path / "other", frames=8, size=192, seed=102,
                            expression="surprise", head_motion=0.5, flow=False)
    other = analyze(files["video"], tracker_options={"brow_mid": 0.556})
    info = personalize(root / "analysis")
    states = list(resynthesize(other, subject=info, shading="wireframe").states())
    assert states[0].image.shape == (256, 256, 3)          # the subject's frame size
    # at the source's neutral frame the model sits on the subject's neutral fiducials
    k = int(np.argmax(other.table["success"].to_numpy() == 1))
    assert np.hypot(*(states[k].fiducials - info.fiducials).T).max() < 1.0
    # and the expression moves it (at its apex: the surprise is over by the last frame)
    apex = len(states) // 2
    assert np.abs(states[apex].vertices - states[k].vertices).max() > 0.1


@pytest.mark.slow
def test_a_fiducial_lost_on_the_neutral_frame_is_left_to_the_model(subject, tmp_path):
    """A contour lost on the neutral frame (a furrow, a brow under hair) leaves its point to
    the face model: the subject is still personalised, where it was refused; too few seen
    points are refused by count."""
    import shutil

    from faceanalysis.resynthesis.personalize import personalize

    root, _ = subject
    lost = tmp_path / "lost"
    shutil.copytree(root / "analysis", lost)
    table = pd.read_csv(lost / "contractions.csv")
    table.loc[0, ["fid_furrow_top_r_x", "fid_furrow_top_r_y"]] = np.nan
    write_contractions(table, lost / "contractions.csv")
    info = personalize(lost)
    assert np.isnan(info.fiducials).any(axis=1).sum() == 1
    res = resynthesize(lost, subject=info, shading="wireframe")
    error = res.report["personalisation"]["landmark_error_px"]
    assert error["by_point"]["furrow_top_r"] is None and error["max"] < 1.0
    table.loc[0, [f"fid_{n}_{a}" for n in ("brow_inner_l", "brow_mid_l", "brow_outer_l")
                  for a in "xy"]] = np.nan
    write_contractions(table, lost / "contractions.csv")
    with pytest.raises(ValueError, match="neutral frame 0 has 7 of its 11 fiducials"):
        personalize(lost)
