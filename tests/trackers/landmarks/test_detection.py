import numpy as np
import pytest

from tests.trackers.landmarks.conftest import far_scene
from trackers.landmarks import FaceDetection, detect_faces
from trackers.landmarks.runtime import litert_available


def test_one_face_on_a_rendered_face(face):
    img, corners = face
    (det,) = detect_faces(img)
    assert isinstance(det, FaceDetection) and det.score > 0.8
    x0, y0, x1, y1 = det.box
    assert x0 < corners[0, 0] < corners[1, 0] < x1 and y0 < corners[:, 1].mean() < y1
    right_eye, left_eye, nose, mouth = det.keypoints[:4]
    assert right_eye[0] < nose[0] < left_eye[0] and right_eye[1] < nose[1] < mouth[1]
    assert np.linalg.norm(mouth - corners.mean(0)) < 0.1 * (x1 - x0)


def test_channel_orders_and_grey(face):
    img, _ = face
    rgb = detect_faces(img)[0]
    bgr = detect_faces(img[:, :, ::-1], channel_order="bgr")[0]
    np.testing.assert_allclose(rgb.box, bgr.box, atol=1e-3)
    grey = detect_faces(img.mean(axis=2).astype(np.uint8))
    width = rgb.box[2] - rgb.box[0]
    assert len(grey) == 1 and np.allclose(grey[0].box, rgb.box, atol=0.1 * width)
    flt = detect_faces(img / 255.0)[0]
    np.testing.assert_allclose(flt.box, rgb.box, atol=1e-3)


def test_no_face_on_blank_or_noise(models):
    assert detect_faces(np.full((360, 640, 3), 128, np.uint8)) == []
    noise = np.random.default_rng(1).integers(0, 256, (360, 640, 3), dtype=np.uint8)
    assert detect_faces(noise) == []


def test_bad_inputs_are_refused(models):
    with pytest.raises(ValueError, match="shape"):
        detect_faces(np.zeros((10, 10, 5), np.uint8))
    with pytest.raises(ValueError, match="'rgb', 'bgr'"):
        detect_faces(np.zeros((10, 10, 3), np.uint8), channel_order="hsv")
    with pytest.raises(ValueError, match="within"):
        detect_faces(np.full((10, 10), 2.0))
    with pytest.raises(ValueError, match="min_score"):
        detect_faces(np.zeros((10, 10), np.uint8), min_score=1.5)


def test_alpha_is_dropped(face):
    img, _ = face
    rgba = np.dstack([img, np.zeros(img.shape[:2], np.uint8)])     # fully transparent too
    assert [d.box for d in detect_faces(rgba)] == [d.box for d in detect_faces(img)] != []


@pytest.mark.skipif(not litert_available(), reason="the full-range detector needs LiteRT")
def test_the_full_range_detector_finds_a_face_the_short_range_one_misses(face):
    img, corners = face
    far, k, offset = far_scene(img)
    assert detect_faces(far) == []
    (det,) = detect_faces(far, model="full")
    x0, y0, x1, y1 = det.box
    mouth = (corners * k + offset).mean(0)    # the mouth's centre in the wide frame
    assert x0 < mouth[0] < x1 and y0 < mouth[1] < y1
    assert 0.5 * 123 * k < x1 - x0 < 1.5 * 123 * k   # the render's face box: 123 of 192 px
    right_eye, left_eye, nose, mouth_kp = det.keypoints[:4]
    assert right_eye[0] < nose[0] < left_eye[0] and nose[1] < mouth_kp[1]
    # (a face of 80 px: the keypoints are coarser than the short-range model's on a near one)
    assert np.linalg.norm(mouth_kp - mouth) < 0.3 * (x1 - x0)
    assert detect_faces(np.full((720, 1280, 3), 128, np.uint8), model="full") == []


def test_the_detector_models_are_checked(models):
    with pytest.raises(ValueError, match="'short', 'full'"):
        detect_faces(np.zeros((10, 10), np.uint8), model="far")
    with pytest.raises(ValueError, match="litert"):
        detect_faces(np.zeros((10, 10), np.uint8), model="full", runtime="opencv")
