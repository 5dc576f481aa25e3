"""analysis.json: input description, quality summary, versions, atomic writing."""

from __future__ import annotations

import json
import pathlib

import cv2
import numpy as np
import pandas as pd
import pytest

from faceanalysis.io.report import (
    FORMAT,
    analysis_metadata,
    check_analysed_input,
    input_metadata,
    quality_summary,
    read_analysis,
    write_analysis,
)
from faceanalysis.io.table import empty_table
from faceanalysis.io.video import open_video

VERSIONS = {"faceanalysis": "0.test", "numpy": np.__version__}


def lost_table():
    t = empty_table(10, frames=np.arange(100, 110), timestamps=np.arange(10) / 25)
    t["success"] = [1, 1, 0, 0, 1, 1, 1, 0, 1, 1]
    t["confidence"] = [0.9, 0.8, 0, 0, 0.7, 0.6, 0.5, 0, 1.0, 0.5]
    return t


def test_quality_summary_counts_and_ranges():
    q = quality_summary(lost_table())
    assert q["frames_total"] == 10 and q["frames_tracked"] == 7 and q["frames_lost"] == 3
    assert q["lost_ranges"] == [[102, 103], [107, 107]]
    assert q["lost_fraction"] == pytest.approx(0.3)
    assert q["mean_confidence"] == pytest.approx(np.mean([0.9, 0.8, 0.7, 0.6, 0.5, 1.0, 0.5]))
    assert q["min_confidence"] == pytest.approx(0.5)
    assert q["lost_ranges_truncated"] is False
    assert (q["first_frame"], q["last_frame"]) == (100, 109)


def test_quality_summary_adds_frames_missing_at_the_end():
    q = quality_summary(lost_table(), frames_missing=5)
    assert q["frames_total"] == 15 and q["frames_lost"] == 8 and q["frames_missing"] == 5


def test_quality_summary_nothing_tracked():
    t = empty_table(4)
    q = quality_summary(t)
    assert q["frames_tracked"] == 0 and q["mean_confidence"] is None
    assert q["lost_ranges"] == [[0, 3]]


def test_quality_summary_validates():
    with pytest.raises(ValueError, match="'success'"):
        quality_summary(pd.DataFrame({"frame": [0]}))
    with pytest.raises(ValueError, match="frames_missing"):
        quality_summary(lost_table(), frames_missing=-1)


def test_metadata_from_a_video_source(tmp_path):
    path = tmp_path / "clip.avi"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 25, (80, 64))
    for i in range(12):
        writer.write(np.full((64, 80, 3), 10 * i, np.uint8))
    writer.release()
    src = open_video(path, start=2, end=12)
    frames = list(src)
    t = empty_table(len(frames), frames=[f.index for f in frames],
                    timestamps=[f.timestamp for f in frames])
    t["success"] = 1
    t["confidence"] = 0.75
    meta = analysis_metadata(src, t, parameters={"estimator": "joint", "sigma": np.float64(2)},
                             versions=VERSIONS, command=["faceanalysis", "analyse"],
                             elapsed_s=1.5, extra={"calibration": {"scale": np.float32(3.5)}})
    assert meta["format"] == FORMAT
    assert meta["input"]["path"] == str(path.resolve())
    assert meta["input"]["size"] == [80, 64] and meta["input"]["fps"] == pytest.approx(25)
    assert meta["input"]["frame_range"] == [2, 12] and meta["input"]["frame_count"] == 12
    assert meta["input"]["kind"] == "video" and meta["input"]["fps_origin"] == "container"
    assert meta["quality"]["frames_tracked"] == 10 and meta["quality"]["frames_lost"] == 0
    assert meta["parameters"] == {"estimator": "joint", "sigma": 2.0}
    assert meta["calibration"] == {"scale": 3.5}
    assert meta["command"] == ["faceanalysis", "analyse"] and meta["elapsed_s"] == 1.5
    json.dumps(meta, allow_nan=False)  # plain JSON types only


def test_default_versions_come_from_info():
    meta = analysis_metadata({"path": "x.mp4"})
    from faceanalysis import __version__

    assert meta["versions"]["faceanalysis"] == __version__
    assert meta["versions"]["numpy"] == np.__version__
    assert meta["quality"] is None


