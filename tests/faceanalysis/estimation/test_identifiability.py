"""Which controls the seen points can tell apart (faceanalysis.estimation.identifiability)."""

from __future__ import annotations

import numpy as np
import pytest

from faceanalysis.estimation.identifiability import (
    IDENTIFIABLE_LIMIT,
    MIRROR_FRAMES,
    REFERENCE_NOISE_CM,
    assess,
    estimator_errors,
    identifiability,
    mirror_agreement,
    mirror_partner,
    tracking_noise,
    traded_pairs,
)
from faceanalysis.estimation.model_response import model_response


def test_identifiability_of_the_generic_face():
    response = model_response()
    t = identifiability(response)
    assert sorted(t.index) == sorted(response.muscles)
    assert ((t["independent"] >= 0) & (t["independent"] <= 1)).all()
    assert (t["signature"] > 0).all()
    # the brows are read off three points each; the levators move the mouth corners and
    # furrows as combinations of the other lower-face muscles do. The zygomaticus major,
    # pulling out as much as up (fitted to real smiles), lies between: its own direction
    brows = t.loc[[m for m in t.index if m.startswith(("frontalis", "corrugator"))]]
    levators = t.loc[[m for m in t.index if m.startswith("levator")]]
    zygomaticus = t.loc[[m for m in t.index if m.startswith("zygomaticus_major")]]
    assert brows["standard_error"].max() * 10 < levators["standard_error"].min()
    assert brows["independent"].min() > 5 * levators["independent"].max()
    assert zygomaticus["standard_error"].max() * 4 < levators["standard_error"].min()
    assert brows["standard_error"].max() < zygomaticus["standard_error"].min()
    assert list(t["standard_error"]) == sorted(t["standard_error"])
    with pytest.raises(ValueError, match="level"):
        identifiability(response, level=1.0)


def test_a_control_that_another_duplicates_is_not_identifiable():
    from faceanalysis.estimation.response import FiducialResponse

    rng = np.random.default_rng(1)
    full = rng.normal(size=(3, 4, 2))
    full[2] = full[1]
    disp = np.stack([np.zeros_like(full), full], axis=1)
    r = FiducialResponse(("a", "b", "b_twin"), tuple("pqrs"), np.zeros((4, 2)), disp,
                         np.ones(3), np.array([0.0, 1.0]))
    t = identifiability(r)
    assert t.loc["a", "independent"] > 0.3 and np.isfinite(t.loc["a", "standard_error"])
    assert t.loc[["b", "b_twin"], "independent"].max() < 1e-9
    assert np.isinf(t.loc[["b", "b_twin"], "standard_error"]).all()




def test_fewer_points_tell_fewer_controls_apart():
    response = model_response()
    full = identifiability(response)
    brows = [p for p in response.fiducials if p.startswith("brow")]
    few = identifiability(response, points=brows)
    lower = [m for m in response.muscles if m.startswith(("zygomaticus", "depressor"))]
    assert np.isinf(few.loc[lower, "standard_error"]).all()
    assert np.isfinite(full.loc[lower, "standard_error"]).all()
    with pytest.raises(ValueError, match="unknown measurement point"):
        identifiability(response, points=["nose"])


def test_tracking_noise_is_measured_from_jitter_not_motion():
    rng = np.random.default_rng(3)
    t = np.linspace(0.0, 4.0, 300)[:, None, None]
    motion = 0.8 * np.sin(2.0 * t) * np.ones((1, 6, 2))
    for s in (0.005, 0.02, 0.05):
        d = motion + rng.normal(0.0, s, motion.shape)
        d[40:60, 2] = np.nan                                   # a point lost for a while
        noise, n = tracking_noise(d)
        assert abs(noise - s) < 0.15 * s and n > 1000
    assert tracking_noise(motion[:2]) == (None, 0)


