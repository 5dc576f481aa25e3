"""``faceanalysis synth``: bad argument values are usage errors (exit 2, usage line)."""

from __future__ import annotations

import pytest


@pytest.mark.parametrize("argv, says", [
    (["--au", "99:0.5"], "unknown action unit"),
    (["--au", "12:abc"], "not 'AU:intensity'"),
    (["--au", "12:e"], "could not convert"),
    (["--au", "12:1.5"], "must be in [0, 1]"),
    (["--expression", "nosuch"], "unknown expression 'nosuch'"),
])
def test_bad_script_or_expression_is_a_usage_error(run_cli, tmp_path, argv, says):
    code, out, err = run_cli("synth", *argv, "--frames", "2", "--size", "32",
                             "-o", tmp_path / "out")
    assert code == 2, err
    assert err.startswith("usage: faceanalysis synth") and says in err, err
    assert "0frame" not in err and not (tmp_path / "out").exists()


class _Terminal:
    """A stderr that says it is a terminal and keeps what is written to it."""

    def __init__(self):
        self.text = ""

    def write(self, s):
        self.text += s
        return len(s)

    def flush(self):
        pass

    def isatty(self):
        return True


@pytest.mark.parametrize("terminal", [True, False])
def test_progress_bar_only_on_a_terminal(tmp_path, monkeypatch, capsys, terminal):
    # a bar redrawn into a log file or a pipe leaves a line of control characters per
    # update: it is drawn on a terminal only (and never with --quiet)
    from faceanalysis.cli.main import main

    stream = _Terminal()
    if terminal:
        monkeypatch.setattr("sys.stderr", stream)
    code = main(["synth", "--expression", "happiness", "--frames", "3", "--size", "48",
                 "--no-flow", "-o", str(tmp_path / "out")])
    err = stream.text if terminal else capsys.readouterr().err
    assert code == 0, err
    assert ("frame/s" in err) is terminal, err
    if terminal:
        stream.text = ""
        code = main(["synth", "--expression", "happiness", "--frames", "3", "--size", "48",
                     "--no-flow", "-q", "-o", str(tmp_path / "quiet")])
        assert code == 0 and "frame/s" not in stream.text, stream.text
