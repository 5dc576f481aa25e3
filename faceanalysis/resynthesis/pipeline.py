"""Resynthesis: :func:`resynthesize` plays a contraction time series on the face model and
renders it (004, Fig. 7c). See :mod:`faceanalysis.resynthesis.render` for how each frame is
made, :mod:`.series` for the input it accepts and :mod:`.personalize` for the subject's model."""

from __future__ import annotations

import json
import logging
import os
from pathlib import Path

import numpy as np

from faceanalysis.io.outputs import ANALYSIS_JSON
from faceanalysis.io.table import JAW, MUSCLES
from faceanalysis.resynthesis.export import MeshExporter
from faceanalysis.resynthesis.options import MESH_FORMATS, SHADINGS, VIEWS
from faceanalysis.resynthesis.personalize import SubjectInfo, personalize, personalize_series
from faceanalysis.resynthesis.render import Resynthesis
from faceanalysis.resynthesis.series import load_series, same_path

log = logging.getLogger(__name__)


def resynthesize(source, *, model=None, subject=None, size=None, view: str = "front",
                 shading: str = "textured", fps: float | None = None,
                 side_by_side: bool = False, output=None, export_meshes=None,
                 mesh_format: str = "obj", input_video=None, overwrite: bool = False,
                 tol: float = 2e-3, texture_seed: int = 0, progress: bool = False,
                 check_flow: bool = True) -> Resynthesis:
    """Drive the face model with a contraction time series and render it (004, Fig. 7c).

    Parameters
    ----------
    source : Analysis, DataFrame or path
        The time series: an :class:`~faceanalysis.analysis.pipeline.Analysis`, an analysis folder,
        a ``contractions.csv`` (all columns, validated by
        :func:`faceanalysis.io.table.read_contractions`, or a partial table holding some muscle
        columns and/or ``jaw_rotation``; missing muscles are driven at 0 with a warning
        that lists them), or a DataFrame of such columns. Rows with ``success == 0`` hold
        the last good contractions.
    model : FaceModel, optional
        Model to drive (default: the generic face).
    subject : Analysis or path, optional
        Personalise: warp the model to this subject's neutral frame (an analysis folder or
        a video) and texture it with that frame (see the module docstring).
    size : int or (width, height), optional
        Frame width (the height follows the input's aspect ratio in the input's framing),
        or an explicit size. Default: the input's size in the front view when the source
        knows it (the analysis's own scale), else 256.
    view : {'front', 'three-quarter', 'profile'}
    shading : {'textured', 'plain', 'wireframe'}
        ``wireframe`` draws the skin mesh and the muscles (004, Fig. 4), redder and thicker
        with contraction.
    fps : float, optional
        Output frame rate (default: the source's).
    side_by_side : bool
        Input frame and resynthesis side by side, the contraction plot with a cursor below.
    output : path, optional
        Write the video here (atomically) before returning.
    export_meshes : path, optional
        Folder for one mesh per frame (``mesh_format``), or a ``.npz`` file of vertex
        trajectories (``vertices`` (T, N, 3) cm, ``triangles``, ``uv``, ``frames``...).
    mesh_format : {'obj', 'ply'}
    input_video : path, optional
        The input video (side by side); default: the subject's video or the one named in
        ``analysis.json``.
    overwrite : bool
        Replace existing outputs.
    texture_seed : int
        Identity seed of the procedural skin texture (:func:`synth.render.paint_skin_texture`)
        of the ``textured`` shading without a subject.
    tol : float
        Equilibrium tolerance in cm (largest solver update; at 2e-3 cm the vertices of the
        256 px frontal view are within ~0.05 px of the converged equilibrium on average).
    progress : bool
        Progress bar on stderr.
    check_flow : bool, keyword-only
        With ``output``, when the analysed video is at hand (``input_video`` or the one
        named in ``analysis.json``) and the table has head frames: compare the video's face
        flow with the flow of the model driven by the contractions, frame by frame, as
        ``faceanalysis validate`` does (:func:`faceanalysis.flow.agreement.
        video_flow_agreement`), and add it to the report (``flow_agreement``). It measures
        the flow of the whole video once more.

    Returns
    -------
    Resynthesis
        Iterable of RGB ``uint8`` frames; ``.path`` is the video when ``output`` was given,
        ``.report`` holds personalisation figures and timings. With ``output``, the
        report is also written beside the video (``.report_path``, the video's name with
        ``.json``), and a personalisation is recorded in the subject's ``analysis.json``
        (key ``resynthesis``).

    Raises
    ------
    ValueError
        Bad options, a non-numeric cell or a value outside its range (row and column named).
    FileNotFoundError
        Missing source, subject or video.
    FileExistsError
        Outputs exist and ``overwrite`` is false.

    Examples
    --------
    >>> import pandas as pd
    >>> drive = pd.DataFrame({"zygomaticus_major_l": [0.0, 0.5], "zygomaticus_major_r": [0.0, 0.5]})
    >>> frames = list(resynthesize(drive, size=64, shading="plain"))
    >>> len(frames), frames[0].shape
    (2, (64, 64, 3))
    """
    if view not in VIEWS:
        raise ValueError(f"unknown view {view!r}; choose from {', '.join(VIEWS)}")
    if shading not in SHADINGS:
        raise ValueError(f"unknown shading {shading!r}; choose from {', '.join(SHADINGS)}")
    if mesh_format not in MESH_FORMATS:
        raise ValueError(f"unknown mesh format {mesh_format!r}; choose from "
                         f"{', '.join(MESH_FORMATS)}")
    if fps is not None and not (np.isfinite(fps) and fps > 0):
        raise ValueError(f"fps must be a positive number, got {fps!r}")
    if not (np.isfinite(tol) and tol > 0):
        raise ValueError(f"tol must be a positive number, got {tol!r}")
    if isinstance(texture_seed, bool) or not isinstance(texture_seed, (int, np.integer)) \
            or texture_seed < 0:
        raise ValueError(f"texture_seed must be a non-negative integer, got {texture_seed!r}")
    if output is not None and Path(output).exists() and not overwrite:
        raise FileExistsError(f"{output} exists; pass --overwrite (overwrite=True) to replace "
                              f"it")
    series = load_series(source)
    if input_video is not None:
        if not Path(input_video).exists():
            from faceanalysis.io.video import missing_input

            raise missing_input(input_video)
        from faceanalysis.io.report import check_analysed_input

        check_analysed_input(input_video, series.metadata.get("input"),
                             analysis=series.folder or "the table")
    if series.missing and len(series.missing) < len(MUSCLES):
        log.warning("muscles missing from the table, driven at 0: %s", ", ".join(series.missing))
    elif series.missing:
        log.warning("no muscle columns in the table: only %s drives the model", JAW)
    if model is None:
        from synth.model import FaceModel

        model = FaceModel.default()
    unknown = [m for m in model.muscle_names if m not in MUSCLES]
    if unknown:
        raise ValueError(f"the model has muscles the table format does not know: {unknown}")
    subj = None
    if isinstance(subject, SubjectInfo):
        subj = subject
    elif subject is not None:
        same = (isinstance(subject, (str, os.PathLike)) and Path(subject).is_file()
                and series.input_path is not None and series.input_path.exists()
                and same_path(series.input_path, subject))
        # the subject is the video the source analysed: its neutral frame is already tracked
        subj = (personalize_series(series, Path(subject), model=model) if same
                else personalize(subject, model=model))
    res = Resynthesis(series, model=model, subject=subj, size=size, view=view, shading=shading,
                      fps=fps, side_by_side=side_by_side, input_video=input_video, tol=tol)
    res.texture_seed = int(texture_seed)
    if output is not None:
        res.write(output, export_meshes=export_meshes, mesh_format=mesh_format,
                  overwrite=overwrite, progress=progress)
        if check_flow:
            res.report["flow_agreement"] = _flow_agreement(series, res, subj, input_video)
        res.report_path = _write_report(res, view, shading)
        if "personalisation" in res.report:
            _record_in_analysis(res, source, subject)
    elif export_meshes is not None:
        exporter = MeshExporter(export_meshes, mesh_format, res.model, overwrite, subj)
        for st in res.states(progress=progress):
            exporter.add(st, res.model)
        res.report["meshes"] = str(exporter.finish(series))
    return res


