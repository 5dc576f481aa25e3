"""Flow validation of an analysis: does the resynthesis move like the input?

The input's face flow (:func:`faceanalysis.flow.dense.video_face_flow`, from the neutral frame, in
the head frame, on the face grid) is compared frame by frame with the flow of the
*resynthesis*: the face model driven by the analysed contractions, rendered, and its exact
image-plane motion from rest taken onto the same grid (:class:`faceanalysis.flow.templates.
ModelView`). The resynthesis is personalised, so that features line up with the subject's: by
default the face model itself is warped to the subject's neutral frame
(:func:`faceanalysis.resynthesis.personalize.personalize`, the 3-D landmark warp of Kähler,
ch. 8); where
that is not possible, the generic resynthesis flow is warped onto the subject's neutral
fiducials in 2-D (:class:`faceanalysis.flow.personalize.SubjectWarp`).

The input's flow is smoothed over time (Gaussian, one frame by default: each frame's flow
is measured on its own, so its noise is independent from frame to frame while faces move
smoothly). The comparison itself (nuisance motions projected out, ``cosine`` and ``epe``
per frame and face region, the summary over the active frames) is
:mod:`faceanalysis.flow.agreement`, which the ``resynth`` report shares.
"""

from __future__ import annotations

import json
import logging
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from faceanalysis.flow.agreement import (
    flow_agreement,
    resynthesis_flow,
    summarize,
    video_flow_agreement,
)
from faceanalysis.flow.templates import REGION_GROUPS, FlowTemplates
from faceanalysis.io.outputs import ANALYSIS_JSON, CONTRACTIONS_CSV, VALIDATION_CSV, VALIDATION_PNG
from faceanalysis.resynthesis.personalize import personal_model

log = logging.getLogger(__name__)

__all__ = ["flow_agreement", "resynthesis_flow", "validate", "ValidationResult",
           "plot_agreement", "shuffled", "summarize", "evaluate_validation"]


def shuffled(contractions: pd.DataFrame, seed: int = 0) -> pd.DataFrame:
    """The rows of ``contractions`` in a random order (a deliberately wrong resynthesis)."""
    rng = np.random.default_rng(seed)
    order = rng.permutation(len(contractions))
    out = contractions.iloc[order].reset_index(drop=True)
    if "frame" in contractions.columns:
        out["frame"] = contractions["frame"].to_numpy()
    return out


@dataclass
class ValidationResult:
    """Per-frame agreement (:func:`flow_agreement`) and its summary."""

    table: pd.DataFrame
    summary: dict
    observed: np.ndarray | None = None
    predicted: np.ndarray | None = None
    paths: dict = field(default_factory=dict)


