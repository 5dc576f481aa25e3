"""Muscle contractions from fiducial displacements.

Two estimators share one input, the fiducial displacements from the neutral frame in
model units (see :mod:`faceanalysis.estimation.calibration`), and one model of how muscles move
fiducials (:class:`~faceanalysis.estimation.response.FiducialResponse`):

``tw93``
    The paper's scheme (004, section V-D): every muscle independently, from its own
    fiducial point, by inverting eq. 5 (``x' = x + c b m``) along the muscle's image-plane
    direction. Here ``b m``, the point's displacement at full contraction, comes from the
    physics model, so tissue mechanics are included, and the tabulated response is
    inverted level by level rather than linearly.
``flow`` (:mod:`faceanalysis.estimation.flow`)
    Bounded least squares of the face's dense optical flow on the model's per-muscle
    flow templates; it needs the video, so :func:`estimate` only names it.
``joint``
    All contractions at once: bounded least squares of every fiducial coordinate against
    the sum of all muscles' responses,
    ``min ||d - sum_m D_m(c_m)||^2 + 2 mu sum_m c_m / upper_m`` subject to
    ``0 <= c_m <= upper_m`` (a non-negative lasso: most muscles rest on most frames).
    Muscles whose effects overlap (inner and major frontalis on the brow, zygomaticus
    and depressor on the mouth corner) share the explanation instead of each claiming
    all of it.

Bounds are the only thing that keeps values in [0, 1]: no clipping after the fact.
"""

from __future__ import annotations

import contextlib
import functools

import numba
import numpy as np

from faceanalysis.estimation.response import FiducialResponse

#: The estimators that read points only (the ``flow`` estimator also needs the video;
#: all three are in :data:`faceanalysis.estimation.registry.ESTIMATORS`).
POINT_ESTIMATORS = ("joint", "tw93")

#: The ``joint`` fit's default sparsity weight (see :func:`estimate_joint`), chosen on
#: four identities of the standard suite and checked on the other six. A sparsity prior
#: rests the muscles the points do not call for by a constant, where a ridge would shrink
#: every activation in proportion.
SPARSITY = 4e-3


@functools.lru_cache(maxsize=1)
def _blas_controller():
    from threadpoolctl import ThreadpoolController

    return ThreadpoolController()


@contextlib.contextmanager
def _one_blas_thread():
    """BLAS limited to one thread: the products of the joint fit are small (tens of
    controls), and a multi-threaded BLAS on a machine whose other cores are busy spends
    more time synchronising threads than computing them."""
    with _blas_controller().limit(limits=1, user_api="blas"):
        yield

#: Which fiducial each muscle is read from by the tw93 estimator (004, V-D).
TW93_FIDUCIALS: dict[str, str] = {
    **{f"frontalis_inner_{s}": f"brow_inner_{s}" for s in "lr"},
    **{f"frontalis_major_{s}": f"brow_mid_{s}" for s in "lr"},
    **{f"frontalis_outer_{s}": f"brow_outer_{s}" for s in "lr"},
    **{f"zygomaticus_major_{s}": f"mouth_corner_{s}" for s in "lr"},
    **{f"depressor_labii_{s}": f"mouth_corner_{s}" for s in "lr"},
    **{f"levator_labii_nasi_{s}": f"furrow_top_{s}" for s in "lr"},
    "jaw_rotation": "chin",
}


def _check_displacements(d: np.ndarray, response: FiducialResponse) -> np.ndarray:
    d = np.asarray(d, dtype=float)
    if d.ndim == 2:
        d = d[None]
    n_fid = len(response.fiducials)
    if d.ndim != 3 or d.shape[1:] != (n_fid, 2):
        raise ValueError(f"displacements must have shape (T, {n_fid}, 2), got {d.shape}")
    return d


def estimate_tw93(displacements: np.ndarray, response: FiducialResponse) -> np.ndarray:
    """Per-muscle inversion of eq. 5 of 004 in the image plane.

    For muscle ``m`` read from fiducial ``f``, the observed displacement of ``f`` is
    projected on the unit direction of ``f``'s displacement at full contraction,
    ``u = D_m(1) / |D_m(1)|``, and the contraction is the level at which the model's
    projected displacement ``D_m(c) . u`` equals it (linear between tabulated
    levels; the bounds 0 and ``upper`` hold where it falls outside).

    Parameters
    ----------
    displacements : ndarray, shape (T, F, 2)
        Fiducial displacements from neutral in model units (cm, y up); NaN for lost frames.
    response : FiducialResponse

    Returns
    -------
    ndarray, shape (T, M)
        One column per ``response.muscles``; muscles the scheme does not read
        (no entry in :data:`TW93_FIDUCIALS`) are NaN, lost frames are NaN.
    """
    d = _check_displacements(displacements, response)
    out = np.full((d.shape[0], len(response.muscles)), np.nan)
    for m, name in enumerate(response.muscles):
        fid = TW93_FIDUCIALS.get(name)
        if fid is None or fid not in response.fiducials:
            continue
        f = response.fiducials.index(fid)
        curve = response.displacement[m, :, f]          # (L, 2)
        full = curve[-1]
        norm = np.linalg.norm(full)
        if norm == 0:
            continue
        u = full / norm
        along = curve @ u                                # monotone in a sane model
        if np.any(np.diff(along) <= 0):
            along = np.maximum.accumulate(along + np.arange(along.size) * 1e-12)
        observed = d[:, f] @ u
        values = response.levels * response.upper[m]
        est = np.interp(observed, along, values)        # np.interp holds the end values
        est[~np.isfinite(observed)] = np.nan
        out[:, m] = est
    return out


