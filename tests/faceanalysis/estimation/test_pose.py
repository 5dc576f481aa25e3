"""Head pose correction (faceanalysis.estimation.pose)."""

import numpy as np
import pytest

from faceanalysis.estimation.pose import (
    correct_pose,
    head_frame_points,
    pose_displacements,
    rest_points_3d,
    rotation_matrix,
)

# a face-like set: brows behind, the lips in front, the chin between (cm, z to the viewer)
REST = np.array([[1.6, 1.8, 1.0], [5.2, 1.8, -1.6], [-5.2, 1.8, -1.6], [2.6, -7.5, 0.4],
                 [-2.6, -7.5, 0.4], [0.0, -8.6, 1.3], [0.0, -10.4, 0.9]])
# eye corners and nose ridge
REF = np.array([[4.2, 0.1, -0.5], [1.8, -0.1, -0.2], [-1.8, -0.1, -0.2], [-4.2, 0.1, -0.5],
                [0.0, 0.6, 0.9], [0.0, -1.5, 1.8], [0.0, -3.5, 2.6]])


def _head_frame_view(points, ref, R, centre, shift):
    """What the tracker's head frame sees: every point rotated by ``R`` about ``centre``
    and moved by ``shift``, then taken back through the 2-D similarity (fitted by plain
    least squares) that carries the reference's rest x-y onto its moved x-y."""
    def move(p):
        return ((p - centre) @ R.T + centre + shift)[:, :2]

    r0, r1 = ref[:, :2], move(ref)
    # similarity x -> s Q x + t as the linear least squares in (a, b, tx, ty)
    A = np.zeros((2 * len(r0), 4))
    A[0::2] = np.c_[r0[:, 0], -r0[:, 1], np.ones(len(r0)), np.zeros(len(r0))]
    A[1::2] = np.c_[r0[:, 1], r0[:, 0], np.zeros(len(r0)), np.ones(len(r0))]
    a, b, tx, ty = np.linalg.lstsq(A, r1.reshape(-1), rcond=None)[0]
    M = np.array([[a, -b], [b, a]])
    return (move(points) - [tx, ty]) @ np.linalg.inv(M).T


@pytest.mark.parametrize("pitch, yaw", [(4.0, 0.0), (0.0, -6.0), (5.0, 8.0), (-12.0, 3.0)])
def test_a_pure_rotation_of_the_rest_points_is_corrected_away(pitch, yaw):
    R = rotation_matrix(np.array(pitch), np.array(yaw))
    # about the renderer's head centre, with a translation: both immaterial in the head frame
    seen = _head_frame_view(REST, REF, R, np.array([0.0, -2.0, -8.0]), np.array([0.3, -0.2, 1.0]))
    disp = np.stack([np.zeros((len(REST), 2)), seen - REST[:, :2]])
    assert np.abs(disp[1]).max() > 0.05                 # the rotation does move them
    pose = np.array([[1.0, -2.0], [1.0 + pitch, -2.0 + yaw]])      # relative to row 0
    out = correct_pose(disp, pose, 0, REST, reference=REF)
    np.testing.assert_allclose(out, 0.0, atol=1e-9)


def test_without_a_reference_the_rotation_is_about_the_centroid():
    R = rotation_matrix(np.array(7.0), np.array(-4.0))
    c = REST.mean(axis=0) + [0.0, 0.0, -3.0]
    moved = ((REST - c) @ R.T + c)[:, :2] - REST[:, :2]
    got = pose_displacements(REST, np.array([[7.0, -4.0]]), centre_depth=-3.0)
    np.testing.assert_allclose(got[0], moved, atol=1e-12)


def test_signs_follow_the_tracker():
    front, back = [0.0, 0.0, 1.0], [0.0, 0.0, -1.0]
    d = pose_displacements(np.array([front, back]), np.array([[10.0, 0.0], [0.0, 10.0]]))
    # positive pitch: the face turns down, its front goes down (model y is up)
    assert d[0, 0, 1] < 0 < d[0, 1, 1]
    # positive yaw: toward the image's right (model +x)
    assert d[1, 0, 0] > 0 > d[1, 1, 0]


