import sys

from faceanalysis.io.cache import cache_dir, source_digest


def test_source_digest_follows_the_code(tmp_path, monkeypatch):
    pkg = tmp_path / "fa_digest_probe"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("x = 1\n")
    (pkg / "muscles.toml").write_text("a = 1\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    sys.modules.pop("fa_digest_probe", None)
    before = source_digest(("fa_digest_probe",))
    source_digest.cache_clear()
    (pkg / "muscles.toml").write_text("a = 2\n")      # data files count, not only code
    after = source_digest(("fa_digest_probe",))
    source_digest.cache_clear()
    assert before != after
    assert source_digest(("fa_digest_probe",)) == after


def test_cache_dir_honours_the_environment(tmp_path, monkeypatch):
    monkeypatch.setenv("FACEANALYSIS_CACHE", str(tmp_path))
    assert cache_dir() == tmp_path
