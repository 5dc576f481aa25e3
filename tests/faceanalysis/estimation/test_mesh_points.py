"""Face-mesh landmarks as measurement points: their place on the model, their motion with the
head's taken out, and the ``mesh`` estimator that reads them."""

import numpy as np
import pytest

from faceanalysis.estimation.calibration import Calibration
from faceanalysis.estimation.mesh_points import (
    DISPLACEMENT_CHUNK,
    RIGID_3D,
    mesh_displacements,
    similarity_3d,
    to_model_units,
)
from faceanalysis.io.table import MUSCLES


def _rotation(pitch, yaw, roll):
    cx, sx = np.cos(pitch), np.sin(pitch)
    cy, sy = np.cos(yaw), np.sin(yaw)
    cz, sz = np.cos(roll), np.sin(roll)
    rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    return rz @ ry @ rx


def _face(seed=0):
    rng = np.random.default_rng(seed)
    pts = rng.normal(0.0, 40.0, (468, 3)) + [320.0, 240.0, 0.0]
    return pts


def test_similarity_3d_recovers_a_turned_scaled_moved_head():
    p = _face()
    rot = _rotation(0.2, -0.3, 0.1)
    s, r, t = similarity_3d(p, 1.3 * p @ rot.T + [5.0, -7.0, 2.0])
    assert s == pytest.approx(1.3)
    np.testing.assert_allclose(r, rot, atol=1e-9)
    np.testing.assert_allclose(t, [5.0, -7.0, 2.0], atol=1e-6)


def test_similarity_3d_refuses_coincident_points():
    with pytest.raises(ValueError, match="coincide"):
        similarity_3d(np.ones((4, 3)), np.zeros((4, 3)))


def test_head_motion_alone_leaves_no_displacement():
    neutral = _face()
    moved = 0.9 * (neutral - neutral.mean(0)) @ _rotation(0.15, 0.25, -0.1).T + [300, 250, 10]
    d = mesh_displacements([neutral, moved, None], 0, [0, 61, 291, 400])
    np.testing.assert_allclose(d[:2], 0.0, atol=1e-9)
    assert np.isnan(d[2]).all()


def test_the_face_own_motion_is_measured_in_the_neutral_image():
    neutral = _face()
    frame = neutral.copy()
    frame[61, :2] += [3.0, -2.0]                          # a mouth corner moves; head still
    rot = _rotation(0.0, 0.3, 0.0)
    turned = (frame - neutral.mean(0)) @ rot.T + neutral.mean(0)
    for stretch in (False, True):
        d = mesh_displacements([neutral, frame, turned], 0, [61, 291], stretch=stretch)
        # (the robust alignment gives the moved point a small weight, not none: 0.01 px)
        np.testing.assert_allclose(d[1], [[3.0, -2.0], [0.0, 0.0]], atol=1e-2)
        # the same motion seen on a turned head is carried back into the neutral pose
        # (exactly by the 3-D similarity; the image stretch, fitted in each frame's own
        # image with the moved point weighed a little, differs by 1e-4 px)
        np.testing.assert_allclose(d[2], d[1], atol=1e-6 if not stretch else 1e-3)


def test_a_sideways_stretch_and_shear_of_the_whole_face_are_not_motion():
    # the landmark model's points of a turning head stretch sideways beyond the rigid
    # rotation; over the whole face that is no expression
    neutral = _face()
    c = neutral[:, :2].mean(axis=0)
    frame = neutral.copy()
    frame[:, :2] = c + (neutral[:, :2] - c) @ np.array([[1.04, 0.02], [-0.015, 1.0]]).T
    frame[61, :2] += [3.0, -2.0]
    truth = [[3.0, -2.0], [0.0, 0.0], [0.0, 0.0]]
    d = mesh_displacements([neutral, frame], 0, [61, 291, 400])
    # (fitted after the similarity, which took up part of the stretch by turning this
    # deep random face: 0.23 px are left of the stretch's 1.5-1.8 px)
    np.testing.assert_allclose(d[1], truth, atol=0.3)
    # the 3-D similarity alone reads the stretch as motion of the points
    plain = mesh_displacements([neutral, frame], 0, [61, 291, 400], stretch=False)
    assert np.abs(plain[1] - truth).max() > 1.0


def test_image_stretch_refuses_points_that_are_not_two_face_meshes():
    from faceanalysis.estimation.mesh_points import image_stretch

    with pytest.raises(ValueError, match="shape"):
        image_stretch(np.zeros((2, 468, 2)), np.zeros((2, 400, 2)))
    with pytest.raises(ValueError, match="shape"):
        image_stretch(np.zeros((468, 2)), np.zeros((468, 2)))


