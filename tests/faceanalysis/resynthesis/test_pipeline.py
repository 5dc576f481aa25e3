"""Resynthesis: the face model driven by a contraction time series, rendered again."""

from __future__ import annotations

import logging

import cv2
import numpy as np
import pandas as pd
import pytest

from faceanalysis.io.table import FIDUCIALS, MUSCLES, empty_table, write_contractions
from faceanalysis.resynthesis.pipeline import resynthesize

SMILE = ("zygomaticus_major_l", "zygomaticus_major_r")


@pytest.fixture(scope="module")
def model():
    from synth.model import FaceModel

    return FaceModel.default()


def _drive(n=4):
    c = np.linspace(0.0, 0.8, n)
    return pd.DataFrame({SMILE[0]: c, SMILE[1]: c, "jaw_rotation": np.linspace(0, 0.1, n)})


def test_partial_csv_drives_the_model_and_warns_about_missing_muscles(tmp_path, model, caplog):
    csv = tmp_path / "partial.csv"
    _drive().to_csv(csv, index=False)
    with caplog.at_level(logging.WARNING, logger="faceanalysis.resynthesis.pipeline"):
        res = resynthesize(csv, model=model, size=64, shading="plain")
    warned = " ".join(r.getMessage() for r in caplog.records)
    assert "frontalis_inner_l" in warned and "orbicularis_oris" in warned
    assert "zygomaticus_major_l" not in warned
    assert set(res.missing) == set(MUSCLES) - set(SMILE)
    frames = list(res)
    assert len(frames) == 4 and frames[0].shape == (64, 64, 3) and frames[0].dtype == np.uint8
    assert np.abs(frames[-1].astype(int) - frames[0]).max() > 30     # the face moved
    assert res.fps == 30.0


@pytest.mark.parametrize("cell, column, message", [
    ("1.5", SMILE[0], r"line 4 \(frame 2\), column zygomaticus_major_l: 1.5 is outside"),
    ("abc", SMILE[1], r"line 4 \(frame 2\), column zygomaticus_major_r: 'abc' is not a number"),
    ("-0.1", "jaw_rotation", r"line 4 \(frame 2\), column jaw_rotation: -0.1 is outside"),
    ("", SMILE[0], r"line 4 \(frame 2\), column zygomaticus_major_l: an empty cell"),
])
def test_bad_cells_are_named_by_row_and_column(tmp_path, model, cell, column, message):
    df = _drive().astype(object)
    df["frame"] = range(4)
    df.loc[2, column] = cell
    csv = tmp_path / "bad.csv"
    df.to_csv(csv, index=False)
    with pytest.raises(ValueError, match=message):
        resynthesize(csv, model=model)


def test_full_table_goes_through_read_contractions(tmp_path, model):
    t = empty_table(3, timestamps=[0.0, 0.04, 0.08])
    t["success"] = 1
    t["confidence"] = 1.0
    t[list(MUSCLES)] = 0.0
    t["jaw_rotation"] = 0.0
    t.loc[1, SMILE[0]] = 2.0
    path = tmp_path / "contractions.csv"
    t.to_csv(path, index=False)
    with pytest.raises(ValueError, match=r"line 3 \(frame 1\), column zygomaticus_major_l"):
        resynthesize(path, model=model)
    t.loc[1, SMILE[0]] = 0.5
    write_contractions(t, path)
    res = resynthesize(tmp_path, model=model, size=48, shading="plain")   # the folder works too
    assert len(list(res)) == 3
    assert res.fps == pytest.approx(25.0)       # from the timestamps


def test_lost_frames_hold_the_last_good_value(model):
    df = _drive(5)
    df["success"] = [1, 1, 0, 0, 1]
    df.loc[2, SMILE[0]] = np.nan                 # lost frames may be empty
    df.loc[3, [SMILE[0], SMILE[1]]] = 0.9        # ...or hold garbage: both are ignored
    states = list(resynthesize(df, model=model, size=48, shading="plain").states())
    np.testing.assert_allclose(states[2].vertices, states[1].vertices)
    np.testing.assert_allclose(states[3].vertices, states[1].vertices)
    assert np.abs(states[4].vertices - states[1].vertices).max() > 1e-3
    assert np.abs(states[1].vertices - states[0].vertices).max() > 1e-3


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


def test_options_are_checked(model):
    with pytest.raises(ValueError, match="view"):
        resynthesize(_drive(), model=model, view="top")
    with pytest.raises(ValueError, match="shading"):
        resynthesize(_drive(), model=model, shading="toon")
    with pytest.raises(ValueError, match="fps"):
        resynthesize(_drive(), model=model, fps=0)
    with pytest.raises(ValueError, match="no muscle columns"):
        resynthesize(pd.DataFrame({"frame": [0, 1]}), model=model)
    with pytest.raises(ValueError, match="side_by_side needs the input video"):
        resynthesize(_drive(), model=model, side_by_side=True)


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


