"""classify takes its neutral reference from a rest frame, not blindly the first frame."""

import numpy as np
import pytest

from faceanalysis.flow.recognition import classify_video


@pytest.fixture(scope="module")
def smile(tmp_path_factory):
    from synth.render.sequence import render_sequence

    out = tmp_path_factory.mktemp("smile")
    return render_sequence(out, expression="happiness", frames=20, size=160, seed=11,
                           flow=False)


def test_a_clip_that_starts_at_the_apex_is_not_neutral(smile):
    from synth.facs import envelope

    apex = int(np.argmax(envelope(20) >= 0.999))      # the onset frames are dropped
    assert apex > 3
    rec = classify_video(smile["video"], start=apex, rest_lookback=0)
    assert rec.label == "happiness", rec.scores
    # the reference is the face at rest at the end of the offset, and it is said
    assert rec.reference_source == "detected" and rec.reference >= 17
    assert rec.as_dict()["reference"] == rec.reference


@pytest.fixture(scope="module")
def relaxing(tmp_path_factory):
    """A smile held from the first frame, relaxing at frame 5 and at rest from frame 11."""
    import pandas as pd

    from faceanalysis.io.table import MUSCLES
    from synth.render.sequence import contraction_timeline, render_sequence

    apex = contraction_timeline(MUSCLES, expression="happiness", frames=20).max()
    env = np.r_[np.ones(5), 0.5 + 0.5 * np.cos(np.pi * np.arange(1, 8) / 7), np.zeros(10)]
    drive = pd.DataFrame(np.outer(env, apex.to_numpy()), columns=apex.index)
    out = tmp_path_factory.mktemp("relaxing")
    return render_sequence(out, contractions=drive, frames=len(drive), size=160, seed=11,
                           flow=False)


def test_the_relaxed_face_is_the_reference_and_it_is_still(relaxing):
    rec = classify_video(relaxing["video"])
    assert rec.reference_source == "detected" and rec.reference >= 11, rec.reference
    assert rec.reference_rest == "still"
    assert rec.label == "happiness", rec.scores


def test_a_lull_is_not_still():
    from faceanalysis.flow.recognition import _pick_rest

    t = np.arange(48.0)
    # total contraction relative to frame 0 in a held laugh, with a brief lull at frame 25
    laugh = -0.6 * np.exp(-(((t - 25) / 3.0) ** 2))
    frame, still = _pick_rest(laugh, t.astype(int), 0)
    assert 24 <= frame <= 26 and still == "moving"
    # a face that relaxes from frame 0 and holds at rest from frame 10
    rest = -2.0 * np.clip(t / 10, 0, 1)
    frame, still = _pick_rest(rest, t.astype(int), 0)
    assert frame >= 10 and still == "still"


def test_the_rest_frame_may_precede_the_range(smile):
    """--start/--end bound what is classified; the face at rest before the range is the
    reference a careful user would pick."""
    from synth.facs import envelope

    apex = int(np.argmax(envelope(20) >= 0.999))
    rec = classify_video(smile["video"], start=apex)
    assert rec.reference < apex and rec.reference_source in ("first", "detected")
    assert rec.label == "happiness", rec.scores
    assert rec.frames.min() >= apex                     # the lead-in is not classified


def test_a_given_neutral_frame_is_used_and_reported(smile):
    rec = classify_video(smile["video"], neutral=0)
    assert rec.reference == 0 and rec.reference_source == "given"
    assert rec.label == "happiness"


def test_a_clip_that_starts_at_rest_keeps_its_first_frame(smile):
    rec = classify_video(smile["video"], end=12)
    assert rec.reference == 0 and rec.reference_source == "first"
    assert rec.label == "happiness"


def test_a_clip_that_starts_at_rest_is_streamed_once_with_the_same_result(smile, monkeypatch):
    import faceanalysis.flow.dense as dense

    streams = []
    real = dense.VideoFlowStream

    class Counted(real):
        def __iter__(self):
            streams.append(self.reference)
            return super().__iter__()

    monkeypatch.setattr(dense, "VideoFlowStream", Counted)
    found = classify_video(smile["video"])
    assert found.reference_source == "first" and streams == [0]
    # the same reference given: the search is skipped and the frames are streamed from it
    given = classify_video(smile["video"], neutral=0)
    assert streams == [0, 0]
    assert given.label == found.label == "happiness"
    assert given.scores == found.scores
    assert [s.as_dict() for s in given.segments] == [s.as_dict() for s in found.segments]
    np.testing.assert_array_equal(given.energy, found.energy)


def test_the_templates_warn_once_and_only_about_the_reference_used(smile, relaxing, monkeypatch,
                                                                   caplog):
    import logging

    import faceanalysis.flow.personalize as personalize

    real = personalize.personalize_from_table

    def warning(templates, table, neutral):
        personalize.log.warning("neutral frame %d: templates checked", neutral)
        return real(templates, table, neutral)

    monkeypatch.setattr(personalize, "personalize_from_table", warning)
    for clip, first in ((smile, True), (relaxing, False)):
        caplog.clear()
        with caplog.at_level(logging.WARNING, logger="faceanalysis.flow.personalize"):
            rec = classify_video(clip["video"])
        said = [r.getMessage() for r in caplog.records if "templates checked" in r.getMessage()]
        # the first pass personalises for the first frame in case it is the reference; where
        # the reference is found elsewhere, that frame's warning is not shown
        assert said == [f"neutral frame {rec.reference}: templates checked"]
        assert (rec.reference_source == "first") == first
