"""Is the neutral frame at rest? A free fit of every frame against it tells raised brows.

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
"""

from __future__ import annotations

import numpy as np

from faceanalysis.estimation.response import FiducialResponse

__all__ = ["BELOW", "BELOW_SHARE", "BROWS", "MIN_FRAMES", "below_neutral"]

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


def below_neutral(displacements: np.ndarray, response: FiducialResponse, *,
                  weights: np.ndarray | None = None,
                  controls=BROWS) -> tuple[dict[str, float], int | None]:
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
    d = np.asarray(displacements, dtype=float)
    n_m = len(response.muscles)
    if d.ndim != 3 or d.shape[1:] != (len(response.fiducials), 2):
        raise ValueError(f"displacements must be (T, {len(response.fiducials)}, 2), got "
                         f"{d.shape}")
    w = np.ones(d.shape[1]) if weights is None else np.asarray(weights, dtype=float)
    cols = [response.muscles.index(c) for c in controls if c in response.muscles]
    seen = np.isfinite(d).all(axis=2)                                   # (T, P)
    rows = np.flatnonzero(seen.sum(axis=1) >= 0.5 * d.shape[1])
    if len(rows) < MIN_FRAMES or not cols:
        return {}, None
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
    free = free / response.upper
    low = free[:, cols] < -BELOW
    shares = {response.muscles[j]: float(s) for j, s in zip(cols, low.mean(axis=0))}
    return shares, int(rows[np.argmin(free[:, cols].mean(axis=1))])
