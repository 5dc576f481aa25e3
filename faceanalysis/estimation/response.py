"""The face model's fiducial response: how each muscle moves the 11 fiducial points.

Estimation inverts this response. It is tabulated once per face model by
equilibrating the model with one muscle (or the jaw) at a time at a few contraction
levels, and recording the orthographic x-y displacement of every fiducial. Between
levels the response is piecewise linear.

Muscles do not combine additively: sheets overlap, biphasic tissue stiffens, the
jaw carries the lower lip away from the muscles that pull it. 004 (section V-D)
ignores this and inverts eq. 5 muscle by muscle. The table therefore also holds
pairwise interaction terms, fitted by least squares to the model's equilibria at
random combinations of contractions::

    D(c) = sum_m f_m(c_m) + sum_(a,b) W_ab * (c_a / u_a) * (c_b / u_b)
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numba
import numpy as np


@dataclass(frozen=True, eq=False)
class FiducialResponse:
    """Tabulated fiducial displacement per muscle and contraction level.

    Parameters
    ----------
    muscles : tuple of str
        Names of the controls (muscles and possibly ``"jaw_rotation"``), length M.
    fiducials : tuple of str
        Fiducial names, length F.
    rest : ndarray, shape (F, 2)
        Rest positions of the fiducials in model space (cm, x = subject's left, y up).
    displacement : ndarray, shape (M, L, F, 2)
        Displacement of each fiducial (cm) when control m alone is at level
        ``levels[l] * upper[m]``; ``displacement[:, 0]`` must be zero.
    upper : ndarray, shape (M,)
        Upper bound of each control (1 for muscles, the largest jaw angle in radians).
    levels : ndarray, shape (L,)
        Uniform levels in [0, 1], from 0 to 1.
    """

    muscles: tuple[str, ...]
    fiducials: tuple[str, ...]
    rest: np.ndarray
    displacement: np.ndarray
    upper: np.ndarray
    levels: np.ndarray
    pairs: np.ndarray | None = None
    interaction: np.ndarray | None = None

    def __post_init__(self):
        m, f = len(self.muscles), len(self.fiducials)
        disp = np.asarray(self.displacement, dtype=float)
        if disp.ndim != 4 or disp.shape[0] != m or disp.shape[2] != f or disp.shape[3] != 2:
            raise ValueError(f"displacement must have shape (M={m}, L, F={f}, 2), "
                             f"got {disp.shape}")
        levels = np.asarray(self.levels, dtype=float)
        if levels.shape != (disp.shape[1],) or levels.size < 2:
            raise ValueError("levels must have one entry per tabulated level (at least 2)")
        if not np.allclose(levels, np.linspace(0.0, 1.0, levels.size)):
            raise ValueError("levels must be uniform from 0 to 1")
        if np.abs(disp[:, 0]).max(initial=0.0) > 1e-9:
            raise ValueError("displacement at level 0 must be zero")
        upper = np.asarray(self.upper, dtype=float)
        if upper.shape != (m,) or np.any(upper <= 0):
            raise ValueError("upper must hold one positive bound per control")
        object.__setattr__(self, "displacement", disp)
        object.__setattr__(self, "levels", levels)
        object.__setattr__(self, "upper", upper)
        object.__setattr__(self, "rest", np.asarray(self.rest, dtype=float).reshape(f, 2))
        if (self.pairs is None) != (self.interaction is None):
            raise ValueError("pairs and interaction go together")
        if self.pairs is not None:
            pairs = np.asarray(self.pairs, dtype=np.intp).reshape(-1, 2)
            inter = np.asarray(self.interaction, dtype=float)
            if inter.shape != (len(pairs), f, 2):
                raise ValueError(f"interaction must have shape (P={len(pairs)}, F={f}, 2), "
                                 f"got {inter.shape}")
            if pairs.size and (pairs.min() < 0 or pairs.max() >= m):
                raise ValueError("pairs index controls that do not exist")
            object.__setattr__(self, "pairs", pairs)
            object.__setattr__(self, "interaction", inter)

    def __repr__(self) -> str:
        # the tables themselves print tens of kB
        pairs = "" if self.pairs is None else f", {len(self.pairs)} pair terms"
        return (f"<FiducialResponse: {len(self.muscles)} controls x {len(self.fiducials)} "
                f"points, {len(self.levels)} levels{pairs}>")

    @property
    def n_levels(self) -> int:
        return self.levels.size

    def _segments(self, c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        s = np.clip(c / self.upper, 0.0, 1.0) * (self.n_levels - 1)
        idx = np.minimum(np.floor(s).astype(np.intp), self.n_levels - 2)
        return idx, s - idx

    def predict(self, c: np.ndarray) -> np.ndarray:
        """Fiducial displacements (T, F, 2) for controls ``c`` of shape (T, M) or (M,)."""
        c = np.atleast_2d(np.asarray(c, dtype=float))
        if c.ndim != 2 or c.shape[1] != len(self.muscles):
            raise ValueError(f"c must have shape (T, {len(self.muscles)}) or "
                             f"({len(self.muscles)},), got {c.shape}")
        if not np.isfinite(c).all():
            raise ValueError("c must be finite (pass np.nan_to_num(c) to treat missing "
                             "controls as at rest)")
        out = np.empty((c.shape[0], len(self.fiducials), 2))
        # one pass per frame over the tabulated segments instead of gathering the
        # (T, M, F, 2) segment ends: the joint fit predicts some 40 times per video
        pairs, inter = self._pair_table
        _piecewise_nb(np.ascontiguousarray(c), self.upper,
                      self.displacement.reshape(len(self.muscles), self.n_levels, -1),
                      pairs, inter, out.reshape(c.shape[0], -1))
        return out

    def jacobian(self, c: np.ndarray) -> np.ndarray:
        """Slope of the response (T, F*2, M) at ``c`` (right-hand slope at breakpoints)."""
        c = np.atleast_2d(np.asarray(c, dtype=float))
        idx, _ = self._segments(c)
        m = np.arange(len(self.muscles))
        slope = self._slopes[m, idx]                                   # (T, M, F*2)
        jac = slope.transpose(0, 2, 1)
        if self.pairs is not None and len(self.pairs):
            # d/dc_a of u_a u_b W_ab = u_b W_ab / upper_a, and symmetrically for b: per
            # control, one product of its partners' u with the W of its pairs
            u = c / self.upper
            for j, (partners, rows) in enumerate(self._pair_groups):
                if len(rows):
                    slope[:, j] += (u[:, partners] / self.upper[j]) @ rows
        return jac

    def best_of(self, trials: np.ndarray, target: np.ndarray, sw: np.ndarray,
                penalty: np.ndarray, best: np.ndarray,
                res: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """A weighted fit's line search: per frame, the trial that lowers the objective most.

        The objective of controls ``c`` on a frame is ``|target - sw * p(c)|^2 + penalty``,
        ``p`` the response's prediction (flattened to ``F*2``); each trial's is formed
        point by point without building its prediction for all frames, the pass over the
        points that dominates a fit's step.

        Parameters
        ----------
        trials : ndarray, shape (S, T, M)
            Candidate controls (finite), ``S`` per frame.
        target : ndarray, shape (T, F*2)
            Weighted measured displacements (``sw`` times them).
        sw : ndarray, shape (T, F*2)
            Per-frame row weights (square roots of the least-squares weights).
        penalty : ndarray, shape (S, T)
            Each trial's objective beyond the residual (priors).
        best : ndarray, shape (T,)
            The objective to beat (the current point's).
        res : ndarray, shape (T, F*2)
            The current point's weighted residuals.

        Returns
        -------
        best : ndarray, shape (T,)
            The lowest objective, the trial's where one beat ``best`` (the first of equals).
        res : ndarray, shape (T, F*2)
            Its weighted residuals.
        choice : ndarray of int, shape (T,)
            The trial kept, -1 where none beat ``best``.

        Examples
        --------
        >>> levels = np.linspace(0, 1, 3)
        >>> disp = np.zeros((1, 3, 1, 2))
        >>> disp[0, :, 0, 1] = levels          # one control lifts one point
        >>> resp = FiducialResponse(("a",), ("p",), np.zeros((1, 2)), disp, np.ones(1),
        ...                         levels)
        >>> trials = np.array([[[0.25]], [[0.5]], [[1.0]]])
        >>> best, res, choice = resp.best_of(trials, np.array([[0.0, 0.5]]), np.ones((1, 2)),
        ...                                  np.zeros((3, 1)), np.array([0.25]),
        ...                                  np.array([[0.0, 0.5]]))
        >>> best.tolist(), res.tolist(), choice.tolist()
        ([0.0], [[0.0, 0.0]], [1])
        """
        n_m, n_k = len(self.muscles), 2 * len(self.fiducials)
        trials = np.ascontiguousarray(trials, dtype=float)
        if trials.ndim != 3 or trials.shape[2] != n_m:
            raise ValueError(f"trials must have shape (S, T, {n_m}), got {trials.shape}")
        n_s, n_t = trials.shape[:2]
        # read only; the kernel writes its results over copies of the current point's
        target, sw = (np.ascontiguousarray(a, dtype=float) for a in (target, sw))
        res = np.array(res, dtype=float, order="C")
        best = np.array(best, dtype=float)
        penalty = np.ascontiguousarray(penalty, dtype=float)
        if (target.shape != (n_t, n_k) or sw.shape != target.shape or res.shape != target.shape
                or penalty.shape != (n_s, n_t) or best.shape != (n_t,)):
            raise ValueError(f"target, sw and res must have shape ({n_t}, {n_k}), penalty "
                             f"({n_s}, {n_t}) and best ({n_t},); got {target.shape}, "
                             f"{sw.shape}, {res.shape}, {penalty.shape} and {best.shape}")
        if not np.isfinite(trials).all():
            raise ValueError("trials must be finite")
        choice = np.empty(n_t, dtype=np.intp)
        pairs, inter = self._pair_table
        _best_of_nb(trials, self.upper,
                    self.displacement.reshape(n_m, self.n_levels, -1), pairs, inter,
                    target, sw, penalty, best, res, choice)
        return best, res, choice

    def normal_equations(self, c: np.ndarray, sw: np.ndarray,
                         r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Gauss-Newton normal equations of a weighted fit at ``c``: ``(J'J, J'r)``.

        ``J`` is :meth:`jacobian` at ``c`` with each row (point coordinate) scaled by
        ``sw``; the products are formed frame by frame without building ``J`` for all
        frames at once, and a pair term whose partner is at rest (most of them, in a
        sparse fit) costs nothing.

        Parameters
        ----------
        c : ndarray, shape (T, M)
            Controls (finite).
        sw : ndarray, shape (T, F*2)
            Per-frame row weights (the square roots of the least-squares weights).
        r : ndarray, shape (T, F*2)
            Weighted residuals.

        Returns
        -------
        hess : ndarray, shape (T, M, M)
        grad : ndarray, shape (T, M)

        Examples
        --------
        >>> levels = np.linspace(0, 1, 3)
        >>> disp = np.zeros((2, 3, 2, 2))
        >>> disp[0, :, :, 1] = levels[:, None]
        >>> disp[1, :, :, 0] = 2 * levels[:, None]
        >>> resp = FiducialResponse(("a", "b"), ("p", "q"), np.zeros((2, 2)), disp,
        ...                         np.ones(2), levels)
        >>> h, g = resp.normal_equations(np.zeros((1, 2)), np.ones((1, 4)), np.ones((1, 4)))
        >>> h[0].tolist(), g[0].tolist()
        ([[2.0, 0.0], [0.0, 8.0]], [2.0, 4.0])
        """
        n_m, n_k = len(self.muscles), 2 * len(self.fiducials)
        c = np.ascontiguousarray(c, dtype=float)
        sw = np.ascontiguousarray(sw, dtype=float)
        r = np.ascontiguousarray(r, dtype=float)
        if c.ndim != 2 or c.shape[1] != n_m or sw.shape != (len(c), n_k) \
                or r.shape != sw.shape:
            raise ValueError(f"c, sw and r must have shapes (T, {n_m}), (T, {n_k}) and "
                             f"(T, {n_k}), got {c.shape}, {sw.shape} and {r.shape}")
        hess = np.empty((len(c), n_m, n_m))
        grad = np.empty((len(c), n_m))
        pairs, inter = self._pair_table
        _normal_nb(c, self.upper, self._slopes, pairs, inter, sw, r, hess, grad)
        return hess, grad

    @functools.cached_property
    def _pair_table(self) -> tuple[np.ndarray, np.ndarray]:
        """The interaction pairs (P, 2) and their terms (P, F*2), empty without any."""
        n_k = 2 * len(self.fiducials)
        if self.pairs is None or not len(self.pairs):
            return np.zeros((0, 2), np.intp), np.zeros((0, n_k))
        return (np.ascontiguousarray(self.pairs, dtype=np.intp),
                np.ascontiguousarray(self.interaction.reshape(len(self.pairs), n_k)))

    @functools.cached_property
    def _pair_groups(self) -> list[tuple[np.ndarray, np.ndarray]]:
        """Per control: (partner controls, their interaction rows (n, F*2))."""
        w = self.interaction.reshape(len(self.pairs), -1)
        groups = []
        for j in range(len(self.muscles)):
            as_a = np.flatnonzero(self.pairs[:, 0] == j)
            as_b = np.flatnonzero(self.pairs[:, 1] == j)
            partners = np.concatenate([self.pairs[as_a, 1], self.pairs[as_b, 0]])
            groups.append((partners, w[np.concatenate([as_a, as_b])]))
        return groups

    @functools.cached_property
    def _slopes(self) -> np.ndarray:
        """(M, L-1, F*2) slope of every segment, per control unit."""
        step = self.upper / (self.n_levels - 1)   # control units per level
        d = self.displacement.reshape(len(self.muscles), self.n_levels, -1)
        return np.diff(d, axis=1) / step[:, None, None]

    def index(self, muscle: str) -> int:
        try:
            return self.muscles.index(muscle)
        except ValueError:
            raise ValueError(f"unknown control {muscle!r}; known: {', '.join(self.muscles)}") \
                from None

    def save(self, path) -> None:
        np.savez_compressed(path, muscles=np.array(self.muscles),
                            fiducials=np.array(self.fiducials), rest=self.rest,
                            displacement=self.displacement, upper=self.upper, levels=self.levels,
                            pairs=np.zeros((0, 2), np.intp) if self.pairs is None else self.pairs,
                            interaction=(np.zeros((0, len(self.fiducials), 2))
                                         if self.interaction is None else self.interaction))

    @classmethod
    def load(cls, path) -> FiducialResponse:
        with np.load(path) as z:
            pairs = z["pairs"] if "pairs" in z and len(z["pairs"]) else None
            inter = z["interaction"] if pairs is not None else None
            return cls(tuple(str(s) for s in z["muscles"]), tuple(str(s) for s in z["fiducials"]),
                       z["rest"], z["displacement"], z["upper"], z["levels"], pairs, inter)


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _predict_row_nb(c, upper, disp, pairs, inter, out):
    # disp (M, L, K): the response at each tabulated level; inter (P, K) the pair terms;
    # c (M,), out (K,). A control at rest adds nothing, nor does any pair it belongs to: in
    # a sparse fit, most of them
    n_m = c.shape[0]
    n_l, n_k = disp.shape[1], disp.shape[2]
    for k in range(n_k):
        out[k] = 0.0
    for m in range(n_m):
        s = min(max(c[m] / upper[m], 0.0), 1.0) * (n_l - 1)
        if s == 0.0:
            continue
        i = min(int(np.floor(s)), n_l - 2)
        f = s - i
        g = 1.0 - f
        for k in range(n_k):
            out[k] += g * disp[m, i, k] + f * disp[m, i + 1, k]
    for p in range(pairs.shape[0]):
        w = (c[pairs[p, 0]] / upper[pairs[p, 0]]) * (c[pairs[p, 1]] / upper[pairs[p, 1]])
        if w != 0.0:
            for k in range(n_k):
                out[k] += w * inter[p, k]


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _piecewise_nb(c, upper, disp, pairs, inter, out):
    # out (T, K): one frame at a time
    for t in range(c.shape[0]):
        _predict_row_nb(c[t], upper, disp, pairs, inter, out[t])


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _best_of_nb(trials, upper, disp, pairs, inter, target, sw, penalty, best, res, choice):
    # trials (S, T, M), penalty (S, T); target, sw, res (T, K); best, choice (T,): per frame,
    # each trial's weighted residual summed as it is formed, and kept where it is the best
    # yet (res and best updated in place)
    n_s, n_t = trials.shape[0], trials.shape[1]
    n_k = target.shape[1]
    pred = np.empty(n_k)
    for t in range(n_t):
        choice[t] = -1
        for s in range(n_s):
            _predict_row_nb(trials[s, t], upper, disp, pairs, inter, pred)
            total = penalty[s, t]
            for k in range(n_k):
                r = target[t, k] - pred[k] * sw[t, k]
                total += r * r
            if total < best[t]:
                best[t] = total
                choice[t] = s
                for k in range(n_k):
                    res[t, k] = target[t, k] - pred[k] * sw[t, k]


@numba.njit(cache=True, nogil=True, fastmath=True, error_model="numpy")
def _normal_nb(c, upper, slopes, pairs, inter, sw, r, hess, grad):
    # slopes (M, L-1, K), inter (P, K): per frame, the weighted Jacobian's rows for each
    # control (contiguous in K), then J'J (upper triangle, mirrored) and J'r
    n_t, n_m = c.shape
    n_s, n_k = slopes.shape[1], slopes.shape[2]
    a = np.empty((n_m, n_k))
    u = np.empty(n_m)
    for t in range(n_t):
        for m in range(n_m):
            u[m] = c[t, m] / upper[m]
            s = min(max(u[m], 0.0), 1.0) * n_s
            i = min(int(np.floor(s)), n_s - 1)
            for k in range(n_k):
                a[m, k] = slopes[m, i, k]
        # d/dc_a of u_a u_b W_ab = u_b W_ab / upper_a (and symmetrically for b)
        for p in range(pairs.shape[0]):
            pa, pb = pairs[p, 0], pairs[p, 1]
            if u[pb] != 0.0:
                f = u[pb] / upper[pa]
                for k in range(n_k):
                    a[pa, k] += f * inter[p, k]
            if u[pa] != 0.0:
                f = u[pa] / upper[pb]
                for k in range(n_k):
                    a[pb, k] += f * inter[p, k]
        for m in range(n_m):
            acc = 0.0
            for k in range(n_k):
                a[m, k] *= sw[t, k]
                acc += a[m, k] * r[t, k]
            grad[t, m] = acc
        # four rows of J' at a time: each pass over a row of J feeds four sums
        m = 0
        while m < n_m:
            for n in range(m, n_m):
                a0 = 0.0
                a1 = 0.0
                a2 = 0.0
                a3 = 0.0
                if m + 3 < n_m:
                    for k in range(n_k):
                        ank = a[n, k]
                        a0 += a[m, k] * ank
                        a1 += a[m + 1, k] * ank
                        a2 += a[m + 2, k] * ank
                        a3 += a[m + 3, k] * ank
                else:
                    for k in range(n_k):
                        ank = a[n, k]
                        a0 += a[m, k] * ank
                        if m + 1 < n_m:
                            a1 += a[m + 1, k] * ank
                        if m + 2 < n_m:
                            a2 += a[m + 2, k] * ank
                hess[t, m, n] = a0
                hess[t, n, m] = a0
                if m + 1 <= n:
                    hess[t, m + 1, n] = a1
                    hess[t, n, m + 1] = a1
                if m + 2 <= n:
                    hess[t, m + 2, n] = a2
                    hess[t, n, m + 2] = a2
                if m + 3 <= n:
                    hess[t, m + 3, n] = a3
                    hess[t, n, m + 3] = a3
            m += 4
