import numpy as np
import pytest

from trackers.fiducials import (
    FIDUCIAL_NAMES,
    HeadFrame,
    apex_fraction,
    arc_point,
    centroid,
    fiducials,
    head_frame,
)
from trackers.layout import layout_from_eyes


def _contours(eyes=((96.0, 105.0), (159.0, 105.0))):
    lay = layout_from_eyes(*eyes, (400, 400))
    return {n: c.points for n, c in lay.contours.items()}


def test_names_and_sides():
    cont = _contours()
    f = fiducials(cont)
    assert tuple(f) == FIDUCIAL_NAMES
    # subject's left on the image's right
    for base in ("brow_inner", "brow_mid", "brow_outer", "mouth_corner", "furrow_top"):
        assert f[f"{base}_l"][0] > f[f"{base}_r"][0]
    assert f["brow_inner_l"][0] < f["brow_mid_l"][0] < f["brow_outer_l"][0]
    assert f["brow_inner_r"][0] > f["brow_mid_r"][0] > f["brow_outer_r"][0]
    np.testing.assert_allclose(f["mouth_corner_l"], cont["upper_lip"][-1])
    np.testing.assert_allclose(f["furrow_top_r"], cont["furrow_r"][0])
    np.testing.assert_allclose(f["chin"], centroid(cont["chin_boss"], closed=True))
    # the template brow arches with its top near its middle
    assert f["brow_mid_l"][1] < min(f["brow_inner_l"][1], f["brow_outer_l"][1])


def test_contour_direction_does_not_matter():
    cont = _contours()
    rev = {n: p[::-1].copy() for n, p in cont.items()}
    a, b = fiducials(cont), fiducials(rev)
    for n in FIDUCIAL_NAMES:
        np.testing.assert_allclose(a[n], b[n], atol=1e-6)


@pytest.mark.parametrize("angle", [-25.0, 12.0, 40.0])
def test_rotation_and_scale_equivariance(angle):
    cont = _contours()
    c = np.array([130.0, 150.0])
    a = np.deg2rad(angle)
    R = 1.3 * np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    moved = {n: (p - c) @ R.T + c + [20.0, -5.0] for n, p in cont.items()}
    h0, h1 = head_frame(cont), head_frame(moved)
    assert h1.roll - h0.roll == pytest.approx(a, abs=1e-9)
    assert h1.scale / h0.scale == pytest.approx(1.3, rel=1e-9)
    f0, f1 = fiducials(cont), fiducials(moved)
    for n in FIDUCIAL_NAMES:
        np.testing.assert_allclose(f1[n], (np.asarray(f0[n]) - c) @ R.T + c + [20, -5],
                                   atol=1e-6)
        # head coordinates are invariant
        np.testing.assert_allclose(h1.to_head([f1[n]]), h0.to_head([f0[n]]), atol=1e-9)


def test_head_frame_from_hairline_and_round_trip():
    cont = _contours()
    h = head_frame(cont)
    np.testing.assert_allclose([h.x, h.y], centroid(cont["hairline"]))
    assert abs(h.roll) < 1e-9
    pts = np.array([[10.0, 20.0], [200.0, 150.0]])
    np.testing.assert_allclose(h.to_image(h.to_head(pts)), pts)
    d = h.as_dict()
    assert set(d) == {"head_x", "head_y", "head_scale", "head_roll"}


def test_brow_mid_fraction_is_used_and_checked():
    cont = _contours()
    f = fiducials(cont, brow_mid_fraction={"l": 0.0, "r": 1.0})
    np.testing.assert_allclose(f["brow_mid_l"], f["brow_inner_l"])
    np.testing.assert_allclose(f["brow_mid_r"], f["brow_outer_r"])
    with pytest.raises(ValueError, match="brow_mid_fraction"):
        fiducials(cont, brow_mid_fraction={"l": 1.5})


def test_apex_fraction():
    x = np.linspace(0.0, 20.0, 41)
    h = HeadFrame(0.0, 0.0, 1.0, 0.0)
    assert apex_fraction(np.c_[x, 0.03 * (x - 10) ** 2], h) == pytest.approx(0.5, abs=0.01)
    assert apex_fraction(np.c_[x, np.zeros_like(x)], h) == 0.5  # no arch


def test_missing_or_bad_contours():
    cont = _contours()
    del cont["chin_boss"]
    with pytest.raises(ValueError, match="chin_boss"):
        fiducials(cont)
    cont = _contours()
    cont["upper_lip"] = cont["upper_lip"].copy()
    cont["upper_lip"][3] = np.nan
    with pytest.raises(ValueError, match="upper_lip.*NaN"):
        fiducials(cont)


def test_arc_point_walks_the_arc_length(rng):
    p = np.array([[0.0, 0.0], [3.0, 4.0], [3.0, 4.0], [3.0, 10.0]])   # 5 + 0 + 6 long
    np.testing.assert_array_equal(arc_point(p, 0.0), [0.0, 0.0])
    np.testing.assert_allclose(arc_point(p, 5 / 11), [3.0, 4.0])
    np.testing.assert_allclose(arc_point(p, 8 / 11), [3.0, 7.0])
    np.testing.assert_array_equal(arc_point(p, 1.0), [3.0, 10.0])
    # beyond the ends: the ends
    np.testing.assert_array_equal(arc_point(p, -0.5), [0.0, 0.0])
    np.testing.assert_array_equal(arc_point(p, 1.5), [3.0, 10.0])
    for _ in range(100):
        q = rng.random((int(rng.integers(2, 20)), 2)) * 100
        f = float(rng.random())
        s = np.r_[0.0, np.cumsum(np.hypot(*np.diff(q, axis=0).T))]
        np.testing.assert_array_equal(arc_point(q, f), [np.interp(f * s[-1], s, q[:, 0]),
                                                        np.interp(f * s[-1], s, q[:, 1])])
    with pytest.raises(ValueError, match="shape"):
        arc_point(np.zeros((3, 3)), 0.5)
