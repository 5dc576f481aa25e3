"""Which controls the seen measurement points can tell apart, at the measured tracking noise.

:func:`identifiability` linearises the model response and asks, for each control, how much of
its motion of the points no combination of the other controls reproduces, and what that
means for an unregularised fit: its standard error per centimetre of measurement noise.
That bound is pessimistic for the ``joint`` estimator, whose bounds and prior that muscles
rest carry it far below. :func:`estimator_errors` measures what the estimator itself does:
it simulates frames in which each control is active (with two others) through the model
response, adds noise, and scores the ``joint`` fit. :func:`tracking_noise` measures a tracked
video's noise from the frame-to-frame jitter of its points, and :func:`assess` puts them
together for ``analysis.json``: a control is *identifiable* when the estimator's simulated
error, at that noise and from the points seen, stays within :data:`IDENTIFIABLE_LIMIT` of the
control's range, and when, in the video's own estimates, it does not trade places with another
control (:func:`traded_pairs`).
"""

from __future__ import annotations

import threading
import weakref

import numpy as np
import pandas as pd

from faceanalysis.estimation.response import FiducialResponse

__all__ = ["identifiability", "estimator_errors", "tracking_noise", "traded_pairs", "assess",
           "mirror_partner", "mirror_agreement", "IDENTIFIABLE_LIMIT", "REFERENCE_NOISE_CM",
           "TRADE_LIMIT", "MIRROR_R", "MIRROR_FRAMES"]

#: Largest simulated RMS error of the ``joint`` estimate (a fraction of the control's range)
#: at which a control counts as identifiable.
IDENTIFIABLE_LIMIT = 0.1
#: Tracking noise assumed where a video is too short to measure its own (cm, per
#: coordinate): the frame-to-frame jitter of the tracked points on the real
#: clips in ``../shared/data/real`` (0.022-0.029 cm with either tracker).
REFERENCE_NOISE_CM = 0.025
#: Above this many points seen, :func:`assess` simulates half as many frames per control.
MANY_POINTS = 32
#: Second differences needed to measure a video's noise.
MIN_SAMPLES = 30
# Frames whose second differences :func:`tracking_noise` forms at a time.
_NOISE_CHUNK = 512
#: Correlation of two controls' frame-to-frame jitter at or below which they trade places
#: (:func:`traded_pairs`). On the real clips with ``mesh``, levator labii and its alar twin
#: reach -0.43 to -0.77 and the two mentalis -0.50 to -0.52; every other pair of active
#: controls stays above -0.33 (with ``joint``, every pair above -0.36).
TRADE_LIMIT = -0.5
#: Second differences, on each of the two controls, needed to judge a pair
#: (a 30-frame sequence's 28 give a correlation's standard error near 0.2).
TRADE_SAMPLES = 100
#: Standard deviation of a control's second differences below which it is taken as still.
TRADE_SPREAD = 0.01
#: Frames tracked in both the video and its mirror image from which :func:`mirror_agreement`
#: compares each control's series; fewer are compared frame by frame.
MIRROR_FRAMES = 30
#: Pearson r below which a moving control's series is not reproduced by its mirrored
#: partner's. On the real clips in ``../shared/data/real`` (``mesh``), the controls that
#: carry the clips' expressions (frontalis, zygomaticus major, depressor labii, both
#: sides) reach 0.78-0.98; 4-5 controls a clip stay under 0.5 (-0.03 to 0.46).
MIRROR_R = 0.5
#: Standard deviation (fraction of the range) over which a control's series moves.
MIRROR_MOVING = 0.02
#: Frame by frame, a value differs from its mirrored partner's when they are more than
#: this fraction of the range apart and more than :data:`MIRROR_SHARE` of the larger.
#: On the 20 IMM people's smiles (neutral then smile), no side of zygomaticus major
#: differs so (it reads 0.08-0.86); the side-lit neutrals' readings over 0.1 mostly do.
MIRROR_GAP = 0.1
MIRROR_SHARE = 0.5


