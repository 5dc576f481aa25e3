"""The 'templates', 'validate' and 'classify' commands."""

import json

import numpy as np
import pytest


@pytest.mark.parametrize("cmd", ["templates", "validate", "classify"])
def test_help(run_cli, cmd):
    code, out, _ = run_cli(cmd, "--help")
    assert code == 0 and "example" in out


def test_validate_and_classify_report_user_mistakes(run_cli, tmp_path):
    code, _, err = run_cli("validate", tmp_path / "none.mp4", "--analysis", tmp_path)
    assert code == 1 and "none.mp4" in err
    video = tmp_path / "v.mp4"
    video.write_bytes(b"x")
    code, _, err = run_cli("validate", video, "--analysis", tmp_path / "missing")
    assert code == 1 and "missing" in err
    code, _, err = run_cli("classify", tmp_path / "none.mp4")
    assert code == 1 and "none.mp4" in err
    code, _, err = run_cli("classify", video, "--method", "lk")
    assert code == 2


def test_validate_and_classify_refuse_a_video_that_is_not_the_analysed_one(subject, run_cli,
                                                                            other_video):
    root, _ = subject
    other = other_video
    before = (root / "analysis" / "analysis.json").read_bytes()
    for command in ("validate", "classify"):
        code, out, err = run_cli(command, other, "--analysis", root / "analysis")
        assert code == 1 and out == ""
        assert err.strip().endswith("is not the input the analysis in "
                                    f"{root / 'analysis'} was made from (video.mp4, 256x256, "
                                    "12 frames): give the analysed video"), err
    assert (root / "analysis" / "analysis.json").read_bytes() == before
    assert not (root / "analysis" / "validation.csv").exists()


@pytest.mark.slow
def test_templates_command_writes_npz_and_previews(run_cli, tmp_path):
    out = tmp_path / "tpl"
    code, stdout, _ = run_cli("templates", "-o", out, "--steps", "3", "-q")
    assert code == 0, stdout
    names = sorted(p.name for p in out.iterdir())
    assert names == ["generic.npz", "generic_controls.png", "generic_energy.png",
                     "generic_expressions.png"]
    from faceanalysis.flow.templates import FlowTemplates

    t = FlowTemplates.load(out / "generic.npz")
    assert t.expression.shape[1] == 3 and np.abs(t.control).max() > 0
    code, _, err = run_cli("templates", "-o", out)
    assert code == 1 and "not empty" in err


@pytest.mark.slow
def test_classify_command_on_a_synthetic_video(run_cli, tmp_path):
    from synth.render import render_sequence

    paths = render_sequence(tmp_path / "seq", expression="surprise", frames=24, size=200,
                            seed=107, head_motion=0.5, noise=1.0, flow=False)
    code, out, err = run_cli("classify", paths["video"], "--json", "-o", tmp_path / "seg.csv")
    assert code == 0, err
    res = json.loads(out)
    assert res["label"] == "surprise"
    assert res["scores"]["surprise"] == max(res["scores"].values())
    assert (tmp_path / "seg.csv").read_text().startswith("start,apex,end,label")


def test_classify_names_each_photograph(run_cli, tmp_path):
    """Photographs (a folder of images without --fps) have no onset nor neighbours: each
    with an expression is named on its own, from the first as the neutral; the same images
    as a video's frames are one frame too short for an expression segment."""
    import cv2

    from tests.faceanalysis._frames import rendered_frames

    frames = rendered_frames(tmp_path / "seq", expression="surprise", frames=12, size=200,
                             seed=107)
    photos = tmp_path / "photos"
    photos.mkdir()
    for k, i in enumerate((0, 6, 0)):                   # neutral, surprise, neutral again
        cv2.imwrite(str(photos / f"{k}.png"), frames[i])
    code, out, err = run_cli("classify", photos)
    assert code == 0, err
    lines = out.splitlines()
    assert lines[0] == "surprise"
    assert "neutral reference: frame 0 (the first photograph with a face" in lines[1]
    assert lines[3].startswith("  frame 1: surprise (") and len(lines) == 4
    code, out, err = run_cli("classify", photos, "--fps", "10", "--json")
    assert code == 0 and json.loads(out)["label"] == "neutral", err


@pytest.mark.slow
def test_laughing_part_of_the_real_video_is_happiness(run_cli, real_video_dir):
    video = real_video_dir / "WolfgangLanger_Pexels.mp4"
    if not video.is_file():
        pytest.skip("WolfgangLanger_Pexels.mp4 not found")
    # frames 250-470 laugh; the face just before (frame 240) is the neutral reference
    code, out, err = run_cli("classify", video, "--start", "250", "--end", "470",
                             "--neutral", "240", "--json", "-q")
    assert code == 0, err
    res = json.loads(out)
    assert res["label"] == "happiness", res["scores"]
    seg = max(res["segments"], key=lambda s: s["end"] - s["start"])
    assert seg["label"] == "happiness" and seg["end"] - seg["start"] > 150


@pytest.mark.slow
def test_the_laugh_without_a_neutral_frame_is_named_or_doubted(run_cli, real_video_dir):
    video = real_video_dir / "WolfgangLanger_Pexels.mp4"
    if not video.is_file():
        pytest.skip("WolfgangLanger_Pexels.mp4 not found")
    # the laugh never shows the face at rest; the reference is searched before it too, and
    # the command either names the laugh or says it cannot vouch for its reference
    code, out, err = run_cli("classify", video, "--start", "250", "--end", "470", "-q")
    assert code == 0, err
    assert "neutral reference: frame" in out
    assert out.splitlines()[0] == "happiness" or "doubtful" in out, out


def test_classify_lists_every_active_stretch_and_the_frames_it_could_not_read():
    """The printed segments are in frame order and include the motion matching no expression
    and the frames without a face: a long video's later laugh cannot silently vanish."""
    import numpy as np

    from faceanalysis.cli.classify import segment_lines
    from faceanalysis.flow.recognition import CLASSES, UNMATCHED, Recognition, Segment

    scores = dict.fromkeys(CLASSES, 0.0)
    happy = Segment(3, 40, 57, "happiness", {**scores, "happiness": 0.7}, 0.03)
    other = Segment(228, 343, 471, UNMATCHED, {**scores, "disgust": 0.21, "anger": 0.13}, 0.05)
    energy = np.full(472, 0.01)
    energy[58:228] = np.nan
    rec = Recognition("happiness", happy.scores, [happy], energy, np.arange(472), 0.003,
                      unmatched=[other])
    assert segment_lines(rec) == [
        "frames 3-57 (apex 40): happiness (0.700)",
        "frames 58-227: not classified (no face tracked, or the face hidden)",
        "frames 228-471 (apex 343): motion that matches no expression (nearest disgust, 0.210)",
    ]
    assert list(rec.table()["start"]) == [3, 228]
