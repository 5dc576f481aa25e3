import json

import numpy as np
import pytest

from tests.trackers.conftest import draw_face
from trackers.layout import (
    CONTOUR_NAMES,
    FaceLayout,
    LayoutContour,
    detect_layout,
    layout_from_eyes,
    refine_layout,
)

EYES = ((96.0, 105.0), (159.0, 105.0))


def test_layout_from_eyes_has_nine_named_contours():
    lay = layout_from_eyes(*EYES, (256, 256))
    assert tuple(lay.contours) == CONTOUR_NAMES
    assert lay.contours["chin_boss"].closed
    assert not any(lay.contours[n].closed for n in CONTOUR_NAMES if n != "chin_boss")
    # _l is the subject's left: on the image's right
    assert lay.contours["brow_l"].points[:, 0].mean() > 127.5
    assert lay.contours["brow_r"].points[:, 0].mean() < 127.5
    # brows start at their inner end, furrows at their top
    assert lay.contours["brow_l"].points[0, 0] < lay.contours["brow_l"].points[-1, 0]
    assert lay.contours["brow_r"].points[0, 0] > lay.contours["brow_r"].points[-1, 0]
    for side in ("l", "r"):
        f = lay.contours[f"furrow_{side}"].points
        assert f[0, 1] < f[-1, 1]
    # vertical order of the features
    y = {n: c.points[:, 1].mean() for n, c in lay.contours.items()}
    assert y["hairline"] < y["brow_l"] < y["nose_tip"] < y["upper_lip"] < y["lower_lip"] \
        < y["chin_boss"]
    assert lay.inter_eye == pytest.approx(63.0)


def test_layout_follows_rotated_eyes():
    a = layout_from_eyes(*EYES, (256, 256))
    ang = np.deg2rad(10)
    c = np.array([127.5, 105.0])
    Rm = np.array([[np.cos(ang), -np.sin(ang)], [np.sin(ang), np.cos(ang)]])
    eyes = [(np.asarray(e) - c) @ Rm.T + c for e in EYES]
    b = layout_from_eyes(*eyes, (256, 256))
    pa = a.contours["upper_lip"].points
    pb = b.contours["upper_lip"].points
    np.testing.assert_allclose(pb, (pa - c) @ Rm.T + c, atol=1e-6)


def test_json_round_trip(tmp_path):
    lay = layout_from_eyes(*EYES, (256, 256))
    path = tmp_path / "layout.json"
    text = lay.to_json(path)
    back = FaceLayout.from_json(path)
    again = FaceLayout.from_json(text)
    for other in (back, again):
        assert tuple(other.contours) == CONTOUR_NAMES
        assert other.image_size == (256, 256)
        for n in CONTOUR_NAMES:
            np.testing.assert_allclose(other.contours[n].points, lay.contours[n].points,
                                       atol=1e-3)
            assert other.contours[n].kind == lay.contours[n].kind
            assert other.contours[n].ends == lay.contours[n].ends
    # a user correction survives the round trip
    d = json.loads(text)
    d["contours"]["brow_l"]["points"][0] = [140.0, 90.0]
    fixed = FaceLayout.from_json(json.dumps(d))
    np.testing.assert_allclose(fixed.contours["brow_l"].points[0], [140, 90])


def test_bad_layout_files(tmp_path):
    with pytest.raises(FileNotFoundError, match="not found"):
        FaceLayout.from_json(tmp_path / "missing.json")
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    with pytest.raises(ValueError, match="bad.json: not valid JSON"):
        FaceLayout.from_json(bad)
    d = json.loads(layout_from_eyes(*EYES, (256, 256)).to_json())
    del d["contours"]["chin_boss"]
    with pytest.raises(ValueError, match="chin_boss"):
        FaceLayout.from_json(json.dumps(d))
    d = json.loads(layout_from_eyes(*EYES, (256, 256)).to_json())
    d["contours"]["hairline"]["points"][0] = [300.0, 10.0]
    with pytest.raises(ValueError, match="hairline.*outside"):
        FaceLayout.from_json(json.dumps(d))
    d = json.loads(layout_from_eyes(*EYES, (256, 256)).to_json())
    d["contours"]["nose_tip"]["kind"] = "ridge"
    with pytest.raises(ValueError, match="kind"):
        FaceLayout.from_json(json.dumps(d))
    with pytest.raises(ValueError, match="n >= 3"):
        LayoutContour(np.zeros((2, 2)))