def identifiability(response: FiducialResponse, *, level: float = 0.0,
                    points=None) -> pd.DataFrame:
    """How far the response's measurement points tell each control from the others.

    The response is linearised at every control at ``level`` of its range. A control's
    *signature* is the motion of all the points over its full range; the *independent*
    share is the part of that signature that no combination of the other controls'
    signatures reproduces (1: only this control moves the points so; 0: others can
    stand in for it); the *standard error* is that of an unregularised least-squares fit
    of all the controls at once per centimetre of measurement noise on each coordinate
    (the diagonal of ``(J^T J)^-1``, square-rooted, in the control's own units). The
    regularisation and the bounds of :func:`~faceanalysis.estimation.estimators.estimate_joint`
    keep real estimates far below it, but only by leaning on the prior that muscles
    rest: a control with a small independent share is read from the points only
    together with the others.

    Parameters
    ----------
    response : FiducialResponse
    level : float, keyword-only
        Where to linearise, as a fraction of each control's range, in [0, 1).
    points : sequence of str, optional
        The measurement points that are seen (default all of ``response.fiducials``).

    Returns
    -------
    DataFrame
        Indexed by control: ``signature`` (cm), ``independent`` (0..1) and
        ``standard_error`` (contraction units, radians for the jaw, per cm of noise),
        best first.

    Raises
    ------
    ValueError
        If ``level`` is outside [0, 1), or ``points`` names a point the response lacks.

    Examples
    --------
    Two points moved by three controls, the third nearly the sum of the other two:

    >>> full = np.array([[[1.0, 0.0], [0.0, 0.0]],             # a moves p right
    ...                  [[0.0, 0.0], [1.0, 0.0]],             # b moves q right
    ...                  [[1.0, 0.1], [1.0, 0.0]]])            # ab: both, p a little up
    >>> disp = np.stack([np.zeros_like(full), full], axis=1)   # levels 0 and 1
    >>> r = FiducialResponse(("a", "b", "ab"), ("p", "q"), np.zeros((2, 2)), disp,
    ...                      np.ones(3), np.array([0.0, 1.0]))
    >>> identifiability(r).round(2)  # doctest: +NORMALIZE_WHITESPACE
             signature  independent  standard_error
    control
    ab            1.42         0.07           10.00
    a             1.00         0.10           10.05
    b             1.00         0.10           10.05

    Each control is a tenth or less its own: 0.1 cm of noise on the points moves each
    estimate by about 1 (its whole range) in a fit without a prior.
    """
    if not 0.0 <= level < 1.0:
        raise ValueError(f"level must be in [0, 1), got {level}")
    upper = np.asarray(response.upper, dtype=float)
    jac = response.jacobian((level * upper)[None])[0] * upper           # (2P, M), cm
    if points is not None:
        unknown = sorted(set(points) - set(response.fiducials))
        if unknown:
            raise ValueError(f"unknown measurement point(s) {unknown}; the response has "
                             f"{', '.join(response.fiducials)}")
        rows = [2 * response.fiducials.index(p) + a for p in points for a in (0, 1)]
        jac = jac[rows]
    signature = np.linalg.norm(jac, axis=0)
    # the part of each column the others leave unexplained; its norm is also
    # 1 / sqrt((J^T J)^-1_mm), so the standard error needs no inverse of its own
    own = np.empty(len(upper))
    for m in range(len(upper)):
        q, _ = np.linalg.qr(np.delete(jac, m, axis=1))
        own[m] = np.linalg.norm(jac[:, m] - q @ (q.T @ jac[:, m]))
    independent = np.divide(own, signature, out=np.zeros_like(own), where=signature > 0)
    se = np.full(len(upper), np.inf)
    told = independent > 1e-9
    se[told] = upper[told] / own[told]
    out = pd.DataFrame({"signature": signature, "independent": independent,
                        "standard_error": se}, index=pd.Index(response.muscles, name="control"))
    return out.sort_values("standard_error")


