"""Contractions fitted through the face model's own equilibrium (the ``model`` estimator)."""

import numpy as np
import pytest

from faceanalysis.estimation.estimators import estimate_joint
from faceanalysis.estimation.model_fit import fit_through_model, personal_model, point_jacobian
from faceanalysis.estimation.model_response import model_points, model_response

TRUTH = (("zygomaticus_major_l", 0.8), ("risorius_l", 0.5), ("frontalis_major_r", 0.6),
         ("jaw_rotation", 0.12))


@pytest.fixture(scope="module")
def setup():
    from synth.model import FaceModel

    model = FaceModel.default()
    response = model_response(model)
    truth = np.zeros(len(response.muscles))
    for name, value in TRUTH:
        truth[response.muscles.index(name)] = value
    return model, response, truth, _points(model, response, truth)[None]


def _points(model, response, c):
    """The model's points at ``c`` from rest, equilibrated tightly (the solver's default
    tolerance leaves a few hundredths of a millimetre that depend on where it started)."""
    model.reset()
    rest = model_points(model, model.equilibrate(tol=1e-7, max_iter=50000),
                        response.fiducials)
    values = dict(zip(response.muscles, np.nan_to_num(c)))
    jaw = values.pop("jaw_rotation")
    model.set_contractions(values, jaw_rotation=jaw)
    moved = model_points(model, model.equilibrate(tol=1e-7, max_iter=50000),
                         response.fiducials)
    model.reset()
    return moved - rest


def _model_residual(model, response, c, d):
    pred = _points(model, response, c)
    return float(np.sqrt(np.mean(np.sum((pred - d) ** 2, axis=1))))


def test_the_fit_explains_the_model_points_the_table_does_not(setup):
    model, response, truth, d = setup
    initial = estimate_joint(d, response, sparsity=0.0)
    fitted, residual = fit_through_model(d, response, model, initial, sparsity=0.0,
                                         robust=None, iterations=6, return_residual=True)
    assert fitted.shape == initial.shape
    assert (fitted >= 0).all() and (fitted <= response.upper + 1e-12).all()
    before = _model_residual(model, response, initial[0], d[0])
    after = _model_residual(model, response, fitted[0], d[0])
    # the table's pairwise terms leave a third of a millimetre; the model's own Jacobian
    # takes the fit to the points
    assert after < 0.1 * before and after < 0.003
    assert residual[0] == pytest.approx(after, abs=1e-3)
    # the 16 points do not tell every muscle apart (a risorius reads in part as its
    # neighbours), but the large ones come back
    for name in ("zygomaticus_major_l", "frontalis_major_r", "jaw_rotation"):
        j = response.muscles.index(name)
        assert abs(fitted[0, j] - truth[j]) < 0.03 * response.upper[j]


def test_rest_reads_rest(setup):
    model, response, _, d = setup
    still = np.zeros_like(d)
    fitted, residual = fit_through_model(still, response, model,
                                         np.zeros((1, len(response.muscles))),
                                         return_residual=True)
    assert np.abs(fitted).max() < 1e-3 and residual[0] < 1e-3


def test_lost_frames_and_unobserved_controls_pass_through(setup):
    model, response, _, d = setup
    frames = np.concatenate([d, np.full_like(d, np.nan), d])
    initial = np.vstack([estimate_joint(d, response)] * 3)
    initial[1] = np.nan
    held = response.muscles.index("corrugator_l")
    initial[2, held] = np.nan
    fitted = fit_through_model(frames, response, model, initial, iterations=1)
    assert np.isnan(fitted[1]).all() and np.isfinite(fitted[0]).all()
    assert np.isnan(fitted[2, held]) and np.isfinite(np.delete(fitted[2], held)).all()


