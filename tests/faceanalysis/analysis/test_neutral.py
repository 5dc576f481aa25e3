"""The checks of the neutral frame and the frame they offer (faceanalysis.analysis.neutral)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from faceanalysis.analysis.neutral import check_neutral
from faceanalysis.estimation.neutral_check import BROWS, MOUTH_OPEN
from faceanalysis.estimation.registry import mesh_response


@pytest.fixture(scope="module")
def response():
    return mesh_response()


def _clip(response, controls, neutral_row, mouth, rng, *, kind="video"):
    """An estimate and tracks for frames ``controls`` (T, M) seen against row
    ``neutral_row``, with mouth measures ``mouth`` (T, 2)."""
    pred = response.predict(controls)
    d = pred - pred[neutral_row] + rng.normal(0, 0.01, pred.shape)
    est = SimpleNamespace(displacements=d, response=response, fit_options={})
    t = len(controls)
    tracks = SimpleNamespace(frames=np.arange(t) + 100, success=np.ones(t, bool),
                             input={"kind": kind, "fps": 25.0})
    return est, tracks, np.asarray(mouth, float)


def _raised(response, share=0.7):
    v = np.zeros(len(response.muscles))
    for name in BROWS:
        v[response.muscles.index(name)] = share * response.upper[response.muscles.index(name)]
    return v


def test_an_open_mouth_is_offered_the_nearest_frame_at_rest(response, caplog):
    rng = np.random.default_rng(0)
    controls = np.zeros((80, len(response.muscles)))
    mouth = np.c_[np.full(80, 0.01), np.full(80, 0.8)] + rng.normal(0, 0.003, (80, 2))
    mouth[:12, 0] = 0.25                               # talking: the mouth open
    mouth[30:34, 0] = 0.2
    est, tracks, mouth = _clip(response, controls, 0, mouth, rng)
    check = check_neutral(est, tracks, 0, mouth=mouth)
    assert check.reasons == ["mouth open"] and check.lips_apart > MOUTH_OPEN
    assert check.advice is not None and check.advice[0] == 112     # frames count from 100
    assert check.calibration()["offered_neutral"] == 112
    with caplog.at_level("WARNING"):
        check.warn("clip.mp4", tracks, how="default")
    said = [r.getMessage() for r in caplog.records]
    assert len(said) == 1 and "mouth is open on the default neutral frame 100" in said[0]
    assert said[0].endswith("(--neutral 112)")


def test_every_warning_offers_the_same_frame(response, caplog):
    rng = np.random.default_rng(1)
    controls = np.zeros((80, len(response.muscles)))
    controls[:10] = _raised(response)                  # brows up, mouth open, then rest
    mouth = np.c_[np.full(80, 0.01), np.full(80, 0.8)] + rng.normal(0, 0.003, (80, 2))
    mouth[:25, 0] = 0.2
    est, tracks, mouth = _clip(response, controls, 0, mouth, rng)
    check = check_neutral(est, tracks, 0, mouth=mouth, blocky=(1.6, 103), coarse=True)
    assert check.reasons == ["coarsely coded", "brows raised", "mouth open"]
    with caplog.at_level("WARNING"):
        check.warn("clip.mp4", tracks, how="default")
    offers = {r.getMessage().rsplit("--neutral ", 1)[1] for r in caplog.records}
    assert len(caplog.records) == 3 and offers == {"125)"}


def test_a_clip_without_rest_is_not_offered_a_wider_mouth(response):
    # crying: the brows raised on the neutral frame, its mouth closed and narrow; then the
    # brows come down in a grimace that widens the mouth, and a laugh widens it more: the
    # clip's levels are its expressions'
    rng = np.random.default_rng(2)
    controls = np.zeros((80, len(response.muscles)))
    controls[:5] = _raised(response)
    mouth = np.c_[np.full(80, 0.01), np.full(80, 0.97)] + rng.normal(0, 0.002, (80, 2))
    mouth[:5, 1] = 0.85
    mouth[5:20, 1] = 0.90                              # the grimace: "narrow" for this clip
    est, tracks, mouth = _clip(response, controls, 0, mouth, rng)
    check = check_neutral(est, tracks, 0, mouth=mouth)
    assert check.reasons == ["brows raised"]
    assert check.advice is None
    assert check.calibration()["offered_neutral"] is None
    # with a grimace no wider than the neutral frame's mouth, it is offered
    mouth[5:20, 1] = 0.86
    assert check_neutral(est, tracks, 0, mouth=mouth).advice[0] == 105


def test_photographs_are_not_checked(response):
    rng = np.random.default_rng(3)
    controls = np.zeros((40, len(response.muscles)))
    controls[1:] = _raised(response)
    est, tracks, _ = _clip(response, controls, 0, np.zeros((40, 2)), rng, kind="images")
    tracks.input["fps_origin"] = "default"
    check = check_neutral(est, tracks, 0, mouth=None)
    assert check.reasons == [] and check.advice is None and check.shares == {}


def test_a_smile_on_the_neutral_frame_is_told_and_rest_offered(response, caplog):
    # closed lips, the corners drawn apart: a smile at the start, then rest
    rng = np.random.default_rng(4)
    controls = np.zeros((80, len(response.muscles)))
    mouth = np.c_[np.full(80, 0.01), np.full(80, 0.8)] + rng.normal(0, 0.003, (80, 2))
    mouth[:15, 1] = 1.0
    est, tracks, mouth = _clip(response, controls, 0, mouth, rng)
    check = check_neutral(est, tracks, 0, mouth=mouth)
    assert check.reasons == ["mouth widened"]
    assert check.calibration()["neutral_mouth_wider"] > 0.15
    assert check.advice is not None and check.advice[0] == 115
    with caplog.at_level("WARNING"):
        check.warn("clip.mp4", tracks, how="default")
    said = [r.getMessage() for r in caplog.records]
    assert len(said) == 1 and "mouth is widened on the default neutral frame 100" in said[0]
    assert said[0].endswith("(--neutral 115)")
