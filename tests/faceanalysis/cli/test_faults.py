"""Faults leave nothing misleading: SIGTERM, reruns, --overwrite, failed runs, an unreachable
scheduler; and every file the commands write follows the user's umask."""

from __future__ import annotations

import os
import signal
import socket
import stat
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[3]


@pytest.fixture(scope="module")
def face(tmp_path_factory):
    """A rendered face (96 px, 3 frames) and a 45-frame clip that repeats it."""
    from faceanalysis.io.video import open_video
    from synth.render.sequence import render_sequence
    from synth.render.video import VideoWriter

    root = tmp_path_factory.mktemp("face")
    files = render_sequence(root / "seq", expression="happiness", frames=3, size=96, seed=3,
                            flow=False)
    frames = [f.image for f in open_video(files["video"])]
    h, w = frames[0].shape[:2]
    with VideoWriter(root / "long.mp4", 25, (w, h), channel_order="bgr") as writer:
        for i in range(45):
            writer.write(frames[i % len(frames)])
    return {"video": files["video"], "long": root / "long.mp4"}


@pytest.fixture
def umask027():
    old = os.umask(0o027)
    yield
    os.umask(old)


def _hidden(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.rglob(".*"))


# --------------------------------------------------------------------------- SIGTERM

@pytest.mark.slow
def test_sigterm_during_the_overlay_leaves_no_partial_file_and_a_rerun_works(face, tmp_path,
                                                                             run_cli):
    out = tmp_path / "out"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(
        [str(REPO), *filter(None, [os.environ.get("PYTHONPATH")])])}
    proc = subprocess.Popen([sys.executable, "-m", "faceanalysis", "analyze", str(face["long"]),
                             "-o", str(out), "--overlay", "-q"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    deadline = time.monotonic() + 300
    while proc.poll() is None and time.monotonic() < deadline:
        if out.is_dir() and any(out.glob(".overlay.*.partial.mp4")):
            proc.send_signal(signal.SIGTERM)
            break
        time.sleep(0.005)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 143, err
    assert err.strip() == "faceanalysis: terminated (SIGTERM)"
    # nothing was finished: the folder the run created went with its partial overlay
    assert not out.exists() or not any(out.iterdir())
    code, _, err = run_cli("analyze", face["long"], "-o", out, "--overlay", "--end", "2", "-q")
    assert code == 0, err
    assert _hidden(out) == []
    assert {p.name for p in out.iterdir()} >= {"contractions.csv", "overlay.mp4"}


def test_sigterm_handler_raises_only_during_the_command_and_is_restored(monkeypatch, run_cli):
    import faceanalysis.cli.info as info_cmd

    before = signal.getsignal(signal.SIGTERM)

    def terminated(args):
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(5)                       # the handler raises before this ends
        return 0

    monkeypatch.setattr(info_cmd, "run", terminated)
    code, _, err = run_cli("info")
    assert code == 143
    assert err.strip() == "faceanalysis: terminated (SIGTERM)"
    assert signal.getsignal(signal.SIGTERM) == before


# --------------------------------------------------------------------------- reruns

def test_rerun_into_a_folder_of_partial_leftovers_is_accepted(face, tmp_path, run_cli):
    out = tmp_path / "out"
    out.mkdir()
    (out / ".overlay.abcd1234.partial.mp4").write_bytes(b"half")   # a kill -9 leftover
    code, _, err = run_cli("analyze", face["video"], "-o", out, "-q")
    assert code == 0, err
    assert _hidden(out) == []


def test_refusal_names_what_the_folder_holds(face, tmp_path, run_cli):
    out = tmp_path / "out"
    out.mkdir()
    (out / ".notes").write_text("mine")
    (out / "contractions.csv").write_text("old")
    code, _, err = run_cli("analyze", face["video"], "-o", out, "-q")
    assert code == 1
    assert err.strip() == (f"faceanalysis: error: {out} is not empty (it holds .notes, "
                           f"contractions.csv); pass --overwrite (overwrite=True) to replace "
                           f"its results")


@pytest.mark.parametrize("command", [("analyze", "-o", "out"), ("classify",), ("probe",),
                                     ("batch", "-o", "out")])
def test_a_url_is_refused_in_one_line_naming_it(tmp_path, run_cli, monkeypatch, command):
    monkeypatch.chdir(tmp_path)
    code, _, err = run_cli(command[0], "https://example.com/clip.mp4", *command[1:])
    assert code == 1
    assert err.startswith("faceanalysis: error: https://example.com/clip.mp4: a URL or stream")
    assert err.count("\n") == 1 and not (tmp_path / "out").exists()


def test_results_are_not_written_among_the_images_they_come_from(tmp_path, run_cli):
    """The plot written into a folder of images would be read as one more picture by the
    next analysis of it; --overwrite does not change that."""
    import cv2

    images = tmp_path / "photos"
    images.mkdir()
    for i in range(2):
        cv2.imwrite(str(images / f"{i}.png"), np.full((48, 64, 3), 90 * i, np.uint8))
    for extra in ([], ["--overwrite"]):
        code, out, err = run_cli("analyze", images, "-o", tmp_path / "photos" / ".", "-q",
                                 *extra)
        assert code == 1 and out == ""
        assert "is the folder of images being analysed: write the results to another" in err
        assert sorted(p.name for p in images.iterdir()) == ["0.png", "1.png"]


def test_overwrite_leaves_only_this_runs_outputs_and_the_users_files(face, tmp_path, run_cli):
    out = tmp_path / "out"
    out.mkdir()
    earlier = ["overlay.mp4", "overlay.avi", "validation.csv", "validation.png",
               "contractions.png", ".overlay.x1y2z3_4.partial.mp4"]
    for name in earlier:
        (out / name).write_bytes(b"an earlier run's")
    (out / "notes.txt").write_text("the user's")
    (out / "overlay.mp4.bak").write_text("the user's")
    code, _, err = run_cli("analyze", face["video"], "-o", out, "--overwrite", "-q")
    assert code == 0, err
    assert sorted(p.name for p in out.iterdir()) == [
        "analysis.json", "contractions.csv", "contractions.png", "notes.txt", "overlay.mp4.bak"]
    assert (out / "contractions.png").read_bytes() != b"an earlier run's"


def test_failed_overwrite_keeps_the_earlier_results(tmp_path, run_cli):
    out = tmp_path / "out"
    out.mkdir()
    (out / "overlay.mp4").write_bytes(b"earlier")
    code, _, _ = run_cli("analyze", tmp_path / "missing.mp4", "-o", out, "--overwrite")
    assert code == 1
    assert [p.name for p in out.iterdir()] == ["overlay.mp4"]


# --------------------------------------------------------------------------- failed runs

def _blank_video(path: Path) -> Path:
    from synth.render.video import VideoWriter

    with VideoWriter(path, 25, (96, 96)) as writer:
        for _ in range(3):
            writer.write(np.full((96, 96, 3), 128, np.uint8))
    return path


def test_failed_run_removes_the_folders_it_created(tmp_path, run_cli):
    video = _blank_video(tmp_path / "blank.mp4")
    code, _, err = run_cli("analyze", video, "-o", tmp_path / "new" / "out", "--overlay")
    assert code == 1 and "no face" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["blank.mp4"]
    existing = tmp_path / "existing"
    existing.mkdir()
    code, _, _ = run_cli("analyze", video, "-o", existing)
    assert code == 1
    assert existing.is_dir()                                  # not the run's to remove


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_unreachable_scheduler_is_one_line_and_writes_nothing(monkeypatch, tmp_path, run_cli):
    from faceanalysis import batch

    monkeypatch.setattr(batch, "SCHEDULER_TIMEOUT_S", 1)
    video = _blank_video(tmp_path / "blank.mp4")
    address = f"tcp://127.0.0.1:{_free_port()}"
    started = time.monotonic()
    code, out, err = run_cli("batch", video, "-o", tmp_path / "res", "--scheduler", address,
                             "-q")
    assert code == 1
    assert time.monotonic() - started < 20
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err
    assert lines[0].startswith(f"faceanalysis: error: cannot connect to the Dask scheduler at "
                               f"{address}")
    assert not (tmp_path / "res").exists()
    code, _, err = run_cli("batch", video, "-o", tmp_path / "res", "--scheduler", "nohost",
                           "-q")
    assert code == 1 and len(err.strip().splitlines()) == 1
    assert "at nohost: missing port number" in err


def test_scheduler_timeout_is_short():
    from faceanalysis import batch

    assert batch.SCHEDULER_TIMEOUT_S <= 10


# --------------------------------------------------------------------------- umask

def _modes(root: Path) -> dict[str, int]:
    return {str(p.relative_to(root)): stat.S_IMODE(p.stat().st_mode)
            for p in root.rglob("*")}


def _assert_umask_027(root: Path) -> None:
    modes = _modes(root)
    assert modes
    for name, mode in modes.items():
        expected = 0o750 if (root / name).is_dir() else 0o640
        assert mode == expected, f"{name}: {oct(mode)}"


@pytest.mark.slow
def test_analyze_and_resynth_follow_the_umask(face, tmp_path, run_cli, umask027):
    out = tmp_path / "analysis"
    code, _, err = run_cli("analyze", face["video"], "-o", out, "--overlay", "-q")
    assert code == 0, err
    assert {p.name for p in out.iterdir()} >= {"contractions.csv", "overlay.mp4"}
    _assert_umask_027(out)
    res = tmp_path / "resynth"
    code, _, err = run_cli("resynth", out, "-o", res / "r.mp4", "--subject", out,
                           "--side-by-side", "--size", "64", "--export-meshes", res / "meshes",
                           "-q")
    assert code == 0, err
    assert (res / "r.mp4").is_file() and any((res / "meshes").iterdir())
    _assert_umask_027(res)


@pytest.mark.slow
def test_templates_follow_the_umask(tmp_path, run_cli, umask027):
    code, _, err = run_cli("templates", "-o", tmp_path / "tpl", "--steps", "2", "--size", "96",
                           "-q")
    assert code == 0, err
    _assert_umask_027(tmp_path / "tpl")


@pytest.mark.slow
def test_batch_follows_the_umask(face, tmp_path, run_cli, umask027):
    code, _, err = run_cli("batch", face["video"], "-o", tmp_path / "res", "--workers", "1",
                           "--overlay", "-q")
    assert code == 0, err
    assert (tmp_path / "res" / "video" / "overlay.mp4").is_file()
    _assert_umask_027(tmp_path / "res")


def test_landmark_tracker_failed_run_leaves_no_overlay(tmp_path, run_cli):
    from trackers.landmarks import ensure_models

    try:
        ensure_models()
    except (RuntimeError, FileNotFoundError) as exc:
        pytest.skip(f"the MediaPipe face models cannot be obtained here: {exc}")
    video = _blank_video(tmp_path / "blank.mp4")
    code, _, err = run_cli("analyze", video, "-o", tmp_path / "new" / "out", "--overlay",
                           "--tracker", "landmarks")
    assert code == 1 and "no face found in any of the 3 frames" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["blank.mp4"]
