"""Pixel normalisation of any frame for measuring and drawing."""

import cv2
import numpy as np
import pytest

from faceanalysis.io.frames import to_bgr_uint8, to_gray_float, to_uint8


@pytest.mark.parametrize(("image", "expected"), [
    (np.full((2, 3), 255, np.uint8), 1.0),
    (np.full((2, 3), 32768, np.uint16), 32768 / 65535),
    (np.full((2, 3, 1), 51, np.uint8), 0.2),
    (np.full((2, 3), 0.25, np.float64), 0.25),
    (np.dstack([np.full((2, 3), 255, np.uint8)] * 3 + [np.zeros((2, 3), np.uint8)]), 1.0),
])
def test_to_gray_float_normalises(image, expected):
    original = image.copy()
    grey = to_gray_float(image)
    assert grey.shape == (2, 3) and grey.dtype == np.float32
    np.testing.assert_allclose(grey, expected, rtol=1e-6)
    np.testing.assert_array_equal(image, original)


def test_to_gray_float_matches_opencv_luma(rng):
    bgr = rng.integers(0, 256, (8, 9, 3), dtype=np.uint8)
    expected = cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY) / 255.0
    np.testing.assert_allclose(to_gray_float(bgr, dtype=np.float64), expected, atol=1 / 255)


def test_to_gray_float_rejects_bad_shapes():
    with pytest.raises(ValueError, match="shape"):
        to_gray_float(np.zeros((2, 3, 5)))
    with pytest.raises(ValueError, match="pixel type"):
        to_gray_float(np.zeros((2, 3), dtype=complex))


def test_to_bgr_uint8():
    out = to_bgr_uint8(np.array([[0, 65535]], np.uint16))
    assert out.shape == (1, 2, 3) and out.dtype == np.uint8
    assert out[0, 1].tolist() == [255, 255, 255]
    bgra = np.zeros((2, 2, 4), np.uint8)
    bgra[..., 0] = 9
    assert to_bgr_uint8(bgra).shape == (2, 2, 3)
    assert to_bgr_uint8(np.full((1, 1), 2.0))[0, 0, 0] == 255  # floats are clipped


def test_to_uint8_refuses_floats_it_would_clip():
    # within the rounding slack a float frame is taken; beyond it, a float frame in 0..255
    # would be clipped to white and every frame read as faceless
    assert to_uint8(np.array([[-1e-4, 0.5, 1.0 + 1e-4]])).tolist() == [[0, 128, 255]]
    for bad, match in [(np.array([[0.0, 255.0]]), r"\[0, 255\]: divide by 255"),
                       (np.array([[0.0, -0.2]]), r"\[-0.2, 0\]"),
                       (np.array([[0.5, np.nan]]), "finite"),
                       (np.array([[0.5, np.inf]], np.float32), "finite")]:
        with pytest.raises(ValueError, match=match):
            to_uint8(bad)


@pytest.mark.parametrize("shape", [(40, 100), (40, 100, 1), (40, 100, 3), (40, 100, 4),
                                   (120, 30, 3), (10, 20, 3)])
def test_fit_image_places_the_picture_by_its_scale_and_offset(shape):
    from faceanalysis.io.frames import fit_image

    image = np.zeros(shape, np.uint8)
    top, left = shape[0] // 3, shape[1] // 3
    image[top:top + 3, left:left + 3] = 250             # a bright block, off the edges
    before = image.copy()
    canvas, scale, offset = fit_image(image, (80, 60))
    np.testing.assert_array_equal(image, before)        # not modified
    assert canvas.shape == (60, 80, *shape[2:]) and canvas.dtype == np.uint8
    assert min(80 / shape[1], 60 / shape[0]) == pytest.approx(scale[0], rel=0.05)
    assert scale[0] == pytest.approx(scale[1], rel=0.05)
    grey = (canvas if canvas.ndim == 2 else canvas[..., 0]).astype(float)
    ys, xs = np.mgrid[:60, :80]
    centre = np.array([(xs * grey).sum(), (ys * grey).sum()]) / grey.sum()
    np.testing.assert_allclose(centre, np.array(scale) * (left + 1, top + 1) + offset, atol=0.3)