def tracking_noise(displacements: np.ndarray, *, points=None) -> tuple[float | None, int]:
    """Noise of tracked points per coordinate (cm) from their frame-to-frame jitter.

    For white noise of standard deviation s on a smooth motion, the second difference
    ``d[t+1] - 2 d[t] + d[t-1]`` has standard deviation ``sqrt(6) s``; its median absolute
    deviation (robust to the motion's own bursts) gives s. Frames where a point is NaN
    break its runs.

    Parameters
    ----------
    displacements : ndarray, shape (T, P, 2)
        Point displacements (cm) per frame; NaN where not measured.
    points : sequence of int, optional, keyword-only
        The points (columns of ``displacements``) to read; default all.

    Returns
    -------
    (float or None, int)
        The noise (None with fewer than :data:`MIN_SAMPLES` second differences) and the
        number of second differences it was measured on.

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> t = np.linspace(0, 1, 400)[:, None, None]
    >>> d = np.sin(3 * t) + rng.normal(0, 0.02, (400, 5, 2))
    >>> round(tracking_noise(d)[0], 3)
    0.02
    >>> round(tracking_noise(d, points=[0, 2])[0], 2)
    0.02
    """
    d = np.asarray(displacements, dtype=float)
    if d.ndim != 3 or d.shape[2] != 2:
        raise ValueError(f"displacements must have shape (T, P, 2), got {d.shape}")
    cols = np.arange(d.shape[1]) if points is None else np.asarray(points, dtype=np.intp)
    if cols.ndim != 1 or (cols.size and (cols.min() < -d.shape[1]
                                         or cols.max() >= d.shape[1])):
        raise ValueError(f"points must index the {d.shape[1]} points of displacements, "
                         f"got {points!r}")
    if d.shape[0] < 3:
        return None, 0
    # a chunk of frames at a time, into one buffer: a long video's second differences are
    # as large as its displacements, and each temporary of them is one more such array
    second = np.empty((d.shape[0] - 2) * cols.size * 2)
    n = 0
    for a in range(0, d.shape[0] - 2, _NOISE_CHUNK):
        seg = d[a:a + _NOISE_CHUNK + 2][:, cols]
        diff = seg[1:-1] * -2.0               # the same sums as d[2:] - 2 d[1:-1] + d[:-2]
        diff += seg[2:]
        diff += seg[:-2]
        diff = diff[np.isfinite(diff)]
        second[n:n + diff.size] = diff
        n += diff.size
    second = second[:n]
    if second.size < MIN_SAMPLES:
        return None, int(second.size)
    # (the median does not depend on the order its partition leaves the values in)
    second -= np.median(second, overwrite_input=True)
    mad = np.median(np.abs(second, out=second), overwrite_input=True)
    return float(1.4826 * mad / np.sqrt(6.0)), int(second.size)


def estimator_errors(response: FiducialResponse, noise: float, *, points=None,
                     draws: int = 24, seed: int = 0, **fit_options) -> pd.Series:
    """RMS error of the ``joint`` estimate of each control, simulated at ``noise``.

    For each control, ``draws`` frames in which it is at a uniform level in [0.2, 0.8] of its
    range and two other controls, drawn at random, in [0, 0.6]; their displacements through
    the response, with Gaussian noise of ``noise`` cm on each coordinate and the points not in
    ``points`` missing, are fitted by
    :func:`~faceanalysis.estimation.estimators.estimate_joint` (with ``fit_options``, e.g. the
    ``sparsity`` and point ``weights`` an estimator used, frame by frame: without a temporal
    prior). Deterministic for a ``seed``.

    Returns
    -------
    Series
        Per control, the RMS error as a fraction of its range; NaN for a control no point
        in ``points`` observes (the estimator leaves it empty).

    Examples
    --------
    >>> from faceanalysis.estimation.model_response import model_response
    >>> err = estimator_errors(model_response(), 0.006)
    >>> bool(err["frontalis_inner_l"] < 0.1), bool(err["levator_labii_l"] > 0.1)
    (True, True)
    """
    from faceanalysis.estimation.estimators import estimate_joint

    if not (np.isfinite(noise) and noise >= 0):
        raise ValueError(f"noise={noise} must be a non-negative number of cm")
    # the simulation is deterministic: a short video or a photograph (the reference noise,
    # every point seen) asks the same question as the last one did
    key = None
    if isinstance(seed, (int, np.integer)):
        key = (float(noise), None if points is None else tuple(points), int(draws), int(seed),
               _fingerprint(fit_options))
        with _ERRORS_LOCK:
            known = _ERRORS.get(response, {}).get(key)
        if known is not None:
            return known.copy()
    rng = np.random.default_rng(seed)
    n, upper = len(response.muscles), np.asarray(response.upper, dtype=float)
    c = np.zeros((n * draws, n))
    for m in range(n):
        rows = slice(m * draws, (m + 1) * draws)
        c[rows, m] = rng.uniform(0.2, 0.8, draws)
        others = [j for j in range(n) if j != m]
        for k in range(draws):
            c[m * draws + k, rng.choice(others, 2, replace=False)] = rng.uniform(0.0, 0.6, 2)
    c *= upper
    d = response.predict(c) + rng.normal(0.0, noise, (len(c), len(response.fiducials), 2))
    if points is not None:
        unknown = sorted(set(points) - set(response.fiducials))
        if unknown:
            raise ValueError(f"unknown measurement point(s) {unknown}")
        d[:, [i for i, p in enumerate(response.fiducials) if p not in set(points)]] = np.nan
    # the simulated frames are independent draws, not a sequence
    est = estimate_joint(d, response, **{**fit_options, "temporal": 0.0})
    err = np.sqrt(np.mean(((est - c) ** 2).reshape(n, draws, n), axis=1))      # (m, control)
    out = pd.Series(np.diag(err) / upper, index=pd.Index(response.muscles, name="control"))
    if key is not None:
        with _ERRORS_LOCK:
            memo = _ERRORS.setdefault(response, {})
            if len(memo) >= _MEMO_SIZE:
                memo.pop(next(iter(memo)))
            memo[key] = out.copy()
    return out


