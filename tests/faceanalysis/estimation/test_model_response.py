"""Measurement points: read the same way off the face model and off the tracked contours."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from faceanalysis.estimation.model_response import (
    CURVE_POINTS,
    MEASUREMENT_POINTS,
    equilibrium_points,
    model_points,
)
from faceanalysis.io.table import FIDUCIALS
from faceanalysis.tracking import POINT_CONTOUR, _measure


@pytest.fixture(scope="module")
def model():
    from synth import FaceModel

    return FaceModel.default()


def test_every_measurement_point_has_a_contour_and_a_model_counterpart(model):
    assert MEASUREMENT_POINTS[: len(FIDUCIALS)] == FIDUCIALS
    assert set(MEASUREMENT_POINTS) <= set(POINT_CONTOUR)
    model.reset()
    rest = model_points(model, model.equilibrate())
    assert rest.shape == (len(MEASUREMENT_POINTS), 2) and np.isfinite(rest).all()
    with pytest.raises(ValueError, match="no measurement point 'nose_ring'"):
        model_points(model, model.surface_vertices, ("nose_ring",))


def test_furrow_points_lie_on_the_furrow_below_its_top(model):
    model.reset()
    p = dict(zip(MEASUREMENT_POINTS, model_points(model, model.equilibrate())))
    for s, sign in (("l", 1.0), ("r", -1.0)):
        top, mid, bottom = (p[f"furrow_{k}_{s}"] for k in ("top", "mid", "bottom"))
        assert top[1] > mid[1] > bottom[1]                  # y up: the furrow runs down
        assert sign * bottom[0] > sign * top[0] > 0         # and out, on its own side
    # the curve's first sample is the furrow_top landmark (same uv point)
    first = model.mesh.curve_positions("furrow_l", model.surface_vertices)[0]
    np.testing.assert_allclose(first[:2], p["furrow_top_l"], atol=1e-9)


def test_furrow_points_follow_the_cheek_and_the_jaw(model):
    model.reset()
    rest = equilibrium_points(model, (), ())
    idx = {n: j for j, n in enumerate(MEASUREMENT_POINTS)}
    smile = equilibrium_points(model, ("zygomaticus_major_l",), (1.0,)) - rest
    assert np.linalg.norm(smile[idx["furrow_mid_l"]]) > 0.05
    assert smile[idx["furrow_mid_l"], 1] > 0                # pulled up toward the zygoma
    assert np.linalg.norm(smile[idx["furrow_mid_r"]]) < 0.5 * np.linalg.norm(
        smile[idx["furrow_mid_l"]])
    model.reset()
    jaw = equilibrium_points(model, ("jaw_rotation",), (0.3,)) - rest
    assert jaw[idx["furrow_bottom_l"], 1] < -0.05          # the lower cheek opens with the jaw
    assert jaw[idx["furrow_bottom_l"], 1] < jaw[idx["furrow_mid_l"], 1]
    model.reset()


def _result(contours, lost=()):
    quality = {name: SimpleNamespace(lost=name in lost) for name in contours}
    fiducials = {name: (float(i), float(i)) for i, name in enumerate(FIDUCIALS)}
    return SimpleNamespace(contours=contours, quality=quality, fiducials=fiducials)


def test_tracker_side_reads_curve_points_by_arc_length_and_loses_only_their_contour():
    furrow = np.c_[np.full(11, 100.0), np.linspace(50.0, 70.0, 11)]
    contours = {"furrow_l": furrow, "furrow_r": furrow + [40.0, 0.0],
                "lower_lip": np.c_[np.linspace(90.0, 130.0, 9), np.full(9, 95.0)],
                "brow_l": furrow, "brow_r": furrow, "upper_lip": furrow, "chin_boss": furrow}
    names = MEASUREMENT_POINTS
    out = _measure(_result(contours), names)
    got = dict(zip(names, out))
    np.testing.assert_allclose(got["furrow_mid_l"], [100.0, 60.0])
    np.testing.assert_allclose(got["furrow_bottom_l"], [100.0, 70.0])
    np.testing.assert_allclose(got["furrow_bottom_r"], [140.0, 70.0])
    np.testing.assert_allclose(got["lip_lower_centre"], [110.0, 95.0])
    lost = dict(zip(names, _measure(_result(contours, lost=("furrow_l",)), names)))
    for name in ("furrow_top_l", "furrow_mid_l", "furrow_bottom_l"):
        assert np.isnan(lost[name]).all()
    assert np.isfinite(lost["furrow_bottom_r"]).all() and np.isfinite(lost["chin"]).all()
    assert set(CURVE_POINTS) <= set(names)