#: Huber threshold of the joint fit, model cm (about half a pixel at 256x256): a point
#: farther than this from the fit pulls less, so that one point the model cannot explain
#: on a frame (a furrow end that stops short) does not drag every control with it.
ROBUST = 0.05

# Largest Jacobian (frames x point coordinates x controls) the joint fit builds at once.
_CHUNK_ELEMENTS = 2_000_000
# Fewest frames a thread is given: below it, a thread's start costs more than it saves.
_MIN_CHUNK = 16
#: Frames :func:`fit_residual` predicts at a time.
_RESIDUAL_CHUNK = 512


#: Refits of the concave debiasing (``estimate_joint(debias=g)``), each with the prior
#: weighed at the last one's values: the local linear approximation of the minimax
#: concave penalty, iterated. The first weighs the prior at the sparse fit's values,
#: which the prior shrank, so a muscle it kept low stays low: simulated frames of three
#: muscles at once (:func:`~faceanalysis.estimation.identifiability.estimator_errors`,
#: at the real clips' noise of 0.006 cm) then read risorius and orbicularis oris 0.10-0.13
#: off; after a second, every muscle is within 0.065 (the relaxed lasso: 0.061).
CONCAVE_STEPS = 2

#: The temporal prior (``estimate_joint(temporal=...)``) refits only the frames whose first
#: fit lies farther than this (a fraction of the range) from their neighbours' mean on some
#: control: on the real clips a third to two thirds of the frames, read as when all are
#: refitted (the frame-to-frame jitter of the contractions within 0.0002).
TEMPORAL_TOLERANCE = 0.05


