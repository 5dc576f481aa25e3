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
import stat
import tempfile
from collections.abc import Iterator
from pathlib import Path

__all__ = ["atomic_path", "prepare_output_dir", "write_bytes_atomic", "write_text_atomic"]


def prepare_output_dir(path: str | os.PathLike, *, overwrite: bool = False) -> Path:
    """Create ``path`` as an output folder, refusing to reuse a non-empty one.

    Parameters
    ----------
    path : path-like
        Folder to create (parents included).
    overwrite : bool, keyword-only
        Allow a folder that already holds files; they are replaced file by file as
        new results are written, never deleted up front.

    Returns
    -------
    Path
        The folder.

    Raises
    ------
    FileExistsError
        If ``path`` holds files and ``overwrite`` is false, or is a file.

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
    FileExistsError: ... is not empty; pass --overwrite to replace its results
    """
    out = Path(path)
    if out.exists() and not out.is_dir():
        raise FileExistsError(f"{out} exists and is not a folder")
    if out.is_dir() and any(out.iterdir()) and not overwrite:
        raise FileExistsError(f"{out} is not empty; pass --overwrite to replace its results")
    out.mkdir(parents=True, exist_ok=True)
    return out


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
    folders are created.

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
    target.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp_name = tempfile.mkstemp(prefix=f".{target.stem}.", suffix=f".partial{target.suffix}",
                                    dir=target.parent)
    tmp = Path(tmp_name)
    try:
        try:
            os.fchmod(fd, mode)                   # mkstemp creates 0o600
        finally:
            os.close(fd)
        yield tmp
        os.replace(tmp, target)
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
