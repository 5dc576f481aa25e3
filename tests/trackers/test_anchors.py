"""Iris anchors and the head frame's stability under expressions."""

import math

import cv2
import numpy as np
import pytest

from tests.trackers.conftest import draw_face
from trackers.anchors import IrisAnchors, find_iris, similarity_from_pairs
from trackers.layout import layout_from_eyes
from trackers.tracking import Tracker

EYES = ((96.0, 105.0), (159.0, 105.0))


def _moved_eyes(angle=0.0, shift=(0.0, 0.0), scale=1.0):
    c = np.mean(EYES, axis=0)
    R = scale * np.array([[math.cos(angle), -math.sin(angle)],
                          [math.sin(angle), math.cos(angle)]])
    return tuple(tuple((np.asarray(e) - c) @ R.T + c + shift) for e in EYES)


def test_find_iris_prefers_the_iris_to_the_eyebrow():
    img, _ = draw_face(irises=True)
    for e in EYES:
        # a guess between brow and eye: the brow is darker and larger
        c = find_iris(img, (e[0] + 3, e[1] - 8), 0.085 * 63, search=12)
        assert c is not None
        assert np.hypot(*(c - e)) < 1.0


def test_find_iris_none_on_a_flat_image():
    assert find_iris(np.full((60, 60), 128, np.uint8), (30, 30), 4.0) is None


def test_find_iris_validates():
    with pytest.raises(ValueError, match="radius"):
        find_iris(np.zeros((20, 20)), (10, 10), 0.1)
    with pytest.raises(ValueError, match="2-D"):
        find_iris(np.zeros((2, 20, 20)), (10, 10), 3.0)


def test_similarity_from_pairs_roundtrip():
    src = np.array([[10.0, 20.0], [50.0, 25.0]])
    a0, b0 = 1.05 * np.exp(0.1j), 3 - 2j
    z = a0 * (src[:, 0] + 1j * src[:, 1]) + b0
    a, b = similarity_from_pairs(src, np.c_[z.real, z.imag])
    assert abs(a - a0) < 1e-12 and abs(b - b0) < 1e-9
    with pytest.raises(ValueError, match="coincide"):
        similarity_from_pairs([[1, 1], [1, 1]], [[0, 0], [1, 1]])


@pytest.mark.parametrize("angle, shift, scale", [
    (0.0, (2.4, -1.3), 1.0), (0.04, (0.0, 0.0), 1.0), (0.0, (0.0, 0.0), 1.04),
    (-0.03, (1.7, 2.2), 0.97)])
def test_iris_anchors_follow_a_rigid_motion(angle, shift, scale):
    img0, _ = draw_face(irises=True, noise=1.0)
    anc = IrisAnchors(img0, EYES)
    img1, _ = draw_face(eyes=_moved_eyes(angle, shift, scale), irises=True, noise=1.0,
                        rng=np.random.default_rng(1))
    a, b = anc.similarity(img1)
    assert abs(abs(a) - scale) < 0.005
    assert abs(np.angle(a) - angle) < 0.01
    z = a * complex(*anc.centres[0]) + b
    truth = _moved_eyes(angle, shift, scale)[0]
    # the iris centres found on frame 0 are near the drawn ones
    assert abs(z - complex(*truth)) < 0.3 + np.hypot(*(anc.centres[0] - EYES[0]))


def test_iris_anchors_ignore_the_lids():
    img0, _ = draw_face(irises=True, noise=1.0)
    anc = IrisAnchors(img0, EYES)
    img1, _ = draw_face(irises=True, noise=1.0, lid_open=0.03, rng=np.random.default_rng(2))
    a, b = anc.similarity(img1)
    z = a * (anc.centres[:, 0] + 1j * anc.centres[:, 1]) + b
    assert np.abs(z - (anc.centres[:, 0] + 1j * anc.centres[:, 1])).max() < 0.3