def test_rigid_points_do_not_include_what_an_expression_moves():
    assert not {61, 291, 0, 17, 13, 14} & set(RIGID_3D)


def test_a_long_video_is_measured_frame_by_frame_as_each_frame_alone():
    # more frames than one chunk, a lost frame at a chunk's edge: every frame's motion is
    # its own, however many frames come with it
    rng = np.random.default_rng(5)
    neutral = _face()
    frames = []
    for _ in range(DISPLACEMENT_CHUNK + 40):
        rot = _rotation(*rng.normal(0.0, 0.1, 3))
        frame = (neutral - neutral.mean(0)) @ rot.T + neutral.mean(0) + rng.normal(0, 2, 3)
        frames.append(frame + rng.normal(0.0, 0.5, frame.shape))
    frames[DISPLACEMENT_CHUNK - 1] = None
    frames[3] = neutral
    idx = [0, 61, 291, 400]
    d = mesh_displacements(frames, 3, idx)
    assert d.shape == (len(frames), 4, 2)
    assert np.isnan(d[DISPLACEMENT_CHUNK - 1]).all()
    for t in (0, DISPLACEMENT_CHUNK - 2, DISPLACEMENT_CHUNK, len(frames) - 1):
        np.testing.assert_array_equal(d[t], mesh_displacements([neutral, frames[t]], 0, idx)[1])
    np.testing.assert_allclose(d[3], 0.0, atol=1e-9)


def test_neutral_frame_without_landmarks_is_refused():
    with pytest.raises(ValueError, match="neutral frame"):
        mesh_displacements([None, _face()], 0, [1])


def test_pixels_become_model_centimetres_through_the_calibration():
    # 10 px per head unit, the head frame turned by 90 degrees; model cm -> head units x2
    cal = Calibration(matrix=np.diag([2.0, -2.0]), offset=np.zeros(2),
                      neutral=np.zeros((1, 2)), residual=0.0)
    head = np.array([100.0, 100.0, 10.0, np.pi / 2])
    d = to_model_units(np.array([[[0.0, 20.0]]]), np.array([[120.0, 90.0]]), head, cal)
    # 20 px down the image = +2 along the head's x axis = +1 cm along the model's x
    np.testing.assert_allclose(d, [[[1.0, 0.0]]], atol=1e-12)
    # one frame or many (more than a chunk): the same per frame
    many = np.tile(np.array([[[0.0, 20.0]]]), (DISPLACEMENT_CHUNK + 3, 1, 1))
    np.testing.assert_allclose(to_model_units(many, np.array([[120.0, 90.0]]), head, cal),
                               np.tile([[[1.0, 0.0]]], (len(many), 1, 1)), atol=1e-12)
    np.testing.assert_allclose(to_model_units(np.array([[0.0, 20.0]]),
                                              np.array([[120.0, 90.0]]), head, cal),
                               [[1.0, 0.0]], atol=1e-12)


def _models_or_skip():
    try:
        from trackers.landmarks import ensure_models

        ensure_models()
    except (RuntimeError, FileNotFoundError) as exc:
        pytest.skip(f"the MediaPipe face models cannot be obtained here: {exc}")


def test_usable_landmarks_lie_on_the_model_skin_off_the_mouth_line():
    _models_or_skip()
    from faceanalysis.estimation.mesh_points import (
        _EYELIDS,
        NAMED_POINTS,
        mesh_correspondence,
    )
    from synth import FaceModel
    from trackers.landmarks.mesh import FACE_OVAL

    corr = mesh_correspondence()
    mesh = FaceModel.default().mesh
    assert len(corr) > 250
    assert not set(corr) & (set(FACE_OVAL) | set(_EYELIDS))
    for i, name in NAMED_POINTS.items():
        assert corr[i][0][0] == mesh.landmarks[name]
    bary = np.array([b for _, b in corr.values()])
    np.testing.assert_allclose(bary.sum(axis=1), 1.0)
    assert (bary >= 0).all()
    # semantic places: the nose tip's landmark on the midline between the nasion and the
    # subnasale, the upper lip's centre above the mouth corners, the chin's below
    v = np.asarray(mesh.vertices)
    at = {i: b @ v[t] for i, (t, b) in corr.items()}
    lm = {n: v[mesh.landmarks[n]] for n in ("nasion", "subnasale", "mouth_corner_l")}
    assert abs(at[1][0]) < 0.2 and lm["subnasale"][1] < at[1][1] < lm["nasion"][1]
    assert at[0][1] > lm["mouth_corner_l"][1] > at[17][1]


