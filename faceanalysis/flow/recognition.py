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
   whose named class has a similarity below :data:`MIN_SCORE` matches no expression: it is
   reported apart (:attr:`Recognition.unmatched`, labelled :data:`UNMATCHED`), not as an
   expression, and does not name the sequence.

Scores per class are reported for the six expressions and for ``neutral`` (0 for a
sequence with an expression; for a neutral one ``1 -`` the best expression score of its
strongest unmatched segment, or ``1 - 0.5 peak / threshold`` without any).

**The neutral reference.** Everything above measures motion *from* a reference frame, so
that frame must show the face at rest: a clip that starts in the middle of a laugh, taken
from its first frame, shows the laugh fading, which matches no expression (neutral).
:func:`classify_video` therefore takes the reference from ``neutral=`` when given, else
detects the **rest frame** (:func:`rest_frame`): the flow from the first tracked frame is
explained, frame by frame, by the face model's per-muscle flow templates (least squares);
the coefficients are each frame's contractions *relative to the first frame*, so the
frame with the smallest total is the least contracted face of the clip, the rest frame
(muscles only contract: a face at rest has the smallest total). The first frame is kept
unless another is less contracted by at least :data:`REST_MARGIN` and by
:data:`REST_NOISE` times the clip's own frame-to-frame noise, so that a neutral or noisily
tracked clip keeps its first frame rather than one picked by noise.
The search covers the classified range and the
:data:`~faceanalysis.flow.options.REST_LOOKBACK` frames before it: a clip cut in the middle
of an expression has no rest frame of its own, while the video often shows the face at rest
just before. What the detector can say of its pick is reported
(:attr:`Recognition.reference_rest`): ``'still'`` when the face holds there for
:data:`REST_HOLD` frames, ``'moving'`` when it does not (the least contracted instant of a
laugh is a lull between bursts, not rest) and ``'unresolved'`` when :data:`REST_NOISE`
times the clip's frame-to-frame noise of the total exceeds twice the margin, so that rest
cannot be told
from expression (real clips with large head motion or a hand over the face). The flow of that
first pass runs from the first frame, which may be the apex of an expression, and large flow is
noisy; so an ``'unresolved'`` pick is judged again from the classification pass's flow, which
runs from the pick and is small near it. After ``'moving'`` or ``'unresolved'`` the labels are
doubtful and the reference should be given.
The reference used is reported (:attr:`Recognition.reference`,
:attr:`Recognition.reference_source`).

