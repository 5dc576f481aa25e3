"""Scores of an analysis against ground truth: refusal of mismatched truth and estimate."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from faceanalysis.evaluation.scores import compare, evaluate
from faceanalysis.io.table import FIDUCIALS, JAW, MUSCLES


def _table(frames, seed=0) -> pd.DataFrame:
    rng = np.random.default_rng(seed)
    n = len(frames)
    data = {"frame": list(frames), "success": [1] * n}
    for m in (*MUSCLES, JAW):
        data[m] = rng.uniform(0, 1, n)
    for f in FIDUCIALS:
        data[f"fid_{f}_x"] = rng.uniform(10, 90, n)
        data[f"fid_{f}_y"] = rng.uniform(10, 90, n)
    return pd.DataFrame(data)


def _sequence(folder, frames, video=b"video A", size=(96, 96)):
    folder.mkdir()
    _table(range(frames)).to_csv(folder / "truth.csv", index=False)
    (folder / "video.mp4").write_bytes(video)
    (folder / "meta.json").write_text(json.dumps(
        {"frames": frames, "fps": 30.0, "size": list(size),
         "files": {"video": "video.mp4", "truth": "truth.csv"}}))
    return folder


def _analysis(folder, video, frames, *, first=0, size=(96, 96), frame_count=None):
    folder.mkdir()
    _table(range(first, first + frames), seed=1).to_csv(folder / "contractions.csv",
                                                        index=False)
    (folder / "analysis.json").write_text(json.dumps({"input": {
        "path": str(video), "size": list(size), "fps": 30.0,
        "frame_count": frame_count if frame_count is not None else frames}}))
    return folder


def test_same_sequence_is_scored(tmp_path):
    seq = _sequence(tmp_path / "seq", 12)
    res = _analysis(tmp_path / "res", seq / "video.mp4", 12)
    report = evaluate(seq, res)
    assert report["frames"] == 12 and report["frames_compared"] == 12


def test_different_lengths_are_refused_naming_both(tmp_path):
    truth, estimate = _table(range(60)), _table(range(30), seed=1)
    with pytest.raises(ValueError, match=r"truth has 60 frames \(0-59\).*estimate has 30 "
                                         r"frames \(0-29\)") as info:
        compare(truth, estimate)
    assert "\n" not in str(info.value) and "allow_partial" in str(info.value)
    assert compare(truth, estimate, allow_partial=True)["frames"] == 30


def test_same_length_other_frames_are_refused(tmp_path):
    with pytest.raises(ValueError, match=r"20 frames \(0-19\).*20 frames \(10-29\)"):
        compare(_table(range(20)), _table(range(10, 30), seed=1))


def test_analysis_of_another_video_is_refused(tmp_path):
    seq = _sequence(tmp_path / "seq", 12)
    other = _sequence(tmp_path / "other", 12, video=b"video B")
    res = _analysis(tmp_path / "res", other / "video.mp4", 12)
    with pytest.raises(ValueError, match="not the same sequence.*other/video.mp4"):
        evaluate(seq, res)
    assert evaluate(seq, res, allow_partial=True)["frames"] == 12
    # a copy of the same video is the same sequence
    copy = _sequence(tmp_path / "copy", 12)
    same = _analysis(tmp_path / "res2", copy / "video.mp4", 12)
    assert evaluate(seq, same)["frames"] == 12


def test_analysis_of_another_size_is_refused(tmp_path):
    seq = _sequence(tmp_path / "seq", 12)
    res = _analysis(tmp_path / "res", tmp_path / "gone.mp4", 12, size=(128, 128))
    with pytest.raises(ValueError, match=r"size \[96, 96\].*\[128, 128\]"):
        evaluate(seq, res)


def test_cli_refuses_mismatch_unless_allow_partial(tmp_path, run_cli):
    seq = _sequence(tmp_path / "seq", 60)
    res = _analysis(tmp_path / "res", tmp_path / "elsewhere.mp4", 30, frame_count=30)
    code, out, err = run_cli("evaluate", "--truth", seq, "--estimate", res)
    assert code == 1 and out == ""
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "60 frames" in lines[0] and "30 frames" in lines[0], err
    assert "--allow-partial" in lines[0]
    code, out, err = run_cli("evaluate", "--truth", seq, "--estimate", res, "--allow-partial",
                             "--json")
    assert code == 0 and json.loads(out)["frames"] == 30


def test_scores_over_the_controls_the_estimate_flags_identifiable():
    from faceanalysis.evaluation.scores import format_table, pool

    truth = _table(range(20))
    estimate = truth.copy()
    good, bad = "zygomaticus_major_l", "risorius_l"
    estimate[good] = truth[good] + 0.02
    estimate[bad] = 1.0 - truth[bad]                  # wrong, and flagged as a guess
    for c in (*MUSCLES, JAW):
        estimate[f"{c}_identifiable"] = 0.0
    estimate[f"{good}_identifiable"] = 1.0
    estimate.loc[:12, f"{JAW}_identifiable"] = 1.0   # 13 of 20 frames: counts
    report = compare(truth, estimate)
    assert report["controls"][good]["identifiable"] == 1.0
    assert report["controls"][bad]["identifiable"] == 0.0
    assert report["identifiable_controls"] == [good, JAW]
    assert report["identifiable_median_rmse"] == pytest.approx(np.median(
        [0.02, report["controls"][JAW]["rmse"]]))
    pooled = pool([report, compare(truth, estimate)])
    assert pooled["identifiable_controls"] == [good, JAW]
    assert "flagged identifiable" in format_table({"joint": pooled})
    # without flags there is nothing to restrict to
    assert "identifiable_controls" not in compare(truth, truth)