@pytest.fixture(scope="module")
def jaw_and_smile(tmp_path_factory):
    """The generic face opening its jaw, then smiling, tracked by the landmark tracker."""
    _models_or_skip()
    import pandas as pd

    from faceanalysis.analysis.pipeline import analyze
    from synth import FaceModel
    from synth.render.sequence import render_sequence

    n = 8
    ramp = np.r_[np.zeros(2), np.linspace(0.0, 1.0, n)]
    script = pd.DataFrame({
        "jaw_rotation": np.r_[0.25 * ramp, np.zeros(n + 2)],
        "zygomaticus_major_l": np.r_[np.zeros(n + 2), ramp],
        "zygomaticus_major_r": np.r_[np.zeros(n + 2), ramp]})
    files = render_sequence(tmp_path_factory.mktemp("mesh"), model=FaceModel.default(),
                            contractions=script, size=256, seed=3, flow=False)
    truth = pd.read_csv(files["truth"])
    return truth, analyze(files["video"], tracker="landmarks", estimator="mesh")


def test_mesh_estimator_reads_the_jaw_and_the_smile(jaw_and_smile):
    # On rendered faces the landmark model reports a fraction of the skin's motion (an
    # open jaw reads about half, docs/accuracy.md): the test asks for the directions.
    _, a = jaw_and_smile
    t = a.table
    jaw_apex, smile_apex = 9, len(t) - 1
    jaw = t["jaw_rotation"].to_numpy()
    assert jaw[jaw_apex] > 0.08 and np.all(np.diff(jaw[2:jaw_apex]) > -0.02)
    assert jaw[jaw_apex] > jaw[jaw_apex + 2:].max() + 0.05     # the jaw closed again
    # (a full smile of the generic face reads about 0.04: the landmark model moves its
    # points far less than the rendered skin moves)
    zyg = (t["zygomaticus_major_l"] + t["zygomaticus_major_r"]).to_numpy() / 2
    assert zyg[smile_apex] > max(0.02, 2 * zyg[:2].max())
    # rest reads rest (the estimator issue's 0.1) on the frames before any motion
    assert t.loc[:1, list(MUSCLES)].max().max() <= 0.1 and t.loc[:1, "jaw_rotation"].max() < 0.02


def test_mesh_estimator_reports_what_it_read(jaw_and_smile):
    _, a = jaw_and_smile
    params = a.metadata["parameters"]
    assert params["estimator"] == "mesh"
    points = params["measurement_points"]
    assert "mouth_corner_l" in points and "mesh_61" in points and len(points) > 250
    ident = a.metadata["identifiability"]
    assert set(ident["points_seen"]) <= set(points)
    assert a.metadata["model_fit"]["median_cm"] < 0.2


def _assert_reads_the_jaw_then_the_smile(t):
    """The jaw opens and closes again, then the smile rises; rest reads rest before both."""
    jaw = t["jaw_rotation"].to_numpy()
    assert jaw[9] > 0.08 and jaw[9] > jaw[11:].max() + 0.05
    zyg = (t["zygomaticus_major_l"] + t["zygomaticus_major_r"]).to_numpy() / 2
    assert zyg[-1] > max(0.02, 2 * zyg[:2].max())
    assert t.loc[:1, list(MUSCLES)].max().max() <= 0.1


def test_model_estimator_fits_the_same_points_through_the_model(jaw_and_smile):
    from faceanalysis.analysis.pipeline import reestimate

    _, a = jaw_and_smile
    b = reestimate(a, "model")
    assert b.metadata["parameters"]["estimator"] == "model"
    assert (b.metadata["parameters"]["measurement_points"]
            == a.metadata["parameters"]["measurement_points"])
    _assert_reads_the_jaw_then_the_smile(b.table)
    # the residual it reports is the model's own, not the table's
    fit = b.metadata["model_fit"]
    assert 0 < fit["median_cm"] <= a.metadata["model_fit"]["median_cm"] + 0.02
    assert not np.allclose(b.fit_residual, a.fit_residual)