Memory: :func:`classify_video` streams the flow
(:class:`~faceanalysis.flow.dense.VideoFlowStream`) and keeps no displacement per frame: the
rest-frame pass reduces each frame to its total contraction, and the classification pass
writes each frame's nuisance-free displacement on the mask to a temporary file (16 kB a
frame on disk) from which the segments are read back a chunk at a time. What grows with the
video is the tracked table and a few numbers a frame.
"""

from __future__ import annotations

import logging
import os
import threading
from dataclasses import dataclass, field, replace

import numpy as np
import pandas as pd

from faceanalysis.flow.dense import FaceFlow
from faceanalysis.flow.grid import remove_rigid
from faceanalysis.flow.options import REST_LOOKBACK
from faceanalysis.flow.templates import EXPRESSION_NAMES, FlowTemplates

log = logging.getLogger(__name__)

__all__ = ["CLASSES", "NEUTRAL_THRESHOLD", "MIN_SCORE", "WEIGHTS", "REST_MARGIN", "Segment",
           "Recognition", "nuisance_free", "motion_energy", "find_segments", "score_segment",
           "classify_flow", "classify_video", "rest_frame", "relative_contraction", "REST_NOISE",
           "calibrate_threshold", "REST_HOLD", "UNMATCHED"]

#: Classes named by the recogniser: the six primary expressions and neutral.
CLASSES = (*EXPRESSION_NAMES, "neutral")
#: RMS displacement on the face mask (head units) above which a frame shows an expression.
#: Calibrated with :func:`calibrate_threshold` (see the module docstring).
NEUTRAL_THRESHOLD = 0.003
#: Smallest similarity of a segment's class; motion below it (noise, talking, residual head
#: motion) matches no expression: the segment is :data:`UNMATCHED`.
MIN_SCORE = 0.2
#: Label of a segment whose motion matches no expression (:attr:`Recognition.unmatched`).
UNMATCHED = "unmatched"
#: Weights of the spatio-temporal displacement correlation and of the motion-energy map
#: correlation in a class score.
WEIGHTS = (0.8, 0.2)
#: A frame replaces the first one as the neutral reference when its total contraction
#: (sum over the model's controls, each as a fraction of its range; see
#: :func:`relative_contraction`) is at least this much smaller.
REST_MARGIN = 0.25
#: ... and by at least this many times the clip's frame-to-frame noise of that total (a
#: robust SD of its second difference), so that noisy tracking on a real video does not
#: pick a random frame.
REST_NOISE = 4.0
#: A rest frame is *still* when the total contraction stays within half the margin of its
#: value for this many frames on one side (a face at rest holds; a lull in a laugh does
#: not).
REST_HOLD = 4
#: Frames processed at a time when the displacement is cleaned (bounds the temporaries).
_CHUNK = 64


@dataclass
class Segment:
    """One expression episode of a sequence.

    Attributes
    ----------
    start, apex, end : int
        Frame numbers (``end`` inclusive).
    label : str
        One of :data:`CLASSES`, or :data:`UNMATCHED` where the motion matches none.
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
    """Result of :func:`classify_flow`: segments, the sequence's label, per-frame energy.

    ``reference`` is the frame number of the neutral reference the motion was measured
    from, and ``reference_source`` how it was chosen: ``'given'`` (``neutral=``),
    ``'detected'`` (:func:`rest_frame` found a less contracted frame than the first),
    ``'first'`` (the first tracked frame, no frame being clearly more at rest) or
    ``'first_photograph'`` (photographs: the first with a face, as the analysis takes it);
    ``reference_rest`` what the detector can say of a found reference (``None`` for a
    given one): ``'still'`` (the face holds there, :data:`REST_HOLD`), ``'moving'`` (it
    does not: probably a lull in an expression rather than the face at rest) or
    ``'unresolved'`` (the clip's tracking noise hides the difference between rest and
    expression); after ``'moving'`` or ``'unresolved'`` the labels are doubtful.

    ``segments`` are the episodes named as expressions; ``unmatched`` those whose motion
    matches no expression template well enough (:data:`MIN_SCORE`: talking, a hand, a head
    turn the nuisance removal leaves, or an expression the templates lack), labelled
    :data:`UNMATCHED` with their scores, so that no active stretch of the video goes
    unreported. Frames whose ``energy`` is NaN were not classified (no face tracked, or the
    face hidden).
    """

    label: str
    scores: dict
    segments: list
    energy: np.ndarray
    frames: np.ndarray
    threshold: float
    reference: int | None = None
    reference_source: str | None = None
    reference_rest: str | None = None
    unmatched: list = field(default_factory=list)

    def __repr__(self) -> str:
        score = self.scores.get(self.label)
        parts = [f"{len(self.segments)} segment{'' if len(self.segments) == 1 else 's'}"]
        if self.unmatched:
            parts.append(f"{len(self.unmatched)} unmatched")
        lost = int(np.count_nonzero(~np.isfinite(np.asarray(self.energy, dtype=float))))
        if lost:
            parts.append(f"{lost} frame{'' if lost == 1 else 's'} not classified")
        reference = ("" if self.reference is None else
                     f" from neutral frame {self.reference} ({self.reference_source}"
                     f"{', ' + self.reference_rest if self.reference_rest else ''})")
        return (f"<Recognition: {self.label}{'' if score is None else f' ({score:.3f})'}"
                f"{reference}; {', '.join(parts)}>")

    def table(self) -> pd.DataFrame:
        """One row per segment, the unmatched ones (label :data:`UNMATCHED`) included, in
        order of their start (``start, apex, end, label, peak_energy, score_<class>``)."""
        cols = ["start", "apex", "end", "label", "peak_energy", *(f"score_{c}" for c in CLASSES)]
        rows = sorted(self.segments + self.unmatched, key=lambda s: s.start)
        return pd.DataFrame([s.as_dict() for s in rows], columns=cols)

    def lost_ranges(self) -> list[tuple[int, int]]:
        """Runs of frames not classified (NaN ``energy``: no face tracked, or the face
        hidden) as (first, last) frame numbers, inclusive."""
        lost = np.flatnonzero(~np.isfinite(np.asarray(self.energy, dtype=float)))
        if not lost.size:
            return []
        breaks = np.flatnonzero(np.diff(lost) > 1)
        firsts = np.r_[lost[0], lost[breaks + 1]]
        lasts = np.r_[lost[breaks], lost[-1]]
        return [(int(self.frames[a]), int(self.frames[b])) for a, b in zip(firsts, lasts)]

    def as_dict(self) -> dict:
        return {"label": self.label, "scores": {k: float(v) for k, v in self.scores.items()},
                "threshold": float(self.threshold),
                "reference": None if self.reference is None else int(self.reference),
                "reference_source": self.reference_source,
                "reference_rest": self.reference_rest,
                "segments": [s.as_dict() for s in self.segments],
                "unmatched": [s.as_dict() for s in self.unmatched],
                "lost_ranges": [list(r) for r in self.lost_ranges()]}


