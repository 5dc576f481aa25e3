"""Contour ends relocated on the features' ends (:mod:`trackers.contour_ends`)."""

import cv2
import numpy as np
import pytest


def test_line_end_found_on_the_grey_step_where_the_ravine_runs_on():
    # a furrow-like line whose prolongation is shaded: the potential's ravine runs on
    # past the line's end, the grey level steps up where the line stops
    from trackers.contour_ends import refine_end
    from trackers.potentials import valley_potential

    img = np.full((40, 100), 200, np.uint8)
    img[18:23, 60:95] = 140
    cv2.line(img, (10, 20), (58, 20), 40, 3)
    pts = np.c_[np.linspace(20, 70, 20), np.full(20, 20.0)]   # overshoots into the shade
    P = valley_potential(img, 1.5)
    assert refine_end(pts, P, 1.5, end=-1, inset=False) is None
    q = refine_end(pts, P, 1.5, end=-1, inset=False, step=True, gray=img)
    assert abs(q[0] - 58.0) < 1.0 and abs(q[1] - 20.0) < 0.2
    # a line that only fades (to 110, the skin being 200) has no end where it fades
    faint = img.copy()
    faint[18:23, 45:60] = np.maximum(faint[18:23, 45:60], 110)
    short = np.c_[np.linspace(20, 58, 20), np.full(20, 20.0)]
    q = refine_end(short, valley_potential(faint, 1.5), 1.5, end=-1, inset=False,
                   step=True, gray=faint)
    assert q is None or q[0] > 55.0
    with pytest.raises(ValueError, match="step=True needs gray"):
        refine_end(pts, P, 1.5, end=-1, step=True)


def test_steady_end_stays_put_where_the_search_overshoots():
    # a band, a gap, then a short dark patch (a brow's inner head beside the shading of
    # the nose): searched from short of the gap the end lands past it, searched from
    # there it lands short again, a swing of 3 px from one frame to the next
    from trackers.contour_ends import refine_end
    from trackers.potentials import potentials_in_boxes, to_gray

    x = np.arange(160)
    dark = np.where((x >= 20) & (x < 80), 90.0, 0.0) + np.where((x >= 88) & (x < 92), 90.0, 0.0)
    band = np.exp(-0.5 * ((np.arange(100)[:, None] - 50) / (8 / 2.355)) ** 8)
    g = to_gray(np.clip(200 - band * dark, 0, 255).astype(np.uint8))
    sigma = 2.0
    P = potentials_in_boxes(g, [("valley", sigma)], [(0, 0, 160, 100)])[0]

    def search(x0, steady):
        pts = np.c_[np.linspace(x0, 30, 12), np.full(12, 50.0)]
        q = refine_end(pts, P, sigma, gray=g, steady=steady)
        assert q is not None
        return q[0]

    first = search(86.0, False)
    assert abs(search(first, False) - first) > sigma          # the plain search swings
    end = search(86.0, True)
    assert abs(search(end, True) - end) < 0.25 * sigma       # the steady one stays put
    assert min(first, search(first, False)) < end < max(first, search(first, False))
