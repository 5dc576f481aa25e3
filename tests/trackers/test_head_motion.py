"""Head motion from features on the eyes and nose (trackers.head_motion)."""

import cv2
import numpy as np
import pytest

from trackers.head_motion import FeatureAnchors, gray_u8, rigid_face_region

EYES = np.array([(100.0, 110.0), (156.0, 110.0)])


def _texture(shape=(256, 256), seed=0):
    rng = np.random.default_rng(seed)
    img = rng.integers(0, 256, shape).astype(np.float32)
    return np.clip(cv2.GaussianBlur(img, (0, 0), 2.0) * 3 - 256, 0, 255).astype(np.uint8)


def _warp(img, a, b):
    M = np.array([[a.real, -a.imag, b.real], [a.imag, a.real, b.imag]])
    return cv2.warpAffine(img, M, img.shape[1::-1], flags=cv2.INTER_LINEAR,
                          borderMode=cv2.BORDER_REFLECT)


def _moved(z, a, b):
    return a * z + b


def test_rigid_region_covers_eyes_and_nose_not_brows_or_mouth():
    m = rigid_face_region(EYES, (256, 256))
    assert m[110, 100] and m[110, 156] and m[140, 128]  # eyes, nose
    assert not m[90, 128]      # brows: 0.36 inter-eye distances above the eyes
    assert not m[190, 128]     # mouth
    assert m.dtype == np.uint8 and m.shape == (256, 256)


def test_follows_a_similarity_without_drift():
    img = _texture()
    anc = FeatureAnchors(img, EYES)
    z = EYES[:, 0] + 1j * EYES[:, 1]
    c = 128 + 128j
    for k in range(1, 41):
        # a slow turn, zoom and drift about the image centre
        a = (1 + 0.002 * k) * np.exp(1j * np.radians(0.25 * k))
        b = c - a * c + (0.4 * k - 0.2j * k)
        got = anc.similarity(_warp(img, a, b))
        assert got is not None, k
    err = np.abs(_moved(z, *got) - _moved(z, a, b))
    assert err.max() < 0.3, err
    assert abs(abs(got[0]) - abs(a)) < 2e-3
    assert abs(np.angle(got[0]) - np.angle(a)) < 2e-3


def test_a_hand_moving_across_the_face_is_outvoted():
    img = _texture()
    hand = _texture(seed=5)
    anc = FeatureAnchors(img, EYES)
    z = EYES[:, 0] + 1j * EYES[:, 1]
    for k in range(1, 16):
        a, b = 1.0 + 0j, complex(0.5 * k, 0.3 * k)
        frame = _warp(img, a, b)
        # a textured patch sliding over the eye on the left and half the nose
        x0 = 40 + 2 * k
        frame[95:150, x0:x0 + 60] = hand[95:150, 30:90]
        got = anc.similarity(frame)
        assert got is not None
    assert np.abs(_moved(z, *got) - _moved(z, a, b)).max() < 0.5


def test_returns_none_when_the_face_is_gone_and_keeps_going():
    img = _texture()
    anc = FeatureAnchors(img, EYES)
    assert anc.similarity(_warp(img, 1, 1 + 0j)) is not None
    assert anc.similarity(np.full_like(img, 128)) is None
    assert anc.inliers == 0


def test_input_errors():
    with pytest.raises(ValueError, match="features"):
        FeatureAnchors(np.full((256, 256), 90, np.uint8), EYES)
    with pytest.raises(ValueError, match="too close"):
        FeatureAnchors(_texture(), [(100, 100), (102, 100)])
    with pytest.raises(ValueError, match="channel_order"):
        FeatureAnchors(_texture(), EYES, channel_order="hsv")
    anc = FeatureAnchors(_texture(), EYES)
    with pytest.raises(ValueError, match="256x256"):
        anc.similarity(_texture((200, 256)))


def test_gray_u8_of_other_dtypes_and_colour():
    g = _texture((20, 30))
    rgb = np.dstack([g, g, g])
    assert np.array_equal(gray_u8(rgb), g)
    assert np.array_equal(gray_u8(g.astype(np.float64) / 255.0), g)
    assert np.array_equal(gray_u8(g.astype(np.uint16) * 257), g)
    src = rgb.copy()
    gray_u8(src, "bgr")
    assert np.array_equal(src, rgb)  # the input is not modified