def test_nan_becomes_null_and_unknown_types_are_named():
    meta = analysis_metadata({"path": "x.mp4"}, parameters={"tol": float("nan")},
                             versions=VERSIONS)
    assert meta["parameters"]["tol"] is None
    with pytest.raises(ValueError, match=r"parameters.model: cannot store a object"):
        analysis_metadata({"path": "x"}, parameters={"model": object()}, versions=VERSIONS)
    with pytest.raises(ValueError, match="'input'"):
        analysis_metadata({"path": "x"}, versions=VERSIONS, extra={"input": 1})


def test_tracker_parameters_given_as_dataclasses_are_recorded():
    # analyze(..., tracker_options={"params": SnakeParams(...)}) used to fail at the very end,
    # when analysis.json was assembled
    from trackers.snakes import SnakeParams

    meta = analysis_metadata({"path": "x.mp4"}, versions=VERSIONS,
                             parameters={"tracker_options": {"params": SnakeParams(a=0.3)}})
    params = meta["parameters"]["tracker_options"]["params"]
    assert params["a"] == 0.3 and params["b"] == SnakeParams().b
    json.dumps(meta)


def test_write_and_read_back(tmp_path):
    meta = analysis_metadata({"path": "x.mp4"}, lost_table(), versions=VERSIONS)
    path = write_analysis(meta, tmp_path / "analysis.json")
    assert read_analysis(path) == meta
    assert path.read_text().endswith("}\n")


def test_read_errors(tmp_path):
    with pytest.raises(FileNotFoundError, match="no such file"):
        read_analysis(tmp_path / "analysis.json")
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    with pytest.raises(ValueError, match=r"bad\.json: not valid JSON"):
        read_analysis(bad)
    other = tmp_path / "other.json"
    other.write_text("[1, 2]")
    with pytest.raises(ValueError, match="not an analysis.json"):
        read_analysis(other)


def test_interrupted_write_leaves_previous_file(tmp_path, monkeypatch):
    path = tmp_path / "analysis.json"
    path.write_text('{"old": true}')

    def broken_write(self, data, *args, **kwargs):
        with open(self, "wb" if isinstance(data, bytes) else "w") as fh:
            fh.write(data[: len(data) // 2])
        raise KeyboardInterrupt

    monkeypatch.setattr(pathlib.Path, "write_text", broken_write)
    monkeypatch.setattr(pathlib.Path, "write_bytes", broken_write)
    with pytest.raises(KeyboardInterrupt):
        write_analysis(analysis_metadata({"path": "x"}, versions=VERSIONS), path)
    monkeypatch.undo()
    assert path.read_text() == '{"old": true}'
    assert list(tmp_path.iterdir()) == [path]


def _clip(path, size, n):
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 10, size)
    for i in range(n):
        writer.write(np.full((size[1], size[0], 3), 20 * i, np.uint8))
    writer.release()
    return path


def test_a_video_given_with_an_analysis_must_be_the_analysed_one(tmp_path):
    analysed = _clip(tmp_path / "a.avi", (64, 48), 5)
    with open_video(analysed) as source:
        recorded = input_metadata(source)
    check_analysed_input(analysed, recorded, analysis="out")
    # a copy elsewhere is the same input
    copy = tmp_path / "moved.avi"
    copy.write_bytes(analysed.read_bytes())
    check_analysed_input(copy, recorded, analysis="out")
    for other, described in [(_clip(tmp_path / "b.avi", (80, 48), 5), "80x48, 5 frames"),
                             (_clip(tmp_path / "c.avi", (64, 48), 7), "64x48, 7 frames")]:
        with pytest.raises(ValueError, match=rf"{other.name} \({described}\) is not the input "
                                             r"the analysis in out was made from \(a\.avi, "
                                             r"64x48, 5 frames\): give the analysed video"):
            check_analysed_input(other, recorded, analysis="out")
    # nothing recorded to hold it to: frames in memory, a table on its own
    other = tmp_path / "b.avi"
    for nothing in (None, {}, {**recorded, "kind": "frames"}, {"kind": "video"}):
        check_analysed_input(other, nothing, analysis="out")
