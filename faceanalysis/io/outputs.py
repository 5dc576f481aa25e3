"""Output folders and atomic files: an interrupted run never leaves a file that looks complete."""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path

#: File names of an analysis folder (``faceanalysis analyze VIDEO -o OUT``).
CONTRACTIONS_CSV = "contractions.csv"
ANALYSIS_JSON = "analysis.json"
CONTRACTIONS_PNG = "contractions.png"
OVERLAY_MP4 = "overlay.mp4"
#: ``faceanalysis validate`` adds these to the analysis folder.
VALIDATION_CSV = "validation.csv"
VALIDATION_PNG = "validation.png"
#: ``faceanalysis demo``'s score of its analysis.
EVALUATION_JSON = "evaluation.json"
#: ``faceanalysis evaluate --suite``'s report.
REPORT_JSON = "report.json"
REPORT_MD = "report.md"
REPORT_PNG = "report.png"
#: ``faceanalysis batch``'s table of every video.
SUMMARY_CSV = "summary.csv"



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
    """
    out = Path(path)
    if out.exists() and not out.is_dir():
        raise FileExistsError(f"{out} exists and is not a folder")
    if out.is_dir() and any(out.iterdir()) and not overwrite:
        raise FileExistsError(f"{out} is not empty; pass --overwrite to replace its results")
    out.mkdir(parents=True, exist_ok=True)
    return out


@contextlib.contextmanager
def atomic_path(target: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary path beside ``target``; rename it onto ``target`` on success.

    The temporary file keeps ``target``'s suffix so that writers that choose a
    format from the file name (OpenCV, matplotlib, pandas) still work. On any
    exception the temporary file is removed and ``target`` is left untouched.
    A ``target`` that exists but is not a regular file (a folder, a device such
    as ``/dev/null``, a FIFO) is refused rather than replaced.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> d = pathlib.Path(tempfile.mkdtemp())
    >>> with atomic_path(d / "table.csv") as tmp:
    ...     _ = tmp.write_text("a,b\\n1,2\\n")
    >>> (d / "table.csv").read_text()
    'a,b\\n1,2\\n'
    """
    target = Path(target)
    if target.is_dir():
        raise IsADirectoryError(f"{target} is a folder, not a file")
    if target.exists() and not target.is_file():
        # Renaming over a device, FIFO or socket would replace it with a plain file.
        raise ValueError(f"{target} exists and is not a regular file; refusing to replace it")
    target.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp_name = tempfile.mkstemp(prefix=f".{target.stem}.", suffix=f".partial{target.suffix}",
                                    dir=target.parent)
    os.close(fd)
    tmp = Path(tmp_name)
    try:
        yield tmp
        os.replace(tmp, target)
    finally:
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()


def write_text_atomic(target: str | os.PathLike, text: str) -> Path:
    """Write ``text`` to ``target`` atomically and return the path."""
    with atomic_path(target) as tmp:
        tmp.write_text(text)
    return Path(target)
