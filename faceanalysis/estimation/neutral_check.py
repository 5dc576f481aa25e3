"""Is the neutral frame at rest? A free fit of every frame against it tells raised brows;
the lips' gap tells an open mouth.

Every contraction is measured from the neutral frame. Where that frame shows an expression
(brows raised as a subject starts to speak, a clip cut to start mid-sentence), the
estimators, which bound each contraction at 0, cannot read the face relaxing below it: the
brows coming down read as rest, and every later raise is read short. A fit without bounds
or prior through the response linearised at rest (:func:`below_neutral`) reads such frames
as negative contractions. For the frontalis the points tell the muscles apart well enough
for that to be a measurement: on cap12 and cap13 analysed from 31 later starting frames (300
frames from each) and whole, the 6 starts whose brows the whole clip's analysis reads raised
by 0.58 or more had 0.85-0.98 of their frames reading a frontalis more than :data:`BELOW` of
its range below them, and the 27 others at most 0.73 (the lower face's controls, which the
points tell apart less well, read below rest on most frames of clips that start at rest).

An open mouth on the neutral frame (a clip cut to start mid-sentence) is told by the
face mesh's inner lips instead (:func:`open_mouth`): the free fit reads the jaw below the
neutral frame only for a wide-open mouth, while lips parted by a tenth of the inter-ocular
distance already bias the lower face (the figures are in ``docs/limitations.md``). A frame
offered instead (:mod:`faceanalysis.analysis.neutral`) has the brows down, the lips closed
and the mouth not widened (:func:`brows_down`, :func:`closed_lips`, :func:`narrow_mouth`).
"""

from __future__ import annotations

import numpy as np

from faceanalysis.estimation.response import FiducialResponse

__all__ = ["BELOW", "BELOW_SHARE", "BROWS", "CLOSED_RUN", "MIN_FRAMES", "MOUTH_OPEN",
           "MOUTH_WIDE", "MOUTH_WIDER", "REST_PERCENTILE", "below_neutral", "brows_down",
           "closed_lips", "free_fit", "narrow_mouth", "nearest", "open_mouth", "wide_mouth"]

#: The controls checked: the frontalis, whose free fit the points determine.
BROWS = tuple(f"frontalis_{part}_{side}" for part in ("inner", "major", "outer")
              for side in "lr")

#: A frame reads a control below the neutral frame when its free fit is lower by more than
#: this share of the control's range.
BELOW = 0.15

#: The neutral frame is taken to show the control contracted when at least this share of
#: the tracked frames reads it below the neutral frame.
BELOW_SHARE = 0.8

#: Fewest tracked frames the check is made on.
MIN_FRAMES = 30

#: The mouth is taken as open on the neutral frame when its lips lie farther apart than
#: the clip's closed level by more than this many inter-ocular distances
#: (:func:`~trackers.landmark_contours.lip_gap`).
MOUTH_OPEN = 0.05

#: The clip's rest level of the lips' gap (its closed level) and of the brows' free fit:
#: this percentile over the tracked frames (a talking face closes its lips, and rests its
#: brows, on more than a tenth of its frames; the lowest frame can be a frown or noise).
REST_PERCENTILE = 10

#: The mouth is taken as widened on the neutral frame (a smile, closed-mouthed or not) when
#: its corners lie farther apart than the clip's rest level by more than this many
#: inter-ocular distances (:func:`wide_mouth`): a smile widens it by 0.1-0.3, a talking
#: mouth's corners move about 0.04 around their median.
MOUTH_WIDE = 0.09

#: A frame offered as nearer rest (:func:`narrow_mouth`) has its mouth no wider than the
#: clip's rest level by more than this many inter-ocular distances: talking moves the mouth
#: corners' distance by about 0.04 around its median, a smile or a grimace widens it by 0.1-0.2.
MOUTH_WIDER = 0.04

#: A frame offered instead starts a run of at least this many tracked frames whose lips
#: lie within ``MOUTH_OPEN / 2`` of the closed level (a pause, not a consonant's closure).
CLOSED_RUN = 5


