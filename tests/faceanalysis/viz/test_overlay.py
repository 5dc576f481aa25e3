"""Drawing tracking results on frames."""

from __future__ import annotations

import numpy as np
import pytest

from faceanalysis.io.table import empty_table
from faceanalysis.viz.overlay import draw_overlay, fiducials_from_row


def test_draws_where_the_points_are_and_leaves_input_alone():
    image = np.zeros((120, 160), np.uint16)
    original = image.copy()
    out = draw_overlay(image, contours={"lip": np.array([[20.0, 100.0], [140.0, 100.0]])},
                       fiducials={"mouth_corner_l": (140.0, 30.0),
                                  "mouth_corner_r": (20.0, 30.0)})
    np.testing.assert_array_equal(image, original)
    assert out.shape == (120, 160, 3) and out.dtype == np.uint8
    assert out[100, 40:120].any(axis=1).all()       # the contour runs along y = 100
    assert not out[60:80, 60:100].any()             # nothing drawn elsewhere
    left, right = out[28:33, 138:143], out[28:33, 18:23]
    assert left.any() and right.any()
    # Left (green) and right (magenta) sides are told apart.
    assert left[..., 1].max() > left[..., 2].max()
    assert right[..., 2].max() > right[..., 1].max()


def test_nan_points_are_skipped():
    out = draw_overlay(np.zeros((50, 50, 3), np.uint8),
                       contours=[np.array([[5.0, 5.0], [np.nan, np.nan], [45.0, 45.0]])],
                       fiducials={"chin": (np.nan, 3.0)}, head=(np.nan, 0, 1, 0))
    assert not out.any()


def test_head_frame_axes_follow_roll():
    out = draw_overlay(np.zeros((100, 100), np.uint8), head=(50.0, 50.0, 40.0, 0.0))
    assert out[50, 62:68].any() and out[62:68, 50].any()   # x right, y down, 20 px long
    assert not out[50, 32:38].any() and not out[32:38, 50].any()
    turned = draw_overlay(np.zeros((100, 100), np.uint8), head=(50.0, 50.0, 40.0, np.pi / 2))
    assert turned[62:68, 50].any() and turned[50, 32:38].any()  # x now down, y to the left
    assert not turned[50, 62:68].any()


def test_lost_and_label():
    out = draw_overlay(np.full((80, 200), 128, np.uint8), lost=True, label="frame 3")
    assert (out[0, :, 2] > 200).all()  # red border
    assert (out[5:20, 2:60] != 128).any()
    # why it was lost: a longer text, reaching further left from the right edge
    why = draw_overlay(np.full((80, 400), 128, np.uint8), lost="under a hand")
    plain = draw_overlay(np.full((80, 400), 128, np.uint8), lost=True)
    def text_start(img):
        return np.flatnonzero((img[4:30, 4:-4, 2] > 200).any(axis=0)).min()
    assert text_start(why) < text_start(plain) - 50


def test_lost_contours_are_drawn_grey():
    contours = {"brow_l": np.array([[20.0, 30.0], [140.0, 30.0]]),
                "hairline": np.array([[20.0, 80.0], [140.0, 80.0]])}
    out = draw_overlay(np.zeros((120, 160, 3), np.uint8), contours=contours,
                       lost_contours={"hairline"})
    held, lost = out[30, 40:120].astype(int), out[80, 40:120].astype(int)
    assert held.any(axis=1).all() and lost.any(axis=1).all()      # both are drawn
    # the held one yellow (red and green over blue), the lost one grey (channels alike)
    assert (held[:, 1] - held[:, 0]).min() > 100
    assert np.abs(lost - lost.mean(axis=1, keepdims=True)).max() <= 2
    # a sequence of contours has no names: all drawn as held
    seq = draw_overlay(np.zeros((120, 160, 3), np.uint8), contours=list(contours.values()),
                       lost_contours={"hairline"})
    assert (seq[80, 40:120, 1].astype(int) - seq[80, 40:120, 0]).min() > 100


def test_bad_contour_shape():
    with pytest.raises(ValueError, match=r"\(K, 2\)"):
        draw_overlay(np.zeros((10, 10)), contours=[np.zeros((3, 3))])


def test_fiducials_from_a_table_row():
    t = empty_table(1)
    t.loc[0, ["fid_chin_x", "fid_chin_y"]] = [4.0, 5.0]
    fid = fiducials_from_row(t.iloc[0])
    assert len(fid) == 11 and fid["chin"] == (4.0, 5.0)
    assert np.isnan(fid["brow_mid_l"][0])


def test_a_hand_is_drawn_as_its_outline():
    u, v = np.meshgrid(np.linspace(40, 120, 7), np.linspace(30, 90, 3))
    hand = np.c_[u.ravel(), v.ravel()]
    out = draw_overlay(np.zeros((120, 160, 3), np.uint8), hands=[hand])
    assert out[30, 50:110].any(axis=1).all() and out[90, 50:110].any(axis=1).all()
    assert out[40:80, 40].any(axis=1).all()          # the hull's left side
    assert not out[45:75, 55:105].any()              # its inside is left as it was
    with pytest.raises(ValueError, match="hands"):
        draw_overlay(np.zeros((20, 20), np.uint8), hands=[np.zeros((3, 3))])


def test_the_lids_are_drawn_round_the_eye():
    t = np.linspace(0, np.pi, 9)
    lower = np.c_[80 - 40 * np.cos(t), 60 + 15 * np.sin(t)]      # outer corner to inner
    upper = np.c_[80 - 40 * np.cos(t[1:8]), 60 - 15 * np.sin(t[1:8])]
    out = draw_overlay(np.zeros((120, 160, 3), np.uint8), eyelids=[np.r_[lower, upper]])
    assert out[60 + 15, 75:85].any() and out[60 - 15, 75:85].any()   # both lids
    # round the eye, not across it: the inner corner does not join the upper lid's start
    assert not out[52:68, 60:100].any()
    with pytest.raises(ValueError, match="eyelids"):
        draw_overlay(np.zeros((20, 20), np.uint8), eyelids=[np.zeros((15, 2))])


def test_marks_are_no_wider_than_a_small_face_calls_for():
    frame = np.zeros((1080, 1920), np.uint8)
    line = {"brow": np.array([[900.0, 500.0], [1000.0, 500.0]])}
    dot = {"chin": (1200.0, 700.0)}

    def widths(head):
        out = draw_overlay(frame, contours=line, fiducials=dot, head=head).any(axis=2)
        return int(out[:, 950].sum()), int(out[700, 1150:1250].sum())

    wide_line, wide_dot = widths(None)              # sized by the 1080-px frame
    small_line, small_dot = widths((1500.0, 200.0, 60.0, 0.0))   # a face 60 px across
    assert small_line < wide_line and small_dot < wide_dot
    assert widths((1500.0, 200.0, 600.0, 0.0)) == (wide_line, wide_dot)   # a large face
