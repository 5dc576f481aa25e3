"""The shared input options of the subcommands that read a video."""

from __future__ import annotations

import argparse

import cv2
import numpy as np
import pytest

from faceanalysis.cli._input import add_input_options, open_input


@pytest.fixture
def parser():
    p = argparse.ArgumentParser(prog="x", exit_on_error=False)
    add_input_options(p)
    return p


def test_options_reach_open_video(parser, tmp_path):
    for i in range(5):
        cv2.imwrite(str(tmp_path / f"f{i}.png"), np.full((80, 80), i, np.uint8))
    args = parser.parse_args([str(tmp_path), "--fps", "12.5", "--start", "1", "--end", "4"])
    src = open_input(args)
    assert src.fps == 12.5 and src.fps_origin == "user"
    assert [f.index for f in src] == [1, 2, 3]


def test_tiny_input_refused_by_default(parser, tmp_path):
    cv2.imwrite(str(tmp_path / "f.png"), np.zeros((40, 50), np.uint8))
    with pytest.raises(ValueError, match="50x40 pixels.*at least 64"):
        open_input(parser.parse_args([str(tmp_path / "f.png")]))


@pytest.mark.parametrize("argv", [["v", "--fps", "0"], ["v", "--fps", "x"],
                                  ["v", "--start", "-2"], ["v", "--end", "1.5"]])
def test_bad_values_are_usage_errors(parser, argv):
    with pytest.raises(argparse.ArgumentError):
        parser.parse_args(argv)


@pytest.mark.parametrize("command", ["analyze", "probe", "classify"])
@pytest.mark.parametrize("start, end", [("10", "5"), ("3", "3")])
def test_end_not_after_start_is_a_usage_error(run_cli, tmp_path, command, start, end):
    cv2.imwrite(str(tmp_path / "f.png"), np.zeros((80, 80), np.uint8))
    extra = ["-o", tmp_path / "out"] if command == "analyze" else []
    code, out, err = run_cli(command, tmp_path / "f.png", "--start", start, "--end", end,
                             *extra)
    assert code == 2, err
    assert err.startswith(f"usage: faceanalysis {command}"), err
    assert f"--end {end} must be after --start {start}" in err
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("command", ["analyze", "batch"])
@pytest.mark.parametrize("options, message", [
    (("--estimator", "mesh", "--tracker", "snakes"), "--estimator mesh reads the landmark"),
    (("--estimator", "tw93", "--refine"), "--refine goes with --estimator joint"),
    (("--estimator", "mesh", "--personalize"), "--personalize goes with --estimator model"),
    (("--personalize",), "--personalize goes with --estimator model, not the default"),
    (("--eyes", "--tracker", "snakes"), "--eyes goes with the landmark tracker"),
    (("--estimator", "flow", "--temporal", "0"), "--temporal goes with --estimator joint"),
    (("--temporal", "-0.5"), "--temporal: must be a number >= 0"),
])
def test_analysis_options_that_cannot_go_together_are_usage_errors(run_cli, tmp_path, command,
                                                                   options, message):
    cv2.imwrite(str(tmp_path / "f.png"), np.zeros((80, 80), np.uint8))
    code, out, err = run_cli(command, tmp_path / "f.png", "-o", tmp_path / "out", *options)
    assert code == 2, err
    assert err.startswith(f"usage: faceanalysis {command}"), err
    assert message in err
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("options, message", [
    (("--face", "520"), "--face: must be X,Y (two numbers, pixels), got '520'"),
    (("--face", "1,nan"), "--face: must be two finite numbers"),
    (("--face", "10,20", "--tracker", "snakes"), "--face goes with the landmark tracker"),
])
def test_a_bad_face_point_is_a_usage_error(run_cli, tmp_path, options, message):
    cv2.imwrite(str(tmp_path / "f.png"), np.zeros((80, 80), np.uint8))
    code, out, err = run_cli("analyze", tmp_path / "f.png", "-o", tmp_path / "out", *options)
    assert code == 2 and message in err, err
    assert not (tmp_path / "out").exists()
