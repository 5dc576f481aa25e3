"""Refinement through the face model itself (``analyze(..., refine=True)``)."""

import numpy as np
import pytest

from faceanalysis.estimation.estimators import estimate_joint
from faceanalysis.estimation.model_response import equilibrium_points, model_response
from faceanalysis.estimation.refine import refine_through_model


@pytest.fixture(scope="module")
def setup():
    from synth.model import FaceModel

    model = FaceModel.default()
    response = model_response(model)
    truth = np.zeros(len(response.muscles))
    for name, value in (("zygomaticus_major_l", 0.8), ("risorius_l", 0.5),
                        ("jaw_rotation", 0.12)):
        truth[response.muscles.index(name)] = value
    model.reset()
    rest = equilibrium_points(model, response.muscles, np.zeros_like(truth),
                              response.fiducials)
    moved = equilibrium_points(model, response.muscles, truth, response.fiducials)
    model.reset()
    return model, response, truth, (moved - rest)[None]


def _model_residual(model, response, c, d):
    model.reset()
    rest = equilibrium_points(model, response.muscles, np.zeros_like(c), response.fiducials)
    pred = equilibrium_points(model, response.muscles, c, response.fiducials) - rest
    model.reset()
    return float(np.sqrt(np.mean((pred - d) ** 2)))


def test_refinement_fits_the_model_better_than_the_table(setup):
    model, response, truth, d = setup
    initial = estimate_joint(d, response)
    refined = refine_through_model(d, response, model, initial)
    assert refined.shape == initial.shape
    assert (refined >= 0).all() and (refined <= response.upper + 1e-12).all()
    before = _model_residual(model, response, initial[0], d[0])
    after = _model_residual(model, response, refined[0], d[0])
    assert after < before


def test_lost_frames_pass_through(setup):
    model, response, _, d = setup
    frames = np.concatenate([d, np.full_like(d, np.nan)])
    initial = np.vstack([estimate_joint(d, response), np.full(len(response.muscles), np.nan)])
    refined = refine_through_model(frames, response, model, initial, iterations=1)
    assert np.isnan(refined[1]).all() and np.isfinite(refined[0]).all()


def test_bad_arguments_are_refused(setup):
    model, response, _, d = setup
    with pytest.raises(ValueError, match="initial must have shape"):
        refine_through_model(d, response, model, np.zeros((2, 3)))
    with pytest.raises(ValueError, match="iterations"):
        refine_through_model(d, response, model, estimate_joint(d, response), iterations=0)