def nuisance_free(displacement: np.ndarray, templates: FlowTemplates) -> np.ndarray:
    """``displacement`` (..., rows, cols, 2) with the templates' nuisance motions projected
    out on the face mask and zero off the mask."""
    d = remove_rigid(displacement, templates.mask, templates.nuisance)
    d = np.array(d, copy=True)
    d[..., ~templates.mask, :] = 0.0
    return d


def _masked_clean(displacement: np.ndarray, templates: FlowTemplates
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Nuisance-free displacement on the mask, ``(T, n, 2)`` ``float32``, and its motion
    energy ``(T,)``, computed a chunk of frames at a time (NaN frames stay NaN)."""
    m = templates.mask
    disp = displacement
    out = np.empty((len(disp), int(m.sum()), 2), np.float32)
    energy = np.empty(len(disp))
    for a in range(0, len(disp), _CHUNK):
        chunk = remove_rigid(disp[a:a + _CHUNK], m, templates.nuisance)[:, m, :]
        out[a:a + _CHUNK] = chunk
        energy[a:a + _CHUNK] = np.sqrt(np.mean(np.sum(chunk ** 2, axis=-1), axis=1))
    return out, energy


def _rows(clean, templates: FlowTemplates, a: int, b: int) -> np.ndarray:
    """Frames ``a..b-1`` of ``clean`` on the mask, ``(b - a, n, 2)`` float64, NaN as 0."""
    part = clean[a:b]
    part = part[:, templates.mask, :] if part.ndim == 4 else part
    return np.nan_to_num(np.asarray(part, dtype=np.float64))


class _FrameStore:
    """Per-frame ``(n, 2)`` ``float32`` arrays kept in a temporary file, not in memory.

    Classification reads a segment's frames after its end is known; keeping every frame's
    displacement in memory would make memory grow with the video (16 kB a frame), so the
    frames go to disk and only the few read back at a time are in memory. Frames never
    written read as NaN (lost). Sliced like an array: ``store[a:b]``.
    """

    def __init__(self, n_frames: int, shape: tuple[int, int]):
        import tempfile

        self.shape = (int(n_frames), *shape)
        self.ndim = 3
        self._row = int(np.prod(shape))
        self._file = tempfile.TemporaryFile()     # noqa: SIM115 - closed by close()
        self._written = np.zeros(n_frames, bool)

    def __len__(self) -> int:
        return self.shape[0]

    def __setitem__(self, i: int, value: np.ndarray) -> None:
        self._file.seek(int(i) * self._row * 4)
        self._file.write(np.ascontiguousarray(value, dtype=np.float32).tobytes())
        self._written[i] = True

    def __getitem__(self, key: slice) -> np.ndarray:
        a, b, step = key.indices(len(self))
        if step != 1:
            raise ValueError("a frame store is read in contiguous ranges")
        b = max(a, b)
        self._file.seek(a * self._row * 4)
        buf = self._file.read((b - a) * self._row * 4)
        out = np.full((b - a) * self._row, np.nan, np.float32)
        got = np.frombuffer(buf, np.float32)
        out[:got.size] = got
        out = out.reshape(b - a, *self.shape[1:])
        out[~self._written[a:b]] = np.nan
        return out

    def close(self) -> None:
        self._file.close()


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
#: Classifications in several threads share the cache; its eviction reads and changes it.
_PREP_LOCK = threading.Lock()


def _prepared(templates: FlowTemplates) -> _Prepared:
    key = id(templates)
    with _PREP_LOCK:
        hit = _PREP_CACHE.get(key)
    if hit is None or hit.t is not templates:
        hit = _Prepared(templates)
        with _PREP_LOCK:
            _PREP_CACHE[key] = hit
            if len(_PREP_CACHE) > 8:
                _PREP_CACHE.pop(next(iter(_PREP_CACHE)))
    return hit


def score_segment(clean: np.ndarray, templates: FlowTemplates, start: int, apex: int,
                  end: int | None = None) -> dict[str, float]:
    """Scores of the expressions for the segment ``clean[start..end]`` with its apex.

    Parameters
    ----------
    clean : (T, rows, cols, 2) or (T, n, 2)
        Nuisance-free displacement from neutral (:func:`nuisance_free`), on the grid or
        already restricted to the ``n`` cells of the templates' mask.
    templates : FlowTemplates
    start, apex, end : int
        Positions in ``clean`` (``end`` inclusive; default ``apex``).
    """
    p = _prepared(templates)
    end = apex if end is None else int(end)
    s0 = max(0, start - 1)                     # the frame before the onset as its zero
    idx = np.linspace(s0, apex, p.steps + 1)[1:]
    lo = np.floor(idx).astype(int)
    hi = np.minimum(lo + 1, apex)
    w = (idx - lo)[:, None, None]
    # only the frames the onset needs, then the segment a chunk at a time: a long segment
    # (or one read from disk, :class:`_FrameStore`) is never held whole
    rows = {r: _rows(clean, templates, r, r + 1)[0] for r in {s0, *lo.tolist(), *hi.tolist()}}
    onset = (1 - w) * np.stack([rows[r] for r in lo]) + w * np.stack([rows[r] for r in hi])
    onset_flat = onset.reshape(p.steps, -1)
    prev = np.concatenate([rows[s0][None], onset[:-1]], axis=0)
    energy = np.sum((onset - prev) ** 2, axis=(0, -1))
    wd, we = WEIGHTS
    onset_score = np.array([wd * _cos(onset_flat, p.expr[e]) + we * _cos(energy, p.energy[e])
                            for e in range(len(templates.expressions))])
    # the whole segment votes: energy-weighted cosine of each frame with the apex templates
    # (weights norm / sum of norms, so the weighted mean is sum(dots) / sum(norms))
    dots = np.zeros(len(onset_score))
    norm_sum = 0.0
    votes = np.zeros(len(onset_score))
    for c in range(start, end + 1, _CHUNK):
        seg = _rows(clean, templates, c, min(c + _CHUNK, end + 1))
        seg = seg.reshape(len(seg), -1)
        norms = np.linalg.norm(seg, axis=1)
        d = seg @ p.apex.T
        dots += d.sum(axis=0)
        norm_sum += float(norms.sum())
        moving = norms > 0
        votes += np.bincount(np.argmax(d[moving], axis=1), minlength=len(onset_score))
    mean_cos = dots / max(norm_sum, 1e-12)
    similarity = 0.5 * (onset_score + mean_cos)
    share = votes / max(votes.sum(), 1)
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
        without segments); ``scores`` are that segment's. Segments matching no expression
        are in ``unmatched``.
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
    clean, energy = _masked_clean(disp, templates)                # (T, n, 2) float32
    return _classify_clean(clean, energy, np.asarray(fr), templates, thr, min_score=min_score,
                           min_length=min_length, min_gap=min_gap)


def _classify_clean(clean, energy: np.ndarray, fr: np.ndarray, templates: FlowTemplates,
                    thr: float, *, min_score: float, min_length: int, min_gap: int,
                    photographs: bool = False) -> Recognition:
    """:func:`classify_flow` from the nuisance-free displacement on the mask (an array or a
    :class:`_FrameStore`) and its motion energy; ``photographs``: each active frame is a
    segment of its own (a photograph has no onset, nor neighbours to join)."""
    segments = []
    unmatched = []                     # segments matching no expression
    runs = ([(i, i) for i in np.flatnonzero(np.nan_to_num(energy, nan=-np.inf) > thr)]
            if photographs else
            find_segments(energy, thr, min_length=min_length, min_gap=min_gap))
    for a, b in runs:
        apex = a + int(np.nanargmax(energy[a:b + 1]))
        scores = score_segment(clean, templates, a, apex, b)
        similarity = scores.pop("_similarity")
        scores["neutral"] = 0.0
        label = max(templates.expressions, key=scores.get)
        matched = similarity[label] >= min_score
        (segments if matched else unmatched).append(
            Segment(int(fr[a]), int(fr[apex]), int(fr[b]), label if matched else UNMATCHED,
                    scores, float(energy[apex])))
    if segments:
        best = max(segments, key=lambda s: s.peak_energy)
        label, scores = best.label, dict(best.scores)
    else:
        label = "neutral"
        if unmatched:
            scores = dict(max(unmatched, key=lambda s: s.peak_energy).scores)
            scores["neutral"] = 1.0 - max(scores[n] for n in templates.expressions)
        else:
            peak = float(np.nanmax(energy)) if np.isfinite(energy).any() else 0.0
            scores = {name: 0.0 for name in templates.expressions}
            scores["neutral"] = 1.0 - 0.5 * min(peak / thr, 1.0)
    return Recognition(label=label, scores=scores, segments=segments, energy=energy,
                       frames=np.asarray(fr), threshold=thr, unmatched=unmatched)


class _ContractionFit:
    """Least-squares fit of the templates' per-control flow to nuisance-free frames."""

    def __init__(self, templates: FlowTemplates):
        m = templates.mask
        basis = remove_rigid(templates.control, m, templates.nuisance)[:, m, :]
        self.A = (basis.reshape(len(basis), -1)
                  * np.asarray(templates.upper, float)[:, None]).T
        G = self.A.T @ self.A
        # a light ridge keeps correlated controls apart
        self.G = G + 1e-3 * np.trace(G) / len(G) * np.eye(len(G))
        self.controls = len(basis)

    def __call__(self, clean: np.ndarray) -> np.ndarray:
        """``(k, n, 2)`` nuisance-free frames on the mask -> ``(k, M)``, NaN rows where lost."""
        out = np.full((len(clean), self.controls), np.nan)
        ok = np.isfinite(clean).all(axis=(1, 2))
        if ok.any():
            rhs = self.A.T @ clean[ok].reshape(int(ok.sum()), -1).astype(np.float64).T
            out[ok] = np.linalg.solve(self.G, rhs).T
        return out


def _stream_chunks(stream):
    """``(positions, displacement (k, rows, cols, 2))`` a chunk of a
    :class:`~faceanalysis.flow.dense.VideoFlowStream`'s frames at a time."""
    pos, buf = [], []
    for i, d in stream:
        pos.append(i)
        buf.append(d)
        if len(buf) == _CHUNK:
            yield np.array(pos), np.stack(buf)
            pos, buf = [], []
    if buf:
        yield np.array(pos), np.stack(buf)


class _HeldBack(logging.Filter):
    """Within it, ``logger``'s records are held back, to be logged later (:meth:`release`)
    or never: they may concern a choice not yet made."""

    def __init__(self, logger: logging.Logger):
        super().__init__()
        self.logger, self.records = logger, []

    def filter(self, record) -> bool:
        self.records.append(record)
        return False

    def __enter__(self):
        self.logger.addFilter(self)
        return self

    def __exit__(self, *exc):
        self.logger.removeFilter(self)
        return False

    def release(self) -> None:
        for record in self.records:
            self.logger.handle(record)
        self.records = []


class _Classified:
    """The frames of the classified range as the pass from the reference frame keeps them:
    the nuisance-free displacement in a :class:`_FrameStore`, the motion energy, and (to judge
    the reference again) the total contraction of every streamed frame."""

    def __init__(self, stream_frames: np.ndarray, start: int, templates: FlowTemplates,
                 total: bool):
        self.stream_frames = stream_frames
        self.keep = stream_frames >= start           # frames before the range: not classified
        self.row = np.cumsum(self.keep) - 1
        self.frames = stream_frames[self.keep]
        self.templates = templates
        self.store = _FrameStore(len(self.frames), (int(templates.mask.sum()), 2))
        self.energy = np.full(len(self.frames), np.nan)
        self.fit = _ContractionFit(templates) if total else None
        self.total = np.full(len(stream_frames), np.nan)

    def add(self, pos: np.ndarray, disp: np.ndarray, cleaned=None) -> None:
        """Frames ``pos`` of the stream with their displacement; ``cleaned``: their
        :func:`_masked_clean` with these templates where the caller has it already."""
        clean, energy = _masked_clean(disp, self.templates) if cleaned is None else cleaned
        if self.fit is not None:
            self.total[pos] = self.fit(clean).sum(axis=1)
        for i, c, v in zip(pos, clean, energy):
            if self.keep[i]:
                self.store[self.row[i]] = c
                self.energy[self.row[i]] = v


def relative_contraction(flow: FaceFlow | np.ndarray, templates: FlowTemplates
                         ) -> np.ndarray:
    """Each frame's contractions relative to the flow's reference frame, ``(T, M)``.

    The nuisance-free displacement of every frame is explained by the templates'
    per-control flow (:attr:`FlowTemplates.control`, nuisance removed, on the mask) by
    least squares (a light ridge keeps correlated controls apart). Coefficients are in
    fractions of each control's range (:attr:`FlowTemplates.upper`): ``+0.5`` on a muscle
    is half its full contraction more than on the reference frame. NaN rows for frames
    without flow.
    """
    disp = flow.displacement if isinstance(flow, FaceFlow) else np.asarray(flow, float)
    fit = _ContractionFit(templates)
    out = np.full((len(disp), fit.controls), np.nan)
    for a in range(0, len(disp), _CHUNK):        # a chunk at a time: no copy of the clip
        out[a:a + _CHUNK] = fit(_masked_clean(disp[a:a + _CHUNK], templates)[0])
    return out


def rest_frame(flow: FaceFlow, templates: FlowTemplates, *, margin: float = REST_MARGIN
               ) -> tuple[int, np.ndarray]:
    """The frame of a clip whose face is most at rest.

    Parameters
    ----------
    flow : FaceFlow
        Flow from any reference frame (e.g. the first tracked one).
    templates : FlowTemplates
        Their per-control flow (:func:`relative_contraction`).
    margin : float
        The flow's reference is kept unless another frame's total contraction (a 5-frame
        running median) is smaller by at least this much (default :data:`REST_MARGIN`)
        and by :data:`REST_NOISE` times the clip's frame-to-frame noise of the total.

    Returns
    -------
    frame : int
        Frame number of the least contracted frame (muscles only contract, so the face at
        rest has the smallest total contraction), or the reference itself.
    total : ndarray (T,)
        Total contraction of each frame relative to the reference (NaN where unknown).
    """
    total = relative_contraction(flow, templates).sum(axis=1)
    frame, _ = _pick_rest(total, np.asarray(flow.frames), int(flow.reference), margin=margin)
    return frame, total


def _pick_rest(total: np.ndarray, frames: np.ndarray, reference: int, *,
               margin: float = REST_MARGIN) -> tuple[int, str]:
    """The rest frame from the total contraction relative to ``reference`` (see
    :func:`rest_frame`) and what can be said of it: ``'still'`` (the face holds there for
    :data:`REST_HOLD` frames), ``'moving'`` (it does not: a lull in an expression rather
    than rest) or ``'unresolved'`` (the clip's frame-to-frame noise of the total exceeds
    the margin: the detector cannot tell a rest frame on this clip)."""
    from scipy.ndimage import median_filter

    ok = np.isfinite(total)
    if ok.sum() < 3:
        return reference, "unresolved"
    # a 5-frame running median: a single mistracked frame is not a rest frame
    smooth = np.full_like(total, np.nan)
    smooth[ok] = median_filter(total[ok], size=5, mode="nearest")
    # the clip's own frame-to-frame noise (robust SD of the second difference, which a
    # smooth expression hardly has, so that a clip's motion is not taken for noise): a frame
    # must be less contracted than the reference by more than noise can explain
    noise = 1.4826 * float(np.median(np.abs(np.diff(total[ok], 2)))) / np.sqrt(6.0)
    tol = max(margin, REST_NOISE * noise)
    best = int(np.nanargmin(smooth))
    at_ref = np.flatnonzero(frames == reference)
    ref_pos = int(at_ref[0]) if at_ref.size and ok[at_ref[0]] else None
    ref_total = float(smooth[ref_pos]) if ref_pos is not None else 0.0
    pick = best if ref_total - float(smooth[best]) >= tol else ref_pos
    if pick is None:
        return reference, "unresolved"
    if REST_NOISE * noise > 2.0 * margin:
        return int(frames[pick]), "unresolved"
    # a face at rest stays there a while; the least contracted instant of a laugh (a lull
    # between two bursts) does not: the total rises again within a few frames on both sides
    good = np.flatnonzero(ok)
    k = int(np.searchsorted(good, pick))
    sides = [smooth[good[max(0, k - REST_HOLD):k]], smooth[good[k + 1:k + 1 + REST_HOLD]]]
    still = any(len(v) == REST_HOLD and np.all(np.abs(v - smooth[pick]) < 0.5 * tol)
                for v in sides)
    return int(frames[pick]), "still" if still else "moving"


def classify_video(video: str | os.PathLike, *, templates: FlowTemplates | None = None,
                   table: pd.DataFrame | None = None, neutral: int | None = None,
                   method: str = "dis", fps: float | None = None, start: int = 0,
                   end: int | None = None, personalised: bool = True,
                   rest_lookback: int = REST_LOOKBACK, threshold: float | None = None,
                   min_score: float = MIN_SCORE, min_length: int = 3,
                   min_gap: int = 5, hidden=None,
                   photographs: bool | None = None) -> Recognition:
    """Recognise the expressions of a video (flow from its neutral frame, then
    :func:`classify_flow`), in memory that does not grow with the video's length.

    Parameters
    ----------
    video : path-like, Frames or array_like
        As :func:`faceanalysis.analysis.pipeline.analyze` takes it.
    templates : FlowTemplates, optional
        Default: the generic face model's (:func:`faceanalysis.flow.templates.default_templates`).
    table : DataFrame, optional
        Head frames (e.g. an analysis's ``contractions.csv``); default: tracked.
    neutral : int, optional
        Neutral frame number; it may precede ``start`` (the frames between are tracked,
        not classified). Default: the detected rest frame (:func:`rest_frame`: the least
        contracted frame by the templates' per-muscle flow) of the range and of the
        ``rest_lookback`` frames before it; the first tracked frame of that span unless
        another is clearly more at rest. The frame used is ``Recognition.reference``,
        how it was chosen ``reference_source`` and whether the face holds still there
        ``reference_rest``.
    method, fps, start, end
        See :func:`faceanalysis.flow.dense.video_face_flow`. ``start`` and ``end`` bound
        the frames classified, not where the reference may come from.
    personalised : bool
        Warp the templates onto the subject's neutral fiducials
        (:func:`faceanalysis.flow.personalize.personalize_from_table`).
    rest_lookback : int, keyword-only
        Frames before ``start`` searched for the rest frame (default
        :data:`~faceanalysis.flow.options.REST_LOOKBACK`): a clip cut in the middle of an
        expression has no rest frame of its own, while the video often shows the face at
        rest just before.
    threshold, min_score, min_length, min_gap
        See :func:`classify_flow`.
    hidden : iterable of int, optional
        Frames on which the face cannot be seen, whose flow is lost rather than bridged
        (:func:`~faceanalysis.flow.dense.video_face_flow`); default: those the tracking
        finds when ``table`` is tracked here, none of a given table's (an analysis's are
        :func:`faceanalysis.io.report.hidden_frames_of` its ``analysis.json``).
    photographs : bool, optional
        The frames are photographs (default: a folder of images given without ``fps``, as
        the analysis takes it, :func:`faceanalysis.io.video.is_photographs`): each
        photograph with an expression is a segment of its own, named by the same scores
        (``min_length`` and ``min_gap`` do not apply), and the neutral reference defaults
        to the first with a face.

    Returns
    -------
    Recognition
        With ``reference``, ``reference_source`` and ``reference_rest`` set.

    Notes
    -----
    The flow is streamed from the first frame of the search span to find the rest frame,
    every frame reduced to its total contraction, then from the rest frame, each frame's
    displacement on the face mask going to a temporary file (16 kB a frame on disk) from
    which the segments are scored. Where the rest frame is the first tracked frame and the
    range starts where the search does, the second stream would be the first again: the
    first keeps the range's frames as the second would (with the templates personalised
    on that frame), and the video is streamed once.
    """
    from faceanalysis.flow.dense import VideoFlowStream
    from faceanalysis.flow.personalize import personalize_from_table
    from faceanalysis.io.video import as_video
    from faceanalysis.tracking import hidden_frames, track

    video = as_video(video)         # frames in memory: messages name them, not their pixels
    if templates is None:
        from faceanalysis.flow.templates import default_templates

        templates = default_templates()
    if neutral is not None and neutral < 0:
        raise ValueError(f"neutral frame {neutral} must be >= 0")
    if end is not None and neutral is not None and neutral >= end:
        raise ValueError(f"neutral frame {neutral} lies after the range end {end}")
    if rest_lookback < 0:
        raise ValueError(f"rest_lookback={rest_lookback} must be >= 0")
    thr = NEUTRAL_THRESHOLD if threshold is None else float(threshold)
    if not thr > 0:
        raise ValueError(f"threshold={thr} must be positive")
    if photographs is None:
        photographs = _photographs(video, fps)
    if photographs:
        rest_lookback = 0               # no rest frame to look for before the range
    first = max(0, start - rest_lookback) if neutral is None else min(start, int(neutral))
    if table is None:
        # the contours are not needed here; keeping them would grow with the video
        tracks = track(video, fps=fps, start=first, end=end, redetect=True,
                       keep_contours=False)
        table = tracks.table
        if hidden is None:
            hidden = hidden_frames(tracks.frames, tracks.lost_reasons)
        del tracks                 # its face meshes: 6 kB a frame that nothing here reads
    options = dict(table=table, method=method, grid=templates.grid, fps=fps, end=end,
                   hidden=hidden)
    rest = None
    kept = None
    given = "given"
    if neutral is None and photographs:
        # as the analysis takes photographs: the first with a face is the neutral one
        seen = table[(table["frame"] >= start) & (table["success"] == 1)]
        if len(seen):
            neutral, given = int(seen["frame"].iloc[0]), "first_photograph"
    try:
        if neutral is None:
            stream = VideoFlowStream(video, start=first, **options)
            fit = _ContractionFit(templates)
            total = np.full(len(stream.frames), np.nan)
            # the pass from the rest frame would stream this same flow again where the rest
            # frame is the first tracked one (most clips) and the range starts where the
            # search does: this pass keeps the range's frames as that one would, with the
            # templates personalised there (their warnings held until that choice is made)
            guess = stream.reference if min(start, stream.reference) == first else None
            held = _HeldBack(logging.getLogger("faceanalysis.flow.personalize"))
            if guess is not None:
                with held:
                    personal = (personalize_from_table(templates, table, guess)
                                if personalised else templates)
                kept = _Classified(stream.frames, start, personal, total=False)
            for pos, disp in _stream_chunks(stream):
                cleaned = _masked_clean(disp, templates)
                total[pos] = fit(cleaned[0]).sum(axis=1)
                if kept is not None:
                    # (templates not personalised: the same cleaning serves both)
                    kept.add(pos, disp, cleaned if kept.templates is templates else None)
            ref, rest = _pick_rest(total, stream.frames, stream.reference)
            source = "first" if ref == stream.reference else "detected"
            if source == "detected":
                log.info("%s: frame %d is more at rest than the first tracked frame %d; it "
                         "is the neutral reference", video, ref, stream.reference)
            if kept is not None and ref == guess:
                held.release()
            elif kept is not None:
                kept.store.close()
                kept = None
            del stream, total
        else:
            ref, source = int(neutral), given
        # where the first pass could not tell rest from noise (its flow runs from the first
        # frame, perhaps the apex of an expression, and is noisy where it is large), the
        # flow from the rest frame found is small near it: judge there whether the face
        # holds still
        rejudge = rest == "unresolved" and source == "detected"
        if kept is None:
            if personalised:
                templates = personalize_from_table(templates, table, ref)
            stream = VideoFlowStream(video, neutral=ref, start=min(start, ref), **options)
            kept = _Classified(stream.frames, start, templates, total=rejudge)
            for pos, disp in _stream_chunks(stream):
                kept.add(pos, disp)
        else:
            templates = kept.templates
        rec = _classify_clean(kept.store, kept.energy, kept.frames, templates, thr,
                              min_score=min_score, min_length=min_length, min_gap=min_gap,
                              photographs=photographs)
    finally:
        if kept is not None:
            kept.store.close()
    if rejudge:
        again, verdict = _pick_rest(kept.total, kept.stream_frames, ref)
        if again == ref:
            rest = verdict
    return replace(rec, reference=int(ref), reference_source=source, reference_rest=rest)


def _photographs(video, fps) -> bool:
    """Whether ``video`` is taken as photographs (an image folder without ``fps``)."""
    from faceanalysis.io.video import Frames, open_video

    if isinstance(video, Frames):
        return False
    with open_video(video, fps=fps) as source:
        return source.photographs


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