def test_tracking_noise_of_a_long_video_reads_every_second_difference_once():
    # more frames than one chunk, points lost across a chunk's edge, a subset of points:
    # the same samples and noise as the formula over the whole array
    rng = np.random.default_rng(8)
    d = rng.normal(0.0, 0.03, (1300, 7, 2))
    d[500:530, 1] = np.nan
    d[1020:1030] = np.nan
    cols = [0, 1, 4, 6]
    second = (d[2:] - 2.0 * d[1:-1] + d[:-2])[:, cols].reshape(-1)
    second = second[np.isfinite(second)]
    expected = 1.4826 * np.median(np.abs(second - np.median(second))) / np.sqrt(6.0)
    noise, n = tracking_noise(d, points=cols)
    assert n == second.size
    assert noise == pytest.approx(expected, rel=1e-12)
    assert tracking_noise(d)[1] > n
    with pytest.raises(ValueError, match="points"):
        tracking_noise(d, points=[7])


def test_assess_marks_what_the_noise_hides():
    response = model_response()
    rng = np.random.default_rng(4)
    shape = (200, len(response.fiducials), 2)
    quiet = assess(response, rng.normal(0.0, 0.001, shape))
    loud = assess(response, rng.normal(0.0, 0.05, shape))
    assert quiet["noise_source"] == "measured" and abs(quiet["noise_cm"] - 0.001) < 2e-4
    assert len(quiet["not_identifiable"]) < len(loud["not_identifiable"])
    assert set(quiet["not_identifiable"]) <= set(loud["not_identifiable"])
    for c in loud["controls"].values():
        assert c["identifiable"] == (c["rmse"] is not None and c["rmse"] <= IDENTIFIABLE_LIMIT)
        assert 0.0 <= c["independent"] <= 1.0
    # one frame: no noise to measure, the reference is used
    one = assess(response, np.zeros((1,) + shape[1:]))
    assert one["noise_source"] == "reference" and one["noise_cm"] == REFERENCE_NOISE_CM
    # points never measured are not counted as seen
    d = rng.normal(0.0, 0.001, shape)
    d[:, [i for i, p in enumerate(response.fiducials) if p.startswith("mouth")]] = np.nan
    part = assess(response, d)
    assert not any(p.startswith("mouth") for p in part["points_seen"])
    with pytest.raises(ValueError, match="shape"):
        assess(response, np.zeros((5, 3, 2)))


def test_the_estimator_tells_the_brows_apart_and_not_the_levators():
    response = model_response()
    quiet = estimator_errors(response, 0.006)
    loud = estimator_errors(response, 0.05)
    brows = [m for m in response.muscles if m.startswith(("frontalis", "corrugator"))]
    assert (quiet[brows] < 0.05).all()
    assert (quiet[["levator_labii_l", "levator_labii_r"]] > IDENTIFIABLE_LIMIT).all()
    assert (loud > quiet - 0.01).all()                        # more noise, larger errors
    np.testing.assert_array_equal(estimator_errors(response, 0.006), quiet)
    # without the brow points the brow muscles are lost
    no_brows = [p for p in response.fiducials if not p.startswith("brow")]
    blind = estimator_errors(response, 0.006, points=no_brows)
    assert not (blind[brows] <= IDENTIFIABLE_LIMIT).any()     # unobserved: NaN
    with pytest.raises(ValueError, match="noise"):
        estimator_errors(response, -1.0)


def test_estimator_errors_are_remembered_per_question_and_not_shared():
    from faceanalysis.estimation import identifiability as ident

    response = model_response()
    first = estimator_errors(response, 0.02, draws=4)
    first.iloc[:] = -1.0                                     # the caller's copy
    again = estimator_errors(response, 0.02, draws=4)
    assert ident._ERRORS[response]
    estimator_errors.cache_clear()
    assert response not in ident._ERRORS
    fresh = estimator_errors(response, 0.02, draws=4)
    np.testing.assert_array_equal(again, fresh)
    assert (fresh.dropna() >= 0).all()
    # another fit, other points or another seed ask another question
    weights = np.ones(len(response.fiducials))
    weights[0] = 10.0
    for kwargs in ({"sparsity": 0.0}, {"weights": weights}, {"seed": 1},
                   {"points": response.fiducials[2:]}):
        other = estimator_errors(response, 0.02, draws=4, **kwargs)
        assert not np.allclose(other, fresh, equal_nan=True), kwargs


