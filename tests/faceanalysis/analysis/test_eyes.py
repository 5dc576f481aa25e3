import json

import cv2
import numpy as np
import pytest

from faceanalysis.analysis.eyes import eye_closures, eye_openness
from faceanalysis.analysis.pipeline import analyze, analyze_to_folder
from faceanalysis.io.table import EYE_COLUMNS, read_contractions
from tests.faceanalysis._photos import models_or_skip


def test_openness_is_relative_to_the_neutral_row():
    g = np.array([[0.1, 0.08], [0.05, 0.0], [np.nan, 0.08]])
    np.testing.assert_allclose(eye_openness(g, 0), [[1, 1], [0.5, 0], [np.nan, 1]])
    assert np.isnan(eye_openness([[0.0, 0.1], [0.1, 0.1]], 0)[:, 0]).all()
    with pytest.raises(ValueError, match="outside"):
        eye_openness(g, 3)
    with pytest.raises(ValueError, match="shape"):
        eye_openness(np.ones((3, 3)), 0)


def test_closures_end_at_unmeasured_frames_and_one_eye_is_not_a_closure():
    o = np.ones((10, 2))
    o[2:6] = 0.1
    o[4] = np.nan                        # not measured: the run ends there
    o[8, 0] = 0.1                        # one eye only: a wink, not closed eyes
    s = eye_closures(o, np.arange(100, 110), np.arange(10) / 10)
    assert [(c["first"], c["last"]) for c in s["closures"]] == [(102, 103), (105, 105)]
    assert s["blinks"] == 2 and s["frames_measured"] == 9
    none = eye_closures(o, np.arange(10), np.full(10, np.nan))
    assert none["blinks"] == 0 and none["blinks_per_minute"] is None
    assert none["closures"][0]["duration_s"] is None
    assert eye_closures(np.full((3, 2), np.nan), np.arange(3), np.arange(3.0)) is None
    with pytest.raises(ValueError, match="positive"):
        eye_closures(o, np.arange(10), np.arange(10.0), level=0)


@pytest.fixture(scope="module")
def models():
    models_or_skip()


@pytest.fixture(scope="module")
def still_face(tmp_path_factory, models):
    from synth.render.sequence import synthesize

    folder = tmp_path_factory.mktemp("still")
    img = synthesize(frames=1, size=320, seed=3, flow=False, texture_size=256,
                     supersample=1).images[0]
    for i in range(5):
        cv2.imwrite(str(folder / f"{i:02d}.png"), img[:, :, ::-1])
    return folder


def test_eyes_open_as_at_rest_on_a_still_face(still_face, tmp_path):
    a = analyze_to_folder(still_face, tmp_path / "out", fps=25, eyes=True)
    o = a.table[list(EYE_COLUMNS)].to_numpy(float)
    # the same image: the crops follow the mesh, which settles over the first frames
    assert np.isfinite(o).all() and np.abs(o - 1).max() < 0.1
    meta = json.loads((tmp_path / "out" / "analysis.json").read_text())
    assert meta["parameters"]["eyes"] is True
    assert meta["eyes"]["closures"] == [] and meta["eyes"]["frames_measured"] == 5
    back = read_contractions(tmp_path / "out" / "contractions.csv")
    np.testing.assert_allclose(back[list(EYE_COLUMNS)].to_numpy(float), o, atol=1e-4)


def test_small_eyes_are_warned_about(still_face, tmp_path, caplog):
    img = cv2.imread(str(still_face / "00.png"))
    for i in range(3):
        cv2.imwrite(str(tmp_path / f"{i}.png"), cv2.resize(img, (96, 96),
                                                            interpolation=cv2.INTER_AREA))
    a = analyze(tmp_path, fps=25, eyes=True)
    corners = a.metadata["eyes"]["eye_corner_distance_px"]
    assert corners < 45
    assert any("eye closures (blinks most) may be missed" in r.message for r in caplog.records)
    caplog.clear()
    big = analyze(still_face, fps=25, end=2, eyes=True)
    assert big.metadata["eyes"]["eye_corner_distance_px"] > 100
    assert not any("may be missed" in r.message for r in caplog.records)


def test_without_eyes_the_columns_are_empty(still_face):
    a = analyze(still_face, fps=25, end=2)
    assert a.table[list(EYE_COLUMNS)].isna().all().all()
    assert a.metadata["eyes"] is None and a.metadata["parameters"]["eyes"] is False


def test_eyes_need_the_landmark_tracker(still_face):
    with pytest.raises(ValueError, match="landmark tracker"):
        analyze(still_face, fps=25, tracker="snakes", eyes=True)


@pytest.mark.real_data
def test_a_real_blink_is_found(real_video_dir, models):
    # cap13 closes both eyes on frames 98-101 (checked by eye), then looks down (the lids
    # at about half their gap on frames 103-118): one blink, the glance not a closure
    a = analyze(real_video_dir / "cap13_edit2.mp4", start=80, end=120, eyes=True)
    o = a.table.set_index("frame")[list(EYE_COLUMNS)]
    assert (o.loc[98:99] < 0.3).all().all() and (o.loc[80:90] > 0.9).all().all()
    closures = a.metadata["eyes"]["closures"]
    assert [(c["first"] >= 97, c["last"] <= 102, c["blink"]) for c in closures] == [
        (True, True, True)]


def test_the_mirror_check_does_not_read_the_mirrored_eyes(still_face):
    a = analyze(still_face, fps=25, eyes=True, mirror_check=True)
    assert np.isfinite(a.tracks.eyes).all()
    assert np.isnan(a.mirrored_tracks.eyes).all()           # not read: nothing uses them
    assert a.metadata["parameters"]["tracker_options"] == {"eyes": True}


def test_closed_eyes_on_photographs_are_no_blinks():
    """A photograph with closed eyes is a closure, not a blink of 1/30 s (the time assumed
    for an image folder): photographs last no time."""
    from types import SimpleNamespace

    import pandas as pd

    from faceanalysis.analysis.pipeline import _eye_summary
    from faceanalysis.io.table import EYE_COLUMNS

    openness = np.array([[1.0, 1.0], [0.1, 0.1], [1.0, 0.9], [0.95, 1.0]])
    table = pd.DataFrame(openness, columns=list(EYE_COLUMNS))
    mesh = np.zeros((468, 3))
    mesh[263, 0] = 100.0                                    # outer eye corners 100 px apart
    tracks = SimpleNamespace(frames=np.arange(4), timestamps=np.arange(4) / 30.0,
                             eyes=np.full((4, 2), 0.2), success=np.ones(4, bool),
                             landmarks=[mesh] * 4,
                             input={"kind": "images", "fps_origin": "user"})
    video = _eye_summary(table, tracks, 0, "frames")
    assert video["blinks"] == 1 and video["closures"][0]["blink"] is True
    tracks.input = {"kind": "images", "fps_origin": "default"}          # photographs
    photos = _eye_summary(table, tracks, 0, "photos")
    assert photos["closures"] == [{"first": 1, "last": 1, "duration_s": None, "blink": False}]
    assert photos["blinks"] == 0 and photos["blinks_per_minute"] is None
