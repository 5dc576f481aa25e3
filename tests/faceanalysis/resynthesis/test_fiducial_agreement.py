"""resynth reports what can fail: its fiducials against the analysis's tracked ones."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pandas as pd

from faceanalysis.io.table import FIDUCIALS
from faceanalysis.resynthesis.pipeline import resynthesize


def _agreement(source, subject, out):
    res = resynthesize(source, subject=subject, output=out, size=128)
    report = json.loads(res.report_path.read_text())
    return report["fiducial_agreement"]


def test_the_report_compares_resynthesised_with_tracked_fiducials(subject, tmp_path):
    root, _ = subject
    analysis = root / "analysis"
    own = _agreement(analysis, analysis, tmp_path / "own.mp4")
    assert np.isfinite(own["mean_px"]) and own["mean_px"] > 0
    assert own["max_px"] >= own["median_px"] > 0
    table = pd.read_csv(analysis / "contractions.csv")
    assert own["frames"] == int(table["success"].sum())
    assert len(own["per_frame"]) == own["frames"]
    # the same contractions with the tracked fiducials moved by 8 px: the figure sees it
    shifted = tmp_path / "shifted"
    shutil.copytree(analysis, shifted)
    for name in FIDUCIALS:
        table[f"fid_{name}_x"] += 8.0
    table.to_csv(shifted / "contractions.csv", index=False)
    moved = _agreement(shifted, analysis, tmp_path / "moved.mp4")
    assert moved["mean_px"] > own["mean_px"] + 2.0


def test_the_command_prints_the_fiducial_agreement_not_the_personalisation(subject, tmp_path,
                                                                           run_cli):
    root, _ = subject
    analysis = root / "analysis"
    code, out, err = run_cli("resynth", analysis, "-o", tmp_path / "r.mp4", "--subject",
                             analysis, "--size", "96", "-q")
    assert code == 0, err
    assert "fiducials vs tracked" in out and "landmark error" not in out
    assert "generic face" not in out
    # without a subject the generic face's features are compared, and the line says so
    code, out, err = run_cli("resynth", analysis, "-o", tmp_path / "g.mp4", "--size", "96",
                             "-q")
    assert code == 0, err
    assert "fiducials vs tracked" in out and "--subject personalises it" in out


def test_another_face_is_not_compared_with_the_tracked_features(subject, tmp_path, run_cli):
    """A subject from another video (expression transfer) has other features than the
    analysed face: the comparison is left out and the command says why, where it printed
    hundreds of pixels as if the resynthesis had failed."""
    root, files = subject
    source = tmp_path / "source"
    shutil.copytree(root / "analysis", source)
    other = tmp_path / "other.mp4"
    other.write_bytes(files["video"].read_bytes())
    meta = json.loads((source / "analysis.json").read_text())
    meta["input"]["path"] = str(other)                    # analysed from another video
    (source / "analysis.json").write_text(json.dumps(meta))
    code, out, err = run_cli("resynth", source, "-o", tmp_path / "r.mp4", "--subject",
                             root / "analysis", "--size", "96", "-q")
    assert code == 0, err
    assert "fiducials vs tracked: not compared (the subject is another video" in out
    report = json.loads((tmp_path / "r.json").read_text())
    assert set(report["fiducial_agreement"]) == {"skipped"}


def test_the_input_video_must_be_the_analysed_one(subject, tmp_path, other_video):
    import pytest

    root, _ = subject
    with pytest.raises(ValueError, match=r"other\.avi \(128x96, 3 frames\) is not the input "
                                         "the analysis in .*analysis was made from"):
        resynthesize(root / "analysis", input_video=other_video, output=tmp_path / "r.mp4")
    assert not (tmp_path / "r.mp4").exists()
