"""resynth reports the flow agreement with the input video, which a wrong drive fails."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pandas as pd

from faceanalysis.io.table import MUSCLES
from faceanalysis.resynthesis.pipeline import resynthesize


def _flow(source, out, **kwargs):
    res = resynthesize(source, output=out, size=96, shading="plain", **kwargs)
    return json.loads(res.report_path.read_text())["flow_agreement"]


def test_the_report_scores_the_true_contractions_above_wrong_ones(subject, tmp_path):
    root, _ = subject
    analysis = root / "analysis"
    true = _flow(analysis, tmp_path / "true.mp4")
    assert true["active_frames"] > 0, true
    assert len(true["per_frame"]) == true["active_frames"]
    # the same timing on the wrong muscles: every muscle plays another's contraction
    wrong_dir = tmp_path / "wrong"
    shutil.copytree(analysis, wrong_dir)
    table = pd.read_csv(analysis / "contractions.csv")
    cols = [m for m in MUSCLES if m in table.columns]
    table[cols] = np.roll(table[cols].to_numpy(), 7, axis=1)
    table.to_csv(wrong_dir / "contractions.csv", index=False)
    wrong = _flow(wrong_dir, tmp_path / "wrong.mp4")
    assert true["mean_cosine"] > 0.5, true["mean_cosine"]
    assert true["mean_cosine"] > wrong["mean_cosine"] + 0.2, (true["mean_cosine"],
                                                              wrong["mean_cosine"])


def test_without_the_video_the_report_says_why(subject, tmp_path):
    root, files = subject
    table = pd.read_csv(root / "analysis" / "contractions.csv")
    agreement = _flow(table, tmp_path / "r.mp4")
    assert "skipped" in agreement
    assert "flow_agreement" not in json.loads(
        resynthesize(table, output=tmp_path / "n.mp4", size=64, shading="plain",
                     check_flow=False).report_path.read_text())
