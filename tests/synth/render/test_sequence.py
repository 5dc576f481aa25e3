"""Sequence generator: flow ground truth against the frames, determinism, files, options."""

import json

import cv2
import numpy as np
import pandas as pd
import pytest

from synth.render.camera import HeadPose
from synth.render.groundtruth import warp_backward
from synth.render.sequence import (
    head_motion_track,
    parse_au_string,
    synthesize,
    write_sequence,
)
from tests.synth.render._kinematic import KinematicFace


def _ramp(T, jaw=0.12):
    return pd.DataFrame({"zygomaticus_major_l": np.linspace(0, 1, T),
                         "zygomaticus_major_r": np.linspace(0, 0.8, T),
                         "frontalis_inner_l": np.linspace(0, 1, T),
                         "jaw_rotation": np.linspace(0, jaw, T)})


@pytest.fixture(scope="module")
def moving():
    # fps=8: slow head motion becomes several px per frame
    return synthesize(model=KinematicFace(), contractions=_ramp(6), seed=3, head_motion=1.5,
                      size=160, fps=8)


def _eroded(m, k=3):
    return cv2.erode(m.astype(np.uint8), np.ones((k, k), np.uint8)).astype(bool)


def test_warping_next_frame_with_true_flow_reproduces_frame(moving):
    seq = moving
    errs, stills = [], []
    for t in range(len(seq.images) - 1):
        m = _eroded(seq.mask[t] & ~seq.occluded[t])
        a = seq.images[t].astype(np.float32)
        b = seq.images[t + 1].astype(np.float32)
        errs.append(np.abs(warp_backward(b, seq.flow[t]) - a)[m].mean())
        stills.append(np.abs(b - a)[m].mean())
    assert max(errs) < 2.0
    assert np.mean(errs) < np.mean(stills) / 3


def test_truth_table_columns_and_fiducials(moving):
    tr = moving.truth
    for c in ("frame", "timestamp", "success", "confidence", "head_x", "head_y", "head_scale",
              "head_roll", "fid_chin_x", "fid_brow_mid_l_y", "fid_mouth_corner_r_visible",
              "zygomaticus_major_l", "jaw_rotation"):
        assert c in tr.columns
    assert (tr.success == 1).all() and (tr.confidence == 1).all()
    assert tr.fid_chin_visible.all()
    # in the head frame (origin, roll, scale), the left mouth corner (image right) moves
    # outward as zygomaticus contracts (0.6 cm in the kinematic driver; the opening jaw
    # cancels its upward pull)
    dx = (tr.fid_mouth_corner_l_x - tr.head_x).to_numpy()
    dy = (tr.fid_mouth_corner_l_y - tr.head_y).to_numpy()
    c, s = np.cos(tr.head_roll.to_numpy()), np.sin(tr.head_roll.to_numpy())
    hx = (c * dx + s * dy) / np.asarray(moving.meta["px_per_cm"])
    assert 0.4 < hx[-1] - hx[0] < 0.7
    assert tr.fid_mouth_corner_l_x.iloc[0] > tr.fid_mouth_corner_r_x.iloc[0]
    assert moving.meta["head_motion"]["poses"][0]["roll"] == 0.0


def test_zero_contraction_sequence_has_zero_flow():
    T = 3
    seq = synthesize(model=KinematicFace(), contractions=_ramp(T) * 0, seed=1, size=96,
                     supersample=1)
    face = seq.mask[:-1]
    assert np.abs(seq.flow[face]).max() < 1e-6
    assert not seq.occluded.any()
    assert np.array_equal(seq.images[0], seq.images[-1])


def test_identical_seeds_give_identical_ground_truth_bytes(tmp_path):
    kw = dict(contractions=_ramp(4), seed=7, head_motion=1.0, illumination=1.0, noise=2.0,
              size=64, supersample=1)
    a = write_sequence(synthesize(model=KinematicFace(), **kw), tmp_path / "a")
    b = write_sequence(synthesize(model=KinematicFace(), **kw), tmp_path / "b")
    for key in ("truth", "flow", "meta"):
        assert a[key].read_bytes() == b[key].read_bytes(), key
    c = write_sequence(synthesize(model=KinematicFace(), **{**kw, "seed": 8}), tmp_path / "c")
    assert a["truth"].read_bytes() != c["truth"].read_bytes()
    with np.load(a["flow"]) as z:
        assert z["flow"].shape == (3, 64, 64, 2) and z["flow"].dtype == np.float32
        assert z["occluded"].shape == z["disoccluded"].shape == (3, 64, 64)
        assert z["mask"].shape == z["depth"].shape == (4, 64, 64)
    meta = json.loads(a["meta"].read_text())
    assert meta["seed"] == 7 and meta["camera"]["kind"] == "orthographic"
    assert a["video"].exists() and a["video"].stat().st_size > 0
    truth = pd.read_csv(a["truth"])
    assert len(truth) == 4 and truth.frame.tolist() == [0, 1, 2, 3]


