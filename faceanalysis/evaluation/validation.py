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
smoothly). Both fields have the nuisance motions (head-frame jitter, out-of-plane head
rotation) projected out on the face mask before they are compared. Agreement per frame and per face
region (:data:`faceanalysis.flow.templates.REGION_GROUPS`):

- ``cosine``: normalised correlation of the two vector fields on the mask (1 = same motion
  pattern up to a positive factor);
- ``epe``: mean end-point error (head units; ``epe_px`` in the input's pixels).

Frames where neither field moves (RMS below
:data:`faceanalysis.flow.recognition.NEUTRAL_THRESHOLD`) carry no pattern to compare; the
summary's ``mean_cosine`` is taken over the *active* frames, and says how many there were.
"""

from __future__ import annotations

import json
import logging
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from faceanalysis.flow.recognition import NEUTRAL_THRESHOLD, motion_energy, nuisance_free
from faceanalysis.flow.templates import REGION_GROUPS, FlowTemplates
from faceanalysis.io.outputs import ANALYSIS_JSON, CONTRACTIONS_CSV, VALIDATION_CSV, VALIDATION_PNG
from faceanalysis.resynthesis.personalize import personal_model

log = logging.getLogger(__name__)

__all__ = ["flow_agreement", "resynthesis_flow", "validate", "ValidationResult",
           "plot_agreement", "shuffled", "summarize", "evaluate_validation"]


def _controls_table(contractions: pd.DataFrame, muscles) -> tuple[np.ndarray, np.ndarray]:
    """Muscle values (T, M) and jaw (T,) with lost rows held at the last good value."""
    T = len(contractions)
    vals = np.zeros((T, len(muscles)))
    for j, m in enumerate(muscles):
        if m in contractions.columns:
            vals[:, j] = pd.to_numeric(contractions[m], errors="coerce").to_numpy(float)
    jaw = (np.array(pd.to_numeric(contractions["jaw_rotation"], errors="coerce"), dtype=float)
           if "jaw_rotation" in contractions.columns else np.zeros(T))
    bad = ~(np.isfinite(vals).all(axis=1) & np.isfinite(jaw))
    if "success" in contractions.columns:
        bad |= contractions["success"].to_numpy() == 0
    last_v, last_j = np.zeros(len(muscles)), 0.0
    for t in range(T):
        if bad[t]:
            vals[t], jaw[t] = last_v, last_j
        else:
            last_v, last_j = vals[t].copy(), float(jaw[t])
    return np.clip(vals, 0.0, 1.0), jaw


def resynthesis_flow(contractions: pd.DataFrame, *, model=None, view=None, grid=None,
                     size: int = 256) -> np.ndarray:
    """Displacement from rest (T, rows, cols, 2) of the model driven by ``contractions``.

    Parameters
    ----------
    contractions : DataFrame
        Muscle columns and ``jaw_rotation`` per row (missing muscles at rest; rows with
        ``success == 0`` or missing values hold the last good row).
    model : FaceModel-like, optional
        Default: the generic face.
    view : ModelView, optional
        A prepared view of the model (reused across calls).
    grid : FaceGrid, optional
    size : int
        Render size (px).
    """
    from faceanalysis.flow.templates import ModelView

    if view is None:
        if model is None:
            from synth.model import FaceModel

            model = FaceModel.default()
        view = ModelView(model, grid=grid, size=size)
    muscles = tuple(view.model.muscle_names)
    vals, jaw = _controls_table(contractions, muscles)
    out = np.zeros((len(vals), *view.grid.shape, 2))
    prev_key = None
    for t in range(len(vals)):
        key = (vals[t].round(6).tobytes(), round(float(jaw[t]), 6))
        if key == prev_key:
            out[t] = out[t - 1]
            continue
        out[t] = view.displacement(dict(zip(muscles, vals[t].tolist())), float(jaw[t]))
        prev_key = key
    if hasattr(view.model, "reset"):
        view.model.reset()
    return out


def shuffled(contractions: pd.DataFrame, seed: int = 0) -> pd.DataFrame:
    """The rows of ``contractions`` in a random order (a deliberately wrong resynthesis)."""
    rng = np.random.default_rng(seed)
    order = rng.permutation(len(contractions))
    out = contractions.iloc[order].reset_index(drop=True)
    if "frame" in contractions.columns:
        out["frame"] = contractions["frame"].to_numpy()
    return out


def flow_agreement(observed: np.ndarray, predicted: np.ndarray, templates: FlowTemplates, *,
                   frames=None, px_per_unit: float | None = None,
                   active_threshold: float = NEUTRAL_THRESHOLD) -> pd.DataFrame:
    """Per-frame agreement of two displacement sequences on the face mask.

    Parameters
    ----------
    observed, predicted : (T, rows, cols, 2)
        Displacements from the neutral frame (head units) on the templates' grid.
    templates : FlowTemplates
        Give the mask, the regions and the nuisance motions (projected out of both).
    frames : array_like, optional
        Frame numbers.
    px_per_unit : float, optional
        The input's head scale (px), for ``epe_px``.
    active_threshold : float
        RMS displacement above which a frame counts as active.

    Returns
    -------
    DataFrame
        ``frame, active, energy_observed, energy_predicted, cosine, epe[, epe_px]`` and
        ``cosine_<region>, epe_<region>`` for the regions of :data:`REGION_GROUPS`; NaN
        where a frame is missing.
    """
    o = np.asarray(observed, dtype=float)
    p = np.asarray(predicted, dtype=float)
    if o.shape != p.shape or o.ndim != 4 or o.shape[1:] != (*templates.grid.shape, 2):
        raise ValueError(f"observed {o.shape} and predicted {p.shape} must both be "
                         f"(T, {templates.grid.rows}, {templates.grid.cols}, 2)")
    T = len(o)
    fr = np.arange(T) if frames is None else np.asarray(frames)
    ok = np.isfinite(o[:, templates.mask]).all(axis=(1, 2)) & \
        np.isfinite(p[:, templates.mask]).all(axis=(1, 2))
    oc = nuisance_free(np.where(ok[:, None, None, None], o, 0.0), templates)
    pc = nuisance_free(np.where(ok[:, None, None, None], p, 0.0), templates)
    eo = motion_energy(oc, templates.mask)
    ep = motion_energy(pc, templates.mask)
    out = {"frame": fr, "active": ok & ((eo > active_threshold) | (ep > active_threshold)),
           "energy_observed": np.where(ok, eo, np.nan),
           "energy_predicted": np.where(ok, ep, np.nan)}
    regions = {"face": templates.mask, **templates.region_masks()}
    for name, m in regions.items():
        suffix = "" if name == "face" else f"_{name}"
        if not m.any():
            out[f"cosine{suffix}"] = np.full(T, np.nan)
            out[f"epe{suffix}"] = np.full(T, np.nan)
            continue
        a = oc[:, m].reshape(T, -1)
        b = pc[:, m].reshape(T, -1)
        na, nb = np.linalg.norm(a, axis=1), np.linalg.norm(b, axis=1)
        with np.errstate(invalid="ignore", divide="ignore"):
            cos = np.sum(a * b, axis=1) / (na * nb)
        cos = np.where((na > 0) & (nb > 0), cos, np.nan)
        epe = np.linalg.norm((oc - pc)[:, m], axis=-1).mean(axis=1)
        out[f"cosine{suffix}"] = np.where(ok, cos, np.nan)
        out[f"epe{suffix}"] = np.where(ok, epe, np.nan)
        if name == "face" and px_per_unit is not None:
            out["epe_px"] = out["epe"] * float(px_per_unit)
    return pd.DataFrame(out)


def summarize(table: pd.DataFrame) -> dict:
    """Summary of :func:`flow_agreement`: means over active frames, per region."""
    act = table[table["active"].astype(bool)]
    summ = {"frames": int(len(table)), "active_frames": int(len(act)),
            "mean_cosine": float(act["cosine"].mean()) if len(act) else None,
            "median_cosine": float(act["cosine"].median()) if len(act) else None,
            "mean_epe": float(act["epe"].mean()) if len(act) else None,
            "mean_epe_all_frames": float(table["epe"].mean()),
            "regions": {}}
    if "epe_px" in table.columns and len(act):
        summ["mean_epe_px"] = float(act["epe_px"].mean())
    for name in REGION_GROUPS:
        c, e = act.get(f"cosine_{name}"), act.get(f"epe_{name}")
        if c is None:
            continue
        summ["regions"][name] = {
            "mean_cosine": None if not c.notna().any() else float(c.mean()),
            "mean_epe": None if not e.notna().any() else float(e.mean())}
    return summ


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


def _smooth_time(displacement: np.ndarray, sigma: float) -> np.ndarray:
    """Gaussian smoothing over frames that skips lost (NaN) frames (normalised weights)."""
    if sigma <= 0:
        return displacement
    from scipy.ndimage import gaussian_filter1d

    ok = np.isfinite(displacement).all(axis=(1, 2, 3))
    w = gaussian_filter1d(ok.astype(float), sigma, mode="nearest")
    num = gaussian_filter1d(np.where(ok[:, None, None, None], displacement, 0.0), sigma,
                            axis=0, mode="nearest")
    with np.errstate(invalid="ignore", divide="ignore"):
        out = num / w[:, None, None, None]
    out[~ok] = np.nan
    return out


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
    from faceanalysis.flow.dense import video_face_flow
    from faceanalysis.flow.personalize import SubjectWarp
    from faceanalysis.flow.templates import ModelView
    from faceanalysis.io.table import FIDUCIALS, heads_from_table, read_contractions
    from faceanalysis.tracking import to_head_frame

    folder = Path(analysis)
    csv = folder / CONTRACTIONS_CSV
    if not csv.is_file():
        raise FileNotFoundError(f"{csv}: no contractions.csv in the analysis folder")
    table = read_contractions(csv)
    meta_path = folder / ANALYSIS_JSON
    meta = json.loads(meta_path.read_text()) if meta_path.is_file() else {}
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
    ff = video_face_flow(video, table=table, neutral=int(neutral), method=method,
                         grid=templates.grid, fps=fps)
    if model is None:
        from synth.model import FaceModel

        model = FaceModel.default()
    drive = table if contractions is None else contractions
    k = int(np.flatnonzero(frames == int(neutral))[0])
    personalisation = "none"
    tpl = templates
    personal = personal_model(folder, model) if personalised == "model" or \
        personalised is True else None
    if personal is not None:
        # the model itself warped to the subject (faceanalysis.resynthesis.personalize.personalize)
        view = ModelView(personal, grid=templates.grid)
        tpl = view.templates()
        pred = resynthesis_flow(drive, view=view)
        personalisation = "model"
    else:
        view = ModelView(model, grid=templates.grid)
        pred = resynthesis_flow(drive, view=view)
        cols = [c for n in FIDUCIALS for c in (f"fid_{n}_x", f"fid_{n}_y")]
        if personalised and all(c in table.columns for c in cols):
            fid = table[cols].to_numpy(float)[k].reshape(len(FIDUCIALS), 2)
            if np.isfinite(fid).all():
                # 2-D landmark warp of the generic resynthesis flow onto the subject
                q = to_head_frame(fid, heads[k])
                pred = SubjectWarp(templates.grid, view.fiducials, q).vectors(pred)
                from faceanalysis.flow.personalize import personalize

                tpl = personalize(templates, q)
                personalisation = "warp"
    # the resynthesis is from the model's rest; the input from its neutral frame
    pred = pred - pred[k]
    if temporal_sigma < 0:
        raise ValueError(f"temporal_sigma={temporal_sigma} must be >= 0")
    obs = _smooth_time(ff.displacement, temporal_sigma)
    pos = {int(f): i for i, f in enumerate(ff.frames)}
    o = np.full_like(pred, np.nan)
    for i, f in enumerate(frames):
        j = pos.get(int(f))
        if j is not None:
            o[i] = obs[j]
    agree = flow_agreement(o, pred, tpl, frames=frames, px_per_unit=float(heads[k, 2]))
    summary = summarize(agree)
    summary.update(method=method, neutral_frame=int(neutral), personalisation=personalisation,
                   temporal_sigma=float(temporal_sigma),
                   grid=templates.grid.as_dict(),
                   resynthesis="shuffled/override" if contractions is not None else "analysis")
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
