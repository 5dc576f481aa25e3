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
        _piecewise_nb(np.ascontiguousarray(c), self.upper,
                      self.displacement.reshape(len(self.muscles), self.n_levels, -1),
                      out.reshape(c.shape[0], -1))
        if self.pairs is not None and len(self.pairs):
            u = c / self.upper
            prod = u[:, self.pairs[:, 0]] * u[:, self.pairs[:, 1]]     # (T, P)
            out += (prod @ self.interaction.reshape(len(self.pairs), -1)).reshape(out.shape)
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
def _piecewise_nb(c, upper, disp, out):
    # disp (M, L, K): the response at each tabulated level; out (T, K)
    n_t, n_m = c.shape
    n_l, n_k = disp.shape[1], disp.shape[2]
    for t in range(n_t):
        for k in range(n_k):
            out[t, k] = 0.0
        for m in range(n_m):
            s = min(max(c[t, m] / upper[m], 0.0), 1.0) * (n_l - 1)
            i = min(int(np.floor(s)), n_l - 2)
            f = s - i
            g = 1.0 - f
            for k in range(n_k):
                out[t, k] += g * disp[m, i, k] + f * disp[m, i + 1, k]