def estimate_joint(displacements: np.ndarray, response: FiducialResponse, *,
                   weights: np.ndarray | None = None, regularization: float = 0.0,
                   sparsity: float = SPARSITY, outer_iterations: int = 4,
                   inner_iterations: int = 120,
                   initial: np.ndarray | None = None, robust: float | None = ROBUST,
                   robust_rounds: int = 2, debias: bool | float = False,
                   quadratic: tuple[np.ndarray, np.ndarray] | None = None,
                   temporal: float = 0.0, threads: int | None = None,
                   precondition: bool = False) -> np.ndarray:
    """Bounded least-squares fit of all contractions at once, frame by frame.

    Minimises, for each frame independently,
    ``sum_f w_f |d_f - sum_m D_{m,f}(c_m)|^2 + lam * sum_m (c_m / upper_m)^2
    + 2 mu * sum_m c_m / upper_m``
    subject to ``0 <= c_m <= upper_m``, where ``D_m`` is the model's piecewise-linear
    response. The problem is solved for all frames together (vectorised): Gauss-Newton
    linearisation of the response, then an accelerated projected-gradient (FISTA)
    solve of the box-constrained quadratic.

    Parameters
    ----------
    displacements : ndarray, shape (T, F, 2)
        Fiducial displacements from neutral in model units; NaN rows are lost frames.
    response : FiducialResponse
    weights : ndarray, shape (F,), optional
        Per-fiducial weights (default 1).
    regularization : float, keyword-only
        ``lam`` (a ridge), relative to the mean squared full-contraction response. It
        shrinks every activation in proportion (the old default, 1e-2, read surprise's
        frontalis inner at about half its value on tracked points); off by default.
    sparsity : float, keyword-only
        ``mu``, on the same relative scale: since contractions are non-negative this
        L1 penalty is linear, so it sets muscles that the points barely call for to
        exactly zero and moves the active ones by a constant instead of a fraction,
        and breaks ties between muscles the points cannot tell apart (see
        :func:`faceanalysis.estimation.identifiability.identifiability`) in favour of fewer. Default
        :data:`SPARSITY`; 0 for a plain bounded least-squares fit.
    outer_iterations, inner_iterations : int, keyword-only
        Gauss-Newton and projected-gradient iterations (each reweighting round runs
        half as many Gauss-Newton iterations from the last solution).
    initial : ndarray, shape (T, M) or (M,), optional
        Starting contractions (default zero, the neutral face).
    robust : float or None, keyword-only
        Huber threshold in model cm (default :data:`ROBUST`): after the fit, each
        point's weight on each frame becomes ``min(1, robust / residual)`` and the
        fit is repeated ``robust_rounds`` times (iteratively reweighted least
        squares), so that a point the model cannot explain on a frame (a furrow's
        lower end that stopped where its line fades while the jaw opened) pulls
        less. None: plain least squares.
    robust_rounds : int, keyword-only
        Reweighting rounds.
    debias : bool or float, keyword-only
        Refit, on each frame, the controls the sparse fit left off rest (the others
        held at rest), so that the prior chooses which muscles act and does not also
        shrink how much. True: without the prior (a relaxed lasso). A number ``g`` in
        (0, 1]: with each control's prior weighed by ``max(0, 1 - c / (g * upper))`` of
        its value ``c``, the slope of the minimax concave penalty there (its local
        linear approximation, Zou & Li 2008, :data:`CONCAVE_STEPS` times from the sparse
        fit's values): values the prior barely let off rest keep most of it, values of
        ``g`` of the range or more none. The
        relaxed lasso jumps from rest to a full refit where the evidence crosses the
        prior's threshold, so a muscle near it switches on and off from frame to
        frame; this refit rises from rest continuously.
    quadratic : (ndarray (M, M), ndarray (T, M)), keyword-only, optional
        A second measurement's least squares in the controls, ``c'Hc - 2 g_t'c`` per
        frame (``H = A'A``, ``g_t = A'y_t`` of a linear model ``y = A c``, e.g. the dense
        flow's templates), added to the objective; a frame whose ``g_t`` is NaN has none.
    temporal : float, keyword-only
        ``nu``, on the scale of ``lam``: the frames are first fitted one by one; then every
        frame with two fitted neighbours (and off their mean by more than
        :data:`TEMPORAL_TOLERANCE`) is fitted again with
        ``nu * sum_m ((c_m - n_m) / upper_m)^2`` added, ``n`` the mean of the neighbours'
        first fits, over the controls both have (one block-Jacobi step of a
        first-difference smoothness prior on the sequence). Where the points tell two
        controls apart only weakly (levator labii and its alar twin), the frame-by-frame
        fit picks between them at random from one frame to the next; the prior settles the
        choice on the one its neighbours made, while a control the points determine barely
        feels it. The rows are taken as consecutive frames; 0 (default) fits each on its
        own, as independent samples need.
    precondition : bool, keyword-only
        Solve each Gauss-Newton step's bounded quadratic to its optimum (:func:`box_qp`
        on the Jacobi-scaled problem). False (default): ``inner_iterations`` of
        projected gradient on the problem as given, which stops short of the optimum in
        the directions the points barely determine and so acts as a prior there (on the
        16 contour points of a real clip the converged fit jumps more from frame to
        frame). The ``mesh`` fit, on hundreds of points, converges
        (:data:`~faceanalysis.estimation.registry.MESH_FIT`).
    threads : int, keyword-only, optional
        Frames are independent problems: a long video's are fitted in chunks, this many at
        once (default :func:`faceanalysis.tracking.thread_budget`; the same numbers for any
        count, to rounding).

    Returns
    -------
    ndarray, shape (T, M)
        Contractions, one column per ``response.muscles``; NaN rows for lost frames.

    Examples
    --------
    >>> import numpy as np
    >>> from faceanalysis.estimation.response import FiducialResponse
    >>> levels = np.linspace(0, 1, 3)
    >>> disp = np.zeros((2, 3, 3, 2))        # (muscles, levels, points, xy)
    >>> disp[0, :, :, 1] = levels[:, None]   # muscle a lifts the three points
    >>> disp[1, :, :, 0] = 2 * levels[:, None]   # muscle b pulls them sideways
    >>> resp = FiducialResponse(("a", "b"), ("p", "q", "r"), np.zeros((3, 2)), disp,
    ...                         np.ones(2), levels)
    >>> seen = np.array([[[1.0, 0.5]] * 3])
    >>> np.round(estimate_joint(seen, resp, sparsity=0), 3)
    array([[0.5, 0.5]])

    One point stuck where it was (a mistracked contour end) barely moves the fit:

    >>> seen[0, 2] = 0.0
    >>> np.round(estimate_joint(seen, resp, sparsity=0, robust=None), 2)
    array([[0.33, 0.33]])
    >>> np.round(estimate_joint(seen, resp, sparsity=0, robust_rounds=8), 2)
    array([[0.49, 0.49]])
    """
    if robust is not None and not (np.isfinite(robust) and robust > 0):
        raise ValueError(f"robust must be a positive threshold or None, got {robust}")
    if not (isinstance(debias, (bool, np.bool_))
            or isinstance(debias, (int, float, np.floating)) and 0 < debias <= 1):
        raise ValueError(f"debias must be True, False or a number in (0, 1], got {debias!r}")
    if isinstance(debias, np.bool_):
        debias = bool(debias)                 # the refit tests ``debias is True``
    temporal = check_temporal(temporal)
    fit = dict(weights=weights, regularization=regularization, sparsity=sparsity,
               outer_iterations=outer_iterations, inner_iterations=inner_iterations,
               robust=robust, robust_rounds=robust_rounds, debias=debias,
               quadratic=quadratic, threads=threads, precondition=precondition)
    first = _fit_frames(displacements, response, initial=initial, **fit)
    if not temporal or len(first) < 3:
        return first
    centre = np.full_like(first, np.nan)
    centre[1:-1] = 0.5 * (first[:-2] + first[2:])           # NaN beside a lost frame
    # a frame already within TEMPORAL_TOLERANCE of its neighbours' mean would barely move
    dev = np.abs(np.nan_to_num(first - centre)) / response.upper
    rows = (np.isfinite(centre).any(axis=1) & np.isfinite(first).any(axis=1)
            & (dev.max(axis=1) > TEMPORAL_TOLERANCE))
    if not rows.any():
        return first
    if quadratic is not None:
        fit["quadratic"] = (quadratic[0], np.asarray(quadratic[1], dtype=float)[rows])
    # from the first fit, a step or two from the refit's optimum: half the inner iterations
    # read the real clips as all do (jitter within 0.0003)
    fit["inner_iterations"] = max(1, inner_iterations // 2)
    out = first.copy()
    out[rows] = _fit_frames(np.asarray(displacements, dtype=float)[rows], response,
                            initial=np.nan_to_num(first[rows]),
                            anchor=(float(temporal), centre[rows]), **fit)
    return out


def check_temporal(temporal) -> float:
    """``temporal`` (:func:`estimate_joint`) as a float; ValueError unless it is a finite
    number >= 0 (not a bool)."""
    if (isinstance(temporal, (bool, np.bool_))
            or not isinstance(temporal, (int, float, np.integer, np.floating))
            or not (np.isfinite(temporal) and temporal >= 0)):
        raise ValueError(f"temporal must be a non-negative number, got {temporal!r}")
    return float(temporal)


def _fit_frames(displacements, response, *, weights, regularization, sparsity,
                outer_iterations, inner_iterations, initial, robust, robust_rounds, debias,
                quadratic, threads, precondition, anchor=None):
    """:func:`estimate_joint` without its temporal prior: the frames fitted independently
    (in chunks, on threads), each control drawn toward ``anchor = (nu, centre)`` where
    ``centre`` is finite."""
    d_all = _check_displacements(displacements, response)
    n_t = d_all.shape[0]
    # frames are independent problems: in chunks, the Jacobians of many points stay small
    chunk = max(1, _CHUNK_ELEMENTS // (d_all.shape[1] * 2 * len(response.muscles)))
    if quadratic is not None:
        qh, qg = (np.asarray(q, dtype=float) for q in quadratic)
        m = len(response.muscles)
        if qh.shape != (m, m) or qg.shape != (n_t, m):
            raise ValueError(f"quadratic must be (H of shape ({m}, {m}), g of shape "
                             f"({n_t}, {m})), got {qh.shape} and {qg.shape}")
    if threads is not None and (isinstance(threads, bool) or int(threads) != threads
                                or threads < 1):
        raise ValueError(f"threads must be a positive integer, got {threads!r}")
    if threads is None:
        from faceanalysis.tracking import thread_budget

        threads = thread_budget()
    if threads > 1 and n_t >= 2 * _MIN_CHUNK:
        # a short sequence (or the temporal prior's few frames) is shared among the threads
        chunk = min(chunk, max(_MIN_CHUNK, -(-n_t // int(threads))))
    if n_t > chunk:
        init = (None if initial is None else
                np.broadcast_to(np.asarray(initial, dtype=float), (n_t, len(response.muscles))))

        def part(a):
            return _fit_frames(
                d_all[a:a + chunk], response, weights=weights, regularization=regularization,
                sparsity=sparsity, outer_iterations=outer_iterations,
                inner_iterations=inner_iterations,
                initial=None if init is None else init[a:a + chunk], robust=robust,
                robust_rounds=robust_rounds, debias=debias,
                quadratic=None if quadratic is None else (qh, qg[a:a + chunk]), threads=1,
                precondition=precondition,
                anchor=None if anchor is None else (anchor[0], anchor[1][a:a + chunk]))

        workers = min(int(threads), -(-n_t // chunk))
        if workers > 1:
            # as many equal chunks per thread, so that none waits on a short last one
            rounds = -(-n_t // (chunk * workers))
            chunk = -(-n_t // (rounds * workers))
        starts = range(0, n_t, chunk)
        if workers < 2:
            return np.concatenate([part(a) for a in starts])
        from concurrent.futures import ThreadPoolExecutor

        # the compiled solves and NumPy's products release the GIL; BLAS keeps one thread
        # per chunk, limited once here for all of them
        with _one_blas_thread(), ThreadPoolExecutor(workers) as pool:
            return np.concatenate(list(pool.map(part, starts)))
    if robust_rounds < 0:
        raise ValueError(f"robust_rounds must be >= 0, got {robust_rounds}")
    with _one_blas_thread():
        c = _estimate_joint(displacements, response, weights, regularization, sparsity,
                            outer_iterations, inner_iterations, initial, quadratic=quadratic,
                            anchor=anchor, precondition=precondition)
        d = np.asarray(displacements, dtype=float)
        fw = None
        for _ in range(robust_rounds if robust is not None else 0):
            fw = _huber_weights(d, response, c, robust)
            c = np.where(np.isfinite(c), _estimate_joint(
                d, response, weights, regularization, sparsity,
                max(1, outer_iterations // 2),
                inner_iterations, np.nan_to_num(c), fw, quadratic=quadratic, anchor=anchor,
                precondition=precondition), c)
        if debias:
            if robust is not None:
                fw = _huber_weights(d, response, c, robust)
            support = np.nan_to_num(c) > 0
            for _ in range(1 if debias is True else CONCAVE_STEPS):
                c0 = np.nan_to_num(c)
                # the prior's share per control and frame: none (the relaxed lasso), or
                # the minimax concave penalty's slope at the last values
                share = (None if debias is True
                         else np.clip(1.0 - c0 / (float(debias) * response.upper), 0.0, 1.0))
                c = np.where(np.isfinite(c), _estimate_joint(
                    d, response, weights, regularization, 0.0 if share is None else sparsity,
                    max(1, outer_iterations // 2), inner_iterations, c0, fw, support=support,
                    quadratic=quadratic, prior_share=share, anchor=anchor,
                    precondition=precondition), c)
        return c


def _huber_weights(d, response, c, robust):
    """Per point and frame, ``min(1, robust / residual)`` of the fit ``c``."""
    r = np.linalg.norm(d - response.predict(np.nan_to_num(c)), axis=2)    # (T, F)
    return np.minimum(1.0, robust / np.maximum(np.nan_to_num(r, nan=0.0), 1e-12))


def _estimate_joint(displacements, response, weights, regularization, sparsity,
                    outer_iterations, inner_iterations, initial, frame_weights=None,
                    support=None, quadratic=None, prior_share=None, anchor=None,
                    precondition=False):
    d = _check_displacements(displacements, response)
    if not regularization >= 0:
        raise ValueError(f"regularization must be >= 0, got {regularization}")
    if not sparsity >= 0:
        raise ValueError(f"sparsity must be >= 0, got {sparsity}")
    if outer_iterations < 1 or inner_iterations < 1:
        raise ValueError("outer_iterations and inner_iterations must be >= 1")
    n_t, n_f = d.shape[0], d.shape[1]
    n_m = len(response.muscles)
    w = np.ones(n_f) if weights is None else np.asarray(weights, dtype=float)
    if w.shape != (n_f,) or np.any(w < 0) or not np.isfinite(w).all():
        raise ValueError(f"weights must be {n_f} finite non-negative values")
    # Points missing on a frame (NaN) get weight 0 there; a frame needs 3 points.
    seen = np.isfinite(d).all(axis=2)                     # (T, F)
    valid = seen.sum(axis=1) >= 3
    out = np.full((n_t, n_m), np.nan)
    if not valid.any():
        return out
    sw = np.repeat(np.sqrt(w)[None, :] * seen[valid], 2, axis=1)      # (T, K)
    if frame_weights is not None:
        sw = sw * np.repeat(np.sqrt(frame_weights[valid]), 2, axis=1)
    dv = np.nan_to_num(d[valid].reshape(-1, n_f * 2)) * sw
    upper = response.upper
    full = response.displacement[:, -1].reshape(n_m, -1)               # (M, K)
    scale = np.mean((full * np.repeat(np.sqrt(w), 2)) ** 2) * n_f * 2
    lam = regularization * scale / upper**2               # per control
    mu = sparsity * scale / upper
    if prior_share is not None:
        mu = mu * np.asarray(prior_share, dtype=float)[valid]     # per frame and control
    # A control none of whose motion falls on the seen points is not observed there.
    sw_prior = np.repeat(np.sqrt(w)[None, :] * seen[valid], 2, axis=1)
    seen_norm = np.sqrt((sw_prior**2) @ (full**2).T)                    # (T, M)
    observed = seen_norm >= 0.25 * np.linalg.norm(full * np.repeat(np.sqrt(w), 2), axis=1)

    # per frame upper bounds: a control outside the support is held at rest
    hi = (np.broadcast_to(upper, (dv.shape[0], n_m)) if support is None
          else np.where(support[valid], upper, 0.0))
    if initial is None:
        c = np.zeros((dv.shape[0], n_m))
    else:
        c = np.broadcast_to(np.asarray(initial, dtype=float), (n_t, n_m))[valid].copy()
        c = np.clip(c, 0.0, hi)                            # a start point, not a result

    if quadratic is not None:
        # another measurement's least squares in c, |y - A c|^2 = c'Hc - 2 g'c + const
        qh = np.asarray(quadratic[0], dtype=float)
        qg = np.nan_to_num(np.asarray(quadratic[1], dtype=float)[valid])
        has = np.isfinite(np.asarray(quadratic[1], dtype=float)[valid]).all(axis=1)
        qh_t = np.where(has[:, None, None], qh[None], 0.0)          # (T, M, M)
        observed = observed | (has[:, None] & (np.diag(qh) > 0)[None])

    if anchor is not None:
        # nu |(c - centre) / upper|^2 where the centre is known: a diagonal quadratic
        centre = np.asarray(anchor[1], dtype=float)[valid]
        nu = np.where(np.isfinite(centre), anchor[0] * scale / upper**2, 0.0)   # (T, M)
        centre = np.nan_to_num(centre)

    def penalty(cc):
        """Per frame, the objective at ``cc`` beyond the weighted residuals: the priors."""
        val = ((lam * cc + 2.0 * mu) * cc).sum(axis=1)
        if anchor is not None:
            val = val + (nu * (cc - centre) ** 2).sum(axis=1)
        if quadratic is not None:
            val = val + np.einsum("tm,tmn,tn->t", cc, qh_t, cc) - 2.0 * np.einsum(
                "tm,tm->t", qg, cc)
        return val

    # the residual at the current point is kept from the line search that accepted it:
    # the response's prediction at hundreds of points is a third of a step's cost
    res = dv - response.predict(c).reshape(-1, n_f * 2) * sw
    current = np.einsum("tk,tk->t", res, res) + penalty(c)
    frame = np.arange(len(c))
    for _ in range(outer_iterations):
        hess, grad0 = response.normal_equations(c, sw, res)
        hess += np.diag(lam)
        grad0 -= lam * c + mu
        if anchor is not None:
            hess[:, np.arange(n_m), np.arange(n_m)] += nu
            grad0 -= nu * (c - centre)
        if quadratic is not None:
            hess = hess + qh_t
            grad0 = grad0 + qg - np.einsum("tmn,tn->tm", qh_t, c)
        step = box_qp(hess, grad0, -c, hi - c, iterations=inner_iterations,
                      precondition=precondition)
        # Backtracking: the surrogate is piecewise linear, so a full Gauss-Newton step
        # can overshoot a breakpoint; keep, per frame, whichever of 1/4, 1/2 and 1 of the
        # step lowers the objective most (the box is convex: all stay feasible).
        trials = np.clip(c[None] + _FRACTIONS[:, None, None] * step[None], 0.0, hi)
        best_val, res, choice = response.best_of(
            trials, dv, sw, np.stack([penalty(t) for t in trials]), current, res)
        gain = current - best_val
        c = np.where((choice >= 0)[:, None], trials[np.maximum(choice, 0), frame], c)
        current = best_val
        if np.all(gain <= 1e-6 * np.maximum(current, 1e-12)):
            break
    out[valid] = np.where(observed, c, np.nan)
    return out


#: The line search's fractions of a Gauss-Newton step, in the order they are tried.
_FRACTIONS = np.array([0.25, 0.5, 1.0])


def box_qp(hess: np.ndarray, grad0: np.ndarray, lo: np.ndarray, hi: np.ndarray, *,
           iterations: int = 300, tol: float = 1e-9, precondition: bool = True) -> np.ndarray:
    """Solve ``min 0.5 x'Hx - g'x`` s.t. ``lo <= x <= hi`` for a batch of small problems.

    Each variable is scaled by the square root of its diagonal entry (Jacobi, which keeps
    the box a box): the controls' Hessians are ill-conditioned mostly through their scales
    (a jaw moving hundreds of points, a muscle a few), and their condition numbers of
    1e4-5e4 fall to 1e2-6e2 scaled. The scaled problem is solved to its optimum by
    projected Newton steps (Bertsekas 1982): the variables at a bound that the gradient
    pushes outward are held there, a Newton step (a Cholesky solve) moves the others, and
    the step is halved along its projection onto the box until the objective falls
    enough (Armijo). Once the held set is the optimum's, the next step lands on the
    optimum, so a problem of 26 variables takes a handful of steps, problem by problem
    (compiled). ``precondition=False`` keeps the accelerated projected gradient (FISTA)
    on the problem as given instead, with step ``1 / ||H||_F`` (``>= lambda_max``).

    Parameters
    ----------
    hess : ndarray, shape (T, M, M)
        Symmetric positive semi-definite matrices.
    grad0 : ndarray, shape (T, M)
    lo, hi : ndarray, shape (T, M)
        Bounds (``lo <= 0 <= hi``: the start point 0 is feasible).
    iterations : int, keyword-only
        At most this many iterations (Newton steps, or FISTA's gradient steps) per problem.
    tol : float, keyword-only
        A problem stops when its projected gradient step, in the scaled variables and
        relative to ``max |g|``, is under this (Newton), or when no variable moved by more
        than this over an iteration (FISTA, checked every tenth).
    precondition : bool, keyword-only
        Scale the variables and take Newton steps as above (default). False: FISTA on the
        problem as given, whose few hundred iterations leave the directions of the
        smallest curvature short of the optimum: a damped step, which a Gauss-Newton fit
        through a model that is not its own surrogate
        (:mod:`faceanalysis.estimation.model_fit`, :mod:`faceanalysis.estimation.refine`)
        relies on where the points barely determine a direction.

    Returns
    -------
    ndarray, shape (T, M)

    Examples
    --------
    Two variables on scales a hundred times apart, the large one bounded:

    >>> h = np.array([[[1e4, 50.0], [50.0, 1.0]]])
    >>> g = np.array([[2e4, 1.0]])
    >>> np.round(box_qp(h, g, np.zeros((1, 2)), np.array([[1.0, 10.0]])), 4)
    array([[1., 0.]])
    """
    hess = np.ascontiguousarray(hess, dtype=float)
    grad0 = np.ascontiguousarray(grad0, dtype=float)
    lo = np.ascontiguousarray(np.broadcast_to(lo, grad0.shape), dtype=float)
    hi = np.ascontiguousarray(np.broadcast_to(hi, grad0.shape), dtype=float)
    if hess.ndim != 3 or hess.shape[1] != hess.shape[2] or grad0.shape != hess.shape[:2]:
        raise ValueError(f"hess must have shape (T, M, M) and grad0 (T, M), got {hess.shape} "
                         f"and {grad0.shape}")
    y = np.zeros_like(grad0)
    if not precondition:
        lipschitz = np.maximum(np.sqrt(np.einsum("tij,tij->t", hess, hess)), 1e-300)
        _fista_nb(hess, grad0, lo, hi, lipschitz, int(iterations), np.full(len(y), float(tol)),
                  y)
        return y
    d = _jacobi_scales(hess)
    _newton_box_nb(hess / d[:, :, None] / d[:, None, :], grad0 / d, lo * d, hi * d,
                   int(iterations), float(tol), y)
    return np.clip(y / d, lo, hi)          # (lo * d) / d is lo only to rounding


def _jacobi_scales(hess: np.ndarray) -> np.ndarray:
    """Per problem and variable, ``d`` with ``x = y / d`` giving the scaled Hessian a unit
    diagonal; a variable no point moves (a zero diagonal) keeps its scale."""
    d = np.sqrt(np.maximum(np.einsum("tii->ti", hess), 0.0))
    floor = 1e-12 * np.maximum(d.max(axis=1, keepdims=True), 1e-300)
    return np.where(d > floor, d, 1.0)


@numba.njit(cache=True, fastmath=True, nogil=True)
def _matvec_nb(h, y, out):
    # four rows at a time: four independent sums per pass over y (a 26 x 26 product in
    # 43 ns against 118 for a row at a time; the FISTA loop is nothing else)
    n = y.shape[0]
    i = 0
    while i + 4 <= n:
        a0 = 0.0
        a1 = 0.0
        a2 = 0.0
        a3 = 0.0
        for j in range(n):
            yj = y[j]
            a0 += h[i, j] * yj
            a1 += h[i + 1, j] * yj
            a2 += h[i + 2, j] * yj
            a3 += h[i + 3, j] * yj
        out[i] = a0
        out[i + 1] = a1
        out[i + 2] = a2
        out[i + 3] = a3
        i += 4
    while i < n:
        acc = 0.0
        for j in range(n):
            acc += h[i, j] * y[j]
        out[i] = acc
        i += 1


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _newton_box_nb(hess, grad0, lo, hi, iterations, tol, x):
    # problem by problem; x holds the start points (feasible) and receives the solutions
    n_t, n = grad0.shape
    hx = np.empty(n)
    hn = np.empty(n)
    g = np.empty(n)
    step = np.empty(n)
    trial = np.empty(n)
    free = np.empty(n, np.intp)
    chol = np.empty((n, n))
    sol = np.empty(n)
    for f in range(n_t):
        h = hess[f]
        xf = x[f]
        big = 0.0
        top = 0.0
        for i in range(n):
            big = max(big, h[i, i])
            top = max(top, abs(grad0[f, i]))
        # a pivot no larger than rounding (a variable no point moves) is raised to this
        ridge = 1e-12 * max(big, 1e-300)
        stop = tol * max(top, 1e-300)
        _matvec_nb(h, xf, hx)
        fx = 0.0
        for i in range(n):
            fx += xf[i] * (0.5 * hx[i] - grad0[f, i])
        for _ in range(iterations):
            pg = 0.0
            for i in range(n):
                g[i] = hx[i] - grad0[f, i]
                pg = max(pg, abs(xf[i] - min(max(xf[i] - g[i], lo[f, i]), hi[f, i])))
            if pg <= stop:
                break
            # held: at (or within the projected step of) a bound the gradient pushes
            # outward; they move by the gradient (the scaled diagonal is 1) and the
            # projection puts them back on their bound
            nf = 0
            for i in range(n):
                near = min(pg, 1e-3 * (hi[f, i] - lo[f, i]))
                if ((xf[i] <= lo[f, i] + near and g[i] > 0.0)
                        or (xf[i] >= hi[f, i] - near and g[i] < 0.0)):
                    step[i] = -g[i]
                else:
                    free[nf] = i
                    nf += 1
            # Newton step of the others: H_FF s = -g_F by Cholesky
            for a in range(nf):
                for b in range(a + 1):
                    acc = h[free[a], free[b]]
                    for k in range(b):
                        acc -= chol[a, k] * chol[b, k]
                    if a == b:
                        chol[a, a] = np.sqrt(max(acc, ridge))
                    else:
                        chol[a, b] = acc / chol[b, b]
            for a in range(nf):
                acc = -g[free[a]]
                for k in range(a):
                    acc -= chol[a, k] * sol[k]
                sol[a] = acc / chol[a, a]
            for a in range(nf - 1, -1, -1):
                acc = sol[a]
                for k in range(a + 1, nf):
                    acc -= chol[k, a] * sol[k]
                sol[a] = acc / chol[a, a]
            for a in range(nf):
                step[free[a]] = sol[a]
            # Armijo along the projection arc
            alpha = 1.0
            fn = fx
            accepted = False
            for _ in range(50):
                drop = 0.0
                for i in range(n):
                    trial[i] = min(max(xf[i] + alpha * step[i], lo[f, i]), hi[f, i])
                    drop += g[i] * (trial[i] - xf[i])
                _matvec_nb(h, trial, hn)
                fn = 0.0
                for i in range(n):
                    fn += trial[i] * (0.5 * hn[i] - grad0[f, i])
                if fn <= fx + 1e-4 * drop:
                    accepted = True
                    break
                alpha *= 0.5
            if not accepted:      # no step lowers the objective beyond rounding
                break
            for i in range(n):
                xf[i] = trial[i]
                hx[i] = hn[i]
            fx = fn


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _fista_nb(hess, grad0, lo, hi, lipschitz, iterations, tol, x):
    # problem by problem (each H stays in cache over its iterations)
    n_t, n_m = grad0.shape
    y = np.empty(n_m)
    g = np.empty(n_m)
    for f in range(n_t):
        h = hess[f]
        for i in range(n_m):
            y[i] = x[f, i]
        inv = 1.0 / lipschitz[f]
        t = 1.0
        for k in range(iterations):
            t_new = 0.5 * (1.0 + np.sqrt(1.0 + 4.0 * t * t))
            mom = (t - 1.0) / t_new
            _matvec_nb(h, y, g)
            for i in range(n_m):
                g[i] -= grad0[f, i]
            moved = 0.0
            for i in range(n_m):
                new = min(max(y[i] - g[i] * inv, lo[f, i]), hi[f, i])
                d = new - x[f, i]
                moved = max(moved, abs(d))
                y[i] = new + mom * d
                x[f, i] = new
            if k % 10 == 9 and moved < tol[f]:
                break
            t = t_new


def fit_residual(displacements: np.ndarray, response: FiducialResponse,
                 contractions: np.ndarray) -> np.ndarray:
    """How far the measured points lie from where the model puts them, frame by frame.

    Parameters
    ----------
    displacements : ndarray, shape (T, F, 2)
        Measured displacements from neutral in model cm (NaN rows: points not seen).
    response : FiducialResponse
    contractions : ndarray, shape (T, M)
        Estimated controls (``response.muscles`` order); NaN entries count as at rest,
        rows all NaN (lost frames) give NaN.

    Returns
    -------
    ndarray, shape (T,)
        Root-mean-square distance, over the points seen on each frame, between the
        measured displacement and the response's prediction at ``contractions``, in
        model cm; NaN where no point is seen or nothing was estimated.

    Examples
    --------
    >>> import numpy as np
    >>> from faceanalysis.estimation.response import FiducialResponse
    >>> levels = np.linspace(0, 1, 3)
    >>> disp = np.zeros((1, 3, 2, 2))
    >>> disp[0, :, :, 1] = levels[:, None]      # one muscle lifts both points by 1 cm
    >>> resp = FiducialResponse(("a",), ("p", "q"), np.zeros((2, 2)), disp, np.ones(1),
    ...                         levels)
    >>> seen = np.array([[[0.0, 0.5], [0.0, 0.5]], [[0.3, 0.5], [-0.3, 0.5]]])
    >>> fit_residual(seen, resp, np.array([[0.5], [0.5]])).round(3).tolist()
    [0.0, 0.3]
    """
    d = _check_displacements(displacements, response)
    c = np.asarray(contractions, dtype=float)
    if c.shape != (d.shape[0], len(response.muscles)):
        raise ValueError(f"contractions must have shape ({d.shape[0]}, "
                         f"{len(response.muscles)}), got {c.shape}")
    out = np.full(d.shape[0], np.nan)
    # a chunk of frames at a time: the prediction and its residual are the size of the
    # displacements (some 6 kB a frame with the face mesh's points)
    for a in range(0, d.shape[0], _RESIDUAL_CHUNK):
        cc = c[a:a + _RESIDUAL_CHUNK]
        r2 = np.sum((d[a:a + _RESIDUAL_CHUNK] - response.predict(np.nan_to_num(cc))) ** 2,
                    axis=2)                                                 # (T, F)
        seen = np.isfinite(r2)
        n = seen.sum(axis=1)
        ok = (n > 0) & np.isfinite(cc).any(axis=1)
        out[a:a + _RESIDUAL_CHUNK][ok] = np.sqrt(np.where(seen, r2, 0.0).sum(axis=1)[ok]
                                                 / n[ok])
    return out


def estimate(displacements: np.ndarray, response: FiducialResponse, *,
             estimator: str = "joint", **kwargs) -> np.ndarray:
    """Dispatch to :func:`estimate_joint` or :func:`estimate_tw93` by name."""
    if estimator == "joint":
        return estimate_joint(displacements, response, **kwargs)
    if estimator == "tw93":
        return estimate_tw93(displacements, response)
    if estimator == "flow":
        raise ValueError("the flow estimator works on the video's dense motion, not on "
                         "fiducials; use faceanalysis.analyze(..., estimator='flow') "
                         "or faceanalysis.estimation.flow.estimate_flow")
    raise ValueError(f"unknown estimator {estimator!r}; choose from "
                     f"{', '.join(POINT_ESTIMATORS)}")
