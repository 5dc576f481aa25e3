"""A run that fails before writing anything leaves no empty output folder (templates, demo,
the standard suite), and an output folder that existed before is kept."""

import pytest


def _fail(*args, **kwargs):
    raise ValueError("no face found in frame 0")


def test_a_failed_demo_leaves_no_folder(tmp_path, monkeypatch):
    import synth.render.sequence
    from faceanalysis.evaluation.demo import run_demo

    monkeypatch.setattr(synth.render.sequence, "render_sequence", _fail)
    with pytest.raises(ValueError, match="no face"):
        run_demo(tmp_path / "runs" / "demo")
    assert list(tmp_path.iterdir()) == []


def test_a_failed_suite_leaves_no_folder_but_keeps_one_that_existed(tmp_path, monkeypatch):
    import synth.render.sequence
    from faceanalysis.evaluation.suite import SuiteConfig, run_suite

    monkeypatch.setattr(synth.render.sequence, "render_sequence", _fail)
    with pytest.raises(ValueError, match="no face"):
        run_suite(tmp_path / "suite", config=SuiteConfig(identities=1, frames=4))
    assert not (tmp_path / "suite").exists()
    (tmp_path / "kept").mkdir()
    with pytest.raises(ValueError, match="no face"):
        run_suite(tmp_path / "kept", config=SuiteConfig(identities=1, frames=4))
    assert (tmp_path / "kept").is_dir()


def test_failed_templates_leave_no_folder(tmp_path, monkeypatch):
    import faceanalysis.resynthesis.templates as templates

    monkeypatch.setattr(templates, "make_templates", _fail)
    with pytest.raises(ValueError, match="no face"):
        templates.write_template_set(tmp_path / "tpl")
    assert not (tmp_path / "tpl").exists()


def test_a_folder_of_photographs_must_hold_some(tmp_path):
    from faceanalysis.evaluation.suite import photographs

    with pytest.raises(FileNotFoundError, match="no such folder"):
        photographs(tmp_path / "missing")
    (tmp_path / "notes.txt").write_text("x")
    with pytest.raises(ValueError, match="no photographs"):
        photographs(tmp_path)
    for name in ("b.JPG", "a.png"):
        (tmp_path / name).write_bytes(b"")
    assert [p.rsplit("/", 1)[-1] for p in photographs(tmp_path)] == ["a.png", "b.JPG"]
    assert len(photographs(tmp_path, limit=1)) == 1
