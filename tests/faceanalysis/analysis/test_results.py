"""The output folder: refuses to overwrite, writes every result, leaves nothing half-done."""

from __future__ import annotations

import numpy as np
import pytest

from faceanalysis.analysis.results import OutputFolder
from faceanalysis.io.report import analysis_metadata, read_analysis
from faceanalysis.io.table import MUSCLES, empty_table, read_contractions
from faceanalysis.io.video import open_video


def table(n=20):
    t = empty_table(n, timestamps=np.arange(n) / 25)
    t["success"] = 1
    t["confidence"] = 0.9
    t[list(MUSCLES)] = 0.1
    return t


def test_writes_all_results(tmp_path):
    out = OutputFolder(tmp_path / "out")
    meta = analysis_metadata({"path": "clip.mp4"}, table(), versions={"faceanalysis": "t"})
    paths = out.write(table(), meta)
    assert {p.name for p in (tmp_path / "out").iterdir()} == {
        "contractions.csv", "analysis.json", "contractions.png"}
    assert len(read_contractions(paths["contractions"])) == 20
    assert read_analysis(paths["analysis"])["quality"]["frames_tracked"] == 20
    with out.overlay_writer(25, (64, 48)) as writer:
        writer.write(np.zeros((48, 64), np.uint8))
    assert len(list(open_video(out.overlay_mp4))) == 1


def test_refuses_existing_results_without_overwrite(tmp_path):
    (tmp_path / "contractions.csv").write_text("old")
    with pytest.raises(FileExistsError, match="--overwrite"):
        OutputFolder(tmp_path)
    out = OutputFolder(tmp_path, overwrite=True)
    out.write(table(), {"format": "x"}, plot=False)
    assert read_contractions(out.contractions_csv)["success"].sum() == 20


def test_bad_table_writes_nothing(tmp_path):
    bad = table()
    bad.loc[3, "risorius_l"] = 2.0
    out = OutputFolder(tmp_path / "out")
    with pytest.raises(ValueError, match=r"frame 3\), column risorius_l"):
        out.write(bad, {"format": "x"})
    assert list((tmp_path / "out").iterdir()) == []


def test_context_removes_earlier_toolkit_files_after_success_only(tmp_path):
    for name in ("overlay.mp4", "validation.csv", "validation.png", "contractions.png"):
        (tmp_path / name).write_text("earlier run")
    (tmp_path / "mine.txt").write_text("the user's")
    with pytest.raises(RuntimeError), OutputFolder(tmp_path, overwrite=True) as out:
        out.write(table(), {"format": "x"}, plot=False)
        raise RuntimeError("failed")
    assert (tmp_path / "overlay.mp4").is_file()            # a failed run removes nothing
    with OutputFolder(tmp_path, overwrite=True) as out:
        out.write(table(), {"format": "x"}, plot=False)
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "analysis.json", "contractions.csv", "mine.txt"]


def test_context_removes_the_folder_it_created_when_nothing_was_written(tmp_path):
    with pytest.raises(ValueError), OutputFolder(tmp_path / "new" / "out") as out, \
            out.overlay_writer(25, (64, 48)) as writer:
        writer.write(np.zeros((48, 64), np.uint8))
        raise ValueError("no face")
    assert list(tmp_path.iterdir()) == []


def test_analysis_prints_as_a_summary_whatever_its_length():
    from faceanalysis.analysis.results import Analysis

    def analysis(n):
        t = table(n)
        t.loc[2, "success"] = 0
        meta = analysis_metadata({"path": "/data/clips/smile.mp4", "kind": "video"}, t,
                                 parameters={"tracker": "landmarks", "estimator": "mesh",
                                             "neutral_frame": 0},
                                 versions={"faceanalysis": "t"})
        contours = [{"brow_l": np.zeros((40, 2)), "lips": np.zeros((80, 2))}] * n
        return Analysis(table=t, contours=contours, metadata=meta,
                        measurements=np.zeros((n, 12, 2)))

    text = repr(analysis(2000))
    assert text.startswith("<Analysis of smile.mp4: analysed 2000 frames (1 lost; neutral "
                           "frame 0; ")
    assert text.endswith("; landmarks tracker, mesh estimator>")
    assert len(text) == len(repr(analysis(20))) + 2 and "\n" not in text


def test_saved_plot_is_titled_with_the_input_file(tmp_path, monkeypatch):
    import faceanalysis.analysis.results as results

    titles = []

    def plot(table, path, **kwargs):
        from types import SimpleNamespace

        titles.append(kwargs.get("title"))
        path.write_bytes(b"png")
        return SimpleNamespace(clear=lambda: None)

    monkeypatch.setattr(results, "plot_contractions", plot)
    meta = analysis_metadata({"path": "/data/clips/smile.mp4"}, table(),
                             versions={"faceanalysis": "t"})
    results.Analysis(table=table(), contours=[], metadata=meta).save(tmp_path / "out")
    assert titles == ["smile.mp4"]
