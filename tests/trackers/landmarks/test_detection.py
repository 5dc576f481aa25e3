import numpy as np
import pytest

from trackers.landmarks import FaceDetection, detect_faces


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
        detect_faces(np.zeros((10, 10, 4), np.uint8))
    with pytest.raises(ValueError, match="'rgb', 'bgr'"):
        detect_faces(np.zeros((10, 10, 3), np.uint8), channel_order="hsv")
    with pytest.raises(ValueError, match="within"):
        detect_faces(np.full((10, 10), 2.0))
    with pytest.raises(ValueError, match="min_score"):
        detect_faces(np.zeros((10, 10), np.uint8), min_score=1.5)
