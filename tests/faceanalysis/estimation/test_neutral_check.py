"""Raised brows on the neutral frame (faceanalysis.estimation.neutral_check)."""

from __future__ import annotations

import numpy as np
import pytest

from faceanalysis.estimation.neutral_check import (
    BELOW_SHARE,
    BROWS,
    MIN_FRAMES,
    below_neutral,
)
from faceanalysis.estimation.registry import CONTOUR_WEIGHT, mesh_response


@pytest.fixture(scope="module")
def response():
    return mesh_response()


def _displacements(response, controls, neutral, rng, noise=0.01):
    """What the points do through ``response`` on frames ``controls`` (T, M) seen against
    a neutral frame ``neutral`` (M,), with tracking noise (cm)."""
    pred = response.predict(np.vstack([neutral, controls]))
    d = pred[1:] - pred[:1]
    return d + rng.normal(0, noise, d.shape)


def _weights(response):
    return np.array([1.0 if n.startswith("mesh_") else CONTOUR_WEIGHT
                     for n in response.fiducials])


def test_a_neutral_frame_with_raised_brows_reads_the_face_below_it(response):
    rng = np.random.default_rng(0)
    m, upper = len(response.muscles), response.upper
    frames = np.zeros((60, m))
    # a talking face at rest but for a smile and a frown now and then
    for name, rows in (("zygomaticus_major_l", slice(10, 20)), ("corrugator_r", slice(30, 40))):
        frames[rows, response.muscles.index(name)] = 0.6 * upper[response.muscles.index(name)]
    raised = np.zeros(m)
    for name in ("frontalis_major_l", "frontalis_major_r", "frontalis_inner_l",
                 "frontalis_inner_r"):
        raised[response.muscles.index(name)] = 0.6 * upper[response.muscles.index(name)]
    frames[45] = raised * 0.1                                  # nearly the raise again
    frames[50] = 0                                             # at rest
    shares, lowest = below_neutral(_displacements(response, frames, raised, rng), response,
                                   weights=_weights(response))
    assert sorted(shares) == sorted(BROWS)
    for name in ("frontalis_major_l", "frontalis_major_r", "frontalis_inner_l",
                 "frontalis_inner_r"):
        assert shares[name] >= BELOW_SHARE
    assert lowest != 45
    # the same face with a neutral frame at rest: nothing reads below it
    shares, _ = below_neutral(_displacements(response, frames, np.zeros(m), rng), response,
                              weights=_weights(response))
    assert max(shares.values()) < 0.1


def test_too_few_frames_or_points_are_not_judged(response):
    rng = np.random.default_rng(1)
    m = len(response.muscles)
    d = _displacements(response, np.zeros((MIN_FRAMES - 1, m)), np.zeros(m), rng)
    assert below_neutral(d, response) == ({}, None)
    d = _displacements(response, np.zeros((MIN_FRAMES + 5, m)), np.zeros(m), rng)
    d[:, : d.shape[1] // 2 + 1] = np.nan                     # most points unseen
    assert below_neutral(d, response) == ({}, None)
    with pytest.raises(ValueError, match=r"displacements must be \(T, \d+, 2\)"):
        below_neutral(d[:, :5], response)
