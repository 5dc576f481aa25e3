"""Output folders and atomic files: an interrupted run never leaves a file that looks complete.

Every file is written under a hidden temporary name beside its target
(``.<stem>.<random>.partial<suffix>``) and renamed onto the target only once it is
complete; on an exception the temporary file is removed and the target is left as it was.
New files get the usual permissions (``0o666`` less the process umask), not the ``0o600``
of :func:`tempfile.mkstemp`; a file that is replaced keeps its permissions.

This is the one atomic writer of the project (``synth`` is the lowest package that needs
one); :class:`synth.render.video.VideoWriter` writes videos through it.
"""

from __future__ import annotations

import contextlib
import os
import re
import stat
import tempfile
from collections.abc import Iterator
from pathlib import Path

__all__ = ["atomic_path", "first_missing_folder", "is_partial", "output_dir", "partial_files",
           "prepare_output_dir", "remove_new_folders", "write_bytes_atomic", "write_text_atomic"]

#: Tag of the temporary files of :func:`atomic_path`: ``.<stem>.<random>.partial<suffix>``.
PARTIAL = ".partial"
# mkstemp's random part: 8 characters of [a-z0-9_]
_PARTIAL_NAME = re.compile(r"^\..*\.[a-z0-9_]{8}\.partial(\.[^.]*)?$")
# how many names a refusal lists
_SHOWN = 5


def is_partial(path: str | os.PathLike) -> bool:
    """Whether ``path`` names a temporary file of :func:`atomic_path` (an unfinished write).

    Examples
    --------
    >>> is_partial(".overlay.k3_9xq2a.partial.mp4"), is_partial("overlay.mp4")
    (True, False)
    """
    return bool(_PARTIAL_NAME.match(Path(path).name))


def partial_files(folder: str | os.PathLike) -> list[Path]:
    """The temporary files of :func:`atomic_path` in ``folder``, left by interrupted writes.

    A run that ends normally, by an exception or by Ctrl-C (or SIGTERM in the command
    line) removes its own; these remain only after ``kill -9``, a crash or a power cut.

    Parameters
    ----------
    folder : path-like
        The folder to look in (not its subfolders).

    Returns
    -------
    list of Path
        Sorted; empty when ``folder`` does not exist.
    """
    folder = Path(folder)
    if not folder.is_dir():
        return []
    return sorted(p for p in folder.iterdir() if is_partial(p) and p.is_file()
                  and not p.is_symlink())


def _describe(names: list[str]) -> str:
    shown = ", ".join(names[:_SHOWN])
    return shown + (f" and {len(names) - _SHOWN} more" if len(names) > _SHOWN else "")


def prepare_output_dir(path: str | os.PathLike, *, overwrite: bool = False) -> Path:
    """Create ``path`` as an output folder, refusing to reuse a non-empty one.

    Parameters
    ----------
    path : path-like
        Folder to create (parents included).
    overwrite : bool, keyword-only
        Allow a folder that already holds files; they are replaced file by file as
        new results are written, never deleted up front.

    Notes
    -----
    Temporary files of :func:`atomic_path` left by an interrupted run (see
    :func:`partial_files`) are not results: a folder holding only those counts as
    empty, and they are removed (with ``overwrite`` too). Do not run two commands into
    the same folder at the same time.

    Returns
    -------
    Path
        The folder.

    Raises
    ------
    FileExistsError
        If ``path`` holds files and ``overwrite`` is false (the message names them), or
        is a file.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> d = pathlib.Path(tempfile.mkdtemp())
    >>> prepare_output_dir(d / "run" / "1").is_dir()
    True
    >>> _ = (d / "run" / "1" / "old.csv").write_text("x")
    >>> prepare_output_dir(d / "run" / "1")  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    FileExistsError: ... is not empty (it holds old.csv); pass --overwrite (overwrite=True) ...
    """
    out = Path(path)
    if out.exists() and not out.is_dir():
        raise FileExistsError(f"{out} exists and is not a folder")
    if out.is_dir():
        leftovers = set(partial_files(out))
        others = sorted(p.name for p in out.iterdir() if p not in leftovers)
        if others and not overwrite:
            raise FileExistsError(f"{out} is not empty (it holds {_describe(others)}); "
                                  f"pass --overwrite (overwrite=True) to replace "
                                  f"its results")
        for leftover in leftovers:           # unfinished writes of an interrupted run
            with contextlib.suppress(FileNotFoundError):
                leftover.unlink()
    out.mkdir(parents=True, exist_ok=True)
    return out


def first_missing_folder(path: str | os.PathLike) -> Path | None:
    """The highest folder of ``path`` (itself included) that does not exist yet, or None.

    What :func:`prepare_output_dir` is about to create, for :func:`remove_new_folders`.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> d = pathlib.Path(tempfile.mkdtemp())
    >>> first_missing_folder(d / "run" / "1") == d / "run", first_missing_folder(d)
    (True, None)
    """
    path = Path(path)
    missing = None
    for folder in (path, *path.parents):
        if folder.exists() or folder.is_symlink():
            break
        missing = folder
    return missing


def remove_new_folders(path: str | os.PathLike, created: str | os.PathLike | None) -> None:
    """Remove ``path`` and its parents up to ``created`` while they are empty.

    Used to take back the folders a run created when it fails before writing
    anything into them; a folder that holds anything (a result, a user's file) is kept,
    and so are its parents. Partial files of :func:`atomic_path` count as nothing.

    Parameters
    ----------
    path : path-like
        The output folder.
    created : path-like or None
        The highest folder that the run created (``path`` or one of its parents); None:
        the run created none, nothing is removed.
    """
    if created is None:
        return
    path, created = Path(path), Path(created)
    for folder in (path, *path.parents):
        for leftover in partial_files(folder):
            with contextlib.suppress(FileNotFoundError):
                leftover.unlink()
        try:
            folder.rmdir()
        except OSError:                     # not empty (or gone): keep it and its parents
            return
        if folder == created:
            return


