"""Batch runner: input discovery, folder names, markers, and real local Dask clusters.

The cluster tests run a small stand-in analysis (`intensity_task`, below) so that they
exercise the runner alone and stay fast; `test_batch_matches_single_video_analysis`
runs the real analysis.
"""

from __future__ import annotations

import functools
import json
import os
import signal
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import pandas as pd
import pytest

from faceanalysis import FaceAnalysisError, batch
from faceanalysis.batch import SUMMARY, run_batch
from faceanalysis.io.corpus import (
    MARKER,
    completion_problem,
    discover_inputs,
    is_complete,
    output_names,
)

# --------------------------------------------------------------------------- stand-in task


def intensity_task(path, output, *, gain=1.0):
    """Stand-in analysis: per-frame intensity statistics in the real output file names.

    Raises ValueError for an unreadable video and FaceAnalysisError for a blank one
    ("no face"), as the real analysis does for such inputs.
    """
    cap = cv2.VideoCapture(str(path))
    means, stds = [], []
    try:
        while True:
            ok, frame = cap.read()
            if not ok:
                break
            grey = cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY).astype(np.float64)
            means.append(grey.mean())
            stds.append(grey.std())
        fps = cap.get(cv2.CAP_PROP_FPS) or 25.0
    finally:
        cap.release()
    if not means:
        raise ValueError(f"{path}: not a readable video")
    if max(stds) < 1.0:
        raise FaceAnalysisError(f"{path}: no face found")
    n = len(means)
    table = pd.DataFrame({
        "frame": np.arange(n), "timestamp": np.arange(n) / fps,
        "success": np.array(stds) > 5.0, "confidence": np.clip(np.array(stds) / 50, 0, 1),
        "head_x": np.full(n, 10.0), "fid_chin_x": np.array(means),
        "zygomaticus_major_l": gain * np.array(means) / 255.0,
        "frontalis_inner_l": gain * np.array(stds) / 255.0,
        "jaw_rotation": np.zeros(n), "AU12_r": np.array(means) / 51.0,
    })
    table.to_csv(Path(output) / "contractions.csv", index=False)
    lost = int((~table["success"]).sum())
    meta = {"input": {"path": str(path), "fps": fps},
            "quality": {"frames_total": n, "frames_lost": lost, "frames_tracked": n - lost}}
    (Path(output) / "analysis.json").write_text(json.dumps(meta))
    plot = np.zeros((20, max(n, 2)), np.uint8)
    plot[19 - np.clip(np.array(means) / 13, 0, 19).astype(int), np.arange(n)] = 255
    cv2.imwrite(str(Path(output) / "contractions.png"), plot)
    return table


def dying_task(path, output, *, flag_dir, always=False, **options):
    """Write part of the outputs, then kill this worker process (once per video unless
    ``always``); afterwards behave like ``intensity_task``."""
    flag = Path(flag_dir) / f"{Path(path).stem}.died"
    if "die" in Path(path).stem and (always or not flag.exists()):
        flag.write_text(str(os.getpid()))
        (Path(output) / "contractions.csv").write_text("frame\n0\n")
        os.kill(os.getpid(), signal.SIGKILL)
        time.sleep(30)
    return intensity_task(path, output, **options)


def write_video(path, n_frames=6, size=40, *, blank=False, seed=0):
    rng = np.random.default_rng(seed)
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 25.0, (size, size))
    assert writer.isOpened()
    texture = rng.integers(0, 255, (size, 2 * size, 3), dtype=np.uint8)
    for t in range(n_frames):
        if blank:
            frame = np.full((size, size, 3), 128, np.uint8)
        else:
            frame = np.ascontiguousarray(texture[:, t:t + size])
        writer.write(frame)
    writer.release()
    return Path(path)


