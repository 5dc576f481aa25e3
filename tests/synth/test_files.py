import os
import stat

import pytest

from synth import files
from synth.files import atomic_path, prepare_output_dir, write_bytes_atomic, write_text_atomic


@pytest.fixture
def umask():
    """Set the process umask for one test and restore it afterwards."""
    old = os.umask(0o022)
    os.umask(old)

    def _set(value):
        os.umask(value)

    yield _set
    os.umask(old)


def _mode(path):
    return stat.S_IMODE(path.stat().st_mode)


# -- atomic_path -------------------------------------------------------------------------

def test_exception_leaves_the_old_file_and_no_temporary(tmp_path):
    target = tmp_path / "table.csv"
    target.write_text("complete old result")
    with pytest.raises(RuntimeError), atomic_path(target) as tmp:
        tmp.write_text("half")
        raise RuntimeError("interrupted")
    assert target.read_text() == "complete old result"
    assert list(tmp_path.iterdir()) == [target]


def test_interrupt_of_a_new_file_leaves_nothing(tmp_path):
    with pytest.raises(KeyboardInterrupt), atomic_path(tmp_path / "new.csv") as tmp:
        tmp.write_text("half")
        raise KeyboardInterrupt
    assert list(tmp_path.iterdir()) == []


def test_temporary_is_hidden_beside_the_target_with_its_suffix(tmp_path):
    target = tmp_path / "sub" / "plot.png"            # missing folders are created
    with atomic_path(target) as tmp:
        assert tmp.parent == target.parent and tmp.name.startswith(".plot.")
        assert tmp.suffix == ".png" and tmp.exists() and not target.exists()
        tmp.write_bytes(b"png")
    assert target.read_bytes() == b"png"
    assert [p.name for p in target.parent.iterdir()] == ["plot.png"]


def test_refuses_a_folder_and_special_files(tmp_path):
    (tmp_path / "folder.csv").mkdir()
    with pytest.raises(IsADirectoryError), atomic_path(tmp_path / "folder.csv"):
        pass
    fifo = tmp_path / "pipe.csv"
    os.mkfifo(fifo)
    with pytest.raises(ValueError, match="not a regular file"), atomic_path(fifo):
        pass
    assert fifo.exists() and not fifo.is_file()
    with pytest.raises(ValueError, match="not a regular file"):
        write_text_atomic(fifo, "x")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["folder.csv", "pipe.csv"]


@pytest.mark.parametrize(("mask", "expected"), [(0o022, 0o644), (0o027, 0o640)])
def test_new_files_follow_the_umask(tmp_path, umask, mask, expected):
    umask(mask)
    assert _mode(write_text_atomic(tmp_path / "a.txt", "a")) == expected
    with atomic_path(tmp_path / "b.bin") as tmp:
        assert _mode(tmp) == expected
    assert _mode(tmp_path / "b.bin") == expected
    assert files._umask() == mask


def test_umask_without_proc(tmp_path, umask, monkeypatch):
    umask(0o027)

    def no_proc(*args, **kwargs):
        raise OSError("no /proc here")

    monkeypatch.setattr(files, "open", no_proc, raising=False)
    assert files._umask() == 0o027
    assert _mode(write_bytes_atomic(tmp_path / "a.bin", b"a")) == 0o640
    assert os.umask(0o027) == 0o027                  # and the umask was restored


def test_a_replaced_file_keeps_its_permissions(tmp_path, umask):
    umask(0o022)
    target = tmp_path / "secret.json"
    target.write_text("{}")
    target.chmod(0o600)
    write_text_atomic(target, '{"a": 1}')
    assert _mode(target) == 0o600 and target.read_text() == '{"a": 1}'


# -- write_*_atomic ----------------------------------------------------------------------

def test_write_text_and_bytes(tmp_path):
    target = tmp_path / "notes.txt"
    assert write_text_atomic(target, "µm\r\nx\n") == target
    assert target.read_bytes() == "µm\r\nx\n".encode()        # UTF-8, no translation
    write_text_atomic(target, "é", encoding="latin-1")
    assert target.read_bytes() == b"\xe9"
    assert write_bytes_atomic(str(target), b"\x00") == target   # str accepted, replaced
    assert target.read_bytes() == b"\x00"
    assert [p.name for p in tmp_path.iterdir()] == ["notes.txt"]