def test_write_refuses_non_empty_folder(tmp_path):
    seq = synthesize(model=KinematicFace(), contractions=_ramp(2), size=48, supersample=1)
    (tmp_path / "x.txt").write_text("keep")
    with pytest.raises(FileExistsError, match="overwrite"):
        write_sequence(seq, tmp_path)
    out = write_sequence(seq, tmp_path, overwrite=True)
    assert out["truth"].exists() and (tmp_path / "x.txt").read_text() == "keep"


def test_dis_flow_agrees_with_ground_truth():
    seq = synthesize(model=KinematicFace(), contractions=_ramp(6, jaw=0.2), seed=2, size=256,
                     head_motion=1.0)
    dis = cv2.DISOpticalFlow_create(cv2.DISOPTICAL_FLOW_PRESET_MEDIUM)
    epes = []
    for t in range(len(seq.images) - 1):
        a = cv2.cvtColor(seq.images[t], cv2.COLOR_RGB2GRAY)
        b = cv2.cvtColor(seq.images[t + 1], cv2.COLOR_RGB2GRAY)
        m = _eroded(seq.mask[t] & ~seq.occluded[t], 5)
        f = dis.calc(a, b, None)
        epes.append(np.linalg.norm(f - seq.flow[t], axis=2)[m].mean())
    assert np.mean(epes) < 0.5


def test_sensor_noise_and_blur_are_applied_to_the_video_only():
    kw = dict(model=None, contractions=_ramp(2), size=64, supersample=1, seed=4)
    clean = synthesize(**{**kw, "model": KinematicFace()})
    noisy = synthesize(**{**kw, "model": KinematicFace()}, noise=4.0)
    d = noisy.images.astype(float) - clean.images.astype(float)
    assert 3.5 < d.std() < 4.5
    assert np.array_equal(clean.flow, noisy.flow)
    assert np.array_equal(clean.clean_images, noisy.clean_images)
    blurred = synthesize(**{**kw, "model": KinematicFace()}, blur=1.0)

    def sharpness(imgs):
        return np.abs(cv2.Laplacian(imgs[0].astype(np.float32), cv2.CV_32F)).mean()

    assert sharpness(blurred.images) < 0.7 * sharpness(clean.images)


def test_grey_and_perspective_options():
    seq = synthesize(model=KinematicFace(), contractions=_ramp(2), size=(80, 60),
                     supersample=1, grey=True, camera="perspective")
    assert seq.images.shape == (2, 60, 80)
    assert seq.meta["camera"]["kind"] == "perspective"


def test_input_validation():
    with pytest.raises(ValueError, match="only one"):
        synthesize(model=KinematicFace(), contractions=_ramp(2), au="12:0.5")
    with pytest.raises(ValueError, match="noise"):
        synthesize(model=KinematicFace(), contractions=_ramp(2), noise=-1)
    with pytest.raises(ValueError, match="AU script item"):
        parse_au_string("12=0.5")
    with pytest.raises(ValueError, match="in \\[0, 1\\]"):
        parse_au_string("12:1.5")
    assert parse_au_string("AU12:0.8,6:0.5") == {12: 0.8, 6: 0.5}


def test_contractions_csv_file(tmp_path):
    p = tmp_path / "c.csv"
    df = _ramp(3)
    df.insert(0, "frame", range(3))
    df.to_csv(p, index=False)
    seq = synthesize(model=KinematicFace(), contractions=p, size=48, supersample=1)
    assert len(seq.images) == 3
    np.testing.assert_allclose(seq.truth.zygomaticus_major_l, [0, 0.5, 1])
    bad = tmp_path / "bad.csv"
    pd.DataFrame({"zygomaticus_major_l": [0.2, 1.7]}).to_csv(bad, index=False)
    with pytest.raises(ValueError, match="outside"):
        synthesize(model=KinematicFace(), contractions=bad, size=48)
    with pytest.raises(FileNotFoundError):
        synthesize(model=KinematicFace(), contractions=tmp_path / "none.csv", size=48)