#: Per response, the last few :func:`estimator_errors` results by their arguments.
_ERRORS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()
_ERRORS_LOCK = threading.Lock()      # batch workers may share a process
_MEMO_SIZE = 8


def _forget_errors() -> None:
    with _ERRORS_LOCK:
        _ERRORS.clear()


# forgets the remembered results (as ``functools.lru_cache``'s ``cache_clear``): a benchmark
# that analyses one video several times then measures what each first analysis costs
estimator_errors.cache_clear = _forget_errors


def _fingerprint(value):
    """A hashable stand-in for fit options: arrays by their dtype, shape and bytes."""
    if isinstance(value, dict):
        return tuple(sorted((k, _fingerprint(v)) for k, v in value.items()))
    if isinstance(value, (list, tuple)):
        return tuple(_fingerprint(v) for v in value)
    if isinstance(value, np.ndarray):
        return (value.dtype.str, value.shape, value.tobytes())
    return repr(value)


def traded_pairs(values: np.ndarray, names, *, limit: float = TRADE_LIMIT,
                 min_samples: int = TRADE_SAMPLES, min_spread: float = TRADE_SPREAD
                 ) -> list[dict]:
    """The pairs of controls that trade places from frame to frame in a video's estimates.

    Where the points tell two controls apart only weakly, what the fit gives one on a frame
    it takes from the other: their sum is measured, their split is noise. It shows in the
    estimates themselves as jitter of opposite sign. For each control, the jitter is its
    second difference ``c(t) - (c(t-1) + c(t+1)) / 2`` (slow, real changes barely enter it);
    two controls whose jitter correlates at or below ``limit`` over at least
    ``min_samples`` frames trade places. A control whose jitter's standard deviation is
    under ``min_spread`` is still and is not judged.

    Parameters
    ----------
    values : ndarray, shape (T, C)
        Estimated controls of consecutive frames (NaN where lost).
    names : sequence of str
        The C control names.

    Returns
    -------
    list of dict
        ``{"controls": [a, b], "correlation": r}``, most negative first.

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> split = rng.uniform(0.2, 0.4, 200)               # a sum of 0.6, split at random
    >>> c = np.column_stack([split, 0.6 - split, np.linspace(0, 1, 200)])
    >>> [p["controls"] for p in traded_pairs(c, ["a", "b", "c"])]
    [['a', 'b']]
    """
    c = np.asarray(values, dtype=float)
    if c.ndim != 2 or c.shape[1] != len(names):
        raise ValueError(f"values must have shape (T, {len(names)}), got {c.shape}")
    if c.shape[0] < 3:
        return []
    jitter = c[1:-1] - 0.5 * (c[:-2] + c[2:])                     # NaN beside a lost frame
    ok = np.isfinite(jitter)
    active = [j for j in range(c.shape[1])
              if ok[:, j].sum() >= min_samples and np.std(jitter[ok[:, j], j]) >= min_spread]
    out = []
    for i, a in enumerate(active):
        for b in active[i + 1:]:
            both = ok[:, a] & ok[:, b]
            if both.sum() < min_samples:
                continue
            x, y = jitter[both, a], jitter[both, b]
            if x.std() == 0 or y.std() == 0:
                continue
            r = float(np.corrcoef(x, y)[0, 1])
            if r <= limit:
                out.append({"controls": [str(names[a]), str(names[b])],
                            "correlation": round(r, 3)})
    return sorted(out, key=lambda p: p["correlation"])