@pytest.mark.parametrize("img", [np.full((120, 160), 128, np.uint8),
                                 np.zeros((64, 64, 3), np.float32)])
def test_no_face_names_the_frame(img):
    with pytest.raises(ValueError, match="no face found in frame 7"):
        detect_layout(img, frame_index=7)


def test_refine_moves_displaced_contours_onto_features():
    img, truth = draw_face()
    lay = layout_from_eyes(*EYES, (256, 256))
    moved = {n: LayoutContour(c.points + [0.0, 4.0], c.closed, c.kind, c.sigma, c.ends)
             for n, c in lay.contours.items()}
    shifted = FaceLayout(moved, lay.image_size, lay.eyes)
    fixed = refine_layout(img, shifted)
    for n in ("brow_l", "brow_r", "upper_lip", "chin_boss", "nose_tip"):
        dy = fixed.contours[n].points[:, 1].mean() - lay.contours[n].points[:, 1].mean()
        assert abs(dy) <= 1.0, (n, dy)
    with pytest.raises(ValueError, match="made for"):
        refine_layout(np.zeros((100, 100), np.uint8), lay)
    # only the contours named are searched; the others stay where they were
    only = refine_layout(img, shifted, names=("brow_l",))
    assert abs(only.contours["brow_l"].points[:, 1].mean()
               - lay.contours["brow_l"].points[:, 1].mean()) <= 1.0
    np.testing.assert_array_equal(only.contours["upper_lip"].points,
                                  shifted.contours["upper_lip"].points)
    with pytest.raises(ValueError, match="unknown contours"):
        refine_layout(img, shifted, names=("ear",))


def _short_lower_face(cut):
    """The cartoon face with a band of ``cut`` inter-eye distances taken out of its
    cheeks, between the eyes and the furrows' tops: nostrils, mouth and chin sit
    ``cut`` higher than the template puts them (real faces' proportions)."""
    img, _ = draw_face(size=(256, 300))
    iod = EYES[1][0] - EYES[0][0]
    top = int(round(EYES[0][1] + 0.3 * iod))
    n = int(round(cut * iod))
    short = np.vstack([img[:top], img[top + n:], np.repeat(img[-1:], n, axis=0)])
    return short, n


def test_refine_finds_a_nose_higher_than_the_template_and_the_lower_face_follows():
    img, n = _short_lower_face(0.4)
    lay = layout_from_eyes(*EYES, (256, 300))
    fixed = refine_layout(img, lay)
    for name in ("nose_tip", "furrow_l", "furrow_r", "upper_lip", "lower_lip", "chin_boss"):
        dy = fixed.contours[name].points[:, 1].mean() - lay.contours[name].points[:, 1].mean()
        assert abs(dy + n) <= 1.5, (name, dy, -n)
    for name in ("brow_l", "brow_r"):
        dy = fixed.contours[name].points[:, 1].mean() - lay.contours[name].points[:, 1].mean()
        assert abs(dy) <= 1.0, (name, dy)


def test_refine_keeps_the_template_nose_when_nothing_lies_above_it():
    img, _ = draw_face(size=(256, 300))
    lay = layout_from_eyes(*EYES, (256, 300))
    fixed = refine_layout(img, lay)
    for name in ("nose_tip", "upper_lip", "chin_boss"):
        dy = fixed.contours[name].points[:, 1].mean() - lay.contours[name].points[:, 1].mean()
        assert abs(dy) <= 1.0, (name, dy)


@pytest.mark.real_data
def test_detect_layout_on_real_video(real_video_dir):
    import cv2

    path = sorted(real_video_dir.glob("*.mp4"))[0]
    cap = cv2.VideoCapture(str(path))
    ok, frame = cap.read()
    cap.release()
    if not ok:
        pytest.skip(f"cannot decode {path.name}")
    lay = detect_layout(frame, channel_order="bgr")
    x, y, w, h = lay.face_box
    for n in ("brow_l", "brow_r", "nose_tip", "upper_lip"):
        cx, cy = lay.contours[n].points.mean(0)
        assert x <= cx <= x + w and y <= cy <= y + h, n