@pytest.fixture
def corpus(tmp_path):
    """Three good clips (two share a stem), a corrupt file and a clip without a face."""
    src = tmp_path / "videos"
    (src / "sub").mkdir(parents=True)
    good = [write_video(src / "a.avi", seed=1), write_video(src / "b.avi", n_frames=8, seed=2),
            write_video(src / "sub" / "a.avi", n_frames=5, seed=3)]
    corrupt = src / "corrupt.avi"
    corrupt.write_bytes(np.random.default_rng(4).integers(0, 256, 3000, np.uint8).tobytes())
    noface = write_video(src / "noface.avi", blank=True)
    return {"dir": src, "good": good, "corrupt": corrupt, "noface": noface,
            "all": [*good, corrupt, noface]}


# --------------------------------------------------------------------------- discovery

def test_discover_files_folders_and_globs(corpus):
    src = corpus["dir"]
    (src / "notes.txt").write_text("x")
    found = discover_inputs([src])
    assert [p.name for p in found] == ["a.avi", "b.avi", "corrupt.avi", "noface.avi"]
    assert all(p.is_absolute() for p in found)
    recursive = discover_inputs([str(src / "**" / "*.avi")])
    assert (src / "sub" / "a.avi").resolve() in recursive
    # duplicates collapse, order follows the patterns, explicit files are taken as given
    both = discover_inputs([src / "b.avi", src, src / "notes.txt"])
    assert both[0].name == "b.avi" and both[-1].name == "notes.txt" and len(both) == 5
    # a link keeps its own name; the file it points to is not listed twice
    (src / "subject7.avi").symlink_to(src / "b.avi")
    assert [p.name for p in discover_inputs([src / "subject7.avi", src / "b.avi"])] == [
        "subject7.avi"]


def test_discover_takes_camcorder_and_phone_suffixes(tmp_path):
    for name in ("clip.MTS", "clip2.m2ts", "old.3gp", "notes.txt", "voice.wav"):
        (tmp_path / name).write_bytes(b"x")
    assert [p.name for p in discover_inputs([tmp_path])] == ["clip.MTS", "clip2.m2ts",
                                                             "old.3gp"]


def test_discover_takes_a_folder_of_images_as_one_input(tmp_path):
    from faceanalysis.io.corpus import input_signature

    for subject in ("s1", "s2"):
        (tmp_path / subject).mkdir()
        for i in range(3):
            cv2.imwrite(str(tmp_path / subject / f"{i}.png"), np.full((8, 8), 40 * i, np.uint8))
    assert discover_inputs([tmp_path / "s1"]) == [(tmp_path / "s1").absolute()]
    # a pattern's folders of images are inputs beside its videos
    write_video(tmp_path / "clip.avi", n_frames=3)
    assert [p.name for p in discover_inputs([str(tmp_path / "*")])] == ["clip.avi", "s1", "s2"]
    # a folder with a video is a folder of videos, as before
    assert [p.name for p in discover_inputs([tmp_path])] == ["clip.avi"]
    # the folder's signature changes with an image changed in place, added or removed
    before = input_signature(tmp_path / "s1")
    cv2.imwrite(str(tmp_path / "s1" / "1.png"), np.full((8, 8), 200, np.uint8))
    os.utime(tmp_path / "s1" / "1.png", ns=(time.time_ns() + 10**9,) * 2)
    assert input_signature(tmp_path / "s1") != before
    before = input_signature(tmp_path / "s1")
    (tmp_path / "s1" / "2.png").unlink()
    assert input_signature(tmp_path / "s1") != before


def test_discover_errors_name_the_pattern(tmp_path):
    with pytest.raises(FileNotFoundError, match="nothing.mp4: no such file"):
        discover_inputs([tmp_path / "nothing.mp4"])
    with pytest.raises(FileNotFoundError, match=r"pattern '.*\*.mkv' matches no file"):
        discover_inputs([str(tmp_path / "*.mkv")])
    (tmp_path / "a.txt").write_text("x")
    with pytest.raises(FileNotFoundError, match="matches 1 path.*no video"):
        discover_inputs([str(tmp_path / "*.txt")])
    with pytest.raises(FileNotFoundError, match="folder holds no video file .* and no images"):
        discover_inputs([tmp_path])
    with pytest.raises(ValueError, match="no inputs"):
        discover_inputs([])


