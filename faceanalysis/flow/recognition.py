"""Expression recognition by flow-template matching (Essa & Pentland's motion templates).

The face displacement from the neutral frame on the face grid
(:func:`faceanalysis.flow.dense.video_face_flow`) is compared with the model-made expression
templates of :mod:`faceanalysis.flow.templates`:

1. **Nuisance removal.** Head-frame jitter (similarity) and out-of-plane head rotation (the
   model's yaw and pitch flow) are projected out of every frame and of every template, on
   the face mask.
2. **Motion energy** per frame: the RMS displacement on the mask (head units). A frame is
   *active* when its energy exceeds ``threshold`` (default :data:`NEUTRAL_THRESHOLD`,
   calibrated on synthetic neutral sequences with head motion, light change and noise,
   see :func:`calibrate_threshold`). Runs of active frames (gaps shorter than ``min_gap``
   frames closed, runs shorter than ``min_length`` dropped) are the **segments**; a
   sequence without one is *neutral*.
3. **Matching.** In a segment, the apex is the frame of largest energy; the observed onset
   (segment start to apex) is resampled to the template's instants, and each expression is
   scored by the normalised correlation (cosine) of the spatio-temporal displacement
   template with the observation and the cosine of the motion-energy maps (weights
   :data:`WEIGHTS`); the whole segment votes too: the energy-weighted mean, over its
   frames, of the cosine between the frame's displacement and the expression's apex
   template. The *similarity* of a class is the mean of the onset score and that mean
   cosine; its *share* is the fraction of the segment's frames whose nearest apex template
   it is (a majority vote, robust to a few frames of head motion or occlusion). The class
   score is ``(2 similarity + share) / 3``; the best score names the segment. A segment
   whose named class has a similarity below :data:`MIN_SCORE` matches no expression and is
   dropped (neutral).

Scores per class are reported for the six expressions and for ``neutral`` (0 for a
sequence with an expression; for a neutral one ``1 -`` the best expression score of its
strongest unmatched segment, or ``1 - 0.5 peak / threshold`` without any).
"""

from __future__ import annotations

import logging
import os
from dataclasses import dataclass, field, replace

import numpy as np
import pandas as pd

from faceanalysis.flow.dense import FaceFlow
from faceanalysis.flow.grid import remove_rigid
from faceanalysis.flow.templates import EXPRESSION_NAMES, FlowTemplates

log = logging.getLogger(__name__)

__all__ = ["CLASSES", "NEUTRAL_THRESHOLD", "MIN_SCORE", "WEIGHTS", "Segment", "Recognition",
           "nuisance_free", "motion_energy", "find_segments", "score_segment",
           "classify_flow", "classify_video", "calibrate_threshold"]

#: Classes named by the recogniser: the six primary expressions and neutral.
CLASSES = (*EXPRESSION_NAMES, "neutral")
#: RMS displacement on the face mask (head units) above which a frame shows an expression.
#: Calibrated with :func:`calibrate_threshold` (see the module docstring).
NEUTRAL_THRESHOLD = 0.003
#: Smallest similarity of a segment's class; motion that matches no expression template
#: (noise, talking, residual head motion) below it is neutral.
MIN_SCORE = 0.2
#: Weights of the spatio-temporal displacement correlation and of the motion-energy map
#: correlation in a class score.
WEIGHTS = (0.8, 0.2)


@dataclass
class Segment:
    """One expression episode of a sequence.

    Attributes
    ----------
    start, apex, end : int
        Frame numbers (``end`` inclusive).
    label : str
        One of :data:`CLASSES`.
    scores : dict
        Class -> score (cosine-like, higher is better).
    peak_energy : float
        Motion energy at the apex (head units).
    """

    start: int
    apex: int
    end: int
    label: str
    scores: dict = field(default_factory=dict)
    peak_energy: float = 0.0

    def as_dict(self) -> dict:
        return {"start": int(self.start), "apex": int(self.apex), "end": int(self.end),
                "label": self.label, "peak_energy": float(self.peak_energy),
                **{f"score_{k}": float(v) for k, v in self.scores.items()}}


