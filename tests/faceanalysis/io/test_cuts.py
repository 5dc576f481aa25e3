import numpy as np
import pytest

from faceanalysis.io.cuts import CUT_THRESHOLD, content_change, shot_cuts, thumbnail


def _hsv_frame(h, s, v, shape=(48, 80)):
    import cv2

    hsv = np.zeros((*shape, 3), np.uint8)
    hsv[...] = (h, s, v)
    return cv2.cvtColor(hsv, cv2.COLOR_HSV2BGR)


def test_thumbnails_keep_the_aspect_and_refuse_what_is_not_a_picture():
    assert thumbnail(np.zeros((360, 640, 3), np.uint8)).shape == (36, 64, 3)
    assert thumbnail(np.zeros((360, 640), np.uint8)).shape == (36, 64)
    assert thumbnail(np.zeros((360, 640, 4), np.uint8)).shape == (36, 64, 3)
    with pytest.raises(ValueError, match="uint8"):
        thumbnail(np.zeros((36, 64, 3), np.float32))
    assert thumbnail(np.full((36, 64), 65535, np.uint16)).max() == 255
    with pytest.raises(ValueError, match="channel_order"):
        thumbnail(np.zeros((36, 64, 3), np.uint8), channel_order="hsv")


def test_hue_changes_the_short_way_round_its_circle():
    a = thumbnail(_hsv_frame(2, 200, 200))
    b = thumbnail(_hsv_frame(178, 200, 200))
    # 4 steps apart on OpenCV's 180-step hue circle, not 176
    assert content_change(a, b) == pytest.approx(4 / 3, abs=0.5)
    assert content_change(a, a) == 0.0


def test_grey_frames_compare_their_values():
    a = thumbnail(np.full((36, 64), 100, np.uint8))
    b = thumbnail(np.full((36, 64), 140, np.uint8))
    assert content_change(a, b) == pytest.approx(40.0)


def test_cuts_are_changes_over_the_threshold_a_shot_apart():
    changes = [np.nan, 1.0, 1.0, CUT_THRESHOLD + 1, 50.0, 2.0, np.nan, 3.0, 90.0]
    assert shot_cuts(changes, min_shot=3) == [3, 8]
    assert shot_cuts(changes, min_shot=0) == [3, 4, 8]
    assert shot_cuts(changes, np.arange(100, 109), min_shot=3) == [103, 108]
    assert shot_cuts([np.nan, 1.0, 2.0]) == []
    # the first shot lasts a shot's length too: two photographs are not two shots
    assert shot_cuts([np.nan, 90.0]) == []
    with pytest.raises(ValueError, match="same length"):
        shot_cuts([1.0, 2.0], [0])
    with pytest.raises(ValueError, match="threshold"):
        shot_cuts([1.0], threshold=0)