def assess(response: FiducialResponse, displacements: np.ndarray, *,
           min_seen: float = 0.5, fit_options: dict | None = None,
           values: np.ndarray | None = None, sequence: bool = True) -> dict:
    """Identifiability of every control from the points seen in a video, for
    ``analysis.json``.

    Parameters
    ----------
    response : FiducialResponse
    displacements : ndarray, shape (T, P, 2)
        The calibrated displacements of ``response.fiducials`` (cm; NaN where not measured).
    min_seen : float, keyword-only
        Fraction of the frames with any measurement on which a point must be measured to
        count as seen.
    fit_options : dict, optional
        Options of the fit whose errors are simulated (see :func:`estimator_errors`).
    values : ndarray, shape (T, C), optional
        The video's estimates of ``response.muscles``: a control that trades places with
        another in them (:func:`traded_pairs`) is not identifiable either.
    sequence : bool, keyword-only
        The frames are a video's, in time (True), or photographs: then neither the
        noise nor the trading is read from one frame to the next (which would be from one
        photograph's expression to another's); the noise is :data:`REFERENCE_NOISE_CM`.

    Returns
    -------
    dict
        ``noise_cm``, ``noise_source`` ('measured' or 'reference'), ``noise_samples``,
        ``limit``, ``points_seen``, ``controls`` (name -> ``rmse``: the ``joint``
        estimator's simulated error at that noise from those points, as a fraction of the
        range, None where no seen point observes the control; ``independent``: the share
        of its motion of the points no other control reproduces; ``traded_with``: the
        controls it trades places with; ``identifiable``), ``traded`` (the pairs of
        :func:`traded_pairs`) and ``not_identifiable`` (names).
    """
    d = np.asarray(displacements, dtype=float)
    if d.ndim != 3 or d.shape[1:] != (len(response.fiducials), 2):
        raise ValueError(f"displacements must have shape (T, {len(response.fiducials)}, 2), "
                         f"got {d.shape}")
    measured = np.isfinite(d).all(axis=2)                        # (T, P)
    frames = measured.any(axis=1)
    share = measured[frames].mean(axis=0) if frames.any() else np.zeros(d.shape[1])
    seen = [p for p, s in zip(response.fiducials, share) if s >= min_seen]
    noise, samples = (tracking_noise(d, points=[response.fiducials.index(p) for p in seen])
                      if sequence else (None, 0))
    source = "measured"
    if noise is None:
        noise, source = REFERENCE_NOISE_CM, "reference"
    if seen:
        # a response of hundreds of points costs each simulated frame as much as its
        # points: half the draws there
        rmse = estimator_errors(response, noise, points=seen,
                                draws=24 if len(seen) <= MANY_POINTS else 12,
                                **(fit_options or {}))
        independent = identifiability(response, points=seen)["independent"]
        controls = {name: {"rmse": (round(float(rmse[name]), 4) if np.isfinite(rmse[name])
                                    else None),
                           "independent": round(float(independent[name]), 4),
                           "identifiable": bool(rmse[name] <= IDENTIFIABLE_LIMIT)}
                    for name in response.muscles}
    else:
        controls = {name: {"rmse": None, "independent": 0.0, "identifiable": False}
                    for name in response.muscles}
    traded = [] if values is None or not sequence else traded_pairs(values, response.muscles)
    for name in response.muscles:
        controls[name]["traded_with"] = [o for p in traded for o in p["controls"]
                                         if name in p["controls"] and o != name]
        if controls[name]["traded_with"]:
            controls[name]["identifiable"] = False
    return {"noise_cm": round(float(noise), 5), "noise_source": source,
            "noise_samples": samples, "limit": IDENTIFIABLE_LIMIT, "points_seen": seen,
            "controls": controls, "traded": traded,
            "not_identifiable": [n for n in response.muscles if not controls[n]["identifiable"]]}


def mirror_partner(name: str) -> str:
    """The control on the other side of the face (the name itself where it has no side).

    Examples
    --------
    >>> mirror_partner("zygomaticus_major_l"), mirror_partner("orbicularis_oris")
    ('zygomaticus_major_r', 'orbicularis_oris')
    """
    side = {"_l": "_r", "_r": "_l"}.get(name[-2:])
    return name[:-2] + side if side else name