def test_output_names_never_collide():
    paths = ["/d/x/clip.mp4", "/d/y/clip.mp4", "/d/y/CLIP.avi", "/d/other.mp4",
             "/d/summary.mp4", "/d/.hidden.mp4", "/d/_finished.mp4"]
    names = output_names(paths)
    assert len(set(n.lower() for n in names)) == len(names)
    assert names[3] == "other"
    assert all(n.lower().startswith("clip-") for n in names[:3])
    assert names[4].startswith("summary-")
    assert names[5].startswith("hidden-") and names[6].startswith("finished-")
    assert output_names(paths) == names  # stable from run to run


def test_run_batch_validates_arguments(corpus, tmp_path):
    with pytest.raises(ValueError, match="workers must be a positive integer"):
        run_batch(corpus["good"], tmp_path / "out", workers=0)
    with pytest.raises(ValueError, match="exclusive"):
        run_batch(corpus["good"], tmp_path / "out", workers=2, scheduler="tcp://x:1")
    with pytest.raises(ValueError, match="task must be callable"):
        run_batch(corpus["good"], tmp_path / "out", task="intensity_task")
    (tmp_path / "file").write_text("x")
    with pytest.raises(FileExistsError, match="not a folder"):
        run_batch(corpus["good"], tmp_path / "file")
    with pytest.raises(FileNotFoundError, match="no such file"):
        run_batch([tmp_path / "missing.avi"], tmp_path / "out")
    (tmp_path / "file_out").mkdir()
    inside = write_video(tmp_path / "file_out" / "overlay.avi")
    with pytest.raises(ValueError, match="every input lies inside"):
        run_batch([inside], tmp_path / "file_out")


# --------------------------------------------------------------------------- one video, no cluster

def test_process_video_marker_and_completeness(corpus, tmp_path):
    video = corpus["good"][1]
    out = tmp_path / "out"
    out.mkdir()
    row = batch._process_video(str(video), str(out), "b", {"gain": 2.0}, intensity_task, False)
    assert row["status"] == "ok" and row["frames"] == 8 and row["error"] == ""
    assert row["duration_s"] == pytest.approx(8 / 25)
    assert set(os.listdir(out)) == {"b"}  # temporary folder renamed into place
    folder = out / "b"
    marker = json.loads((folder / MARKER).read_text())
    assert marker["input"]["size"] == video.stat().st_size
    assert marker["options"] == {"gain": 2.0}
    assert set(marker["outputs"]) == {"contractions.csv", "analysis.json", "contractions.png"}
    table = pd.read_csv(folder / "contractions.csv")
    ok = table["success"].to_numpy()
    assert row["mean_zygomaticus_major_l"] == pytest.approx(
        table["zygomaticus_major_l"][ok].mean())
    # the AU intensities are averaged as the contractions are (researchers read AUs)
    assert row["mean_AU12_r"] == pytest.approx(table["AU12_r"][ok].mean())
    assert "mean_head_x" not in row and "mean_frame" not in row

    assert is_complete(folder, video, options={"gain": 2.0})
    assert "other options" in completion_problem(folder, video, options={"gain": 1.0})
    png = folder / "contractions.png"
    png.write_bytes(png.read_bytes() + b"x")
    assert "bytes, the marker says" in completion_problem(folder, video)
    png.unlink()
    assert "contractions.png is missing" in completion_problem(folder, video)
    batch._process_video(str(video), str(out), "b", {}, intensity_task, True)  # overwrite
    assert is_complete(folder, video, options={})
    os.utime(video, ns=(video.stat().st_atime_ns, video.stat().st_mtime_ns + 10**9))
    assert "changed since" in completion_problem(folder, video)
    (folder / MARKER).write_text("{not json")
    assert "unreadable" in completion_problem(folder, video)
    (folder / MARKER).unlink()
    assert not is_complete(folder, video)


