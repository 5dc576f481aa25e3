import pytest

from faceanalysis.io.outputs import atomic_path, prepare_output_dir, write_text_atomic


def test_prepare_refuses_non_empty_folder(tmp_path):
    (tmp_path / "contractions.csv").write_text("old")
    with pytest.raises(FileExistsError, match="--overwrite"):
        prepare_output_dir(tmp_path)
    assert (tmp_path / "contractions.csv").read_text() == "old"
    assert prepare_output_dir(tmp_path, overwrite=True) == tmp_path


def test_prepare_creates_nested_folder(tmp_path):
    out = prepare_output_dir(tmp_path / "a" / "b")
    assert out.is_dir()


def test_prepare_rejects_a_file(tmp_path):
    f = tmp_path / "f"
    f.write_text("x")
    with pytest.raises(FileExistsError, match="not a folder"):
        prepare_output_dir(f)


def test_atomic_write_leaves_old_file_on_failure(tmp_path):
    target = tmp_path / "table.csv"
    target.write_text("complete old result")
    with pytest.raises(RuntimeError), atomic_path(target) as tmp:
        tmp.write_text("half")
        raise RuntimeError("interrupted")
    assert target.read_text() == "complete old result"
    assert list(tmp_path.iterdir()) == [target]


def test_atomic_write_keeps_suffix_and_replaces(tmp_path):
    target = tmp_path / "plot.png"
    with atomic_path(target) as tmp:
        assert tmp.suffix == ".png"
        tmp.write_bytes(b"png")
    assert target.read_bytes() == b"png"
    write_text_atomic(target, "new")
    assert target.read_text() == "new"


def test_atomic_write_refuses_to_replace_special_files(tmp_path):
    import os

    import pytest

    (tmp_path / "folder.csv").mkdir()
    with pytest.raises(IsADirectoryError), atomic_path(tmp_path / "folder.csv"):
        pass
    fifo = tmp_path / "pipe.csv"
    os.mkfifo(fifo)
    with pytest.raises(ValueError, match="not a regular file"), atomic_path(fifo):
        pass
    assert not fifo.is_file() and fifo.exists()
