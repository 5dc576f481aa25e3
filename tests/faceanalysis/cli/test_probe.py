"""``faceanalysis probe``: input description, and bad input as one-line errors with exit 1."""

from __future__ import annotations

import json

import cv2
import numpy as np


def make_clip(path, n=12):
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 20, (96, 72))
    for i in range(n):
        writer.write(np.full((72, 96, 3), 15 * i, np.uint8))
    writer.release()
    return path


def test_probe_describes_a_video(run_cli, tmp_path):
    clip = make_clip(tmp_path / "clip.avi")
    code, out, err = run_cli("probe", clip, "--json", "--decode", "--start", "2")
    assert code == 0, err
    info = json.loads(out)
    assert info["size"] == [96, 72] and info["fps"] == 20 and info["frame_count"] == 12
    assert info["n_frames"] == 10 and info["frames_decoded"] == 10
    assert info["frames_lost_mid_stream"] == 0 and info["missing_tail"] == 0


def test_probe_image_folder_with_fps(run_cli, tmp_path):
    for i in range(3):
        cv2.imwrite(str(tmp_path / f"{i}.tif"), np.zeros((70, 70), np.uint16))
    code, out, _ = run_cli("probe", tmp_path, "--fps", "50")
    assert code == 0
    assert "images" in out and "uint16" in out and "user" in out


def one_line_error(run_cli, *argv):
    code, out, err = run_cli(*argv)
    lines = err.strip().splitlines()
    assert code == 1 and out == ""
    assert len(lines) == 1 and lines[0].startswith("faceanalysis: error: "), err
    return lines[0]


def test_bad_inputs_are_one_line_errors(run_cli, tmp_path):
    assert "no such file" in one_line_error(run_cli, "probe", tmp_path / "missing.mp4")
    noise = tmp_path / "noise.mp4"
    noise.write_bytes(np.random.default_rng(0).bytes(4000))
    assert "not a video" in one_line_error(run_cli, "probe", noise)
    empty = tmp_path / "empty"
    empty.mkdir()
    assert "no images" in one_line_error(run_cli, "probe", empty)
    clip = make_clip(tmp_path / "clip.avi")
    assert "start (12)" in one_line_error(run_cli, "probe", clip, "--start", "12")
    # an empty range is a usage error (issue 28, item 9): exit 2 with the usage line
    code, out, err = run_cli("probe", clip, "--start", "5", "--end", "3")
    assert code == 2 and out == "" and "--end 3 must be after --start 5" in err, err


def test_bad_option_is_a_usage_error(run_cli, tmp_path):
    code, _, err = run_cli("probe", tmp_path, "--fps", "-3")
    assert code == 2 and "positive" in err


def test_probe_prints_the_real_end_of_the_range(run_cli, tmp_path):
    clip = make_clip(tmp_path / "clip.avi")
    code, out, err = run_cli("probe", clip, "--json", "--start", "2")
    assert code == 0, err
    assert json.loads(out)["frame_range"] == [2, 12]
    code, out, err = run_cli("probe", clip)
    assert code == 0 and "None" not in out, out
    assert "[0, 12]" in out, out


def test_probe_decode_lists_the_shots(run_cli, tmp_path):
    clip = tmp_path / "cut.avi"
    writer = cv2.VideoWriter(str(clip), cv2.VideoWriter_fourcc(*"MJPG"), 20, (96, 72))
    rng = np.random.default_rng(0)
    for i in range(40):
        # a slowly brightening grey room, then, from frame 25, a green one
        colour = (60 + i,) * 3 if i < 25 else (40, 160, 60)
        frame = np.full((72, 96, 3), colour, np.uint8)
        writer.write(np.clip(frame + rng.integers(-2, 3, frame.shape), 0, 255).astype(np.uint8))
    writer.release()
    code, out, err = run_cli("probe", clip, "--json", "--decode")
    assert code == 0, err
    info = json.loads(out)
    assert info["shot_cuts"] == [25] and info["shots"] == [[0, 24], [25, 39]]
    code, out, _ = run_cli("probe", clip, "--json", "--decode", "--start", "30")
    assert json.loads(out)["shots"] == [[30, 39]]


def test_probe_finds_the_first_face_and_its_size(run_cli, tmp_path):
    from synth.render.sequence import synthesize
    from tests.faceanalysis._photos import models_or_skip

    models_or_skip()
    img = synthesize(frames=1, size=192, seed=3, flow=False, texture_size=256,
                     supersample=1).images[0]
    img = cv2.cvtColor(np.ascontiguousarray(img), cv2.COLOR_RGB2BGR)
    blank = np.full_like(img, 120)
    for i, frame in enumerate((blank, blank, img, img)):
        cv2.imwrite(str(tmp_path / f"{i}.png"), frame)
    code, out, err = run_cli("probe", tmp_path, "--face", "--json")
    assert code == 0, err
    info = json.loads(out)
    assert info["first_face"] == 2 and info["face_detector"] == "short"
    assert 30 < info["interocular_px"] < 100 and info["face_small"] is False
    x0, y0, x1, y1 = info["face_box"]
    assert 0 <= x0 < x1 <= 192 and 0 <= y0 < y1 <= 192
    assert len(info["faces"]) == 1
    # two faces: both are listed, for analyze --face to pick one
    two = np.full((192, 400, 3), img[0, 0], np.uint8)
    two[:, :192] = img
    two[40:152, 260:372] = cv2.resize(img, (112, 112), interpolation=cv2.INTER_AREA)
    cv2.imwrite(str(tmp_path / "two.png"), two)
    code, out, err = run_cli("probe", tmp_path / "two.png", "--face", "--json")
    faces = sorted(json.loads(out)["faces"])
    assert code == 0 and len(faces) == 2, err
    assert faces[0][2] < 200 and faces[1][0] > 250 and faces[1][2] <= 400
    # the same face shrunk to 96 px: small, and found only at full range (with LiteRT)
    from trackers.landmarks.runtime import litert_available

    if litert_available():
        wide = np.full((720, 1280, 3), img[0, 0], np.uint8)
        wide[240:336, 640:736] = cv2.resize(img, (96, 96), interpolation=cv2.INTER_AREA)
        far = tmp_path / "far.png"
        cv2.imwrite(str(far), wide)
        code, out, err = run_cli("probe", far, "--face")
        assert code == 0, err
        assert "face_detector   full" in out and "face_small      True" in out
    # no face in the frames looked at
    code, out, err = run_cli("probe", tmp_path, "--face", "--end", "2", "--json")
    assert code == 0, err
    assert json.loads(out)["first_face"] is None
