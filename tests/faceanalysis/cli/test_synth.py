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