def test_model_estimator_through_the_personalised_face(jaw_and_smile):
    from faceanalysis.analysis.pipeline import reestimate
    from faceanalysis.estimation.registry import Observations, mesh_neutral, mesh_response

    _, a = jaw_and_smile
    # the neutral frame's points through the calibration lie where the generic face,
    # which was rendered, has them, give or take how the landmark model places them
    response = mesh_response()
    k = int(np.flatnonzero(a.tracks.frames == a.metadata["parameters"]["neutral_frame"])[0])
    obs = Observations(tracks=a.tracks, response=a.response, displacements=None, neutral=k,
                       options={}, calibration=a.calibration)
    neutral = mesh_neutral(obs, response)
    assert np.isfinite(neutral).all(axis=1).sum() > 250
    dist = np.linalg.norm(neutral - response.rest, axis=1)
    assert np.nanmedian(dist) < 0.3
    b = reestimate(a, "model", personalize=True)
    assert b.metadata["parameters"]["personalize"] is True
    _assert_reads_the_jaw_then_the_smile(b.table)
    generic = reestimate(a, "model")
    assert generic.metadata["parameters"]["personalize"] is False
    assert not np.allclose(b.fit_residual, generic.fit_residual, equal_nan=True)
    with pytest.raises(ValueError, match="personalize works with the model estimator"):
        reestimate(a, "mesh", personalize=True)


def test_mesh_estimator_needs_the_landmark_tracker(jaw_and_smile):
    from faceanalysis.analysis.pipeline import reestimate
    from faceanalysis.tracking import Tracks

    _, a = jaw_and_smile
    base = reestimate(a, "joint")
    no_mesh = type(base)(**{**base.__dict__,
                            "tracks": Tracks(**{**a.tracks.__dict__, "landmarks": None})})
    with pytest.raises(ValueError, match="tracker='landmarks'"):
        reestimate(no_mesh, "mesh")


def test_mesh_estimator_with_the_snakes_tracker_is_refused_before_any_work(tmp_path):
    from faceanalysis.analysis.pipeline import analyze

    with pytest.raises(ValueError, match="mesh estimator reads the landmark tracker"):
        analyze(tmp_path / "not_read.mp4", estimator="mesh", tracker="snakes")


def test_a_region_the_tracker_lost_takes_its_face_mesh_points_with_it(jaw_and_smile):
    from faceanalysis.estimation.registry import (
        Observations,
        mesh_observations,
        mesh_regions,
        mesh_response,
        regions_lost,
    )
    from faceanalysis.tracking import POINT_CONTOUR, Tracks

    _, a = jaw_and_smile
    points = a.tracks.points.copy()
    brow_l = [j for j, p in enumerate(a.tracks.point_names) if POINT_CONTOUR[p] == "brow_l"]
    points[5, brow_l] = np.nan                              # the left brow lost on frame 5
    tracks = Tracks(**{**a.tracks.__dict__, "points": points})
    lost = regions_lost(tracks)
    assert lost["brow_l"].tolist() == [t == 5 for t in range(len(tracks))]
    assert not lost["brow_r"].any() and not lost["lower_face"].any()

    response = mesh_response()
    region = mesh_regions(response)
    assert {"brow_l", "brow_r", "lower_face"} == set(region)
    obs = Observations(tracks, a.response, np.zeros((len(tracks), len(a.response.fiducials), 2)),
                       0, calibration=a.calibration)
    d = mesh_observations(obs, response)
    n_contour = len(response.fiducials) - len(region)
    mesh_d = d[:, n_contour:]
    in_brow = np.array([r == "brow_l" for r in region])
    assert np.isnan(mesh_d[5, in_brow]).all() and np.isfinite(mesh_d[5, ~in_brow]).all()
    assert np.isfinite(mesh_d[4]).all()


def test_fused_estimator_reads_the_smile_the_mesh_misses(jaw_and_smile):
    # the dense flow in the same fit follows the rendered skin the landmark model does not
    from faceanalysis.analysis.pipeline import reestimate

    truth, a = jaw_and_smile
    mesh, fused = (reestimate(a, e).table for e in ("mesh", "fused"))
    smile_apex, jaw_apex = len(truth) - 1, 9

    def zyg(t):
        return (t["zygomaticus_major_l"] + t["zygomaticus_major_r"]).to_numpy() / 2

    # the full smile: fused reads over half of it, the mesh alone under a quarter
    assert zyg(fused)[smile_apex] > 0.5 > 2 * zyg(mesh)[smile_apex]
    assert fused["jaw_rotation"][jaw_apex] > mesh["jaw_rotation"][jaw_apex]
    assert fused.loc[:1, list(MUSCLES)].max().max() <= 0.1
    params = reestimate(a, "fused").metadata["parameters"]
    assert params["estimator"] == "fused" and "mesh_61" in params["measurement_points"]