def test_iris_anchors_fail_without_eyes():
    img, _ = draw_face()
    with pytest.raises(ValueError, match="iris"):
        IrisAnchors(img, EYES)
    with pytest.raises(ValueError, match="too close"):
        IrisAnchors(img, [(10, 10), (12, 10)])


def _head(tracker, img):
    h = tracker.track(img).head
    return np.array([h.x, h.y, h.scale, h.roll])


EXPRESSION = dict(brow_raise=0.06, jaw=0.08, hair_raise=0.03, nose_drop=0.04, lid_open=0.02)


def test_head_frame_stable_under_expression():
    lay = layout_from_eyes(*EYES, (256, 256))
    heads = {}
    for mode in ("eyes", "contours"):
        tr = Tracker(lay, head_anchor=mode)
        h0 = _head(tr, draw_face(irises=True, noise=1.0)[0])
        h1 = _head(tr, draw_face(irises=True, noise=1.0, rng=np.random.default_rng(3),
                                 **EXPRESSION)[0])
        heads[mode] = h1 - h0
        heads[mode][2] /= h0[2]
    d = heads["eyes"]
    assert np.hypot(d[0], d[1]) < 0.3 and abs(d[2]) < 0.005 and abs(d[3]) < 0.005, d
    # the contours alone move with the expression (the hairline rises, nostrils drop)
    assert abs(heads["contours"][1]) > 1.0 or abs(heads["contours"][2]) > 0.01


def test_head_frame_follows_rigid_motion_during_expression():
    lay = layout_from_eyes(*EYES, (256, 256))
    tr = Tracker(lay)
    h0 = _head(tr, draw_face(irises=True, noise=1.0)[0])
    assert tr.head_source == "contours"  # the first frame defines the frame
    angle, shift = 0.03, np.array([2.0, -1.5])
    h1 = _head(tr, draw_face(eyes=_moved_eyes(angle, tuple(shift)), irises=True, noise=1.0,
                             rng=np.random.default_rng(4), **EXPRESSION)[0])
    assert tr.head_source == "eyes"
    c = np.mean(EYES, axis=0)
    R = np.array([[math.cos(angle), -math.sin(angle)], [math.sin(angle), math.cos(angle)]])
    expect = (h0[:2] - c) @ R.T + c + shift
    assert np.hypot(*(h1[:2] - expect)) < 0.5
    assert abs(h1[3] - h0[3] - angle) < 0.005
    assert abs(h1[2] / h0[2] - 1) < 0.005


def test_head_frame_falls_back_on_contours_without_eyes():
    lay = layout_from_eyes(*EYES, (256, 256))
    tr = Tracker(lay)
    img = draw_face()[0]
    tr.track(img)
    assert tr.anchors is None
    res = tr.track(np.roll(img, 2, axis=1))
    assert res.extra["head_source"] == "contours"
    with pytest.raises(ValueError, match="iris"):
        Tracker(lay, head_anchor="eyes").track(img)
    with pytest.raises(ValueError, match="head_anchor"):
        Tracker(lay, head_anchor="nose")


def test_head_frame_chains_contours_when_the_eyes_close():
    lay = layout_from_eyes(*EYES, (256, 256))
    tr = Tracker(lay)
    img0 = draw_face(irises=True, noise=1.0)[0]
    h0 = _head(tr, img0)
    shifted = draw_face(eyes=_moved_eyes(0.0, (1.5, 0.0)), irises=True, noise=1.0)[0]
    _head(tr, shifted)
    # eyes "closed": paint the almonds over with skin
    closed = shifted.copy()
    for e in _moved_eyes(0.0, (1.5, 0.0)):
        cv2.ellipse(closed, (int(e[0]), int(e[1])), (16, 9), 0, 0, 360, 190, -1)
    h2 = _head(tr, closed)
    assert tr.head_source == "contours"
    assert abs(h2[0] - h0[0] - 1.5) < 0.5 and abs(h2[1] - h0[1]) < 0.5


