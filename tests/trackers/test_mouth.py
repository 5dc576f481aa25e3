"""Mouth corners on the grey level (:mod:`trackers.mouth`)."""

import numpy as np
import pytest


def _open_mouth(jaw_px, *, size=(120, 160), corners=((45.0, 60.0), (115.0, 60.0)), noise=1.0):
    import cv2

    img = np.full(size, 190, np.uint8)
    (x0, y0), (x1, y1) = corners
    cx, cy = 0.5 * (x0 + x1), 0.5 * (y0 + y1)
    half = 0.5 * (x1 - x0)
    # lips (mid grey), the line where they meet, and the cavity opened by the jaw
    cv2.ellipse(img, (int(cx), int(cy)), (int(half), 10 + jaw_px), 0, 0, 360, 140, -1,
                cv2.LINE_AA)
    cv2.line(img, (int(x0) + 1, int(y0)), (int(x1) - 1, int(y1)), 45, 2, cv2.LINE_AA)
    if jaw_px:
        t = np.linspace(0, np.pi, 40)
        lens = np.c_[cx + (half - 1) * np.cos(t), cy + jaw_px * np.sin(t)]
        cv2.fillPoly(img, [np.round(np.vstack([lens, lens[::-1] * [1, 0] + [0, 2 * cy - 1]])
                                    ).astype(np.int32)], 30, cv2.LINE_AA)
    rng = np.random.default_rng(0)
    return np.clip(img + rng.normal(0, noise, img.shape), 0, 255).astype(np.uint8)


@pytest.mark.parametrize("jaw_px", [0, 6, 10])
def test_mouth_corners_closed_and_open(jaw_px):
    from trackers.mouth import mouth_corners

    img = _open_mouth(jaw_px)
    # a contour that follows the cavity's lower border, short of the corners
    x = np.linspace(62, 98, 15)
    lip = np.c_[x, 60 + jaw_px * np.sin(np.pi * (x - 45) / 70)]
    got = mouth_corners(img, lip, width=70.0)
    assert got[0] is not None and got[1] is not None
    assert np.hypot(*(got[0] - (45, 60))) < 1.5
    assert np.hypot(*(got[1] - (115, 60))) < 1.5


def test_mouth_corners_stay_near_the_previous_corner_when_a_furrow_crosses_the_window():
    import cv2

    from trackers.mouth import mouth_corners

    # upper lip lifted off the teeth (disgust): the contour sits on the teeth's top edge,
    # and the nasolabial furrow runs down just outside the corner
    img = np.full((120, 160), 200, np.uint8)
    cv2.ellipse(img, (80, 70), (40, 9), 0, 0, 360, 120, -1)      # lips
    cv2.ellipse(img, (80, 67), (28, 4), 0, 0, 360, 235, -1)      # upper teeth
    cv2.line(img, (50, 72), (110, 72), 50, 2)                    # where the lips part
    cv2.line(img, (40, 70), (52, 72), 50, 2)
    cv2.line(img, (108, 72), (120, 70), 50, 2)                   # corners at x = 40 / 120
    cv2.line(img, (116, 32), (124, 58), 30, 2)                   # the furrow
    lip = np.c_[np.linspace(54, 106, 15), np.full(15, 63.0)]
    blind = mouth_corners(img, lip, width=80)
    assert np.hypot(*(blind[1] - (120, 70))) > 8                 # the furrow wins
    prev = [np.array([40.0, 70.0]), np.array([120.0, 70.5])]
    got = mouth_corners(img, lip, width=80, previous=prev)
    assert np.hypot(*(got[0] - (40, 70))) < 1.5
    assert np.hypot(*(got[1] - (120, 70))) < 1.5
    with pytest.raises(ValueError, match="two corners"):
        mouth_corners(img, lip, previous=[prev[0]])


def test_mouth_corners_validates_and_gives_up():
    from trackers.mouth import mouth_corners

    with pytest.raises(ValueError, match="lip"):
        mouth_corners(np.zeros((20, 20)), [[1, 1], [2, 2]])
    flat = np.full((60, 100), 128, np.uint8)
    assert mouth_corners(flat, np.c_[np.linspace(30, 70, 9), np.full(9, 30.0)]) == [None, None]
