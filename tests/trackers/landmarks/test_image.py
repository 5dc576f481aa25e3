"""Frame validation shared by the landmark models."""

import numpy as np
import pytest

from trackers.landmarks._image import check_image


def test_alpha_is_dropped_and_the_picture_kept():
    rng = np.random.default_rng(0)
    colour = rng.integers(0, 256, (6, 5, 3), dtype=np.uint8)
    alpha = rng.integers(0, 256, (6, 5, 1), dtype=np.uint8)
    for order in ("rgb", "bgr"):
        out = check_image(np.concatenate([colour, alpha], axis=2), order)
        assert out.flags.c_contiguous
        np.testing.assert_array_equal(out, colour)
    np.testing.assert_array_equal(check_image(np.concatenate([colour[..., :1], alpha], 2), "rgb"),
                                  colour[..., 0])
    np.testing.assert_array_equal(check_image(colour[..., :1], "rgb"), colour[..., 0])
    assert check_image(colour, "rgb") is colour


@pytest.mark.parametrize(("image", "match"), [
    (np.zeros((6, 5, 5), np.uint8), r"\(6, 5, 5\) is not a grey \(H, W\) or colour"),
    (np.zeros((1, 5, 3), np.uint8), "is not a grey"),
    (np.zeros((6, 5), np.int32), "dtype int32"),
    (np.full((6, 5), 255.0), r"within \[0, 1\]"),
])
def test_bad_frames_are_refused(image, match):
    with pytest.raises(ValueError, match=match):
        check_image(image, "rgb")
