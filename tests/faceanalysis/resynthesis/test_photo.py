"""Photo-real synthetic faces: the model fitted to a photograph and textured with it.

The 'photograph' is a render of a procedural face (tests make their own data); what is
checked holds for any photograph the landmark model finds a face in.
"""

import json

import cv2
import numpy as np
import pandas as pd
import pytest

from faceanalysis.io.table import FIDUCIALS
from tests.faceanalysis._photos import rendered_photograph


@pytest.fixture(scope="module")
def photo(tmp_path_factory):
    return rendered_photograph(tmp_path_factory.mktemp("photo") / "person.png", seed=5,
                               size=(288, 320))


@pytest.fixture(scope="module")
def face(photo):
    from faceanalysis.resynthesis.photo import photo_face

    return photo_face(photo)


def _grey(img):
    return cv2.cvtColor(img, cv2.COLOR_RGB2GRAY).astype(float)


def test_rest_frame_reproduces_the_photograph(face):
    from faceanalysis.resynthesis.photo import synthesize_face

    seq = synthesize_face(face, frames=1, flow=False)
    assert seq.images.shape == (1, 320, 288, 3)
    inside = cv2.erode(seq.skin_mask[0].astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
    assert inside.sum() > 0.3 * inside.size
    err = np.abs(_grey(seq.images[0]) - _grey(face.photo))
    assert err[inside].mean() <= 4.0
    assert err[~seq.mask[0]].mean() <= 1.0          # the scene around the face too


def test_fitted_model_sits_on_the_tracked_face(face, photo):
    from faceanalysis.resynthesis.photo import synthesize_face
    from faceanalysis.tracking import track

    truth = synthesize_face(face, frames=1, flow=False).truth
    tracked = track(photo, tracker="landmarks").fiducials[0]
    fit = np.array([[truth[f"fid_{n}_x"][0], truth[f"fid_{n}_y"][0]] for n in FIDUCIALS])
    # the model's fiducials on the rest frame land where the tracker found them
    assert np.median(np.hypot(*(fit - tracked).T)) < 2.0
    assert face.report()["landmark_error_px"]["max"] < 2.0


def test_a_smile_moves_the_photographed_mouth_with_exact_truth(face):
    from faceanalysis.resynthesis.photo import synthesize_face

    seq = synthesize_face(face, au="12:1.0", frames=8, flow=True)
    t = seq.truth
    apex = int(np.argmax(t["zygomaticus_major_l"]))
    assert t["zygomaticus_major_l"][apex] > 0.8
    for side, outward in (("l", 1), ("r", -1)):
        dx = t[f"fid_mouth_corner_{side}_x"][apex] - t[f"fid_mouth_corner_{side}_x"][0]
        dy = t[f"fid_mouth_corner_{side}_y"][apex] - t[f"fid_mouth_corner_{side}_y"][0]
        assert dy < -0.5 and outward * dx > 0           # up and out, in the image
    # the photographed skin moves at the mouth corner
    corner = np.round([t["fid_mouth_corner_l_x"][0], t["fid_mouth_corner_l_y"][0]]).astype(int)
    x0, y0 = corner - 12
    change = np.abs(_grey(seq.images[apex]) - _grey(seq.images[0]))[y0:y0 + 24, x0:x0 + 24]
    assert change.mean() > 2.0
    assert seq.flow.shape == (7, 320, 288, 2)
    assert seq.meta["identity"]["photo"]["photo"].endswith("person.png")


def test_head_motion_moves_the_head_its_background_and_their_truth(face):
    from faceanalysis.resynthesis.photo import synthesize_face
    from synth.render import warp_backward

    seq = synthesize_face(face, frames=12, flow=True, head_motion=1.5, seed=2)
    heads = seq.truth[["head_x", "head_y"]].to_numpy()
    assert np.ptp(heads, axis=0).max() > 2.0
    fids = seq.truth[[f"fid_{n}_x" for n in FIDUCIALS]].to_numpy()
    assert np.isfinite(fids).all()
    # hair, ears and the scene move with the head, and the true flow says how: frame t
    # comes back from frame t+1 warped by it, on the background as on the face
    t = int(np.argmax(np.abs(seq.flow[:, ~seq.mask[0]]).mean(axis=(1, 2))))
    bg = ~seq.mask[t] & ~seq.mask[t + 1] & ~seq.occluded[t]
    bg[:8] = bg[-8:] = False
    bg[:, :8] = bg[:, -8:] = False
    assert np.abs(seq.flow[t][bg]).max() > 0.3
    a, b = _grey(seq.images[t]), _grey(seq.images[t + 1])
    back = warp_backward(b, seq.flow[t])
    assert np.abs(back - a)[bg].mean() < 0.5 * np.abs(b - a)[bg].mean()


def test_size_frames_the_face_like_the_procedural_faces(photo):
    from faceanalysis.resynthesis.photo import synthesize_face

    seq = synthesize_face(photo, size=128, frames=1, flow=False)
    assert seq.images.shape == (1, 128, 128, 3)
    t = seq.truth
    brows = np.array([t["fid_brow_mid_l_x"][0], t["fid_brow_mid_r_x"][0]])
    assert 20 < np.ptp(brows) < 90                    # the face fills the frame
    assert 0.3 < seq.mask[0].mean() < 0.9


def test_cli_synth_face_writes_a_decodable_video(photo, tmp_path):
    from faceanalysis.cli.main import main

    out = tmp_path / "out"
    rc = main(["synth", "--face", str(photo), "--expression", "surprise", "--frames", "6",
               "--size", "96", "--no-flow", "-q", "-o", str(out)])
    assert rc == 0
    truth = pd.read_csv(out / "truth.csv")
    assert len(truth) == 6 and truth["frontalis_inner_l"].max() > 0.3
    meta = json.loads((out / "meta.json").read_text())
    assert meta["size"] == [96, 96] and meta["identity"]["photo"]["photo"] == str(photo)
    video = next(p for p in out.iterdir() if p.stem == "video")
    cap = cv2.VideoCapture(str(video))
    n = 0
    while cap.read()[0]:
        n += 1
    assert n == 6


@pytest.mark.parametrize("name, content, code, message", [
    ("missing.jpg", None, 1, "no such photograph"),
    ("clip.mp4", b"not a video", 1, "not a photograph"),
])
def test_cli_synth_face_refuses_what_is_not_a_photograph(tmp_path, capsys, name, content,
                                                         code, message):
    from faceanalysis.cli.main import main

    path = tmp_path / name
    if content is not None:
        path.write_bytes(content)
    rc = main(["synth", "--face", str(path), "-q", "-o", str(tmp_path / "out")])
    assert rc == code
    assert message in capsys.readouterr().err


def test_cli_synth_face_refuses_a_perspective_camera(photo, tmp_path, capsys):
    from faceanalysis.cli.main import main

    rc = main(["synth", "--face", str(photo), "--camera", "perspective", "-q",
               "-o", str(tmp_path / "out")])
    assert rc == 1
    assert "orthographic" in capsys.readouterr().err


def test_a_photograph_without_a_face_is_refused(tmp_path):
    from trackers.landmarks import ensure_models

    try:
        ensure_models()
    except (RuntimeError, FileNotFoundError) as exc:
        pytest.skip(f"the MediaPipe face models cannot be obtained here: {exc}")
    from faceanalysis.resynthesis.photo import photo_face

    path = tmp_path / "wall.png"
    cv2.imwrite(str(path), np.full((200, 200, 3), 128, np.uint8))
    with pytest.raises(ValueError, match="no face"):
        photo_face(path)


def test_a_fitted_face_refuses_a_framing_it_cannot_take(face):
    from faceanalysis.resynthesis.photo import synthesize_face

    with pytest.raises(ValueError, match="fill frames a photograph"):
        synthesize_face(face, fill=0.5, frames=1, flow=False)
    with pytest.raises(ValueError, match="differs from the appearance"):
        synthesize_face(face, size=64, frames=1, flow=False)
