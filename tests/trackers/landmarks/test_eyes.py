import cv2
import numpy as np
import pytest

from trackers.landmarks import LandmarkTracker
from trackers.landmarks.eyes import EYE_CORNERS, eye_roi_transform, eyelid_contours, lid_gaps

# the mesh's eye contours (the subject's left, then right): the openings painted over below
_OPENINGS = ([263, 249, 390, 373, 374, 380, 381, 382, 362, 398, 384, 385, 386, 387, 388, 466],
             [33, 7, 163, 144, 145, 153, 154, 155, 133, 173, 157, 158, 159, 160, 161, 246])


def test_both_crops_put_the_outer_corner_on_the_left():
    pts = np.zeros((468, 2))
    pts[[33, 133, 362, 263]] = [[100, 50], [120, 52], [160, 52], [180, 50]]
    outer = {"l": 263, "r": 33}
    for eye, (a, b) in EYE_CORNERS.items():
        m = eye_roi_transform(pts, eye)
        left, right = m @ [0, 31.5, 1], m @ [63, 31.5, 1]
        inner = b if outer[eye] == a else a
        assert (np.linalg.norm(left - pts[outer[eye]]) < np.linalg.norm(left - pts[inner]))
        assert np.linalg.norm(right - pts[inner]) < np.linalg.norm(right - pts[outer[eye]])
        # the crop's y axis points down the image on both (the left eye's is mirrored
        # in x only)
        assert (m @ [31.5, 63, 1])[1] > (m @ [31.5, 0, 1])[1]


def test_bad_arguments():
    with pytest.raises(ValueError, match="eye must be one of"):
        eye_roi_transform(np.zeros((468, 2)), "left")
    with pytest.raises(ValueError, match="points must have shape"):
        eye_roi_transform(np.zeros((10, 2)), "l")
    with pytest.raises(ValueError, match="contours must have shape"):
        lid_gaps(np.zeros((2, 15, 2)))


@pytest.fixture(scope="module")
def rendered(models):
    from synth.render.sequence import synthesize

    seq = synthesize(frames=1, size=320, seed=3, flow=False, texture_size=256, supersample=1)
    img = seq.images[0]
    return img, LandmarkTracker().track(img).points


def test_the_lids_are_traced_where_the_mesh_puts_the_eyes(rendered):
    img, pts = rendered
    c = eyelid_contours(img, pts)
    assert c.shape == (2, 16, 2)
    iod = np.linalg.norm(pts[263] - pts[33])
    for j, opening in enumerate(_OPENINGS):
        # each traced lid point lies on its eye, near the mesh's own contour
        assert np.linalg.norm(c[j].mean(axis=0) - pts[opening].mean(axis=0)) < 0.05 * iod
    gaps = lid_gaps(c) / iod
    assert ((gaps > 0.03) & (gaps < 0.15)).all(), gaps


def test_a_mirrored_face_swaps_the_eyes(rendered):
    img, pts = rendered
    iod = np.linalg.norm(pts[263] - pts[33])
    gaps = lid_gaps(eyelid_contours(img, pts)) / iod
    flipped = np.ascontiguousarray(img[:, ::-1])
    m = LandmarkTracker().track(flipped).points
    mirrored = lid_gaps(eyelid_contours(flipped, m)) / iod
    # the same eyes, their crops placed from another run of the mesh (0.08 and 0.068 IOD
    # for the wider one at 320 px)
    np.testing.assert_allclose(mirrored[::-1], gaps, rtol=0.2)


def test_eyes_painted_shut_read_narrower(rendered):
    img, pts = rendered
    mask = np.zeros(img.shape[:2], np.uint8)
    for opening in _OPENINGS:
        cv2.fillPoly(mask, [np.round(pts[opening]).astype(np.int32)], 255)
    shut = cv2.inpaint(img, cv2.dilate(mask, np.ones((3, 3), np.uint8)), 5, cv2.INPAINT_TELEA)
    open_, closed = lid_gaps(eyelid_contours(img, pts)), lid_gaps(eyelid_contours(shut, pts))
    assert (closed < 0.75 * open_).all(), (open_, closed)