def mirror_agreement(values: np.ndarray, mirrored: np.ndarray, names, *, upper=None,
                     min_frames: int = MIRROR_FRAMES, min_r: float = MIRROR_R,
                     moving: float = MIRROR_MOVING, gap: float = MIRROR_GAP,
                     share: float = MIRROR_SHARE) -> dict:
    """Whether a video's estimates come back when the same video is analysed mirrored.

    A face mirrored left to right makes the same expression with its sides exchanged: a
    control measured from the face's motion reads on the mirrored video what its partner
    on the other side (:func:`mirror_partner`) read on the video. What the landmark model
    or the fit makes of one particular picture (lighting, a pattern of the skin, a
    region the model is unsure of) need not. With at least ``min_frames`` frames
    estimated in both, each control's series is compared with its mirrored partner's: one
    that moves (standard deviation over ``moving`` of its range in either) and whose
    Pearson r is under ``min_r`` is *not reproduced*. With fewer frames (photographs),
    each value is compared with its partner's on the same frame: more than ``gap`` of the
    range and more than ``share`` of the larger apart, it is not reproduced on that frame.

    Parameters
    ----------
    values : ndarray, shape (T, C)
        The video's estimates of ``names`` (NaN on lost frames).
    mirrored : ndarray, shape (T, C)
        The mirrored video's estimates of ``names``, frame for frame (its ``_l`` controls
        are the subject's right).
    names : sequence of str
        The C controls.
    upper : array_like, shape (C,), optional
        Each control's range (default 1): the thresholds are fractions of it.

    Returns
    -------
    dict
        ``frames`` (the number estimated in both), ``rule`` ('series' or 'frames'),
        ``controls`` (name -> ``moving`` and ``r``, None where it does not move, with
        'series'; ``frames_not_reproduced`` with 'frames'; and ``reproduced``, False
        where not reproduced on any frame), ``not_reproduced`` (names) and ``mask``
        (ndarray of bool, shape (T, C): the values not reproduced, frame by frame; with
        'series', a not reproduced control's every compared frame).

    Examples
    --------
    >>> t = np.linspace(0, 6, 60)
    >>> smile = np.clip(np.sin(t), 0, None)
    >>> x = np.column_stack([smile, 0.9 * smile, 0.2 * (np.cos(3 * t) > 0)])
    >>> y = np.column_stack([0.9 * smile, smile, np.zeros(60)])    # sides exchanged
    >>> check = mirror_agreement(x, y, ["zyg_l", "zyg_r", "mentalis_l"])
    >>> check["rule"], check["not_reproduced"]
    ('series', ['mentalis_l'])
    """
    names = [str(n) for n in names]
    x = np.asarray(values, dtype=float)
    y = np.asarray(mirrored, dtype=float)
    if x.ndim != 2 or x.shape[1] != len(names):
        raise ValueError(f"values must have shape (T, {len(names)}), got {x.shape}")
    if y.shape != x.shape:
        raise ValueError(f"mirrored must have the shape of values {x.shape}, got {y.shape}")
    scale = np.ones(len(names)) if upper is None else np.asarray(upper, dtype=float)
    if scale.shape != (len(names),) or np.any(scale <= 0):
        raise ValueError(f"upper must hold {len(names)} positive ranges")
    partner = [names.index(mirror_partner(n)) if mirror_partner(n) in names else j
               for j, n in enumerate(names)]
    x = x / scale
    y = y[:, partner] / scale
    both = np.isfinite(x).all(axis=1) & np.isfinite(y).all(axis=1)
    n = int(both.sum())
    mask = np.zeros(x.shape, dtype=bool)
    controls = {}
    if n >= min_frames:
        rule = "series"
        a, b = x[both], y[both]
        sa, sb = a.std(axis=0), b.std(axis=0)
        for j, name in enumerate(names):
            moves = bool(max(sa[j], sb[j]) > moving)
            r = (float(np.corrcoef(a[:, j], b[:, j])[0, 1]) if sa[j] > 0 and sb[j] > 0
                 else 0.0)
            ok = not moves or r >= min_r
            controls[name] = {"moving": moves, "r": round(r, 3) if moves else None,
                              "reproduced": ok}
            if not ok:
                mask[both, j] = True
    else:
        rule = "frames"
        apart = np.abs(x - y) > np.maximum(gap, share * np.fmax(x, y))
        mask = apart & both[:, None]
        for j, name in enumerate(names):
            k = int(mask[:, j].sum())
            controls[name] = {"frames_not_reproduced": k, "reproduced": k == 0}
    return {"frames": n, "rule": rule, "controls": controls,
            "not_reproduced": [n_ for n_ in names if not controls[n_]["reproduced"]],
            "mask": mask}
