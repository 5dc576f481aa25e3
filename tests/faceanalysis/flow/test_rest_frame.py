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
    rec = classify_video(smile["video"], start=apex)
    assert rec.label == "happiness", rec.scores
    # the reference is the face at rest at the end of the offset, and it is said
    assert rec.reference_source == "detected" and rec.reference >= 17
    assert rec.as_dict()["reference"] == rec.reference


def test_a_given_neutral_frame_is_used_and_reported(smile):
    rec = classify_video(smile["video"], neutral=0)
    assert rec.reference == 0 and rec.reference_source == "given"
    assert rec.label == "happiness"


def test_a_clip_that_starts_at_rest_keeps_its_first_frame(smile):
    rec = classify_video(smile["video"], end=12)
    assert rec.reference == 0 and rec.reference_source == "first"
    assert rec.label == "happiness"
