"""How much of the skin's motion the tracked points report."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from faceanalysis.estimation.model_response import model_response
from faceanalysis.evaluation.motion_gain import exact_displacements, motion_gain


def _motion(t=5, p=4, seed=0):
    e = np.random.default_rng(seed).normal(size=(t, p, 2))
    e[0] = 0.0
    return e


def test_a_point_that_follows_the_skin_has_gain_one_and_one_that_stands_still_zero():
    e = _motion()
    m = e.copy()
    m[:, 1] = 0.0
    m[:, 2] *= 0.3
    gain, motion = motion_gain(m, e)
    np.testing.assert_allclose(gain, [1.0, 0.0, 0.3, 1.0])
    np.testing.assert_allclose(motion, np.sqrt((e ** 2).sum(axis=(0, 2))))


def test_a_gain_is_the_least_squares_share_not_the_ratio_of_lengths():
    # a point that moves as far as its skin, but across it, reports none of its motion
    e = np.zeros((2, 1, 2))
    e[1, 0] = [1.0, 0.0]
    m = np.zeros_like(e)
    m[1, 0] = [0.0, 1.0]
    gain, _ = motion_gain(m, e)
    assert gain[0] == pytest.approx(0.0)


def test_frames_a_point_was_not_measured_on_do_not_count():
    e = _motion()
    m = 0.5 * e
    m[2:, 0] = np.nan          # lost on the later frames: scored on the first two only
    m[:, 3] = np.nan           # never measured
    gain, motion = motion_gain(m, e)
    np.testing.assert_allclose(gain[:3], 0.5)
    assert np.isnan(gain[3]) and motion[3] == 0.0
    assert motion[0] == pytest.approx(np.sqrt((e[:2, 0] ** 2).sum()))


def test_a_point_that_did_not_move_has_no_gain():
    e = _motion()
    e[:, 2] = 0.0
    gain, _ = motion_gain(e + 0.01, e)
    assert np.isnan(gain[2]) and np.isfinite(gain[[0, 1, 3]]).all()


def test_bad_arguments_are_refused():
    e = _motion()
    with pytest.raises(ValueError, match="same shape"):
        motion_gain(e[:, :3], e)
    with pytest.raises(ValueError, match=r"\(T, P, 2\)"):
        motion_gain(e[..., 0], e[..., 0])
    bad = e.copy()
    bad[1, 1, 0] = np.nan
    with pytest.raises(ValueError, match="finite"):
        motion_gain(e, bad)
    with pytest.raises(ValueError, match="min_motion"):
        motion_gain(e, e, min_motion=-1.0)


def test_exact_displacements_start_at_zero_and_follow_the_smile():
    from synth import FaceModel

    response = model_response()
    names = list(response.fiducials)
    table = pd.DataFrame({"zygomaticus_major_l": [0.0, 1.0], "zygomaticus_major_r": [0.0, 1.0]})
    d = exact_displacements(FaceModel.default(), table, response)
    assert d.shape == (2, len(names), 2)
    np.testing.assert_allclose(d[0], 0.0, atol=1e-9)
    # the subject's left corner goes to the subject's left (x > 0) and up, the right one
    # mirrored, as the response table says they do
    left, right = d[1, names.index("mouth_corner_l")], d[1, names.index("mouth_corner_r")]
    assert left[0] > 0.1 and right[0] < -0.1 and left[1] > 0.1 and right[1] > 0.1
    one = np.zeros((1, len(response.muscles)))
    for side in "lr":
        one[0, response.index(f"zygomaticus_major_{side}")] = 1.0
    table_says = response.predict(one)[0]
    for name in ("mouth_corner_l", "mouth_corner_r"):
        j = names.index(name)
        np.testing.assert_allclose(d[1, j], table_says[j], atol=0.05)
    with pytest.raises(ValueError, match="calibrate_on"):
        exact_displacements(FaceModel.default(), table, response, calibrate_on=2)


def test_pooled_gains_weigh_each_sequence_by_its_motion():
    from faceanalysis.evaluation.motion_gain import pool_gains

    gain, motion = pool_gains([[0.5, np.nan], [1.0, 0.8]], [[1.0, 0.0], [2.0, 1.0]])
    np.testing.assert_allclose(gain, [(0.5 * 1 + 1.0 * 4) / 5, 0.8])
    np.testing.assert_allclose(motion, [np.sqrt(5.0), 1.0])


def test_a_rendered_smile_measures_the_points_the_analysis_read(tmp_path):
    from faceanalysis.evaluation.motion_gain import sequence_gain
    from synth import FaceModel
    from synth.face_shape import FaceShape
    from synth.render.sequence import render_sequence

    # the face render_sequence draws for a seed
    render_sequence(tmp_path, expression="happiness", frames=8, size=256, seed=3, flow=False)
    gain, motion, analysis = sequence_gain(tmp_path, FaceModel.build(FaceShape.random(3)))
    names = list(analysis.estimate.response.fiducials)
    assert gain.shape == motion.shape == (len(names),)
    corners = [names.index(f"mouth_corner_{s}") for s in "lr"]
    # the smile moves the corners a few millimetres, and the tracked corners follow it
    assert (motion[corners] > 0.2).all()
    assert ((gain[corners] > 0.3) & (gain[corners] < 1.5)).all()
    # any analysis: the free snakes read the 16 contour points
    gain, _, analysis = sequence_gain(tmp_path, FaceModel.build(FaceShape.random(3)),
                                      tracker="snakes")
    assert analysis.metadata["parameters"]["tracker"] == "snakes" and gain.shape == (16,)