def _flow_agreement(series, res: Resynthesis, subject, input_video) -> dict:
    """The flow agreement of the resynthesis with the analysed video, for the report; a
    ``skipped`` reason when it cannot be measured."""
    from faceanalysis.flow.agreement import video_flow_agreement
    from faceanalysis.io.report import hidden_frames_of
    from faceanalysis.io.table import HEAD_COLUMNS

    video = Path(input_video) if input_video is not None else series.input_path
    table = series.table
    if video is None or not video.exists():
        return {"skipped": "the analysed video is not at hand (pass input_video / --input)"}
    if table is None or "frame" not in table.columns or \
            not all(c in table.columns for c in HEAD_COLUMNS):
        return {"skipped": "the table has no frame numbers and head frames"}
    neutral = int(series.frames[series.neutral_row])
    # the personalised model is compared as it is when it was made from this video's
    # neutral frame; otherwise the generic model's flow is warped onto the subject in 2-D
    same = (subject is not None and subject.source and Path(subject.source).exists()
            and same_path(subject.source, video))
    try:
        agree, summary, _, _ = video_flow_agreement(
            video, table, neutral=neutral, model=None if same else res.model,
            personal=res.model if same else None, hidden=hidden_frames_of(series.metadata))
    except ValueError as exc:
        return {"skipped": str(exc)}
    act = agree[agree["active"].astype(bool)]
    return {"what": "cosine and end-point error between the input video's face flow and the "
                    "resynthesis's, from the neutral frame, nuisance motion removed "
                    "(as 'faceanalysis validate'); means over active frames",
            "video": str(video), **summary,
            "per_frame": [[int(f), None if not np.isfinite(c) else round(float(c), 4)]
                          for f, c in zip(act["frame"], act["cosine"])]}


