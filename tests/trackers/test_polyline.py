"""Polylines resampled at equal arc length (:mod:`trackers.polyline`)."""

import numpy as np
import pytest

from trackers.polyline import resample_polyline


def test_resample_polyline():
    pts = resample_polyline([[0, 0], [10, 0], [10, 10]], spacing=2.0)
    assert len(pts) == 11
    np.testing.assert_allclose(np.hypot(*np.diff(pts, axis=0).T), 2.0)
    closed = resample_polyline([[0, 0], [10, 0], [10, 10], [0, 10]], 8, closed=True)
    assert len(closed) == 8
    np.testing.assert_allclose(closed[1], [5, 0])


@pytest.mark.parametrize("closed", [False, True])
def test_resample_polyline_interpolates_at_equal_arc_lengths(rng, closed):
    # the compiled resampler gives exactly what interpolating the arc length does,
    # repeated vertices included (a contour end moved onto its neighbour)
    for _ in range(200):
        p = np.round(rng.random((int(rng.integers(2, 30)), 2)) * 50, 1)
        if len(p) > 2:
            p[1] = p[0]
        n = int(rng.integers(2, 40))
        q = np.vstack([p, p[:1]]) if closed else p
        s = np.r_[0.0, np.cumsum(np.hypot(*np.diff(q, axis=0).T))]
        if s[-1] == 0:
            continue
        t = np.linspace(0, s[-1], n + 1 if closed else n)[:n]
        before = p.copy()
        got = resample_polyline(p, n, closed=closed)
        np.testing.assert_array_equal(got, np.c_[np.interp(t, s, q[:, 0]),
                                                 np.interp(t, s, q[:, 1])])
        np.testing.assert_array_equal(p, before)
