"""The result of an analysis and its output folder.

:class:`Analysis` holds the table, the metadata and what led to them.
:class:`OutputFolder` checks the folder when it is created (so that a run fails
before any work if ``OUT`` holds results and ``overwrite`` is false), then writes
each result atomically: ``contractions.csv``, ``analysis.json``,
``contractions.png`` and, on request, ``overlay.mp4``. Used as a context manager
around a run, it removes the folder again if the run fails before writing into it,
and after a run with ``overwrite`` the earlier run's files that were not written again.
"""

from __future__ import annotations

import contextlib
import os
import stat
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from faceanalysis.estimation.calibration import Calibration
from faceanalysis.estimation.registry import Estimate
from faceanalysis.estimation.response import FiducialResponse
from faceanalysis.io.outputs import (
    ANALYSIS_JSON,
    ANALYSIS_OUTPUTS,
    CONTRACTIONS_CSV,
    CONTRACTIONS_PNG,
    OVERLAY_MP4,
    first_missing_folder,
    prepare_output_dir,
    remove_new_folders,
)
from faceanalysis.io.report import input_name, summary_line, write_analysis
from faceanalysis.io.table import (
    FIDUCIALS,
    JAW,
    MUSCLES,
    head_turn,
    measured_values,
    write_contractions,
)
from faceanalysis.io.video import is_photographs
from faceanalysis.tracking import Tracks
from faceanalysis.viz.plots import plot_contractions
from synth.render.video import VideoWriter

__all__ = ["Analysis", "OutputFolder"]