def test_an_analysis_table_with_lost_frames_names_them_and_resynth(tmp_path):
    # an analysis's contractions.csv: lost frames (success = 0) have empty values
    p = tmp_path / "contractions.csv"
    df = _ramp(4)
    df.insert(0, "frame", [10, 11, 12, 13])
    df.insert(1, "success", [1, 0, 0, 1])
    df.loc[[1, 2], ["zygomaticus_major_l", "zygomaticus_major_r", "frontalis_inner_l",
                    "jaw_rotation"]] = np.nan
    df.to_csv(p, index=False)
    with pytest.raises(ValueError, match=r"frontalis_inner_l is empty or not a number on 2 "
                                         r"frames \(11, 12\).*success = 0.*resynth"):
        synthesize(model=KinematicFace(), contractions=p, size=48)
    # a plain table: its rows are named, 1-based as a spreadsheet shows them
    plain = tmp_path / "plain.csv"
    pd.DataFrame({"zygomaticus_major_l": ["0.2", "x", "0.3"]}).to_csv(plain, index=False)
    with pytest.raises(ValueError, match=r"on 1 data row \(2\); every row is rendered$"):
        synthesize(model=KinematicFace(), contractions=plain, size=48)


def test_a_misspelt_muscle_column_is_refused_not_rendered_at_rest(tmp_path):
    p = tmp_path / "script.csv"
    pd.DataFrame({"zygomaticus_major_l": [0.0, 0.5], "zygomaticus_mayor_r": [0.0, 0.5],
                  "notes": ["a", "b"]}).to_csv(p, index=False)
    with pytest.raises(ValueError, match=r"column 'zygomaticus_mayor_r' is not a control of "
                                         r"the face model \(did you mean "
                                         r"'zygomaticus_major_r'\?\)"):
        synthesize(model=KinematicFace(), contractions=p, size=48)


def test_head_motion_track_starts_frontal_and_is_smooth():
    poses = head_motion_track(40, 5)
    assert poses[0] == HeadPose()
    rolls = np.array([p.roll for p in poses])
    assert np.abs(np.diff(rolls)).max() < 1.0 and np.abs(rolls).max() > 0.2


def test_physics_model_surprise_opens_a_dark_mouth():
    """End to end with synth.model.FaceModel (the default model of the generator)."""
    seq = synthesize(expression="surprise", frames=8, seed=3, size=128)
    tr = seq.truth
    assert tr.jaw_rotation.max() > 0.1
    apex = int(tr.jaw_rotation.idxmax())
    assert tr.fid_chin_y[apex] > tr.fid_chin_y[0] + 2          # the chin drops
    assert tr.fid_brow_mid_l_y[apex] < tr.fid_brow_mid_l_y[0] - 0.5   # brows go up
    assert "AU26_r" in tr.columns and tr.AU26_r[apex] > 1
    # the mouth cavity shows as a dark region between the mouth corners
    grey = cv2.cvtColor(seq.images[apex], cv2.COLOR_RGB2GRAY).astype(float)
    xl, xr = tr.fid_mouth_corner_r_x[apex], tr.fid_mouth_corner_l_x[apex]
    y = 0.5 * (tr.fid_mouth_corner_l_y[apex] + tr.fid_mouth_corner_r_y[apex])
    cx = int(round(0.5 * (xl + xr)))
    col0 = cv2.cvtColor(seq.images[0], cv2.COLOR_RGB2GRAY).astype(float)[:, cx]
    below = grey[int(y):int(y) + 8, cx]
    assert below.min() < 0.5 * np.median(col0[int(y) - 20:int(y) - 10])
    assert seq.disoccluded[:apex].any()                        # the opening mouth uncovers
    assert seq.meta["identity"]["shape"] is not None


def test_sequence_prints_its_size_not_its_frames(moving):
    assert repr(moving) == ("<SyntheticSequence: 6 frames of 160x160 at 8 fps, seed 3; with "
                            "flow and clean_images>")
