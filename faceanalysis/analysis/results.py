"""The output folder of an analysis: one place for file names and how each file is written.

:class:`OutputFolder` checks the folder when it is created (so that a run fails
before any work if ``OUT`` holds results and ``overwrite`` is false), then writes
each result atomically: ``contractions.csv``, ``analysis.json``,
``contractions.png`` and, on request, ``overlay.mp4``.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path

import pandas as pd

from faceanalysis.io.outputs import prepare_output_dir
from faceanalysis.viz.plots import plot_contractions
from faceanalysis.io.report import write_analysis
from faceanalysis.io.table import write_contractions
from faceanalysis.io.video_writer import VideoWriter

__all__ = ["OutputFolder"]


class OutputFolder:
    """Results of one analysis, written atomically into ``path``.

    Parameters
    ----------
    path : path-like
        Output folder (created with its parents).
    overwrite : bool, keyword-only
        Allow a folder that already holds files; they are replaced one by one.

    Raises
    ------
    FileExistsError
        If ``path`` holds files and ``overwrite`` is false, or is a file.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> from faceanalysis.io.table import empty_table
    >>> out = OutputFolder(pathlib.Path(tempfile.mkdtemp()) / "run")
    >>> t = empty_table(3, timestamps=[0, 0.04, 0.08])
    >>> sorted(p.name for p in out.write(t, {"format": "example"}).values())
    ['analysis.json', 'contractions.csv', 'contractions.png']
    """

    CONTRACTIONS = "contractions.csv"
    ANALYSIS = "analysis.json"
    PLOT = "contractions.png"
    OVERLAY = "overlay.mp4"

    def __init__(self, path: str | os.PathLike, *, overwrite: bool = False):
        self.path = prepare_output_dir(path, overwrite=overwrite)

    @property
    def contractions_csv(self) -> Path:
        return self.path / self.CONTRACTIONS

    @property
    def analysis_json(self) -> Path:
        return self.path / self.ANALYSIS

    @property
    def contractions_png(self) -> Path:
        return self.path / self.PLOT

    @property
    def overlay_mp4(self) -> Path:
        return self.path / self.OVERLAY

    def overlay_writer(self, fps: float, size: tuple[int, int]) -> VideoWriter:
        """An atomic :class:`~faceanalysis.io.video_writer.VideoWriter` for ``overlay.mp4``."""
        return VideoWriter(self.overlay_mp4, fps, size)

    def write(self, table: pd.DataFrame, metadata: Mapping, *, plot: bool = True,
              title: str | None = None) -> dict[str, Path]:
        """Write the table, the metadata and (by default) the plot; returns their paths.

        The table is validated before anything is written, so a bad table
        leaves no new file behind.
        """
        paths = {"contractions": write_contractions(table, self.contractions_csv)}
        if plot:
            fig = plot_contractions(table, self.contractions_png, title=title)
            fig.clear()
            paths["plot"] = self.contractions_png
        paths["analysis"] = write_analysis(metadata, self.analysis_json)
        return paths