@pytest.mark.real_data
def test_detect_layout_puts_the_lower_contours_on_real_faces_features(real_video_dir):
    import cv2

    paths = sorted(real_video_dir.glob("*.mp4"))
    if not paths:
        pytest.skip("no real videos")
    for path in paths:
        cap = cv2.VideoCapture(str(path))
        ok, frame = cap.read()
        cap.release()
        lay = detect_layout(frame, channel_order="bgr")
        eye_r, eye_l = lay.eyes
        d = eye_l - eye_r
        down = np.array([-d[1], d[0]]) / np.hypot(*d) ** 2

        def depth(name, lay=lay, eye_r=eye_r, eye_l=eye_l, down=down):
            return float((lay.contours[name].points.mean(0) - (eye_r + eye_l) / 2) @ down)

        # these faces' nostrils lie 0.55-0.6 inter-eye distances below the eyes, the
        # mouth line near 1.0 and the chin boss near 1.45; the template has 1.0, 1.36, 1.83
        assert 0.45 < depth("nose_tip") < 0.7, (path.name, depth("nose_tip"))
        assert 0.85 < depth("upper_lip") < 1.15, (path.name, depth("upper_lip"))
        assert 1.3 < depth("chin_boss") < 1.6, (path.name, depth("chin_boss"))


def test_ends_one_mode_or_a_pair():
    pts = np.c_[np.linspace(0, 20, 8), np.zeros(8)]
    c = LayoutContour(pts, ends=("line", "tip"))
    assert c.end_modes == ("line", "tip")
    assert LayoutContour(pts, ends="tip").end_modes == ("tip", "tip")
    assert LayoutContour(pts, ends=["tip", "tip"]).ends == "tip"
    for bad in ("lines", ("line",), ("line", "tip", "tip"), ("line", "nope")):
        with pytest.raises(ValueError, match="ends must be one of"):
            LayoutContour(pts, ends=bad)
    # the furrows' tops are found on the grey step, their lower ends on the ravine
    lay = layout_from_eyes((96, 105), (159, 105), (256, 256))
    assert lay.contours["furrow_l"].end_modes == ("line", "tip")


def test_haar_cascades_load_once_per_thread():
    import threading

    from trackers.layout import _cascade

    a = _cascade("haarcascade_eye.xml")
    assert _cascade("haarcascade_eye.xml") is a
    other = []
    t = threading.Thread(target=lambda: other.append(_cascade("haarcascade_eye.xml")))
    t.start()
    t.join()
    assert other[0] is not a and not other[0].empty()


@pytest.fixture(scope="module")
def rendered_face(tmp_path_factory):
    """A 256x256 render of the face model (BGR), whose face the Haar cascade finds."""
    import cv2

    from synth.render.sequence import render_sequence

    files = render_sequence(tmp_path_factory.mktemp("face") / "s", expression="happiness",
                            frames=2, size=256, seed=3, noise=1.0, flow=False)
    cap = cv2.VideoCapture(str(files["video"]))
    ok, img = cap.read()
    cap.release()
    assert ok
    return img


def test_detection_box_is_that_of_a_full_search(rendered_face):
    # large faces are searched first; the box must be the one a search from the
    # smallest size gives (the cascade's scales do not depend on where they start)
    import cv2

    from trackers.layout import _cascade
    from trackers.potentials import to_gray

    g8 = cv2.equalizeHist(np.clip(to_gray(rendered_face, channel_order="bgr") + 0.5, 0, 255)
                          .astype(np.uint8))
    faces = _cascade("haarcascade_frontalface_default.xml").detectMultiScale(
        g8, scaleFactor=1.1, minNeighbors=4, minSize=(40, 40))
    largest = tuple(int(v) for v in max(faces, key=lambda f: f[2] * f[3]))
    assert detect_layout(rendered_face, channel_order="bgr").face_box == largest


def test_detection_finds_a_face_smaller_than_a_quarter_of_the_frame(rendered_face):
    import cv2

    x, y, w, h = detect_layout(rendered_face, channel_order="bgr").face_box
    pad = 250
    big = cv2.copyMakeBorder(rendered_face, pad, pad, pad, pad, cv2.BORDER_REPLICATE)
    assert min(big.shape[:2]) // 4 > w       # only the second, small-scale search sees it
    bx, by, bw, bh = detect_layout(big, channel_order="bgr").face_box
    assert abs(bx - (x + pad)) <= 3 and abs(by - (y + pad)) <= 3 and abs(bw - w) <= 3
