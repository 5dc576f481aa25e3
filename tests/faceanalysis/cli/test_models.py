"""``faceanalysis models``: where the face models are; missing models as one clear line."""

from __future__ import annotations


def test_models_without_download_in_an_empty_cache_fails_in_one_line(run_cli, tmp_path,
                                                                     monkeypatch):
    monkeypatch.setenv("FACEANALYSIS_MODELS", str(tmp_path / "models"))
    monkeypatch.delenv("FACEANALYSIS_MODEL_WHEEL", raising=False)
    code, out, err = run_cli("models", "--no-download")
    assert code == 1 and out == ""
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "missing" in lines[0] and "--wheel" in lines[0]


def test_models_from_a_missing_wheel_names_it(run_cli, tmp_path, monkeypatch):
    monkeypatch.setenv("FACEANALYSIS_MODELS", str(tmp_path / "models"))
    code, _, err = run_cli("models", "--wheel", tmp_path / "nosuch.whl")
    assert code == 1 and "nosuch.whl" in err and len(err.strip().splitlines()) == 1