@contextlib.contextmanager
def output_dir(path: str | os.PathLike, *, overwrite: bool = False) -> Iterator[Path]:
    """:func:`prepare_output_dir` for the duration of a run that writes into it.

    If the block raises (Ctrl-C included) the folders that were created for it are
    removed again while they hold nothing, so that a failed run leaves no empty folder
    behind; a folder that existed before is always kept.

    Parameters
    ----------
    path : path-like
        Folder to create (parents included).
    overwrite : bool, keyword-only
        As for :func:`prepare_output_dir`.

    Yields
    ------
    Path
        The folder.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> d = pathlib.Path(tempfile.mkdtemp())
    >>> with output_dir(d / "run" / "1") as out:
    ...     raise RuntimeError("no face found")
    Traceback (most recent call last):
    ...
    RuntimeError: no face found
    >>> list(d.iterdir())
    []
    """
    path = Path(path)
    created = first_missing_folder(path)
    out = prepare_output_dir(path, overwrite=overwrite)
    try:
        yield out
    except BaseException:
        remove_new_folders(out, created)
        raise


def _umask() -> int:
    """The process umask, read without changing it where the system allows."""
    # Linux (4.7+) reports it in /proc; os.umask can only read it by setting it, which
    # briefly changes it for every thread of the process.
    with (contextlib.suppress(OSError, ValueError, IndexError),
          open("/proc/self/status", encoding="ascii", errors="replace") as fh):
        for line in fh:
            if line.startswith("Umask:"):
                return int(line.split()[1], 8)
    old = os.umask(0o077)
    os.umask(old)
    return old


@contextlib.contextmanager
def atomic_path(target: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary path beside ``target``; rename it onto ``target`` on success.

    The temporary file keeps ``target``'s suffix so that writers that choose a
    format from the file name (OpenCV, matplotlib, pandas) still work. On any
    exception the temporary file is removed and ``target`` is left untouched.
    A ``target`` that exists but is not a regular file (a folder, a device such
    as ``/dev/null``, a FIFO) is refused rather than replaced. Missing parent
    folders are created (and removed again on an exception, while empty).

    Parameters
    ----------
    target : path-like
        The final file.

    Yields
    ------
    Path
        An empty file beside ``target`` (same folder, so the rename is atomic), with
        ``0o666`` less the umask as permissions, or those of ``target`` if it exists.

    Raises
    ------
    IsADirectoryError
        If ``target`` is a folder.
    ValueError
        If ``target`` exists and is not a regular file.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> d = pathlib.Path(tempfile.mkdtemp())
    >>> with atomic_path(d / "table.csv") as tmp:
    ...     _ = tmp.write_text("a,b\\n1,2\\n")
    >>> (d / "table.csv").read_text()
    'a,b\\n1,2\\n'
    >>> with atomic_path(d / "table.csv") as tmp:
    ...     _ = tmp.write_text("half")
    ...     raise RuntimeError("interrupted")
    Traceback (most recent call last):
    ...
    RuntimeError: interrupted
    >>> (d / "table.csv").read_text(), sorted(p.name for p in d.iterdir())
    ('a,b\\n1,2\\n', ['table.csv'])
    """
    target = Path(target)
    if target.is_dir():
        raise IsADirectoryError(f"{target} is a folder, not a file")
    if target.exists() and not target.is_file():
        # Renaming over a device, FIFO or socket would replace it with a plain file.
        raise ValueError(f"{target} exists and is not a regular file; refusing to replace it")
    try:
        mode = stat.S_IMODE(target.stat().st_mode) & 0o777
    except FileNotFoundError:
        mode = 0o666 & ~_umask()
    created = first_missing_folder(target.parent)
    target.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp_name = tempfile.mkstemp(prefix=f".{target.stem}.", suffix=f"{PARTIAL}{target.suffix}",
                                    dir=target.parent)
    tmp = Path(tmp_name)
    try:
        try:
            os.fchmod(fd, mode)                   # mkstemp creates 0o600
        finally:
            os.close(fd)
        yield tmp
        os.replace(tmp, target)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()
        remove_new_folders(target.parent, created)   # the folders made for it, if empty
        raise
    finally:
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()


def write_bytes_atomic(target: str | os.PathLike, data: bytes) -> Path:
    """Write ``data`` to ``target`` atomically (see :func:`atomic_path`).

    Parameters
    ----------
    target : path-like
        The final file.
    data : bytes-like
        The whole content.

    Returns
    -------
    Path
        ``target``.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> d = pathlib.Path(tempfile.mkdtemp())
    >>> write_bytes_atomic(d / "a.bin", b"\\x00\\x01").read_bytes()
    b'\\x00\\x01'
    """
    with atomic_path(target) as tmp:
        tmp.write_bytes(data)
    return Path(target)


def write_text_atomic(target: str | os.PathLike, text: str, *,
                      encoding: str = "utf-8") -> Path:
    """Write ``text`` to ``target`` atomically (see :func:`atomic_path`).

    The text is encoded as is: no newline translation on any platform, so the bytes
    on disk do not depend on the system.

    Parameters
    ----------
    target : path-like
        The final file.
    text : str
        The whole content.
    encoding : str, keyword-only
        UTF-8 by default (not the locale's encoding).

    Returns
    -------
    Path
        ``target``.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> d = pathlib.Path(tempfile.mkdtemp())
    >>> write_text_atomic(d / "notes" / "a.txt", "µm\\n").read_bytes()
    b'\\xc2\\xb5m\\n'
    """
    return write_bytes_atomic(target, text.encode(encoding))
