import json
import subprocess
import sys

import pytest

from faceanalysis import __version__
from faceanalysis.cli.main import SUBCOMMANDS


def test_version(run_cli):
    code, out, _ = run_cli("--version")
    assert code == 0
    assert out.strip() == f"faceanalysis {__version__}"


def test_help_lists_every_subcommand(run_cli):
    code, out, _ = run_cli("--help")
    assert code == 0
    for name in SUBCOMMANDS:
        assert name in out


_HEAVY = ("numpy", "cv2", "pandas", "numba", "scipy", "matplotlib", "synth")


def _loaded_after(*argv: str) -> list[str]:
    """The numerical libraries a fresh interpreter has loaded after ``faceanalysis ARGV``."""
    code = ("import sys\n"
            "from faceanalysis.cli.main import main\n"
            "try:\n"
            f"    main({list(argv)!r})\n"
            "except SystemExit:\n"
            "    pass\n"
            f"print('loaded:', *(m for m in {_HEAVY!r} if m in sys.modules))\n")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    return proc.stdout.splitlines()[-1].split()[1:]


@pytest.mark.parametrize("argv", [("--help",), ("--version",),
                                  *((name, "--help") for name in SUBCOMMANDS)])
def test_help_and_version_load_no_numerical_library(argv):
    # they answer at once: nothing of the analysis loads to print them
    assert _loaded_after(*argv) == []


def test_a_subcommand_s_parser_is_the_same_built_alone():
    from faceanalysis.cli.main import build_parser

    argv = ["analyze", "v.mp4", "-o", "out", "--estimator", "tw93", "--start", "3"]
    alone = vars(build_parser(only="analyze").parse_args(argv))
    every = vars(build_parser().parse_args(argv))
    assert {k: v for k, v in alone.items() if not k.startswith("_")} == \
        {k: v for k, v in every.items() if not k.startswith("_")}


def test_unknown_subcommand_is_a_one_line_usage_error():
    proc = subprocess.run([sys.executable, "-m", "faceanalysis", "nosuchcmd"],
                          capture_output=True, text=True)
    assert proc.returncode == 2
    assert "Traceback" not in proc.stderr
    assert "invalid choice: 'nosuchcmd'" in proc.stderr


def test_no_subcommand_prints_help_and_fails(run_cli):
    code, _, err = run_cli()
    assert code == 2
    assert "usage:" in err


def test_info_json_reports_core_libraries(run_cli):
    code, out, _ = run_cli("info", "--json")
    assert code == 0
    info = json.loads(out)
    assert info["faceanalysis"] == __version__
    for lib in ("numpy", "scipy", "cv2", "skimage", "pandas"):
        assert info[lib], lib


def test_user_errors_become_one_line_exit_1(monkeypatch, run_cli):
    import faceanalysis.cli.info as info_cmd

    def boom(args):
        raise FileNotFoundError("clip.mp4: no such file")

    monkeypatch.setattr(info_cmd, "run", boom)
    code, _, err = run_cli("info")
    assert code == 1
    assert err.strip() == "faceanalysis: error: clip.mp4: no such file"


def test_numeric_options_are_checked_before_any_work(run_cli, tmp_path):
    for argv in (["resynth", "x.csv", "-o", tmp_path / "y.mp4", "--fps", "-3"],
                 ["batch", "a.mp4", "-o", tmp_path / "b", "--workers", "0"],
                 ["analyze", "a.mp4", "-o", tmp_path / "c", "--neutral", "-1"],
                 ["analyze", "a.mp4", "-o", tmp_path / "c", "--neutral", "first"],
                 ["demo", "-o", tmp_path / "d", "--frames", "zero"]):
        code, _, err = run_cli(*argv)
        assert code == 2, argv
        assert "Traceback" not in err
    assert not any(tmp_path.iterdir())


def test_classify_with_a_text_file_as_templates_says_so(run_cli, tmp_path):
    (tmp_path / "notes.txt").write_text("my notes\n")
    (tmp_path / "v.png").write_bytes(b"")
    code, out, err = run_cli("classify", tmp_path / "v.png", "--templates",
                             tmp_path / "notes.txt")
    assert code == 1
    assert len(err.strip().splitlines()) == 1 and "pickle" not in err, err
    assert "notes.txt: not a flow-templates file" in err, err