@dataclass
class Analysis:
    """The result of :func:`~faceanalysis.analysis.pipeline.analyze`.

    Attributes
    ----------
    table : DataFrame
        One row per frame, the columns of ``contractions.csv`` (see
        :func:`faceanalysis.io.table.contraction_columns`).
    contours : list of dict or None
        Per frame, contour name -> (n, 2) node positions in pixels (None for frames
        that could not be decoded).
    metadata : dict
        The content of ``analysis.json``.
    calibration : Calibration
        The neutral-frame calibration.
    response : FiducialResponse
        The model response of the 16 contour points (the calibration's; the estimators
        that read more points carry theirs in ``estimate``).
    measurements : ndarray, shape (T, P, 2)
        Image positions of the response's measurement points (the 11 fiducials and
        the lower lip's centre) per frame; NaN for lost frames.
    fit_residual : ndarray, shape (T,)
        Per frame, the root-mean-square distance in model cm between the measured
        point displacements and the face model's prediction at the estimate (see
        :data:`faceanalysis.analysis.pipeline.MAX_FIT_RESIDUAL`); NaN for lost frames.
    track_confidence : ndarray, shape (T,)
        The tracker's confidence alone; the table's ``confidence`` is its minimum with
        ``MAX_FIT_RESIDUAL / fit_residual``.
    tracks : Tracks or None
        What the tracker saw (:func:`faceanalysis.tracking.track`).
    mirrored_tracks : Tracks or None
        What it saw in the video mirrored, with ``mirror_check`` (else None).
    estimate : Estimate or None
        What the estimator fitted (:class:`~faceanalysis.estimation.registry.Estimate`):
        the response table of the points it read (``estimate.response.fiducials``, e.g.
        the contour points and the face mesh's), their displacements from the neutral
        frame in model cm (``estimate.displacements``, x = subject's left, y up) and its
        values before the table's post-processing.
    """

    table: pd.DataFrame
    contours: list
    metadata: dict
    calibration: Calibration | None = None
    response: FiducialResponse | None = None
    measurements: np.ndarray | None = None
    timings: dict = field(default_factory=dict)
    fit_residual: np.ndarray | None = None
    track_confidence: np.ndarray | None = None
    tracks: Tracks | None = None
    mirrored_tracks: Tracks | None = None
    estimate: Estimate | None = None

    def __repr__(self) -> str:
        # a summary, not the fields: their repr grows with the video (a 100-frame clip's
        # contours alone print 2 MB), which stalls a notebook that shows the result
        meta = self.metadata or {}
        params = meta.get("parameters") or {}
        methods = ", ".join(f"{params[key]} {key}" for key in ("tracker", "estimator")
                            if params.get(key))
        return (f"<Analysis of {input_name(meta.get('input'))}: "
                f"{summary_line(meta, len(self.table))}"
                f"{'; ' + methods if methods else ''}>")

    @property
    def fiducials(self) -> np.ndarray:
        """Tracked fiducials, shape (T, 11, 2), pixels; NaN for lost frames."""
        cols = [c for name in FIDUCIALS for c in (f"fid_{name}_x", f"fid_{name}_y")]
        return self.table[cols].to_numpy(float).reshape(len(self.table), len(FIDUCIALS), 2)

    @property
    def contractions(self) -> pd.DataFrame:
        """Muscle columns and ``jaw_rotation``, indexed by frame."""
        return self.table.set_index("frame")[[*MUSCLES, JAW]]

    @property
    def measured(self) -> pd.DataFrame:
        """Muscle columns, ``jaw_rotation`` and the action units, indexed by frame, empty
        where the value is not measured (lost frames, ``<column>_identifiable`` 0; see
        :func:`~faceanalysis.io.table.measured_values`)."""
        return measured_values(self.table).set_index(self.table["frame"])

    def plot(self, path: str | os.PathLike | None = None, **kwargs):
        """The time-series plot (like Fig. 8 of 004); saved to ``path`` if given. Controls
        the points cannot tell apart are drawn faded."""
        return plot_contractions(self.table, path,
                                 **{**_plot_options(self.table, self.metadata), **kwargs})

    def save(self, output: str | os.PathLike, *, overwrite: bool = False) -> dict[str, Path]:
        """Write ``contractions.csv``, ``analysis.json`` and ``contractions.png`` to ``output``."""
        with OutputFolder(output, overwrite=overwrite) as folder:
            return folder.write(self.table, self.metadata,
                                title=input_name(self.metadata.get("input")))


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

    Notes
    -----
    Used as a context manager (``with OutputFolder(out) as folder: ...``) around the
    run that fills it: if the block raises, the folders created for it are removed
    again while they hold nothing (see :func:`~synth.files.remove_new_folders`); if it
    succeeds, the toolkit's files of an earlier run (:data:`ANALYSIS_OUTPUTS`:
    an overlay, a validation of the earlier results...) that the block did not write
    again are removed (:meth:`remove_stale`), so that the folder describes one run.
    Other files are never touched. Temporary files of an interrupted earlier run are
    removed when the folder is opened (:func:`~synth.files.prepare_output_dir`).

    Examples
    --------
    >>> import tempfile, pathlib
    >>> from faceanalysis.io.table import empty_table
    >>> out = OutputFolder(pathlib.Path(tempfile.mkdtemp()) / "run")
    >>> t = empty_table(3, timestamps=[0, 0.04, 0.08])
    >>> sorted(p.name for p in out.write(t, {"format": "example"}).values())
    ['analysis.json', 'contractions.csv', 'contractions.png']
    """

    CONTRACTIONS = CONTRACTIONS_CSV
    ANALYSIS = ANALYSIS_JSON
    PLOT = CONTRACTIONS_PNG
    OVERLAY = OVERLAY_MP4

    def __init__(self, path: str | os.PathLike, *, overwrite: bool = False):
        self._created = first_missing_folder(path)
        self.path = prepare_output_dir(path, overwrite=overwrite)
        # the toolkit's files already there: those still identical after the run are stale
        self._before = {name: ident for name in ANALYSIS_OUTPUTS
                        if (ident := _identity(self.path / name)) is not None}

    def __enter__(self) -> OutputFolder:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.remove_stale()
        else:
            remove_new_folders(self.path, self._created)

    def remove_stale(self) -> list[Path]:
        """Remove the toolkit's files that were here before and were not written again.

        Returns
        -------
        list of Path
            The files removed (an earlier run's ``overlay.mp4``, ``validation.*``...).
        """
        removed = []
        for name, before in self._before.items():
            path = self.path / name
            if _identity(path) == before:
                with contextlib.suppress(FileNotFoundError):
                    path.unlink()
                    removed.append(path)
        self._before = {}
        return removed

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
        """An atomic :class:`~synth.render.video.VideoWriter` of BGR frames for
        ``overlay.mp4``."""
        return VideoWriter(self.overlay_mp4, fps, size, channel_order="bgr")

    def write(self, table: pd.DataFrame, metadata: Mapping, *, plot: bool = True,
              title: str | None = None) -> dict[str, Path]:
        """Write the table, the metadata and (by default) the plot; returns their paths.

        The table is validated before anything is written, so a bad table
        leaves no new file behind.
        """
        paths = {"contractions": write_contractions(table, self.contractions_csv)}
        if plot:
            fig = plot_contractions(table, self.contractions_png, title=title,
                                    **_plot_options(table, metadata))
            fig.clear()
            paths["plot"] = self.contractions_png
        paths["analysis"] = write_analysis(metadata, self.analysis_json)
        return paths


def _identity(path: Path) -> tuple | None:
    """What tells a regular file from the one written in its place (None: no such file)."""
    try:
        st = path.lstat()
    except (FileNotFoundError, NotADirectoryError):
        return None
    if not stat.S_ISREG(st.st_mode):
        return None                  # a link or a folder of the user's: never removed
    return st.st_dev, st.st_ino, st.st_mtime_ns, st.st_size


def _plot_options(table: pd.DataFrame, metadata: Mapping) -> dict:
    """What ``analysis.json`` tells :func:`~faceanalysis.viz.plots.plot_contractions`: the
    controls to fade, the turned heads to hatch, why frames were lost, the shot cuts, and
    whether the rows are photographs."""
    meta = metadata if isinstance(metadata, Mapping) else {}
    quality = meta.get("quality") or {}
    return {"not_identifiable": _not_identifiable(meta), "turned": _turned(table, meta),
            "lost_reasons": quality.get("lost_reasons"),
            "cuts": quality.get("shot_cuts") or (),
            "photographs": is_photographs(meta.get("input"))}


def _turned(table: pd.DataFrame, metadata: Mapping) -> np.ndarray | None:
    """Per row, whether the head is turned beyond ``analysis.json``'s
    ``model_fit.head_turn.limit_deg`` from the neutral frame's pose (None: not known)."""
    if not isinstance(metadata, Mapping):
        return None
    fit = metadata.get("model_fit")
    limit = (fit.get("head_turn") or {}).get("limit_deg") if isinstance(fit, Mapping) else None
    neutral = (metadata.get("parameters") or {}).get("neutral_frame")
    if limit is None or neutral is None:
        return None
    with np.errstate(invalid="ignore"):
        return head_turn(table, neutral) > float(limit)


def _not_identifiable(metadata: Mapping) -> tuple[str, ...]:
    """The controls ``analysis.json`` says the points cannot tell apart."""
    ident = metadata.get("identifiability") if isinstance(metadata, Mapping) else None
    return tuple(ident.get("not_identifiable", ())) if isinstance(ident, Mapping) else ()
