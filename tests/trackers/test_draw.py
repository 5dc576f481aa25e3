import numpy as np
import pytest

from trackers import HeadFrame, draw_contours, draw_fiducials, draw_head_frame


def test_draw_returns_new_colour_image():
    img = np.full((40, 50), 100, np.uint8)
    copy = img.copy()
    out = draw_contours(img, {"brow_l": np.array([[5.0, 5.0], [45.0, 5.0], [45.0, 30.0]]),
                              "chin_boss": np.array([[10.0, 20], [20, 20], [15, 30]])},
                        color=(255, 0, 0), lost={"chin_boss"}, lost_color=(0, 255, 0))
    np.testing.assert_array_equal(img, copy)
    assert out.shape == (40, 50, 3) and out.dtype == np.uint8
    assert out[5, 25, 0] > 200 and out[5, 25, 1] < 60  # tracked colour
    assert tuple(out[25, 15]) == (100, 100, 100)  # inside the triangle: untouched
    assert out[20, 15, 1] > 200 and out[20, 15, 0] < 60  # lost colour, contour closed
    out = draw_fiducials(out, {"chin": (25.0, 20.0)}, color=(0, 0, 255), labels=True)
    assert tuple(out[20, 25]) == (0, 0, 255)
    out = draw_head_frame(out, HeadFrame(10.0, 35.0, 20.0, 0.0), color=(9, 9, 9), size=4)
    assert out[35, 12].max() < 60


def test_float_and_rgba_inputs():
    f = np.zeros((20, 20), np.float64)
    out = draw_fiducials(f, {"a": (10.0, 10.0)})
    assert out.dtype == np.uint8 and out.shape == (20, 20, 3)
    rgba = np.zeros((20, 20, 4), np.uint8)
    assert draw_contours(rgba, [np.array([[1.0, 1], [18, 18]])]).shape == (20, 20, 3)


def test_bad_inputs():
    with pytest.raises(ValueError, match="non-empty"):
        draw_contours(np.zeros((0, 0)), [])
    with pytest.raises(ValueError, match="NaN"):
        draw_fiducials(np.full((5, 5), np.nan), {})
    with pytest.raises(ValueError, match="finite"):
        draw_contours(np.zeros((5, 5)), [np.array([[np.nan, 1.0], [2, 2]])])
    with pytest.raises(ValueError, match="HeadFrame"):
        draw_head_frame(np.zeros((5, 5)), (1, 2, 3, 4))
