"""``faceanalysis resynth``."""

from __future__ import annotations

import pytest

from tests.faceanalysis.resynthesis._series import SMILE, _drive


def test_cli_resynth(tmp_path, run_cli):
    csv = tmp_path / "c.csv"
    _drive(3).to_csv(csv, index=False)
    code, out, err = run_cli("resynth", csv, "-o", tmp_path / "r.mp4", "--size", "48",
                             "--shading", "wireframe", "-q")
    assert code == 0, err
    assert "3 frames" in out and (tmp_path / "r.json").is_file()
    code, out, err = run_cli("resynth", csv, "-o", tmp_path / "r.mp4", "-q")
    assert code == 1 and "exists" in err
    bad = _drive(3)
    bad.loc[1, SMILE[0]] = 7
    bad.to_csv(csv, index=False)
    code, out, err = run_cli("resynth", csv, "-o", tmp_path / "s.mp4", "-q")
    assert code == 1 and "column zygomaticus_major_l" in err and "line 3" in err
    video = tmp_path / "clip.mp4"                # a video where the table should be
    video.write_bytes(b"\x00\x00\x00\x18ftypmp42\xc3\x28\xff\xfe" * 20)
    code, out, err = run_cli("resynth", video, "-o", tmp_path / "t.mp4", "-q")
    assert code == 1 and "not a CSV table" in err


@pytest.mark.slow
def test_cli_personalised_report_goes_into_analysis_json(subject, tmp_path, run_cli):
    import json

    root, _ = subject
    code, out, err = run_cli("resynth", root / "analysis", "-o", tmp_path / "p.mp4",
                             "--subject", root / "analysis", "-q")
    assert code == 0, err
    meta = json.loads((root / "analysis" / "analysis.json").read_text())
    assert meta["resynthesis"]["landmark_error_px"]["mean"] < 1.0
    assert "photometric" in meta["resynthesis"]