def below_neutral(displacements: np.ndarray, response: FiducialResponse, *,
                  weights: np.ndarray | None = None, controls=BROWS,
                  fit=None) -> tuple[dict[str, float], int | None]:
    """How often each of ``controls`` reads below the neutral frame, and the frame where
    they read lowest.

    Parameters
    ----------
    displacements : ndarray, shape (T, P, 2)
        The points' displacements from the neutral frame (model units; NaN where a point
        is not seen, whole rows where a frame is lost), as the estimators read them.
    response : FiducialResponse
        The model response of those points.
    weights : ndarray, shape (P,), optional
        Each point's weight in the fit (the estimator's); equal by default.
    controls : sequence of str, keyword-only
        The controls to report (of ``response.muscles``; others are left out).
    fit : tuple, optional
        :func:`free_fit` of the same, computed already.

    Returns
    -------
    shares : dict
        Control -> share of the frames with at least half the points seen whose free fit
        (least squares through the response linearised at rest, no bounds, no prior) reads
        it more than :data:`BELOW` of its range below 0. Empty under :data:`MIN_FRAMES`
        such frames.
    lowest : int or None
        The row where the mean of the reported controls' free fit is lowest (a frame
        nearer rest, if the neutral frame is not); None where ``shares`` is empty.

    Examples
    --------
    >>> import numpy as np
    >>> from faceanalysis.estimation.response import FiducialResponse
    >>> levels = np.linspace(0, 1, 3)
    >>> disp = np.zeros((1, 3, 2, 2))
    >>> disp[0, :, :, 1] = -levels[:, None]          # the muscle lifts both points
    >>> resp = FiducialResponse(("frontalis_major_l",), ("p", "q"), np.zeros((2, 2)), disp,
    ...                         np.ones(1), levels)
    >>> seen = np.zeros((40, 2, 2))
    >>> seen[:, :, 1] = 0.3                          # every frame lower than the neutral
    >>> seen[7, :, 1] = 0.5
    >>> shares, lowest = below_neutral(seen, resp)
    >>> shares, lowest
    ({'frontalis_major_l': 1.0}, 7)
    """
    rows, free, names = (free_fit(displacements, response, weights=weights, controls=controls)
                         if fit is None else fit)
    if len(rows) < MIN_FRAMES or not names:
        return {}, None
    low = free < -BELOW
    shares = {name: float(s) for name, s in zip(names, low.mean(axis=0))}
    return shares, int(rows[np.argmin(free.mean(axis=1))])


def free_fit(displacements, response: FiducialResponse, *, weights=None, controls=BROWS):
    """Each frame's fit without bounds or prior through the response linearised at rest.

    Parameters as :func:`below_neutral`.

    Returns
    -------
    rows : ndarray of int
        The frames fitted: those with at least half the points seen.
    free : ndarray, shape (len(rows), C)
        The fit of each of the ``C`` ``controls`` in ``response.muscles``, in its range
        (empty under :data:`MIN_FRAMES` rows).
    names : list of str
        Those controls.
    """
    d = np.asarray(displacements, dtype=float)
    n_m = len(response.muscles)
    if d.ndim != 3 or d.shape[1:] != (len(response.fiducials), 2):
        raise ValueError(f"displacements must be (T, {len(response.fiducials)}, 2), got "
                         f"{d.shape}")
    w = np.ones(d.shape[1]) if weights is None else np.asarray(weights, dtype=float)
    cols = [response.muscles.index(c) for c in controls if c in response.muscles]
    names = [response.muscles[j] for j in cols]
    seen = np.isfinite(d).all(axis=2)                                   # (T, P)
    rows = np.flatnonzero(seen.sum(axis=1) >= 0.5 * d.shape[1])
    if len(rows) < MIN_FRAMES or not cols:
        return rows, np.empty((len(rows), len(cols))), names
    jac = response.jacobian(np.zeros((1, n_m)))[0]                      # (P*2, M)
    free = np.empty((len(rows), n_m))
    # frames that see the same points share one factorisation
    masks, group = np.unique(seen[rows], axis=0, return_inverse=True)
    for g, mask in enumerate(masks):
        sw = np.repeat(np.sqrt(w) * mask, 2)
        a = jac * sw[:, None]
        h = a.T @ a
        # a trace-scaled whisper of ridge: controls the seen points do not move stay 0
        h += 1e-6 * np.trace(h) / n_m * np.eye(n_m)
        at = group == g
        y = np.nan_to_num(d[rows[at]]).reshape(int(at.sum()), -1) * sw
        free[at] = np.linalg.solve(h, a.T @ y.T).T
    return rows, (free / response.upper)[:, cols], names


def brows_down(displacements, response: FiducialResponse, *, weights=None,
               controls=BROWS, fit=None) -> np.ndarray:
    """The frames whose brows are down: the mean free fit of ``controls`` (as
    :func:`below_neutral` fits them; ``fit``: :func:`free_fit` computed already) at most
    :data:`BELOW` above its rest level over the clip (its :data:`REST_PERCENTILE`
    percentile).

    Returns
    -------
    ndarray of bool, shape (T,)
        False where a frame is not fitted (under half its points seen) and on every frame
        under :data:`MIN_FRAMES` fitted ones.
    """
    rows, free, names = (free_fit(displacements, response, weights=weights, controls=controls)
                         if fit is None else fit)
    out = np.zeros(len(np.asarray(displacements)), bool)
    if len(rows) < MIN_FRAMES or not names:
        return out
    out[rows] = _above_rest(free.mean(axis=1), "levels") <= BELOW
    return out


def closed_lips(gaps) -> np.ndarray:
    """The frames inside a run of at least :data:`CLOSED_RUN` whose lips lie within
    ``MOUTH_OPEN / 2`` of the clip's closed level (the :data:`REST_PERCENTILE` percentile
    of the lip gaps ``gaps``, NaN where a frame is lost): a pause, not a consonant's
    closure. All False under :data:`MIN_FRAMES` frames with a gap.

    Examples
    --------
    >>> g = np.full(40, 0.2)
    >>> g[10:16] = g[30:32] = 0.01                   # a pause and a consonant
    >>> np.flatnonzero(closed_lips(g)).tolist()
    [10, 11, 12, 13, 14, 15]
    """
    return _closed_runs(_above_rest(gaps, "gaps"), len(np.asarray(gaps)))