def _skin(img, angle=0.0, shift=(0.0, 0.0)):
    """``img`` with a fine skin texture that moves rigidly with the eyes."""
    rng = np.random.default_rng(11)
    t = cv2.GaussianBlur(rng.normal(0, 1, (256, 256)).astype(np.float32), (0, 0), 1.2)
    c = np.mean(EYES, axis=0)
    M = cv2.getRotationMatrix2D(tuple(c), -math.degrees(angle), 1.0)
    M[:, 2] += shift
    t = cv2.warpAffine(t, M, (256, 256), borderMode=cv2.BORDER_REFLECT)
    return np.clip(img + 40 * t, 0, 255).astype(np.uint8)


def test_head_frame_from_features_follows_the_head_not_the_expression():
    # eyes not drawn (closed): the features on the eyes and nose carry the head frame
    # (what 'auto' falls back on when no iris is found), and unlike the contours'
    # frame it does not follow the hairline and nostrils that the expression moves
    lay = layout_from_eyes(*EYES, (256, 256))
    heads = {}
    for mode in ("features", "contours"):
        tr = Tracker(lay, head_anchor=mode)
        h0 = _head(tr, _skin(draw_face(noise=1.0)[0]))
        assert tr.anchors is None
        angle, shift = 0.02, (1.5, -1.0)
        for k in range(1, 6):
            img = draw_face(eyes=_moved_eyes(angle * k / 5, tuple(np.multiply(shift, k / 5))),
                            noise=1.0, rng=np.random.default_rng(k),
                            **{n: v * k / 5 for n, v in EXPRESSION.items() if n != "lid_open"})
            h1 = _head(tr, _skin(img[0], angle * k / 5, np.multiply(shift, k / 5)))
        heads[mode] = (h0, h1, tr.head_source)
    h0, h1, source = heads["features"]
    assert source == "features"
    c = np.mean(EYES, axis=0)
    R = np.array([[math.cos(angle), -math.sin(angle)], [math.sin(angle), math.cos(angle)]])
    expect = (h0[:2] - c) @ R.T + c + shift
    assert np.hypot(*(h1[:2] - expect)) < 0.3
    assert abs(h1[3] - h0[3] - angle) < 0.003 and abs(h1[2] / h0[2] - 1) < 0.003
    h0c, h1c, source = heads["contours"]
    assert source == "contours"
    err_contours = np.hypot(*(h1c[:2] - ((h0c[:2] - c) @ R.T + c + shift)))
    assert err_contours > 1.0  # what the features save the head frame from


@pytest.mark.parametrize("mode", ["features", "contours"])
def test_redetection_keeps_the_head_frame_the_features_give(monkeypatch, mode):
    # a re-detection re-places the contours; with the features following the head its
    # frame stays theirs, not the two detections' eyes (here turned by 5 degrees)
    import trackers.tracking as tracking

    lay = layout_from_eyes(*EYES, (256, 256))
    turned = layout_from_eyes(*_moved_eyes(math.radians(5.0)), (256, 256))
    monkeypatch.setattr(tracking, "detect_layout", lambda *a, **k: turned)
    tr = Tracker(lay, head_anchor=mode)
    img = _skin(draw_face(noise=1.0)[0])
    h0 = _head(tr, img)
    _head(tr, img)
    source = tr.head_source
    got = tr._redetect(img, n_lost=len(tr.names) + 1,
                       anchored=tr.last_head if source in ("eyes", "features") else None)
    assert got is not None
    h1 = got[1]
    if mode == "features":
        assert source == "features" and tr.head_source == "features"
        assert abs(h1.roll - h0[3]) < 1e-3 and np.hypot(h1.x - h0[0], h1.y - h0[1]) < 0.3
        assert tr.features is not None  # still followed, not seeded again
    else:
        assert tr.head_source == "detection"
        assert abs(h1.roll - h0[3] - math.radians(5.0)) < 1e-3