def test_failed_encoding_leaves_nothing(tmp_path):
    with pytest.raises(UnicodeEncodeError):
        write_text_atomic(tmp_path / "a.txt", "µ", encoding="ascii")
    assert list(tmp_path.iterdir()) == []


# -- prepare_output_dir ------------------------------------------------------------------

def test_prepare_refuses_non_empty_folder(tmp_path):
    (tmp_path / "contractions.csv").write_text("old")
    with pytest.raises(FileExistsError, match="--overwrite"):
        prepare_output_dir(tmp_path)
    assert (tmp_path / "contractions.csv").read_text() == "old"
    assert prepare_output_dir(tmp_path, overwrite=True) == tmp_path
    assert (tmp_path / "contractions.csv").read_text() == "old"


def test_prepare_creates_nested_folder_and_rejects_a_file(tmp_path):
    assert prepare_output_dir(tmp_path / "a" / "b").is_dir()
    f = tmp_path / "f"
    f.write_text("x")
    with pytest.raises(FileExistsError, match="not a folder"):
        prepare_output_dir(f, overwrite=True)


def test_prepare_takes_a_folder_of_partial_leftovers_as_empty_and_removes_them(tmp_path):
    leftovers = [tmp_path / ".overlay.ab_12xyz.partial.mp4", tmp_path / ".table.k3k3k3k3.partial"]
    for p in leftovers:
        p.write_bytes(b"half")
    assert files.partial_files(tmp_path) == sorted(leftovers)
    assert prepare_output_dir(tmp_path) == tmp_path
    assert list(tmp_path.iterdir()) == []


def test_prepare_refusal_names_the_contents_and_touches_nothing(tmp_path):
    names = [".hidden", "a.csv", "b.png", "c", "d", "e", "f"]
    for name in names:
        (tmp_path / name).write_text("x")
    (tmp_path / ".a.abcdefgh.partial.csv").write_text("half")
    with pytest.raises(FileExistsError) as info:
        prepare_output_dir(tmp_path)
    assert str(info.value) == (f"{tmp_path} is not empty (it holds .hidden, a.csv, b.png, c, d "
                               f"and 2 more); pass --overwrite (overwrite=True) to replace its "
                               f"results")
    assert len(list(tmp_path.iterdir())) == 8
    prepare_output_dir(tmp_path, overwrite=True)            # results kept, leftover gone
    assert sorted(p.name for p in tmp_path.iterdir()) == names


def test_partial_names_are_those_of_atomic_path_only(tmp_path):
    with atomic_path(tmp_path / "overlay.mp4") as tmp:
        assert files.is_partial(tmp)
    for name in ("overlay.mp4", ".partial", "notes.partial.txt", ".my.partial.mp4",
                 ".a.partial-0123456789ab"):
        assert not files.is_partial(name), name


def test_output_dir_removes_the_folders_it_created_when_the_run_fails(tmp_path):
    with pytest.raises(KeyboardInterrupt), files.output_dir(tmp_path / "a" / "b") as out, \
            atomic_path(out / "half.csv") as tmp:
        tmp.write_text("half")
        raise KeyboardInterrupt
    assert list(tmp_path.iterdir()) == []
    with pytest.raises(RuntimeError), files.output_dir(tmp_path / "a" / "b") as out:
        write_text_atomic(out / "done.csv", "a result")
        raise RuntimeError("later step failed")
    assert (tmp_path / "a" / "b" / "done.csv").is_file()            # kept with its result
    (tmp_path / "c").mkdir()
    with pytest.raises(RuntimeError), files.output_dir(tmp_path / "c"):
        raise RuntimeError("failed")
    assert (tmp_path / "c").is_dir()                                # existed before


def test_atomic_path_removes_the_parents_it_created_on_failure(tmp_path):
    with pytest.raises(RuntimeError), atomic_path(tmp_path / "x" / "y" / "v.mp4"):
        raise RuntimeError("no frame")
    assert list(tmp_path.iterdir()) == []