def test_two_controls_that_trade_places_are_found_and_slow_opposite_changes_are_not():
    rng = np.random.default_rng(2)
    t = np.arange(300)
    split = rng.uniform(0.0, 0.3, 300)                   # the sum is 0.5, the split noise
    smile = np.clip(np.sin(t / 40.0), 0, None)           # a smile, then a frown: slow and
    frown = np.clip(-np.sin(t / 40.0), 0, None)          # opposite, but not a trade
    c = np.column_stack([0.2 + split, 0.3 - split, smile, frown, np.zeros(300)])
    c[:, 2:4] += rng.normal(0, 0.02, (300, 2))           # each jitters on its own
    names = ["levator_labii_l", "levator_labii_nasi_l", "zyg", "dep", "still"]
    pairs = traded_pairs(c, names)
    assert [p["controls"] for p in pairs] == [["levator_labii_l", "levator_labii_nasi_l"]]
    assert pairs[0]["correlation"] < -0.9
    # too few frames to judge: nothing is claimed
    assert traded_pairs(c[:60], names) == []
    c[::3] = np.nan                                      # lost frames break the runs
    assert traded_pairs(c, names) == []
    with pytest.raises(ValueError, match="shape"):
        traded_pairs(c, names[:3])


def test_assess_flags_controls_that_trade_places_in_the_estimates():
    response = model_response()
    rng = np.random.default_rng(5)
    d = rng.normal(0.0, 0.001, (200, len(response.fiducials), 2))
    values = np.zeros((200, len(response.muscles)))
    a, b = response.index("mentalis_l"), response.index("mentalis_r")
    split = rng.uniform(0.0, 0.2, 200)
    values[:, a], values[:, b] = 0.1 + split, 0.3 - split
    plain = assess(response, d)
    flagged = assess(response, d, values=values)
    assert plain["traded"] == [] and flagged["traded"][0]["controls"] == ["mentalis_l",
                                                                           "mentalis_r"]
    assert plain["controls"]["mentalis_l"]["identifiable"]
    for name, other in (("mentalis_l", "mentalis_r"), ("mentalis_r", "mentalis_l")):
        assert flagged["controls"][name]["traded_with"] == [other]
        assert not flagged["controls"][name]["identifiable"]
        assert name in flagged["not_identifiable"]
    rest = set(flagged["not_identifiable"]) - {"mentalis_l", "mentalis_r"}
    assert rest == set(plain["not_identifiable"])


NAMES = ["zygomaticus_major_l", "zygomaticus_major_r", "corrugator_l", "corrugator_r",
         "mentalis_l", "mentalis_r", "orbicularis_oris", "jaw_rotation"]


def _smiling_video(rng, frames=120):
    """Estimates of a face that smiles twice and opens the jaw, and of the same video
    mirrored (sides exchanged), each with its own noise."""
    t = np.linspace(0, 4 * np.pi, frames)
    smile = np.clip(np.sin(t), 0, None)
    jaw = 10.0 * np.clip(np.sin(t + 1), 0, None)                 # degrees, range 20
    x = np.zeros((frames, len(NAMES)))
    x[:, 0], x[:, 1], x[:, 7] = 0.8 * smile, 0.6 * smile, jaw
    y = x[:, [1, 0, 3, 2, 5, 4, 6, 7]].copy()                    # the mirrored video
    x[:, :7] += rng.normal(0, 0.005, (frames, 7))
    y[:, :7] += rng.normal(0, 0.005, (frames, 7))
    return np.clip(x, 0, None), np.clip(y, 0, None)


def test_mirror_partners_exchange_sides():
    assert [mirror_partner(n) for n in NAMES] == [
        "zygomaticus_major_r", "zygomaticus_major_l", "corrugator_r", "corrugator_l",
        "mentalis_r", "mentalis_l", "orbicularis_oris", "jaw_rotation"]