def test_the_point_jacobian_follows_the_skin(setup):
    model, response, _, _ = setup
    skin = model.surface_vertices
    rng = np.random.default_rng(1)
    motion = rng.normal(size=(2, *skin.shape)) * 0.01
    from faceanalysis.estimation.model_response import model_points

    jac = point_jacobian(model, skin, response.fiducials, motion)
    base = model_points(model, skin, response.fiducials)
    for i in range(2):
        h = 1e-4
        moved = model_points(model, skin + h * motion[i], response.fiducials)
        np.testing.assert_allclose(jac[i], (moved - base) / h, atol=1e-3)


def test_bad_arguments_are_refused(setup):
    model, response, _, d = setup
    initial = np.zeros((1, len(response.muscles)))
    with pytest.raises(ValueError, match="initial must have shape"):
        fit_through_model(d, response, model, np.zeros((2, 3)))
    with pytest.raises(ValueError, match="displacements must have shape"):
        fit_through_model(d[:, :3], response, model, initial)
    with pytest.raises(ValueError, match="iterations"):
        fit_through_model(d, response, model, initial, iterations=0)
    with pytest.raises(ValueError, match="robust"):
        fit_through_model(d, response, model, initial, robust=-1.0)
    with pytest.raises(ValueError, match="knee"):
        fit_through_model(d, response, model, initial, knee=0.0)
    with pytest.raises(ValueError, match="weights"):
        fit_through_model(d, response, model, initial, weights=np.ones(3))


@pytest.fixture(scope="module")
def other_face():
    """The generic face's mesh response, and another face's neutral points in its model cm
    (calibrated on the contour points, as an analysis's neutral frame is)."""
    import pandas as pd

    from faceanalysis.estimation.model_response import MEASUREMENT_POINTS
    from faceanalysis.estimation.registry import mesh_response
    from faceanalysis.evaluation.ceiling import _neutral, perfect_measurements
    from synth.face_shape import FaceShape
    from synth.model import FaceModel

    response = mesh_response()
    other = FaceModel.build(FaceShape.random(1001))
    exact = perfect_measurements(other, pd.DataFrame({"jaw_rotation": [0.0]}),
                                 response.fiducials)
    return response, _neutral(exact, response, len(MEASUREMENT_POINTS))


def _rest_points(model, response):
    model.reset()
    return model_points(model, model.equilibrate(tol=1e-6), response.fiducials)


def test_the_personal_model_takes_the_subjects_neutral_shape(setup, other_face):
    model, *_ = setup
    response, neutral = other_face
    personal, blend = personal_model(neutral, response, model)
    assert blend == 1.0
    generic = np.linalg.norm(_rest_points(model, response) - neutral, axis=1)
    own = np.linalg.norm(_rest_points(personal, response) - neutral, axis=1)
    # the generic face lies about 2 mm from this face's points; its personalised copy at
    # rest within a few hundredths of a millimetre of them (the warp carries every fourth
    # face-mesh point; the rest follow the skin between them)
    assert np.median(generic) > 0.1
    assert np.median(own) < 0.02 and np.percentile(own, 90) < 0.06
    assert personal.muscle_names == model.muscle_names
    # the generic model is left as it was
    assert np.median(np.linalg.norm(_rest_points(model, response) - neutral, axis=1)) \
        == pytest.approx(np.median(generic))


def test_a_warp_that_would_fold_the_face_is_blended_toward_its_affine_part(setup, other_face):
    model, *_ = setup
    response, neutral = other_face
    bad = neutral.copy()
    mesh = [j for j, n in enumerate(response.fiducials) if n.startswith("mesh_")]
    bad[mesh[40]] += [4.0, 0.0]             # one point 4 cm across the cheek
    personal, blend = personal_model(bad, response, model)
    assert 0.0 <= blend < 1.0
    assert np.isfinite(personal.surface_vertices).all()


def test_personal_model_refuses_bad_arguments(setup, other_face):
    model, *_ = setup
    response, neutral = other_face
    with pytest.raises(ValueError, match="neutral must have shape"):
        personal_model(neutral[:5], response, model)
    with pytest.raises(ValueError, match="every"):
        personal_model(neutral, response, model, every=0)
    with pytest.raises(ValueError, match="at least 10 seen points"):
        personal_model(np.full_like(neutral, np.nan), response, model)
