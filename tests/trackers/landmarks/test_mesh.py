import numpy as np
import pytest

from trackers.landmarks import detect_faces, face_landmarks
from trackers.landmarks.detection import FaceDetection


def test_mouth_corners_near_the_rendered_ones(face):
    img, corners = face
    det = detect_faces(img)[0]
    points, presence = face_landmarks(img, det)
    assert points.shape == (468, 3) and presence > 0.9
    iod = np.linalg.norm(points[263, :2] - points[33, :2])
    # 61 is the subject's right mouth corner (image left), as the renderer's "_r"
    assert np.linalg.norm(points[[61, 291], :2] - corners, axis=1).max() < 0.1 * iod
    tracked, presence = face_landmarks(img, points)    # the crop from its own landmarks
    assert presence > 0.9
    assert np.linalg.norm(tracked[[61, 291], :2] - corners, axis=1).max() < 0.1 * iod


def test_presence_is_low_without_a_face(face):
    img, _ = face
    det = detect_faces(img)[0]
    noise = np.random.default_rng(2).integers(0, 256, img.shape, dtype=np.uint8)
    assert face_landmarks(noise, det)[1] < 0.5
    blank = FaceDetection(det.box, det.keypoints, det.score)
    assert face_landmarks(np.full_like(img, 128), blank)[1] < 0.5


def test_bad_roi_is_refused(face):
    with pytest.raises(ValueError, match="468"):
        face_landmarks(face[0], np.zeros((68, 2)))
