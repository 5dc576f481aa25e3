import cv2
import numpy as np
import pytest

from trackers.potentials import (
    gaussian_potential,
    paper_potential,
    to_gray,
    valley_potential,
)


def test_dtypes_share_8bit_units():
    base = np.zeros((20, 20), np.float64)
    base[:, 10:] = 1.0
    p_float = gaussian_potential(base, 1.5)
    p_u8 = gaussian_potential((base * 255).astype(np.uint8), 1.5)
    p_u16 = gaussian_potential((base * 65535).astype(np.uint16), 1.5)
    p_bool = gaussian_potential(base.astype(bool), 1.5)
    for other in (p_u8, p_u16, p_bool):
        np.testing.assert_allclose(other, p_float, atol=1e-3)
    assert p_float.dtype == np.float32
    assert p_float.min() < -30  # a 255-level step gives a deep ravine


def test_colour_frames_and_channel_order():
    rgb = np.zeros((10, 12, 3), np.uint8)
    rgb[..., 0] = 255  # pure red
    g_rgb = to_gray(rgb)
    g_bgr = to_gray(rgb, channel_order="bgr")
    assert np.allclose(g_rgb, 0.299 * 255, atol=0.5)
    assert np.allclose(g_bgr, 0.114 * 255, atol=0.5)
    rgba = np.dstack([rgb, np.full((10, 12), 7, np.uint8)])
    assert np.allclose(to_gray(rgba), g_rgb)


def test_input_not_modified():
    img = np.random.default_rng(0).random((16, 16))
    copy = img.copy()
    gaussian_potential(img)
    valley_potential(img)
    paper_potential(img)
    np.testing.assert_array_equal(img, copy)


@pytest.mark.parametrize("bad, match", [
    (np.zeros((0, 0)), "at least"),
    (np.zeros((1, 1)), "at least"),
    (np.zeros((1, 50)), "at least"),
    (np.zeros((5,)), "2-D"),
    (np.zeros((5, 5, 2)), "channels"),
    (np.array([["a"] * 4] * 4), "numeric"),
])
def test_bad_images(bad, match):
    for fn in (gaussian_potential, valley_potential, paper_potential):
        with pytest.raises(ValueError, match=match):
            fn(bad)


def test_nan_pixels_raise():
    img = np.ones((8, 8))
    img[3, 5] = np.nan
    with pytest.raises(ValueError, match="row 3, col 5"):
        gaussian_potential(img)
    img[3, 5] = np.inf
    with pytest.raises(ValueError, match="NaN or infinite"):
        paper_potential(img)


def test_float_outside_unit_range_raises():
    with pytest.raises(ValueError, match=r"\[0, 1\]"):
        gaussian_potential(np.full((8, 8), 200.0))


def test_bad_sigma():
    with pytest.raises(ValueError, match="sigma"):
        gaussian_potential(np.ones((8, 8)), sigma=0)


def test_edge_ravine_position():
    img = np.zeros((40, 41), np.float32)
    img[:, 20:] = 200.0 / 255  # edge between x=19 and x=20
    P = gaussian_potential(img, 2.0)
    row = P[20].astype(float)
    i = int(np.argmin(row))
    assert i in (19, 20)
    assert row[19] == pytest.approx(row[20], rel=1e-4)


@pytest.mark.parametrize("shape", [(2, 2), (3, 7), (6, 3), (23, 31)])
def test_edge_potential_is_minus_the_blurred_gradient_magnitude(rng, shape):
    # central differences inside, one-sided on the border (np.gradient's rule)
    from trackers.potentials import _edge_nb

    g = (rng.random(shape) * 255).astype(np.float32)
    P = np.empty_like(g)
    _edge_nb(g, P)
    gy, gx = np.gradient(g.astype(np.float64))
    np.testing.assert_allclose(P, -np.hypot(gx, gy), rtol=1e-6, atol=1e-4)
    img = (rng.random((40, 50)) * 255).astype(np.uint8)
    blurred = cv2.GaussianBlur(to_gray(img), (13, 13), sigmaX=2.0, sigmaY=2.0,
                               borderType=cv2.BORDER_REFLECT)
    gy, gx = np.gradient(blurred.astype(np.float64))
    np.testing.assert_allclose(gaussian_potential(img, 2.0), -np.hypot(gx, gy), rtol=1e-5,
                               atol=1e-4)


def test_paper_potential_is_forward_difference():
    img = np.zeros((16, 16), np.uint8)
    img[:, 8:] = 200
    P = paper_potential(img)
    assert int(np.argmin(P[8])) == 7
    Pc = paper_potential(img, centred=True)
    # the centred variant is symmetric about the edge at x = 7.5
    assert Pc[8, 7] == pytest.approx(Pc[8, 8], rel=1e-5)
    assert Pc[8, 7] < Pc[8, 6]


def test_valley_centre_of_dark_band_not_inside_dark_region():
    img = np.full((60, 60), 200, np.uint8)
    img[20:27, :30] = 40  # dark band, rows 20..26, centre 23
    img[40:, 30:] = 40  # large dark region
    P = valley_potential(img, sigma=2.5)
    assert int(np.argmin(P[:, 10])) == 23
    assert P[55, 50] == 0.0  # no pull inside a uniform dark region
    assert P[23, 10] < -20


def test_roi_matches_full():
    img = np.random.default_rng(1).random((80, 90)).astype(np.float32)
    for fn in (gaussian_potential, valley_potential):
        full = fn(img, 2.0)
        crop = fn(img, 2.0, roi=(10, 20, 60, 70))
        assert crop.shape == (50, 50)
        np.testing.assert_allclose(crop, full[20:70, 10:60], atol=1e-4)
    full = paper_potential(img)
    np.testing.assert_allclose(paper_potential(img, roi=(10, 20, 60, 70)), full[20:70, 10:60],
                               atol=1e-4)
    with pytest.raises(ValueError, match="roi"):
        gaussian_potential(img, roi=(200, 200, 300, 300))