def test_process_video_bad_input_is_a_failed_row_without_leftovers(corpus, tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    for video, expected in [(corpus["corrupt"], "ValueError: .*not a readable video"),
                            (corpus["noface"], "FaceAnalysisError: .*no face found")]:
        row = batch._process_video(str(video), str(out), video.stem, {}, intensity_task, False)
        assert row["status"] == "failed"
        assert pd.Series([row["error"]]).str.match(expected).all(), row["error"]
    assert list(out.iterdir()) == []


def overlay_task(path, output, *, overlay=False, suffix=".avi"):
    intensity_task(path, output)
    if overlay and suffix:
        (Path(output) / f"overlay{suffix}").write_bytes(b"frames")


def test_overlay_is_expected_when_asked_for_under_either_codec_name(corpus, tmp_path):
    video = corpus["good"][0]
    for i, (suffix, status) in enumerate([(".mp4", "ok"), (".avi", "ok"), (None, "failed")]):
        out = tmp_path / f"out{i}"
        out.mkdir()
        task = functools.partial(overlay_task, suffix=suffix)
        row = batch._process_video(str(video), str(out), "a", {"overlay": True}, task, False)
        assert row["status"] == status, row["error"]
        if status == "ok":
            assert is_complete(out / "a", video, options={"overlay": True})
            (out / "a" / f"overlay{suffix}").unlink()
            assert not is_complete(out / "a", video)
        else:
            assert row["error"] == "RuntimeError: the analysis wrote no overlay.mp4"


# --------------------------------------------------------------------------- real clusters

def test_cluster_run_isolates_failures_and_resumes(corpus, tmp_path, caplog):
    out = tmp_path / "out"
    summary = run_batch([corpus["dir"], corpus["dir"] / "sub"], out, workers=2,
                        task=intensity_task, options={"gain": 1.5})
    assert len(summary) == 5
    by_video = summary.set_index("video")
    for video in corpus["good"]:
        row = by_video.loc[str(video)]
        assert row["status"] == "ok" and not row["resumed"]
        assert is_complete(out / row["output"], video, options={"gain": 1.5})
        # identical to the same analysis run in this process
        reference = tmp_path / "ref" / row["output"]
        reference.mkdir(parents=True)
        intensity_task(video, reference, gain=1.5)
        for name in ("contractions.csv", "analysis.json", "contractions.png"):
            assert (out / row["output"] / name).read_bytes() == (reference / name).read_bytes()
    assert by_video.loc[str(corpus["corrupt"]), "status"] == "failed"
    assert "not a readable video" in by_video.loc[str(corpus["corrupt"]), "error"]
    assert "no face found" in by_video.loc[str(corpus["noface"]), "error"]
    assert not (out / "corrupt").exists() and not (out / "noface").exists()
    names = sorted(p.name for p in out.iterdir())
    assert names == sorted([*summary["output"][summary["status"] == "ok"], SUMMARY])
    on_disk = pd.read_csv(out / SUMMARY)
    assert list(on_disk["video"]) == [str(v) for v in discover_inputs(
        [corpus["dir"], corpus["dir"] / "sub"])]
    assert on_disk["frames"].tolist()[:2] == [6, 8] and on_disk["frames"].isna().sum() == 2
    assert on_disk.columns[:9].tolist() == ["video", "output", "status", "resumed", "frames",
                                            "frames_lost", "duration_s", "processing_s", "error"]
    assert {"mean_zygomaticus_major_l", "mean_frontalis_inner_l",
            "mean_jaw_rotation"} <= set(on_disk.columns)

    # the rerun skips the finished videos and tries the failed ones again
    stamp = {v: (out / n / MARKER).stat().st_mtime_ns
             for v, n in zip(summary["video"], summary["output"]) if (out / n).exists()}
    caplog.set_level("INFO", logger="faceanalysis.batch")
    again = run_batch([corpus["dir"], corpus["dir"] / "sub"], out, workers=2,
                      task=functools.partial(intensity_task), options={"gain": 1.5})
    assert again.attrs["skipped"] == 3
    assert "3 finished before (skipped)" in caplog.text
    assert list(again["resumed"]) == [True, True, False, False, True]
    assert list(again["status"]) == list(summary["status"])
    pd.testing.assert_frame_equal(again.drop(columns=["resumed", "processing_s"]),
                                  summary.drop(columns=["resumed", "processing_s"]))
    for v, mtime in stamp.items():
        assert (out / by_video.loc[v, "output"] / MARKER).stat().st_mtime_ns == mtime
    # with nothing left to do no cluster is contacted (this scheduler does not exist)
    done = run_batch(corpus["good"], out, scheduler="tcp://127.0.0.1:9", task=intensity_task,
                     options={"gain": 1.5})
    assert done["resumed"].all() and done.attrs["skipped"] == 3
    # a subset of the inputs gives a.avi another folder name: its result is still found
    alone = run_batch(corpus["good"][:1], out, scheduler="tcp://127.0.0.1:9",
                      task=intensity_task, options={"gain": 1.5})
    assert alone["resumed"].all()
    assert alone["output"][0] == by_video.loc[str(corpus["good"][0]), "output"] != "a"
    # other options: the finished folders are not reused, and not replaced silently
    other = run_batch(corpus["good"], out, scheduler="tcp://127.0.0.1:9", task=intensity_task,
                      options={"gain": 2.0})
    assert other["status"].tolist() == ["failed"] * 3
    assert other["error"].str.contains("other options").all()
    assert other["error"].str.contains("--overwrite").all()


def test_worker_death_is_retried_and_leaves_nothing_finished(tmp_path):
    import dask
    import distributed  # noqa: F401  (its config defaults must exist before config.set)

    src = tmp_path / "v"
    src.mkdir()
    videos = [write_video(src / "ok1.avi", seed=1), write_video(src / "die_once.avi", seed=2),
              write_video(src / "die_always.avi", seed=3), write_video(src / "ok2.avi", seed=4)]
    flags = tmp_path / "flags"
    flags.mkdir()

    def task(path, output):
        return dying_task(path, output, flag_dir=flags, always="always" in Path(path).stem)

    out = tmp_path / "out"
    with dask.config.set({"distributed.scheduler.allowed-failures": 1}):
        summary = run_batch(videos, out, workers=2, task=task)
    status = dict(zip(summary["output"], summary["status"]))
    assert status == {"ok1": "ok", "die_once": "ok", "die_always": "failed", "ok2": "ok"}
    assert (flags / "die_once.died").exists()  # it really died once and was retried
    assert "KilledWorker" in summary.set_index("output").loc["die_always", "error"]
    assert is_complete(out / "die_once", videos[1])
    assert sorted(p.name for p in out.iterdir()) == ["die_once", "ok1", "ok2", SUMMARY]


def test_partial_folder_of_a_dead_worker_is_not_taken_as_finished(corpus, tmp_path):
    out = tmp_path / "out"
    video = corpus["good"][0]
    leftover = out / ".a.partial-deadbeef"
    leftover.mkdir(parents=True)
    (leftover / "contractions.csv").write_text("frame\n0\n")
    (out / "a").mkdir()  # an unfinished folder under the final name is refused, not reused
    summary = run_batch([video], out, task=intensity_task)
    assert summary["status"].tolist() == ["failed"]
    assert "not a finished result" in summary["error"][0] and "--overwrite" in summary["error"][0]
    assert not leftover.exists()
    summary = run_batch([video], out, workers=1, task=intensity_task, overwrite=True)
    assert summary["status"].tolist() == ["ok"] and is_complete(out / "a", video)


# --------------------------------------------------------------------------- command line

def test_cli_batch(corpus, tmp_path, monkeypatch, run_cli):
    monkeypatch.setattr(batch, "run_batch", functools.partial(run_batch, task=intensity_task))
    out = tmp_path / "out"
    with monkeypatch.context() as m:
        # on a terminal: the progress bar, with the counts
        m.setattr(sys.stderr, "isatty", lambda: True, raising=False)
        code, stdout, stderr = run_cli("batch", corpus["dir"], "-o", out, "--workers", "2")
    assert code == 0
    assert str(out / SUMMARY) in stdout
    assert "4 video(s): 2 ok, 2 failed; skipped 0 finished before" in stderr
    assert "corrupt.avi" in stderr and "noface.avi" in stderr
    assert "ok=2 failed=2 left=0" in stderr and "frames/s" in stderr  # the progress bar
    assert "distributed" not in stderr and "Traceback" not in stderr  # no cluster chatter
    # into a log file or a pipe: no bar, the same report
    code, _, stderr = run_cli("batch", corpus["good"][0], "-o", tmp_path / "piped")
    assert code == 0 and "1 video(s): 1 ok, 0 failed" in stderr and "frames/s" not in stderr
    # the finished ones again: skipped (and said so before any work), no cluster needed
    code, stdout, stderr = run_cli("batch", *corpus["good"][:2], "-o", out, "-q",
                                   "--scheduler", "tcp://127.0.0.1:9")
    assert code == 0
    assert "2 ok, 0 failed; skipped 2 finished before" in stderr
    code, stdout, stderr = run_cli("batch", *corpus["good"][:2], "-o", out,
                                   "--scheduler", "tcp://127.0.0.1:9")
    assert "2 finished before (skipped), 0 to analyse" in stderr
    code, _, stderr = run_cli("batch", corpus["corrupt"], corpus["noface"], "-o",
                              tmp_path / "bad", "--workers", "1", "-q")
    assert code == 1
    assert "every video failed" in stderr
    code, _, stderr = run_cli("batch", tmp_path / "nope*.avi", "-o", out)
    assert code == 1 and "matches no file" in stderr
    code, _, _ = run_cli("batch", corpus["dir"], "-o", out, "--workers", "2",
                         "--scheduler", "tcp://127.0.0.1:1")
    assert code == 2


def test_only_non_default_analysis_options_are_recorded(tmp_path, monkeypatch):
    from faceanalysis.batch import analysis_options
    from faceanalysis.cli.batch import _options
    from faceanalysis.cli.main import build_parser

    parser = build_parser()
    args = parser.parse_args(["batch", "x.mp4", "-o", "out"])
    assert analysis_options(_options(args)) == {}
    monkeypatch.chdir(tmp_path)
    args = parser.parse_args(["batch", "x.mp4", "-o", "out", "--estimator", "tw93",
                              "--start", "2", "--end", "9", "--fps", "25", "--layout",
                              "lay.json", "--overlay", "--estimator", "joint"])
    assert analysis_options(_options(args)) == {"start": 2, "end": 9, "fps": 25.0, "overlay": True,
                                      "layout": str(tmp_path / "lay.json")}


# --------------------------------------------------------------------------- the real analysis

@pytest.fixture(scope="module")
def face_corpus(tmp_path_factory):
    """Two rendered face clips (same file name in two folders), a clip without a face and
    a corrupt file; plus the fiducial response of the face that rendered them."""
    from faceanalysis.estimation.model_response import tabulate_response
    from synth.render.sequence import synthesize, write_sequence
    from tests.faceanalysis._kinematic_face import KinematicFace

    model = KinematicFace()
    root = tmp_path_factory.mktemp("faces")
    videos = []
    for i, (zygomaticus, frontalis) in enumerate([(0.8, 0.0), (0.0, 0.6)]):
        n = 8
        timeline = pd.DataFrame({
            "zygomaticus_major_l": np.linspace(0, zygomaticus, n),
            "zygomaticus_major_r": np.linspace(0, zygomaticus, n),
            "frontalis_inner_l": np.linspace(0, frontalis, n),
            "frontalis_inner_r": np.linspace(0, frontalis, n)})
        seq = synthesize(model=model, contractions=timeline, seed=i, size=160, fps=10,
                         flow=False, supersample=1)
        videos.append(Path(write_sequence(seq, root / f"subject{i}")["video"]))
    rng = np.random.default_rng(0)
    noface = root / "noface.avi"
    writer = cv2.VideoWriter(str(noface), cv2.VideoWriter_fourcc(*"MJPG"), 10.0, (160, 160))
    background = cv2.GaussianBlur(rng.integers(0, 255, (160, 200, 3), dtype=np.uint8),
                                  (0, 0), 3)
    for t in range(6):
        writer.write(np.ascontiguousarray(background[:, t:t + 160]))
    writer.release()
    corrupt = root / "corrupt.mp4"
    corrupt.write_bytes(rng.integers(0, 256, 5000, dtype=np.uint8).tobytes())
    return {"good": videos, "noface": noface, "corrupt": corrupt,
            "all": [*videos, noface, corrupt],
            "response": tabulate_response(model, (*model.muscle_names, "jaw_rotation"))}


@pytest.mark.slow
def test_batch_of_the_analysis_equals_single_process_analysis(face_corpus, tmp_path):
    # The analysis itself (tracking, calibration, estimation, files), with the fiducial
    # response of the face that rendered the clips passed in.
    from faceanalysis.analysis.pipeline import analyze_to_folder

    task = functools.partial(analyze_to_folder, response=face_corpus["response"])
    out = tmp_path / "out"
    summary = run_batch(face_corpus["all"], out, workers=2, task=task)
    by_video = summary.set_index("video")
    assert by_video.loc[str(face_corpus["corrupt"]), "status"] == "failed"
    assert "not a video" in by_video.loc[str(face_corpus["corrupt"]), "error"]
    assert by_video.loc[str(face_corpus["noface"]), "status"] == "failed"
    assert "no face" in by_video.loc[str(face_corpus["noface"]), "error"]
    for video in face_corpus["good"]:
        row = by_video.loc[str(video)]
        assert row["status"] == "ok", row["error"]
        assert row["frames"] == 8 and row["frames_lost"] == 0
        folder = out / row["output"]
        assert is_complete(folder, video)
        reference = analyze_to_folder(video, tmp_path / "ref" / row["output"],
                                      response=face_corpus["response"])
        assert (folder / "contractions.csv").read_bytes() == \
            (tmp_path / "ref" / row["output"] / "contractions.csv").read_bytes()
        meta = json.loads((folder / "analysis.json").read_text())
        assert meta["quality"] == reference.metadata["quality"]
        assert row["mean_zygomaticus_major_l"] == pytest.approx(
            reference.table["zygomaticus_major_l"].mean(), abs=1e-6)
        # and what says how far to trust them
        assert row["mean_confidence"] == pytest.approx(
            reference.metadata["quality"]["mean_confidence"])
        fit = reference.metadata["model_fit"]
        assert row["frames_over_fit_limit"] == fit["frames_over_limit"]
        turned = fit["head_turn"]["frames_over_limit"]
        assert (pd.isna(row["frames_turned"]) if turned is None
                else row["frames_turned"] == turned)
        assert row["shot_cuts"] == len(reference.metadata["quality"]["shot_cuts"]) == 0
        assert row["neutral_frame"] == reference.metadata["parameters"]["neutral_frame"]
        blocks = reference.metadata["calibration"]["neutral_blockiness"]
        assert (pd.isna(row["neutral_blockiness"]) if blocks is None
                else row["neutral_blockiness"] == blocks)
        offered = reference.metadata["calibration"]["offered_neutral"]
        assert (pd.isna(row["offered_neutral"]) if offered is None
                else row["offered_neutral"] == offered)
        iod = reference.metadata["quality"]["interocular_px"]
        assert pd.isna(row["interocular_px"]) if iod is None else row["interocular_px"] == iod
    # the smiling clip smiles more than the frowning one, in the summary as in the truth
    smile, brows = (by_video.loc[str(v)] for v in face_corpus["good"])
    assert smile["mean_zygomaticus_major_l"] > brows["mean_zygomaticus_major_l"]

    again = run_batch(face_corpus["all"], out, workers=2, task=task)
    assert again.attrs["skipped"] == 2
    assert again["status"].tolist() == summary["status"].tolist()


@pytest.mark.slow
def test_default_task_is_the_analysis(face_corpus, tmp_path):
    try:
        from synth import FaceModel  # noqa: F401
    except ImportError:
        pytest.skip("synth.FaceModel (the physics model) is not in synth yet; the default "
                    "analysis needs it for its response table")
    from faceanalysis.analysis.pipeline import analyze_to_folder

    video = face_corpus["good"][0]
    summary = run_batch([video], tmp_path / "out", workers=1)
    assert summary["status"].tolist() == ["ok"], summary["error"][0]
    analyze_to_folder(video, tmp_path / "ref")
    assert (tmp_path / "out" / summary["output"][0] / "contractions.csv").read_bytes() == \
        (tmp_path / "ref" / "contractions.csv").read_bytes()


def test_the_summary_averages_only_the_measured_values(tmp_path):
    table = pd.DataFrame({
        "frame": [0, 1, 2, 3], "timestamp": [0.0, 0.04, 0.08, 0.12], "success": [1, 1, 1, 0],
        "confidence": [1.0, 0.9, 0.8, 0.0],
        "zygomaticus_major_l": [0.2, 0.4, 0.9, np.nan],
        "zygomaticus_major_l_identifiable": [1, 1, 0, np.nan],
        "mentalis_l": [0.1, 0.3, 0.2, np.nan], "mentalis_l_identifiable": [0, 0, 0, np.nan],
        "jaw_rotation": [0.0, 0.1, 0.2, np.nan]})                  # (an older table: no flag)
    table.to_csv(tmp_path / "contractions.csv", index=False)
    (tmp_path / "analysis.json").write_text(json.dumps({"quality": {
        "frames_total": 4, "frames_lost": 1, "lost_reasons": {"hand": 1}}}))
    row = batch._summarise(tmp_path)
    assert (row["frames_lost_hand"], row["frames_lost_no_face"]) == (1, 0)
    assert row["mean_zygomaticus_major_l"] == pytest.approx(0.3)     # not the 0.9
    assert np.isnan(row["mean_mentalis_l"])                          # never measured
    assert row["mean_jaw_rotation"] == pytest.approx(0.1)
    assert row["mean_zygomaticus_major_l_identifiable"] == pytest.approx(2 / 3)


def test_the_summary_counts_the_blinks_of_an_analysis_with_eyes(tmp_path):
    table = pd.DataFrame({"frame": [0, 1, 2], "timestamp": [0.0, 0.04, 0.08],
                          "success": [1, 1, 1], "confidence": [1.0, 1.0, 1.0],
                          "eye_openness_l": [1.0, 0.1, 1.0], "eye_openness_r": [1.0, 0.2, 0.9]})
    table.to_csv(tmp_path / "contractions.csv", index=False)
    eyes = {"blinks": 1, "blinks_per_minute": 500.0,
            "closures": [{"first": 1, "last": 1, "duration_s": 0.04, "blink": True}]}
    (tmp_path / "analysis.json").write_text(json.dumps({"quality": {}, "eyes": eyes}))
    row = batch._summarise(tmp_path)
    assert (row["blinks"], row["blinks_per_minute"], row["eye_closures"]) == (1, 500.0, 1)
    assert row["mean_eye_openness_r"] == pytest.approx(0.7)
    # without --eyes (null) there are no blink columns
    (tmp_path / "analysis.json").write_text(json.dumps({"quality": {}, "eyes": None}))
    assert "blinks" not in batch._summarise(tmp_path)


def test_photographs_have_no_duration_in_the_summary(tmp_path):
    table = pd.DataFrame({"frame": [0, 1, 2], "timestamp": [0.0, 1 / 30, 2 / 30],
                          "success": [1, 1, 1], "confidence": [1.0, 1.0, 1.0]})
    table.to_csv(tmp_path / "contractions.csv", index=False)
    photographs = {"kind": "images", "fps": 30.0, "fps_origin": "default", "frame_count": 3}
    (tmp_path / "analysis.json").write_text(json.dumps({"quality": {},
                                                        "input": photographs}))
    assert np.isnan(batch._summarise(tmp_path)["duration_s"])       # not a 0.1 s video
    frames = {**photographs, "fps_origin": "user"}                 # a sequence, --fps 30
    (tmp_path / "analysis.json").write_text(json.dumps({"quality": {}, "input": frames}))
    assert batch._summarise(tmp_path)["duration_s"] == pytest.approx(0.1)