def test_output_under_a_file_says_which_part_is_a_file(run_cli, tmp_path):
    (tmp_path / "somefile.txt").write_text("x")
    code, out, err = run_cli("evaluate", "--suite", "standard", "--identities", "1",
                             "--frames", "3", "-o", tmp_path / "somefile.txt" / "out", "-q")
    assert code == 1
    assert "Errno" not in err and len(err.strip().splitlines()) == 1, err
    assert f"{tmp_path / 'somefile.txt'} is a file, not a folder" in err, err


def test_a_signal_wrapped_by_compiled_code_still_ends_the_run_as_a_signal(monkeypatch, capsys):
    # a SIGTERM that lands inside a Numba dispatcher comes back as a SystemError whose
    # context is Terminated: the run must still end as terminated (143), not crash
    from faceanalysis.cli import info, main

    def wrapped(args):
        try:
            raise main.Terminated(15)
        except main.Terminated as exc:
            raise SystemError("returned a result with an exception set") from exc

    monkeypatch.setattr(info, "run", wrapped)
    assert main.main(["info"]) == 143
    assert "terminated" in capsys.readouterr().err


def test_evaluate_faces_goes_with_the_standard_suite(run_cli, tmp_path):
    code, _, err = run_cli("evaluate", "--suite", "ceiling", "--faces", tmp_path, "-q")
    assert code == 1
    assert "--faces and --tracker go with --suite standard" in err, err
    code, _, err = run_cli("evaluate", "--suite", "standard", "--faces", tmp_path / "none",
                           "-o", tmp_path / "out", "-q")
    assert code == 1
    assert f"{tmp_path / 'none'}: no such folder of photographs" in err, err
    assert not (tmp_path / "out").exists()


def test_logs_follow_stderr_after_it_is_replaced():
    # a run under a replaced stderr (a notebook's, pytest's capture) must not leave the
    # process logging into that stream once it is closed
    import contextlib
    import io
    import logging

    from faceanalysis.cli._common import configure_logging

    root = logging.getLogger()
    handlers, level = root.handlers[:], root.level
    try:
        first = io.StringIO()
        with contextlib.redirect_stderr(first):
            configure_logging(quiet=True)
            logging.getLogger("faceanalysis").warning("during the run")
        first.close()
        later = io.StringIO()
        with contextlib.redirect_stderr(later):
            logging.getLogger("faceanalysis").warning("after it")
        assert later.getvalue() == "WARNING: after it\n"
    finally:
        root.handlers[:] = handlers
        root.setLevel(level)


def test_one_v_shows_the_toolkit_s_debug_messages_and_two_every_library_s():
    import contextlib
    import io
    import logging

    from faceanalysis.cli._common import OWN_LOGGERS, configure_logging

    root = logging.getLogger()
    handlers, level = root.handlers[:], root.level
    try:
        for verbosity, library_too in ((1, False), (2, True)):
            err = io.StringIO()
            with contextlib.redirect_stderr(err):
                configure_logging(verbosity)
                logging.getLogger("faceanalysis.analysis.pipeline").debug("ours")
                logging.getLogger("trackers.anchored").debug("tracker's")
                logging.getLogger("matplotlib.font_manager").debug("findfont")
                logging.getLogger("matplotlib").info("library info")
            out = err.getvalue()
            assert "DEBUG: ours" in out and "DEBUG: tracker's" in out, out
            assert ("findfont" in out) == library_too, out
            assert "INFO: library info" in out
        err = io.StringIO()
        with contextlib.redirect_stderr(err):
            configure_logging(0)
            logging.getLogger("faceanalysis.analysis.pipeline").debug("ours")
            logging.getLogger("faceanalysis").info("progress")
        assert err.getvalue() == "INFO: progress\n"
    finally:
        root.handlers[:] = handlers
        root.setLevel(level)
        for name in OWN_LOGGERS:
            logging.getLogger(name).setLevel(logging.NOTSET)