def test_no_pose_change_is_the_identity():
    rng = np.random.default_rng(0)
    disp = rng.normal(scale=0.2, size=(5, len(REST), 2))
    pose = np.tile([3.0, -2.0], (5, 1))
    out = correct_pose(disp, pose, 2, REST, reference=REF)
    assert out is not disp
    np.testing.assert_array_equal(out, disp)


def test_frames_without_a_pose_are_left_as_they_are():
    rng = np.random.default_rng(1)
    disp = rng.normal(scale=0.2, size=(4, len(REST), 2))
    disp[3, 2] = np.nan
    pose = np.array([[0.0, 0.0], [np.nan, np.nan], [2.0, np.nan], [5.0, 5.0]])
    out = correct_pose(disp, pose, 0, REST, reference=REF)
    np.testing.assert_array_equal(out[:3], disp[:3])
    assert not np.allclose(out[3, :2], disp[3, :2])
    assert np.isnan(out[3, 2]).all()                     # a missing point stays missing
    # the snakes tracker: no pose anywhere (or none on the neutral frame)
    np.testing.assert_array_equal(correct_pose(disp, np.full((4, 2), np.nan), 0, REST), disp)
    pose[0] = np.nan
    np.testing.assert_array_equal(correct_pose(disp, pose, 0, REST), disp)


def test_bad_input_is_refused():
    disp = np.zeros((3, len(REST), 2))
    pose = np.zeros((3, 2))
    with pytest.raises(ValueError, match="pose must have shape"):
        correct_pose(disp, np.zeros((2, 2)), 0, REST)
    with pytest.raises(ValueError, match="rest must have shape"):
        correct_pose(disp, pose, 0, REST[:, :2])
    with pytest.raises(ValueError, match="neutral row"):
        correct_pose(disp, pose, 3, REST)
    with pytest.raises(ValueError, match="displacements"):
        correct_pose(disp[0], pose, 0, REST)
    with pytest.raises(ValueError, match="reference"):
        pose_displacements(REST, pose, reference=REF[:1])
    with pytest.raises(ValueError, match="centre_depth"):
        pose_displacements(REST, pose, centre_depth=np.nan)
    with pytest.raises(ValueError, match="no finite point"):
        pose_displacements(np.full((2, 3), np.nan), pose)


def test_model_points_in_3d():
    from faceanalysis.estimation.model_response import MEASUREMENT_POINTS, model_points
    from synth.mesh import generate_face_mesh
    from synth.model import DEFAULT_RESOLUTION

    rest = rest_points_3d(MEASUREMENT_POINTS)
    mesh = generate_face_mesh(resolution=DEFAULT_RESOLUTION)

    class _Model:                                        # model_points reads only .mesh
        pass

    m = _Model()
    m.mesh = mesh
    # the same x-y as the response's rest points; depths in front of the jaw angles
    np.testing.assert_allclose(rest[:, :2], model_points(m, mesh.vertices), atol=1e-9)
    assert np.all(rest[:, 2] > mesh.vertices[mesh.landmarks["jaw_angle_l"], 2])
    ref = head_frame_points()
    assert ref.shape == (9, 3) and np.isfinite(ref).all()
    with pytest.raises(ValueError, match="no measurement point"):
        rest_points_3d(("ear_lobe",))


def test_pipeline_applies_it_only_with_a_pose():
    from faceanalysis.analysis.pipeline import _correct_pose
    from faceanalysis.estimation.model_response import model_response

    response = model_response()
    disp = np.zeros((3, len(response.fiducials), 2))
    out, applied = _correct_pose(disp, np.full((3, 2), np.nan), 0, response, True)
    assert out is disp and not applied
    out, applied = _correct_pose(disp, np.array([[0, 0], [0, 0], [3.0, 4.0]]), 0, response,
                                 False)
    assert out is disp and not applied
    out, applied = _correct_pose(disp, np.array([[0, 0], [0, 0], [3.0, 4.0]]), 0, response,
                                 True)
    assert applied and np.all(out[:2] == 0) and np.abs(out[2]).max() > 0.05
