"""Raised brows and an open mouth on the neutral frame
(faceanalysis.estimation.neutral_check)."""

from __future__ import annotations

import numpy as np
import pytest

from faceanalysis.estimation.neutral_check import (
    BELOW_SHARE,
    BROWS,
    CLOSED_RUN,
    MIN_FRAMES,
    MOUTH_OPEN,
    MOUTH_WIDE,
    MOUTH_WIDER,
    below_neutral,
    brows_down,
    closed_lips,
    narrow_mouth,
    nearest,
    open_mouth,
    wide_mouth,
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


def _talking(rng, frames=120):
    """Lip gaps (inter-ocular distances) of a talking face: lips at rest (0.01) half the
    time, open by up to 0.3 in syllables of 3-8 frames."""
    g = np.full(frames, 0.01) + rng.normal(0, 0.003, frames)
    t = 0
    while t < frames:
        n = int(rng.integers(3, 9))
        if rng.random() < 0.5:
            g[t:t + n] += rng.uniform(0.08, 0.3)
        t += n
    return g


def test_an_open_mouth_on_the_neutral_frame_is_told_and_a_closed_one_offered():
    rng = np.random.default_rng(0)
    g = _talking(rng)
    g[:6] = [0.25, 0.28, 0.2, 0.01, 0.22, 0.3]      # mid-sentence, a consonant's closure
    g[40:50] = 0.01                                  # a pause
    excess, closed = open_mouth(g, 0)
    assert excess > MOUTH_OPEN
    # offered: the first run of closed lips nearest the neutral frame, not frame 3
    assert closed is not None and closed != 3
    assert np.all(g[closed:closed + CLOSED_RUN] <= 0.01 + MOUTH_OPEN / 2 + 0.01)
    # the same clip from its pause: the mouth at rest there
    excess, _ = open_mouth(g, 45)
    assert abs(excess) < MOUTH_OPEN / 2


def test_lips_that_rest_apart_are_not_an_open_mouth():
    # a face whose lips never close: the closed level is its own, not 0
    rng = np.random.default_rng(1)
    g = _talking(rng) + 0.06
    excess, _ = open_mouth(g, int(np.argmin(np.abs(g - 0.07))))
    assert excess < MOUTH_OPEN


def test_an_open_mouth_is_not_judged_on_too_few_frames():
    g = np.full(MIN_FRAMES + 10, np.nan)
    g[:MIN_FRAMES - 1] = 0.01
    g[0] = 0.3
    assert open_mouth(g, 0) == (None, None)          # too few frames with a gap
    g[:] = 0.01
    g[5] = np.nan
    assert open_mouth(g, 5) == (None, None)          # the neutral frame has none
    g[:] = 0.3                                       # open throughout: no closed run
    excess, closed = open_mouth(g, 0)
    assert excess == pytest.approx(0.0) and closed is not None
    with pytest.raises(ValueError, match="neutral row 99"):
        open_mouth(g, 99)


def test_frames_with_the_brows_down_are_those_near_the_lowest(response):
    rng = np.random.default_rng(2)
    m, upper = len(response.muscles), response.upper
    frames = np.zeros((60, m))
    raise_ = np.zeros(m)
    for name in BROWS:
        raise_[response.muscles.index(name)] = 0.7 * upper[response.muscles.index(name)]
    frames[:25] = raise_                              # brows up, then down
    frames[40:45] = 0.3 * raise_                      # up a little
    down = brows_down(_displacements(response, frames, raise_, rng), response,
                      weights=_weights(response))
    assert not down[:25].any() and down[25:40].all() and down[45:].all()
    assert not down[40:45].any()
    d = _displacements(response, frames, raise_, rng)
    d[30] = np.nan                                    # a lost frame is never offered
    assert not brows_down(d, response)[30]
    assert not brows_down(d[:MIN_FRAMES - 1], response).any()


def test_closed_lips_are_pauses_and_nearest_picks_the_closest():
    g = np.full(50, 0.2)
    g[20:23] = 0.01                                   # a consonant: too short
    g[30:40] = 0.01                                   # a pause
    g[35] = np.nan                                    # lost: breaks the run
    closed = closed_lips(g)
    assert np.flatnonzero(closed).tolist() == list(range(30, 35))   # 36-39: too short
    assert nearest(closed, 0) == 30 and nearest(closed, 49) == 34
    assert nearest(np.zeros(5, bool), 2) is None
    assert not closed_lips(g[:MIN_FRAMES - 1]).any()
    with pytest.raises(ValueError, match="1-D"):
        closed_lips(g[:, None])


def test_a_widened_mouth_is_not_at_rest():
    rng = np.random.default_rng(3)
    w = 0.8 + rng.normal(0, 0.01, 80)                 # talking at rest
    w[20:30] = 0.98                                   # a smile
    w[50] = np.nan                                    # lost
    narrow = narrow_mouth(w)
    assert not narrow[20:30].any() and not narrow[50]
    assert narrow[:20].mean() > 0.9 and narrow[60:].mean() > 0.9
    assert np.all(w[narrow] <= np.nanpercentile(w, 10) + MOUTH_WIDER)
    assert not narrow_mouth(w[:MIN_FRAMES - 1]).any()


def test_a_smile_on_the_neutral_frame_widens_the_mouth_past_talking():
    rng = np.random.default_rng(4)
    w = 0.8 + rng.uniform(-0.03, 0.05, 120)          # talking: the corners move
    assert wide_mouth(w, int(np.argmax(w))) < MOUTH_WIDE   # its widest vowel is no smile
    w[:12] = 0.8 + MOUTH_WIDE + 0.05                  # starts smiling
    assert wide_mouth(w, 0) > MOUTH_WIDE
    w[0] = np.nan
    assert wide_mouth(w, 0) is None
    assert wide_mouth(w[:MIN_FRAMES - 1], 1) is None
    with pytest.raises(ValueError, match="neutral row 200"):
        wide_mouth(w, 200)
