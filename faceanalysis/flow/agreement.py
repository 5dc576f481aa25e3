"""Agreement of two face flows: a video's and its resynthesis's (the model driven by the
analysed contractions), frame by frame on the face grid.

:func:`flow_agreement` compares two displacement sequences from the neutral frame; both have
the nuisance motions (head-frame jitter, out-of-plane head rotation) projected out on the face
mask first. Per frame and per face region (:data:`faceanalysis.flow.templates.REGION_GROUPS`):

- ``cosine``: normalised correlation of the two vector fields on the mask (1 = same motion
  pattern up to a positive factor);
- ``epe``: mean end-point error (head units; ``epe_px`` in the input's pixels).

Frames where neither field moves (RMS below
:data:`faceanalysis.flow.recognition.NEUTRAL_THRESHOLD`) carry no pattern to compare; the
summary's ``mean_cosine`` is taken over the *active* frames, and says how many there were.

:func:`video_flow_agreement` does the whole comparison for a video and its contractions
table; ``faceanalysis validate`` (:func:`faceanalysis.evaluation.validation.validate`) and the
report of ``faceanalysis resynth`` both use it, which is why it lives here, below both.
"""

from __future__ import annotations

import os

import numpy as np
import pandas as pd

from faceanalysis.flow.recognition import NEUTRAL_THRESHOLD, motion_energy, nuisance_free
from faceanalysis.flow.templates import REGION_GROUPS, FlowTemplates

__all__ = ["flow_agreement", "resynthesis_flow", "summarize", "smooth_time",
           "video_flow_agreement"]


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


def smooth_time(displacement: np.ndarray, sigma: float) -> np.ndarray:
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


def video_flow_agreement(video: str | os.PathLike, table: pd.DataFrame, *, neutral: int,
                         model=None, personal=None, contractions: pd.DataFrame | None = None,
                         templates: FlowTemplates | None = None, method: str = "dis",
                         fps: float | None = None, personalised: bool = True,
                         temporal_sigma: float = 1.0, hidden=None
                         ) -> tuple[pd.DataFrame, dict, np.ndarray, np.ndarray]:
    """Flow of a video against the flow of the face model driven by its contractions.

    Parameters
    ----------
    video : path-like
        The analysed video.
    table : DataFrame
        Its ``contractions.csv``: head frames, fiducials and (unless ``contractions``) the
        drive.
    neutral : int
        Frame number of the neutral frame (the input's flow is measured from it).
    model : FaceModel-like, optional
        The generic model (default: the generic face).
    personal : FaceModel-like, optional
        The model already warped to the subject; its motion is compared as it is.
    contractions : DataFrame, optional
        Drive the model with these instead of ``table``'s.
    templates : FlowTemplates, optional
        Mask, regions and nuisance motions (default: the generic templates).
    method : {'dis', 'farneback', 'tvl1'}
        Flow of the input.
    personalised : bool
        Without ``personal``: warp the generic model's flow onto the subject's neutral
        fiducials in 2-D (:class:`faceanalysis.flow.personalize.SubjectWarp`).
    temporal_sigma : float
        Gaussian smoothing of the input flow over time (frames; 0 = none).
    hidden : iterable of int, optional
        Frames on which the face cannot be seen (an analysis's ``quality.hidden_ranges``,
        :func:`faceanalysis.io.report.hidden_frames_of`): the input's flow there is lost,
        not bridged (:func:`~faceanalysis.flow.dense.video_face_flow`).

    Returns
    -------
    agreement : DataFrame
        :func:`flow_agreement` per row of ``table``.
    summary : dict
        :func:`summarize`, with ``method``, ``neutral_frame``, ``personalisation``
        (``'model'``, ``'warp'`` or ``'none'``), ``temporal_sigma`` and ``grid``.
    observed, predicted : ndarray (T, rows, cols, 2)
    """
    from faceanalysis.flow.dense import video_face_flow
    from faceanalysis.flow.personalize import SubjectWarp
    from faceanalysis.flow.templates import ModelView
    from faceanalysis.io.table import FIDUCIALS, heads_from_table
    from faceanalysis.tracking import to_head_frame

    if temporal_sigma < 0:
        raise ValueError(f"temporal_sigma={temporal_sigma} must be >= 0")
    heads = heads_from_table(table)
    frames = table["frame"].to_numpy(int)
    hits = np.flatnonzero(frames == int(neutral))
    if hits.size == 0:
        raise ValueError(f"neutral frame {neutral} is not a row of the table")
    k = int(hits[0])
    if templates is None:
        from faceanalysis.flow.templates import default_templates

        templates = default_templates(model)
    if model is None and personal is None:
        from synth.model import FaceModel

        model = FaceModel.default()
    ff = video_face_flow(video, table=table, neutral=int(neutral), method=method,
                         grid=templates.grid, fps=fps, hidden=hidden)
    drive = table if contractions is None else contractions
    personalisation = "none"
    tpl = templates
    if personal is not None:
        # the model itself warped to the subject
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
    obs = smooth_time(ff.displacement, temporal_sigma)
    pos = {int(f): i for i, f in enumerate(ff.frames)}
    o = np.full_like(pred, np.nan)
    for i, f in enumerate(frames):
        j = pos.get(int(f))
        if j is not None:
            o[i] = obs[j]
    agree = flow_agreement(o, pred, tpl, frames=frames, px_per_unit=float(heads[k, 2]))
    summary = summarize(agree)
    summary.update(method=method, neutral_frame=int(neutral), personalisation=personalisation,
                   temporal_sigma=float(temporal_sigma), grid=templates.grid.as_dict())
    return agree, summary, o, pred