def test_a_video_whose_mirror_image_reads_the_same_is_reproduced(rng):
    x, y = _smiling_video(rng)
    upper = [1.0] * 7 + [20.0]
    check = mirror_agreement(x, y, NAMES, upper=upper)
    assert check["rule"] == "series" and check["frames"] == len(x)
    assert check["not_reproduced"] == [] and not check["mask"].any()
    zyg = check["controls"]["zygomaticus_major_l"]
    assert zyg["moving"] and zyg["r"] > 0.95
    # a still control is not judged: nothing to reproduce
    assert check["controls"]["corrugator_l"] == {"moving": False, "r": None, "reproduced": True}


def test_a_reading_the_mirror_image_does_not_repeat_is_not_reproduced(rng):
    x, y = _smiling_video(rng)
    upper = [1.0] * 7 + [20.0]
    # the video reads the left corrugator in bursts that its mirror image does not show;
    # the right mentalis reads noise in both, uncorrelated
    x[:, 2] = 0.3 * (np.arange(len(x)) % 40 < 10)
    y[:, 3] = 0.0
    x[:, 5] = rng.uniform(0, 0.3, len(x))
    y[:, 4] = rng.uniform(0, 0.3, len(x))
    x[5, :] = np.nan                                              # a lost frame
    check = mirror_agreement(x, y, NAMES, upper=upper)
    assert check["frames"] == len(x) - 1
    assert check["not_reproduced"] == ["corrugator_l", "mentalis_r"]
    assert check["controls"]["corrugator_l"]["r"] == 0.0         # still in the mirror
    assert abs(check["controls"]["mentalis_r"]["r"]) < 0.5
    mask = check["mask"]
    assert mask[:, [2, 5]].sum(axis=0).tolist() == [len(x) - 1] * 2
    assert not mask[5].any() and mask.sum() == 2 * (len(x) - 1)
    # the jaw's range scales its thresholds: the same motion in degrees is still reproduced
    assert check["controls"]["jaw_rotation"]["reproduced"]


def test_few_frames_are_compared_value_by_value(rng):
    x, y = _smiling_video(rng, frames=MIRROR_FRAMES - 1)
    x[3, 2] = 0.35                      # read on the video only
    x[4, 4], y[4, 5] = 0.30, 0.24       # read on both, within half of the larger
    x[6, 6], y[6, 6] = 0.08, 0.0        # apart by less than 0.1 of the range
    check = mirror_agreement(x, y, NAMES, upper=[1.0] * 7 + [20.0])
    assert check["rule"] == "frames"
    assert check["not_reproduced"] == ["corrugator_l"]
    assert check["controls"]["corrugator_l"] == {"frames_not_reproduced": 1,
                                                 "reproduced": False}
    assert np.argwhere(check["mask"]).tolist() == [[3, 2]]


def test_mirror_agreement_checks_its_inputs():
    x = np.zeros((40, len(NAMES)))
    with pytest.raises(ValueError, match="values must have shape"):
        mirror_agreement(x[:, :3], x[:, :3], NAMES)
    with pytest.raises(ValueError, match="mirrored must have the shape"):
        mirror_agreement(x, x[:10], NAMES)
    with pytest.raises(ValueError, match="positive ranges"):
        mirror_agreement(x, x, NAMES, upper=[0.0] * len(NAMES))


def test_photographs_read_no_noise_nor_trading_from_one_to_the_next():
    response = model_response()
    rng = np.random.default_rng(0)
    # each frame a different expression: their differences are no noise
    d = rng.normal(0, 0.3, (6, len(response.fiducials), 2))
    video = assess(response, d)
    photos = assess(response, d, sequence=False)
    assert video["noise_source"] == "measured" and video["noise_cm"] > 0.1
    assert photos["noise_source"] == "reference" and photos["noise_cm"] == REFERENCE_NOISE_CM
    assert photos["traded"] == []