def test_cli_resynth(tmp_path, run_cli):
    csv = tmp_path / "c.csv"
    _drive(3).to_csv(csv, index=False)
    code, out, err = run_cli("resynth", csv, "-o", tmp_path / "r.mp4", "--size", "48",
                             "--shading", "wireframe", "-q")
    assert code == 0, err
    assert "3 frames" in out and (tmp_path / "r.json").is_file()
    code, out, err = run_cli("resynth", csv, "-o", tmp_path / "r.mp4", "-q")
    assert code == 1 and "exists" in err
    bad = _drive(3)
    bad.loc[1, SMILE[0]] = 7
    bad.to_csv(csv, index=False)
    code, out, err = run_cli("resynth", csv, "-o", tmp_path / "s.mp4", "-q")
    assert code == 1 and "column zygomaticus_major_l" in err and "line 3" in err
    video = tmp_path / "clip.mp4"                # a video where the table should be
    video.write_bytes(b"\x00\x00\x00\x18ftypmp42\xc3\x28\xff\xfe" * 20)
    code, out, err = run_cli("resynth", video, "-o", tmp_path / "t.mp4", "-q")
    assert code == 1 and "not a CSV table" in err


# --------------------------------------------------------------------------- synthetic subject
@pytest.fixture(scope="module")
def subject(tmp_path_factory):
    """Identity 101 smiling, rendered and analysed (the analysis folder)."""
    from faceanalysis.analysis.pipeline import analyze_to_folder
    from synth.render.sequence import render_sequence

    root = tmp_path_factory.mktemp("subject")
    files = render_sequence(root / "input", frames=12, size=256, seed=101,
                            expression="happiness", flow=False)
    analyze_to_folder(files["video"], root / "analysis")
    return root, files


@pytest.mark.slow
def test_framing_follows_the_head_frame(subject, model):
    """Resynthesised with its own identity, the neutral fiducials land on the truth."""
    from synth.mesh import FaceShape
    from synth.model import FaceModel

    root, files = subject
    truth = pd.read_csv(files["truth"])
    res = resynthesize(root / "analysis", model=FaceModel.build(FaceShape.random(101)),
                       shading="wireframe")
    st = next(iter(res.states()))
    t = np.array([[truth.loc[0, f"fid_{n}_x"], truth.loc[0, f"fid_{n}_y"]] for n in FIDUCIALS])
    assert np.hypot(*(st.fiducials - t).T).mean() < 1.0


@pytest.mark.slow
def test_personalisation_on_synthetic_subject(subject, tmp_path):
    from faceanalysis.resynthesis.pipeline import personalize

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
def test_cli_personalised_report_goes_into_analysis_json(subject, tmp_path, run_cli):
    import json

    root, _ = subject
    code, out, err = run_cli("resynth", root / "analysis", "-o", tmp_path / "p.mp4",
                             "--subject", root / "analysis", "-q")
    assert code == 0, err
    meta = json.loads((root / "analysis" / "analysis.json").read_text())
    assert meta["resynthesis"]["landmark_error_px"]["mean"] < 1.0
    assert "photometric" in meta["resynthesis"]


@pytest.mark.slow
def test_round_trip_small_case():
    from faceanalysis.resynthesis.pipeline import round_trip

    # the standard suite's sequence length (faceanalysis.evaluation.suite.SuiteConfig.frames)
    table = round_trip([(101, "surprise")], frames=30)
    assert table.loc[0, "frames"] >= 28
    assert table.loc[0, "fiducial_error_px"] < 1.5


@pytest.mark.slow
def test_personalise_from_the_video_itself(subject):
    from faceanalysis.resynthesis.pipeline import personalize

    root, files = subject
    info = personalize(files["video"])          # analyses the first frame
    assert info.neutral_frame == 0 and info.image.shape == (256, 256, 3)
    res = resynthesize(root / "analysis", subject=files["video"], shading="wireframe")
    assert res.report["personalisation"]["landmark_error_px"]["max"] < 1.0
    assert len(list(res)) == 12


def test_framing_matches_the_camera_and_pose_it_makes():
    from faceanalysis.resynthesis.pipeline import Framing, framing_from_head
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


@pytest.mark.slow
def test_personalisation_falls_back_when_the_warp_is_invalid(subject, tmp_path, caplog):
    """Crossed mouth corners would fold the face: the warp is softened, and says so."""
    import shutil

    from faceanalysis.resynthesis.pipeline import personalize

    root, _ = subject
    bad = tmp_path / "bad"
    shutil.copytree(root / "analysis", bad)
    table = pd.read_csv(bad / "contractions.csv")
    table.loc[0, ["fid_mouth_corner_l_x", "fid_mouth_corner_r_x"]] = \
        table.loc[0, ["fid_mouth_corner_r_x", "fid_mouth_corner_l_x"]].to_numpy()
    write_contractions(table, bad / "contractions.csv")
    with caplog.at_level(logging.WARNING, logger="faceanalysis.resynthesis.pipeline"):
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
    from faceanalysis.resynthesis.pipeline import personalize
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
    # and the expression moves it
    assert np.abs(states[-1].vertices - states[k].vertices).max() > 0.1
