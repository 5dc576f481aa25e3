import numpy as np
import pytest

from trackers.landmark_contours import (
    eye_centres,
    landmark_curves,
    layout_from_landmarks,
    lip_gap,
    mouth_width,
)
from trackers.layout import CONTOUR_NAMES, TEMPLATE, layout_from_eyes


def _mesh_from_template(eye_r=(100.0, 120.0), eye_l=(160.0, 120.0)):
    """468 points where every mesh point a curve uses sits on the template's curve: a
    face whose landmarks agree with the layout template."""
    from trackers.landmark_contours import (
        _BROW_EDGES,
        _LIP_INNER,
        CHIN_CENTRE,
        EYE_POINTS,
        MESH_CURVES,
    )

    lay = layout_from_eyes(eye_r, eye_l, (256, 256))
    pts = np.full((468, 2), 128.0)
    for k, idx in enumerate(EYE_POINTS):
        pts[list(idx)] = (eye_r, eye_l)[k]

    def put(indices, curve):
        t = np.linspace(0, len(curve) - 1, len(indices))
        pts[list(indices)] = np.c_[np.interp(t, np.arange(len(curve)), curve[:, 0]),
                                   np.interp(t, np.arange(len(curve)), curve[:, 1])]

    for name, (up, lo) in _BROW_EDGES.items():
        put(up, lay.contours[name].points)
        put(lo, lay.contours[name].points)
    lip = lay.contours["upper_lip"].points
    pts[61], pts[291] = lip[0], lip[-1]
    put(_LIP_INNER[0], lip[1:-1])
    put(_LIP_INNER[1], lip[1:-1])
    for name, idx in MESH_CURVES.items():
        put(idx, lay.contours[name].points)
    # the chin's tip below the lower lip's lowest point (17) so that the chin boss's
    # centre falls where the template has it
    centre = lay.contours["chin_boss"].points.mean(axis=0)
    pts[152] = pts[17] + (centre - pts[17]) / CHIN_CENTRE
    return pts, lay


def test_curves_run_in_the_templates_direction():
    pts, lay = _mesh_from_template()
    curves = landmark_curves(pts)
    assert set(curves) == set(CONTOUR_NAMES) - {"hairline"}
    for name, curve in curves.items():
        ref = lay.contours[name].points
        # same first end as the template's (brows inner, furrows top, lips from the left)
        assert np.linalg.norm(curve[0] - ref[0]) < np.linalg.norm(curve[0] - ref[-1]) + 1e-9 \
            or lay.contours[name].closed, name


def test_layout_from_landmarks_keeps_the_templates_settings():
    pts, lay = _mesh_from_template()
    got = layout_from_landmarks(pts, (256, 256))
    assert got.source == "landmarks"
    np.testing.assert_allclose(got.eyes, eye_centres(pts))
    for name in CONTOUR_NAMES:
        c, ref = got.contours[name], lay.contours[name]
        assert (c.closed, c.kind, c.sigma) == (ref.closed, ref.kind, ref.sigma)
        # the placed curve lies on the template's curve
        d = np.linalg.norm(c.points[:, None] - ref.points[None], axis=2).min(axis=1)
        assert d.max() < 1.5, name
    # the mouth line's ends are the mesh's corners, not relocated by the tracker
    assert got.contours["upper_lip"].ends == "free"


def test_lip_gap_measures_the_opening_in_interocular_distances():
    from trackers.landmark_contours import _LIP_INNER

    closed, _ = _mesh_from_template()
    assert lip_gap(closed) == pytest.approx(0.0, abs=1e-9)      # both lips on one line
    opened = closed.copy()
    opened[list(_LIP_INNER[1])] += [0.0, 9.0]                 # lower lip 9 px down
    assert lip_gap(opened) == pytest.approx(9.0 / 60.0)          # eyes 60 px apart
    # the same face twice the size, moved and turned by 30 degrees: the same opening
    turn = np.deg2rad(30.0)
    rot = np.array([[np.cos(turn), -np.sin(turn)], [np.sin(turn), np.cos(turn)]])
    assert lip_gap(2.0 * opened @ rot.T + [40.0, -7.0]) == pytest.approx(9.0 / 60.0)
    with pytest.raises(ValueError, match="468"):
        lip_gap(np.zeros((68, 2)))


def test_mouth_width_is_the_corners_distance_in_interocular_distances():
    pts, _ = _mesh_from_template()
    width = np.hypot(*(pts[291] - pts[61])) / 60.0              # eyes 60 px apart
    assert mouth_width(pts) == pytest.approx(width)
    wide = pts.copy()
    wide[61] -= [3.0, 0.0]
    wide[291] += [3.0, 0.0]                                     # a smile: 6 px wider
    assert mouth_width(wide) == pytest.approx(width + 0.1)
    assert mouth_width(0.5 * wide + 11.0) == pytest.approx(width + 0.1)


def test_mouth_measures_take_many_frames_at_once():
    a, _ = _mesh_from_template()
    b = a.copy()
    b[[87, 14, 317]] += [0.0, 12.0]
    b[291] += [6.0, 0.0]
    both = np.stack([a, b])
    np.testing.assert_allclose(lip_gap(both), [lip_gap(a), lip_gap(b)])
    np.testing.assert_allclose(mouth_width(both), [mouth_width(a), mouth_width(b)])
    assert lip_gap(b) > lip_gap(a) and mouth_width(b) > mouth_width(a)


def test_bad_landmarks_are_refused():
    with pytest.raises(ValueError, match="468"):
        landmark_curves(np.zeros((68, 2)))
    with pytest.raises(ValueError, match="468"):
        layout_from_landmarks(np.zeros((468,)), (64, 64))


def test_template_and_curves_share_names():
    assert set(TEMPLATE) == set(CONTOUR_NAMES)