def narrow_mouth(widths) -> np.ndarray:
    """The frames whose mouth is no wider than the clip's rest level (the
    :data:`REST_PERCENTILE` percentile of ``widths``, the mouth corners' distance in
    inter-ocular distances, NaN where a frame is lost) by more than :data:`MOUTH_WIDER`:
    no smile or grimace. All False under :data:`MIN_FRAMES` frames with a width.

    Examples
    --------
    >>> w = np.full(40, 0.8)
    >>> w[:10] = 1.0                                 # a smile
    >>> np.flatnonzero(~narrow_mouth(w)).tolist()
    [0, 1, 2, 3, 4, 5, 6, 7, 8, 9]
    """
    above = _above_rest(widths, "widths")
    if above is None:
        return np.zeros(len(np.asarray(widths)), bool)
    return above <= MOUTH_WIDER                       # (NaN, a lost frame: False)


def nearest(allowed, neutral: int) -> int | None:
    """The row of ``allowed`` (bool, shape (T,)) nearest ``neutral`` (the earlier of two
    as near); None where none is allowed.

    >>> nearest(np.array([True, False, False, True, True]), 2)
    3
    >>> nearest(np.array([True, False, True]), 1)
    0
    """
    rows = np.flatnonzero(np.asarray(allowed, bool))
    return int(rows[np.argmin(np.abs(rows - neutral))]) if rows.size else None


def open_mouth(gaps, neutral: int) -> tuple[float | None, int | None]:
    """How much farther apart the lips are on the neutral frame than the clip's closed
    level, and the frame nearest it whose lips are closed.

    Parameters
    ----------
    gaps : array_like, shape (T,)
        Each frame's lip gap in inter-ocular distances
        (:func:`~trackers.landmark_contours.lip_gap`); NaN where the frame is lost.
    neutral : int
        Row of the neutral frame.

    Returns
    -------
    excess : float or None
        The neutral frame's gap less the closed level (the :data:`REST_PERCENTILE`
        percentile of the gaps); None under :data:`MIN_FRAMES` frames with a gap or
        where the neutral frame has none. Over :data:`MOUTH_OPEN` the mouth is open there.
    closed : int or None
        The row nearest the neutral frame among :func:`closed_lips`; None if none is.

    Examples
    --------
    >>> g = np.full(60, 0.01)
    >>> g[:20] = 0.2                                 # talking over the first 20 frames
    >>> excess, closed = open_mouth(g, 0)
    >>> round(excess, 2), closed
    (0.19, 20)
    """
    above = _above_rest(gaps, "gaps", neutral)
    if above is None or not np.isfinite(above[neutral]):
        return None, None
    return float(above[neutral]), nearest(_closed_runs(above, len(above)), neutral)


def wide_mouth(widths, neutral: int) -> float | None:
    """How much farther apart the mouth corners are on the neutral frame than at the clip's
    rest level (the :data:`REST_PERCENTILE` percentile of ``widths``, the corners' distance
    in inter-ocular distances, :func:`~trackers.landmark_contours.mouth_width`; NaN where a
    frame is lost). Over :data:`MOUTH_WIDE` the mouth is widened there, as in a smile.
    None under :data:`MIN_FRAMES` frames with a width or where the neutral frame has none.

    Examples
    --------
    >>> w = np.full(60, 0.8)
    >>> w[:10] = 0.98                                # a smile over the first 10 frames
    >>> round(wide_mouth(w, 0), 2), round(wide_mouth(w, 30), 2)
    (0.18, 0.0)
    """
    above = _above_rest(widths, "widths", neutral)
    if above is None or not np.isfinite(above[neutral]):
        return None
    return float(above[neutral])


def _above_rest(values, name: str, neutral: int | None = None) -> np.ndarray | None:
    """Each of ``values`` (1-D; NaN where a frame is lost) less the clip's rest level, the
    :data:`REST_PERCENTILE` percentile of those seen; None under :data:`MIN_FRAMES` seen.
    ``neutral``, if given, must be a row of them."""
    v = np.asarray(values, dtype=float)
    if v.ndim != 1 or (neutral is not None and not 0 <= neutral < len(v)):
        inside = "" if neutral is None else f" with the neutral row {neutral} inside it"
        raise ValueError(f"{name} must be 1-D{inside}, got shape {v.shape}")
    seen = np.isfinite(v)
    if seen.sum() < MIN_FRAMES:
        return None
    return v - np.percentile(v[seen], REST_PERCENTILE)


def _closed_runs(gaps_above_rest, length: int) -> np.ndarray:
    """:func:`closed_lips` of the lip gaps less their rest level (None: too few frames)."""
    out = np.zeros(length, bool)
    if gaps_above_rest is None:
        return out
    shut = gaps_above_rest <= MOUTH_OPEN / 2                   # (NaN: False)
    run = np.convolve(shut, np.ones(CLOSED_RUN, int), mode="valid") == CLOSED_RUN
    for start in np.flatnonzero(run):
        out[start:start + CLOSED_RUN] = True
    return out