def plot_agreement(table: pd.DataFrame, path=None, *, title: str | None = None):
    """Cosine and end-point error per frame (face and regions); saved to ``path`` if given."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(8, 7))
    ax1, ax2, ax3 = fig.subplots(3, 1, sharex=True)
    x = table["frame"].to_numpy()
    for name in REGION_GROUPS:
        if f"cosine_{name}" in table:
            ax1.plot(x, table[f"cosine_{name}"], lw=0.8, alpha=0.7, label=name)
    ax1.plot(x, table["cosine"], "k", lw=1.8, label="face")
    ax1.set_ylabel("cosine")
    ax1.set_ylim(-1.05, 1.05)
    ax1.legend(fontsize=7, ncol=4, loc="lower right")
    inactive = ~table["active"].astype(bool).to_numpy()
    for ax in (ax1, ax2):
        ax.fill_between(x, 0, 1, where=inactive, transform=ax.get_xaxis_transform(),
                        color="0.9", step="mid", lw=0)
    ax2.plot(x, table["epe"], "k", lw=1.5)
    ax2.set_ylabel("end-point error\n(head units)")
    ax3.plot(x, table["energy_observed"], label="input")
    ax3.plot(x, table["energy_predicted"], label="resynthesis")
    ax3.set_ylabel("RMS motion\n(head units)")
    ax3.set_xlabel("frame")
    ax3.legend(fontsize=7)
    fig.suptitle(title or "flow agreement: input vs resynthesis (grey: inactive frames)",
                 fontsize=9)
    fig.tight_layout()
    if path is not None:
        from faceanalysis.io.outputs import atomic_path

        with atomic_path(Path(path)) as tmp:
            fig.savefig(tmp, dpi=110, format="png")
    return fig


def validate(video: str | os.PathLike, analysis: str | os.PathLike, *,
             method: str = "dis", model=None, templates: FlowTemplates | None = None,
             personalised: bool = True, contractions: pd.DataFrame | None = None,
             write: bool = True, fps: float | None = None,
             temporal_sigma: float = 1.0) -> ValidationResult:
    """Compare the flow of a video with the flow of its analysis's resynthesis.

    Parameters
    ----------
    video : path-like
        The analysed video.
    analysis : path-like
        The analysis output folder (``contractions.csv``, ``analysis.json``).
    method : {'dis', 'farneback', 'tvl1'}
        Flow of the input.
    model : FaceModel-like, optional
        Model of the resynthesis (default: the generic face).
    templates : FlowTemplates, optional
        Mask, regions and nuisance motions (default: the generic templates).
    personalised : bool or {'model', 'warp'}
        Personalise the resynthesis: ``True``/``'model'``: the face model warped to the
        subject's neutral frame (:func:`faceanalysis.resynthesis.personalize.personalize`,
        3-D), falling
        back to ``'warp'``: the generic resynthesis flow warped onto the subject's neutral
        fiducials in 2-D (:class:`faceanalysis.flow.personalize.SubjectWarp`). ``False``: the
        generic face as it is.
    contractions : DataFrame, optional
        Drive the resynthesis with these instead of the analysis's (e.g. :func:`shuffled`).
    write : bool
        Write ``validation.csv`` and ``validation.png`` into the analysis folder and add the
        summary to its ``analysis.json`` (key ``validation``).
    temporal_sigma : float
        Gaussian smoothing of the input flow over time (frames; 0 = none). Each frame's
        flow is measured on its own, so its noise is independent from frame to frame while
        the face moves smoothly; one frame of smoothing halves the noise's variance.

    Returns
    -------
    ValidationResult
    """
    from faceanalysis.io.report import check_analysed_input, hidden_frames_of
    from faceanalysis.io.table import heads_from_table, read_contractions

    folder = Path(analysis)
    csv = folder / CONTRACTIONS_CSV
    if not csv.is_file():
        raise FileNotFoundError(f"{csv}: no contractions.csv in the analysis folder")
    table = read_contractions(csv)
    meta_path = folder / ANALYSIS_JSON
    meta = json.loads(meta_path.read_text()) if meta_path.is_file() else {}
    check_analysed_input(video, meta.get("input"), analysis=folder)
    neutral = meta.get("parameters", {}).get("neutral_frame")
    heads = heads_from_table(table)
    ok = np.isfinite(heads).all(axis=1)
    if not ok.any():
        raise ValueError(f"{csv}: no tracked frame")
    frames = table["frame"].to_numpy(int)
    if neutral is None or int(neutral) not in set(frames[ok].tolist()):
        neutral = int(frames[np.argmax(ok)])
    if templates is None:
        from faceanalysis.flow.templates import default_templates

        templates = default_templates(model)
    if model is None:
        from synth.model import FaceModel

        model = FaceModel.default()
    personal = personal_model(folder, model) if personalised == "model" or \
        personalised is True else None
    agree, summary, o, pred = video_flow_agreement(
        video, table, neutral=int(neutral), model=model, personal=personal,
        contractions=contractions, templates=templates, method=method, fps=fps,
        personalised=bool(personalised), temporal_sigma=temporal_sigma,
        hidden=hidden_frames_of(meta))
    summary.update(resynthesis="shuffled/override" if contractions is not None
                   else "analysis")
    result = ValidationResult(agree, summary, o, pred)
    if write:
        from faceanalysis.io.outputs import write_text_atomic
        from faceanalysis.io.report import write_analysis

        result.paths["table"] = write_text_atomic(
            folder / VALIDATION_CSV, agree.to_csv(index=False, float_format="%.6f",
                                                    lineterminator="\n"))
        plot_agreement(agree, folder / VALIDATION_PNG)
        result.paths["plot"] = folder / VALIDATION_PNG
        meta["validation"] = summary
        result.paths["analysis"] = write_analysis(meta, meta_path)
    return result


def evaluate_validation(identities=range(101, 104), expressions=("happiness", "surprise",
                                                                    "anger", "sadness"), *,
                        frames: int = 40, size: int = 256, head_motion: float = 0.3,
                        illumination: float = 0.3, noise: float = 2.0,
                        templates: FlowTemplates | None = None, workdir=None,
                        shuffle_seed: int = 0) -> dict:
    """Flow agreement on synthetic sequences analysed by the toolkit.

    Every sequence (identity x expression, with head motion, light change and noise; by
    default at the levels of the standard evaluation suite) is rendered, analysed by
    :func:`faceanalysis.analysis.pipeline.analyze` (``joint`` estimator) and validated three ways:
    the resynthesis of the analysis itself, of the ``flow`` estimator's contractions
    (:func:`faceanalysis.estimation.flow.estimate_flow`), and of the flow estimate shuffled
    in time (a deliberately wrong resynthesis).

    Returns
    -------
    dict with ``table`` (one row per sequence: mean cosine and EPE of each variant) and
    ``summary`` (means over sequences).
    """
    import tempfile

    from faceanalysis.analysis.pipeline import analyze_to_folder
    from faceanalysis.estimation.flow import estimate_flow
    from synth.render import render_sequence

    if templates is None:
        from faceanalysis.flow.templates import default_templates

        templates = default_templates()
    root = Path(workdir) if workdir is not None else Path(tempfile.mkdtemp(prefix="flowval-"))
    rows = []
    for seed in identities:
        for expr in expressions:
            d = root / f"id{int(seed):03d}_{expr}"
            paths = render_sequence(d / "seq", overwrite=True, expression=expr, frames=frames,
                                    size=size, seed=int(seed), head_motion=head_motion,
                                    illumination=illumination, noise=noise, flow=False)
            a = analyze_to_folder(paths["video"], d / "out", overwrite=True)
            row = {"identity": int(seed), "expression": expr}
            res = validate(paths["video"], d / "out", templates=templates, write=False)
            row.update(cosine_joint=res.summary["mean_cosine"], epe_joint=res.summary["mean_epe"])
            est = estimate_flow(paths["video"], a.table, templates=templates)
            flow_table = a.table.copy()
            for c in est.columns:
                flow_table[c] = est[c].to_numpy()
            res = validate(paths["video"], d / "out", templates=templates, write=False,
                           contractions=flow_table)
            row.update(cosine_flow=res.summary["mean_cosine"], epe_flow=res.summary["mean_epe"])
            res = validate(paths["video"], d / "out", templates=templates, write=False,
                           contractions=shuffled(flow_table, shuffle_seed))
            row.update(cosine_shuffled=res.summary["mean_cosine"],
                       epe_shuffled=res.summary["mean_epe"])
            rows.append(row)
    table = pd.DataFrame(rows)
    summary = {c: float(table[c].mean()) for c in table.columns
               if c.startswith(("cosine_", "epe_"))}
    summary.update(sequences=len(table), frames=frames, size=size, head_motion=head_motion,
                   illumination=illumination, noise=noise)
    return {"table": table, "summary": summary}