@dataclass
class Recognition:
    """Result of :func:`classify_flow`: segments, the sequence's label, per-frame energy."""

    label: str
    scores: dict
    segments: list
    energy: np.ndarray
    frames: np.ndarray
    threshold: float

    def table(self) -> pd.DataFrame:
        """One row per segment (``start, apex, end, label, peak_energy, score_<class>``)."""
        cols = ["start", "apex", "end", "label", "peak_energy", *(f"score_{c}" for c in CLASSES)]
        return pd.DataFrame([s.as_dict() for s in self.segments], columns=cols)

    def as_dict(self) -> dict:
        return {"label": self.label, "scores": {k: float(v) for k, v in self.scores.items()},
                "threshold": float(self.threshold),
                "segments": [s.as_dict() for s in self.segments]}


def nuisance_free(displacement: np.ndarray, templates: FlowTemplates) -> np.ndarray:
    """``displacement`` (..., rows, cols, 2) with the templates' nuisance motions projected
    out on the face mask and zero off the mask."""
    d = remove_rigid(displacement, templates.mask, templates.nuisance)
    d = np.array(d, copy=True)
    d[..., ~templates.mask, :] = 0.0
    return d


def motion_energy(displacement: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """RMS displacement magnitude on ``mask`` per frame, ``(T,)``; NaN frames give NaN."""
    d = np.asarray(displacement, dtype=float)
    m = np.asarray(mask, dtype=bool)
    sq = np.sum(d[:, m] ** 2, axis=-1)                    # (T, n)
    return np.sqrt(np.mean(sq, axis=1))


def find_segments(energy: np.ndarray, threshold: float, *, min_length: int = 3,
                  min_gap: int = 5) -> list[tuple[int, int]]:
    """Runs of frames with ``energy > threshold`` as (first, last) positions.

    Gaps shorter than ``min_gap`` frames between runs are closed; runs shorter than
    ``min_length`` are dropped. NaN energy (lost frames) counts as inactive.

    Examples
    --------
    >>> find_segments(np.array([0, 0, 1, 1, 1, 0, 1, 1, 0, 0, 0, 0, 0, 0, 1, 0]), 0.5)
    [(2, 7)]
    """
    if min_length < 1 or min_gap < 0:
        raise ValueError("min_length must be >= 1 and min_gap >= 0")
    active = np.nan_to_num(np.asarray(energy, dtype=float), nan=-np.inf) > threshold
    runs = []
    t, n = 0, len(active)
    while t < n:
        if active[t]:
            s = t
            while t < n and active[t]:
                t += 1
            runs.append([s, t - 1])
        else:
            t += 1
    merged: list[list[int]] = []
    for r in runs:
        if merged and r[0] - merged[-1][1] - 1 < min_gap:
            merged[-1][1] = r[1]
        else:
            merged.append(r)
    return [(a, b) for a, b in merged if b - a + 1 >= min_length]


def _cos(a: np.ndarray, b: np.ndarray) -> float:
    na, nb = np.linalg.norm(a), np.linalg.norm(b)
    if na == 0 or nb == 0:
        return 0.0
    return float(np.dot(a.ravel(), b.ravel()) / (na * nb))


class _Prepared:
    """Templates with nuisance removed, flattened on the mask (cached per templates)."""

    def __init__(self, templates: FlowTemplates):
        self.t = templates
        m = templates.mask
        expr = nuisance_free(templates.expression, templates)      # (E, S, r, c, 2)
        self.steps = expr.shape[1]
        self.expr = expr[:, :, m, :].reshape(len(expr), self.steps, -1)
        # motion energy of the nuisance-free onset
        prev = np.concatenate([np.zeros_like(expr[:, :1]), expr[:, :-1]], axis=1)
        self.energy = np.sum((expr - prev) ** 2, axis=(1, -1))[:, m]   # (E, n)
        apex = expr[:, -1][:, m, :].reshape(len(expr), -1)
        self.apex = apex / np.maximum(np.linalg.norm(apex, axis=1, keepdims=True), 1e-12)


_PREP_CACHE: dict = {}


def _prepared(templates: FlowTemplates) -> _Prepared:
    key = id(templates)
    hit = _PREP_CACHE.get(key)
    if hit is None or hit.t is not templates:
        hit = _PREP_CACHE[key] = _Prepared(templates)
        if len(_PREP_CACHE) > 8:
            _PREP_CACHE.pop(next(iter(_PREP_CACHE)))
    return hit


def score_segment(clean: np.ndarray, templates: FlowTemplates, start: int, apex: int,
                  end: int | None = None) -> dict[str, float]:
    """Scores of the expressions for the segment ``clean[start..end]`` with its apex.

    Parameters
    ----------
    clean : (T, rows, cols, 2)
        Nuisance-free displacement from neutral (:func:`nuisance_free`).
    templates : FlowTemplates
    start, apex, end : int
        Positions in ``clean`` (``end`` inclusive; default ``apex``).
    """
    p = _prepared(templates)
    end = apex if end is None else int(end)
    m = templates.mask
    s0 = max(0, start - 1)                     # the frame before the onset as its zero
    idx = np.linspace(s0, apex, p.steps + 1)[1:]
    lo = np.floor(idx).astype(int)
    hi = np.minimum(lo + 1, apex)
    w = (idx - lo)[:, None, None]
    obs = np.nan_to_num(clean[:, m, :])
    onset = (1 - w) * obs[lo] + w * obs[hi]                          # (S, n, 2)
    onset_flat = onset.reshape(p.steps, -1)
    prev = np.concatenate([obs[s0][None], onset[:-1]], axis=0)
    energy = np.sum((onset - prev) ** 2, axis=(0, -1))
    wd, we = WEIGHTS
    onset_score = np.array([wd * _cos(onset_flat, p.expr[e]) + we * _cos(energy, p.energy[e])
                            for e in range(len(templates.expressions))])
    # the whole segment votes: energy-weighted cosine of each frame with the apex templates
    seg = obs[start:end + 1].reshape(end + 1 - start, -1)
    norms = np.linalg.norm(seg, axis=1)
    w = norms / max(norms.sum(), 1e-12)
    cos = (seg @ p.apex.T) / np.maximum(norms, 1e-12)[:, None]
    mean_cos = w @ cos
    similarity = 0.5 * (onset_score + mean_cos)
    moving = norms > 0
    share = (np.bincount(np.argmax(cos[moving], axis=1), minlength=len(onset_score))
             / max(int(moving.sum()), 1))
    out = {name: float((2.0 * similarity[e] + share[e]) / 3.0)
           for e, name in enumerate(templates.expressions)}
    out["_similarity"] = {name: float(similarity[e])
                          for e, name in enumerate(templates.expressions)}
    return out


def classify_flow(flow: FaceFlow | np.ndarray, templates: FlowTemplates, *,
                  threshold: float | None = None, min_score: float = MIN_SCORE,
                  min_length: int = 3, min_gap: int = 5, frames=None) -> Recognition:
    """Name the expression of each segment of a sequence from its face flow.

    Parameters
    ----------
    flow : FaceFlow or ndarray (T, rows, cols, 2)
        Displacement from the neutral frame on the templates' grid.
    templates : FlowTemplates
    threshold : float, optional
        Motion energy of an expression (default :data:`NEUTRAL_THRESHOLD`).
    min_score : float
        Smallest best score of an expression segment (:data:`MIN_SCORE`).
    min_length, min_gap : int
        See :func:`find_segments`.
    frames : array_like, optional
        Frame numbers (default: from the FaceFlow, or ``0..T-1``).

    Returns
    -------
    Recognition
        ``label`` is the label of the segment with the largest peak energy (``neutral``
        without segments); ``scores`` are that segment's.
    """
    if isinstance(flow, FaceFlow):
        disp = flow.displacement
        fr = flow.frames if frames is None else np.asarray(frames)
        if flow.grid != templates.grid:
            raise ValueError("the flow and the templates use different face grids")
    else:
        disp = np.asarray(flow, dtype=float)
        fr = np.arange(len(disp)) if frames is None else np.asarray(frames)
    if disp.ndim != 4 or disp.shape[1:] != (*templates.grid.shape, 2):
        raise ValueError(f"displacement must have shape (T, {templates.grid.rows}, "
                         f"{templates.grid.cols}, 2), got {disp.shape}")
    thr = NEUTRAL_THRESHOLD if threshold is None else float(threshold)
    if not thr > 0:
        raise ValueError(f"threshold={thr} must be positive")
    clean = nuisance_free(disp, templates)
    energy = motion_energy(clean, templates.mask)
    segments = []
    dropped = []                       # (peak energy, scores) of segments matching nothing
    for a, b in find_segments(energy, thr, min_length=min_length, min_gap=min_gap):
        apex = a + int(np.nanargmax(energy[a:b + 1]))
        scores = score_segment(clean, templates, a, apex, b)
        similarity = scores.pop("_similarity")
        scores["neutral"] = 0.0
        label = max(templates.expressions, key=scores.get)
        if similarity[label] < min_score:
            dropped.append((float(energy[apex]), scores))
            continue
        segments.append(Segment(int(fr[a]), int(fr[apex]), int(fr[b]), label, scores,
                                float(energy[apex])))
    if segments:
        best = max(segments, key=lambda s: s.peak_energy)
        label, scores = best.label, dict(best.scores)
    else:
        label = "neutral"
        if dropped:
            scores = dict(max(dropped, key=lambda s: s[0])[1])
            scores["neutral"] = 1.0 - max(scores[n] for n in templates.expressions)
        else:
            peak = float(np.nanmax(energy)) if np.isfinite(energy).any() else 0.0
            scores = {name: 0.0 for name in templates.expressions}
            scores["neutral"] = 1.0 - 0.5 * min(peak / thr, 1.0)
    return Recognition(label=label, scores=scores, segments=segments, energy=energy,
                       frames=np.asarray(fr), threshold=thr)


def classify_video(video: str | os.PathLike, *, templates: FlowTemplates | None = None,
                   table: pd.DataFrame | None = None, neutral: int | None = None,
                   method: str = "dis", fps: float | None = None, start: int = 0,
                   end: int | None = None, personalised: bool = True,
                   **kwargs) -> Recognition:
    """Recognise the expressions of a video (flow from its neutral frame, then
    :func:`classify_flow`).

    Parameters
    ----------
    video : path-like
    templates : FlowTemplates, optional
        Default: the generic face model's (:func:`faceanalysis.flow.templates.default_templates`).
    table : DataFrame, optional
        Head frames (e.g. an analysis's ``contractions.csv``); default: tracked.
    neutral : int, optional
        Neutral frame number (default: the first tracked frame); it may precede ``start``
        (the frames between are tracked, not classified).
    method, fps, start, end
        See :func:`faceanalysis.flow.dense.video_face_flow`.
    personalised : bool
        Warp the templates onto the subject's neutral fiducials
        (:func:`faceanalysis.flow.personalize.personalize_from_table`).
    **kwargs
        Passed to :func:`classify_flow` (``threshold``, ``min_length``, ``min_gap``).
    """
    from faceanalysis.flow.dense import video_face_flow
    from faceanalysis.flow.personalize import personalize_from_table
    from faceanalysis.tracking import track

    if templates is None:
        from faceanalysis.flow.templates import default_templates

        templates = default_templates()
    if neutral is not None and neutral < 0:
        raise ValueError(f"neutral frame {neutral} must be >= 0")
    first = start if neutral is None else min(start, int(neutral))
    if end is not None and neutral is not None and neutral >= end:
        raise ValueError(f"neutral frame {neutral} lies after the range end {end}")
    if table is None:
        table = track(video, fps=fps, start=first, end=end, redetect=True).table
    ff = video_face_flow(video, table=table, neutral=neutral, method=method,
                         grid=templates.grid, fps=fps, start=first, end=end)
    if personalised:
        templates = personalize_from_table(templates, table, ff.reference)
    if first < start:                      # the neutral frame precedes the range: drop it
        keep = ff.frames >= start
        ff = replace(ff, displacement=ff.displacement[keep], valid=ff.valid[keep],
                     frames=ff.frames[keep])
    return classify_flow(ff, templates, **kwargs)


def calibrate_threshold(neutral_energies, expression_energies) -> float:
    """A motion-energy threshold between neutral and expressive sequences.

    Parameters
    ----------
    neutral_energies : array_like
        Peak energy of each neutral sequence.
    expression_energies : array_like
        Peak energy of each expressive sequence.

    Returns
    -------
    float
        The geometric mean of the largest neutral peak and the smallest expressive one
        (when they overlap: twice the 95th percentile of the neutral peaks).

    Examples
    --------
    >>> round(calibrate_threshold([0.001, 0.002], [0.008, 0.02]), 4)
    0.004
    """
    n = np.asarray(neutral_energies, dtype=float)
    e = np.asarray(expression_energies, dtype=float)
    if n.size == 0 or e.size == 0:
        raise ValueError("need at least one neutral and one expressive sequence")
    if n.max() < e.min():
        return float(np.sqrt(n.max() * e.min()))
    return float(2.0 * np.percentile(n, 95))


# ---------------------------------------------------------------------------- evaluation
def synthetic_face_flow(seq, grid, *, method: str = "dis"):
    """Face flow of a rendered :class:`synth.render.SyntheticSequence` through the toolkit's
    own front end: the tracker's head frames on the (degraded) frames, then
    :func:`faceanalysis.flow.dense.face_flow` from frame 0.

    Returns
    -------
    FaceFlow, table
        The table has the tracker's ``frame, success, head_*, fid_*`` columns.
    """
    import cv2

    from faceanalysis.flow.dense import face_flow
    from trackers import Tracker, detect_layout

    imgs = seq.images
    bgr = [cv2.cvtColor(im, cv2.COLOR_RGB2BGR) if im.ndim == 3 else im for im in imgs]
    from faceanalysis.io.table import FIDUCIALS, heads_from_table

    tracker = Tracker(detect_layout(bgr[0], channel_order="bgr"), channel_order="bgr")
    rows = []
    for t, im in enumerate(bgr):
        r = tracker.track(im)
        rec = {"frame": t, "success": int(bool(r.success)), "head_x": r.head.x,
               "head_y": r.head.y, "head_scale": r.head.scale, "head_roll": r.head.roll}
        for n in FIDUCIALS:
            rec[f"fid_{n}_x"], rec[f"fid_{n}_y"] = (float(v) for v in r.fiducials[n])
        rows.append(rec)
    table = pd.DataFrame(rows)
    return face_flow(bgr, heads_from_table(table), grid=grid, method=method), table


def evaluate_recognition(identities=range(100, 110), *, templates: FlowTemplates | None = None,
                         frames: int = 30, size: int = 256, head_motion: float = 1.0,
                         illumination: float = 1.0, noise: float = 2.0,
                         emphasis: tuple = (0.7, 1.0), method: str = "dis",
                         threshold: float | None = None, personalised: bool = True,
                         progress=None) -> dict:
    """Recognition accuracy on synthetic sequences of unseen identities.

    For every identity seed (``FaceShape.random(seed)``, its own texture) and every class of
    :data:`CLASSES`, a sequence is rendered (expression at a random emphasis in
    ``emphasis``, or neutral) with head motion, light change and sensor noise, tracked and
    classified (with the templates personalised on the tracked neutral fiducials unless
    ``personalised`` is false).

    Returns
    -------
    dict with ``accuracy``, ``confusion`` (DataFrame, rows = truth, columns = predicted),
    ``results`` (DataFrame: identity, truth, predicted, peak_energy, scores) and the
    settings.
    """
    from faceanalysis.flow.personalize import personalize_from_table
    from synth.render import synthesize

    if templates is None:
        from faceanalysis.flow.templates import default_templates

        templates = default_templates()
    ids = [int(i) for i in identities]
    if not ids:
        raise ValueError("identities must hold at least one seed")
    rows = []
    total = len(ids) * len(CLASSES)
    for i in ids:
        rng = np.random.default_rng([i, 0xE7A1])
        for cls in CLASSES:
            emph = float(rng.uniform(*emphasis))
            seq = synthesize(expression=None if cls == "neutral" else cls, frames=frames,
                             size=size, seed=i, head_motion=head_motion,
                             illumination=illumination, noise=noise, flow=False,
                             intensity=emph)
            ff, table = synthetic_face_flow(seq, templates.grid, method=method)
            tpl = personalize_from_table(templates, table, 0) if personalised else templates
            rec = classify_flow(ff, tpl, threshold=threshold)
            rows.append({"identity": i, "truth": cls, "predicted": rec.label,
                         "emphasis": emph if cls != "neutral" else 0.0,
                         "peak_energy": float(np.nanmax(rec.energy)),
                         **{f"score_{k}": float(v) for k, v in rec.scores.items()}})
            if progress is not None:
                progress(len(rows), total)
    res = pd.DataFrame(rows)
    conf = pd.crosstab(res["truth"], res["predicted"]).reindex(index=list(CLASSES),
                                                              columns=list(CLASSES),
                                                              fill_value=0)
    return {"accuracy": float((res["truth"] == res["predicted"]).mean()), "confusion": conf,
            "results": res, "identities": ids, "frames": frames, "size": size,
            "head_motion": head_motion, "illumination": illumination, "noise": noise,
            "method": method, "templates": dict(templates.meta)}