def _write_report(res: Resynthesis, view: str, shading: str) -> Path:
    """The report beside the video (``resynth.json`` for ``resynth.mp4``)."""
    from faceanalysis.io.outputs import write_text_atomic

    report = {"video": str(res.path), "frames": len(res), "fps": res.fps,
              "size": list(res.size), "view": view, "shading": shading,
              "missing_muscles": list(res.missing), **res.report}
    return write_text_atomic(res.path.with_suffix(".json"),
                             json.dumps(report, indent=1) + "\n")


def _analysis_json_for(source, subject) -> Path | None:
    """The analysis.json that records the personalisation: the subject's analysis folder,
    or the source's analysis when the subject is the video it analysed."""
    if not isinstance(subject, (str, os.PathLike)) or not isinstance(source, (str, os.PathLike)):
        return None
    subject = Path(subject)
    if subject.is_dir() and (subject / ANALYSIS_JSON).is_file():
        return subject / ANALYSIS_JSON
    src = Path(source)
    meta_path = (src if src.is_dir() else src.parent) / ANALYSIS_JSON
    if meta_path.is_file():
        try:
            analysed = json.loads(meta_path.read_text()).get("input", {}).get("path")
        except (OSError, json.JSONDecodeError):
            return None
        if same_path(analysed, subject):
            return meta_path
    return None


def _record_in_analysis(res: Resynthesis, source, subject) -> None:
    """Add the personalisation's figures to the subject's ``analysis.json``."""
    from faceanalysis.io.report import write_analysis

    meta_path = _analysis_json_for(source, subject)
    if meta_path is None:
        return
    meta = json.loads(meta_path.read_text())
    meta["resynthesis"] = {"video": str(res.path.resolve()), **res.report["personalisation"]}
    write_analysis(meta, meta_path)
