"""Discrete deformable contours (snakes) exactly as eqs. 7-12 of 004.

Each contour is a chain of nodes ``x_i = (x, y)`` (image pixels, x right, y down)
joined by springs. For node ``i`` of a system of ``N`` nodes:

* tension (eq. 7), explicit: spring ``i`` joins node ``i`` to the next node,
  ``r_i = x_{i+1} - x_i``, ``e_i = ||r_i|| - l_i`` and ``alpha_i = a_i e_i r_i / ||r_i||``;
  a stretched spring pulls its two nodes together, a compressed one pushes them apart;
* viscoelastic rest lengths (eq. 8): ``dl_i/dt = nu_i e_i``;
* rigidity (eq. 9), implicit: ``beta = K x`` with ``K = sum_j b_j d_j d_j^T`` and
  ``d_j`` the second-difference stencil ``x_{j-1} - 2 x_j + x_{j+1}``; this is eq. 9
  term by term;
* image and user forces (eq. 12): ``f_i = p_i F(x_i) + f^u_i`` with ``F = -grad P``
  sampled bilinearly (see :mod:`trackers.potentials` for the sign);
* semi-implicit Euler (eq. 11): ``(gamma/dt I + K) x^{t+dt} = gamma/dt x^t - alpha^t + f^t``.

The matrix ``A = gamma/dt I + K`` is constant, so it is factored **once** per
:class:`ContourSystem` (banded Cholesky, bandwidth 2) and every step of every frame
reuses the factor (004: "we factorize it only once"). Several contours live in one
system separated by ``a_i = b_i = 0``: no spring joins them and no rigidity stencil
straddles the break, so they are exactly decoupled and the matrix stays
block-pentadiagonal. Ends of an open contour are *free* (natural boundary: no
stencil is centred on an end node) or *fixed* (a stiff anchor on the end nodes).
A *closed* contour adds two stencils that wrap around (and, with
``tension='split'``, one wrapping spring); they are kept out of the banded factor and
applied by a rank-2 (rank-3) Sherman-Morrison-Woodbury correction precomputed at
factorisation time, so a closed contour costs the same O(n) per step.

The relaxation loop (force sampling, tension, rest-length update, banded solve,
cyclic correction, movement test) runs inside one Numba kernel. Equilibrium is
declared when no node moved more than ``tol`` pixels in the last step (or when the
root-mean-square move is below ``tol``, ``criterion='rms'``). Forces are either given
as fields ``-grad P`` or computed from the potentials at the four pixels around each
node; each contour can have its own field (and field box) and its own ``p``.

Default parameters are the paper's (004 V-E): ``gamma/dt = 0.5``, ``a = 1``,
``b = 0.5``, ``nu = 0.2``, ``p = 0.001`` for potentials in 8-bit intensity units
(every potential in :mod:`trackers.potentials` is). The paper's filter has an
effective width of about one pixel; a Gaussian potential of width ``sigma`` has
ravines ``(sigma / 0.9)**3`` times flatter, and :func:`paper_equivalent_strength`
gives the ``p`` that keeps the paper's speed of descent.

Parts: :mod:`trackers.snake_types` (the parameters, contours and results),
:mod:`trackers.snake_kernel` (the compiled relaxation loop) and :mod:`trackers.polyline`
(resampling); this module holds the solver, :class:`ContourSystem`.
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence

import numpy as np
from scipy.linalg import cho_solve_banded, cholesky_banded

from trackers.snake_kernel import _first_outside, _relax_kernel, _solve_inplace
from trackers.snake_types import Contour, RelaxResult, SnakeParams, _per_node

__all__ = [
    "ContourSystem",
    "paper_equivalent_strength",
    "factorization_count",
]

_FACTORIZATIONS = 0
_ANCHOR = 1.0e8  # stiffness of the anchor holding a fixed end node, relative units


def factorization_count() -> int:
    """Number of matrix factorisations done by :class:`ContourSystem` in this process.

    Every system factors its matrix exactly once, when it is built; stepping,
    relaxing and tracking never factor again. Tests count with this.

    Examples
    --------
    >>> import numpy as np
    >>> before = factorization_count()
    >>> s = ContourSystem([Contour(np.c_[np.arange(10.0), np.zeros(10)] + 5)])
    >>> factorization_count() - before
    1
    """
    return _FACTORIZATIONS


def paper_equivalent_strength(sigma: float, p: float = 0.001) -> float:
    """Image-force strength for a Gaussian potential of width ``sigma`` that descends
    its ravines as fast as the paper's filter with strength ``p``.

    The curvature at the bottom of an edge ravine of eq. 13 falls as ``sigma**-3``;
    the paper's two five-point averages have an effective width of about 0.9 px.

    Parameters
    ----------
    sigma : float
        Gaussian width in pixels.
    p : float
        Strength for the paper's filter (004 V-E uses 0.001).

    Returns
    -------
    float

    Examples
    --------
    >>> round(paper_equivalent_strength(0.9), 6)
    0.001
    """
    sigma = float(sigma)
    if not np.isfinite(sigma) or sigma <= 0:
        raise ValueError(f"sigma must be positive, got {sigma}")
    return float(p) * (sigma / 0.9) ** 3


class ContourSystem:
    """Several deformable contours simulated together, with one factored matrix.

    Parameters
    ----------
    contours : sequence of Contour or array_like (n, 2)
        The contours; plain arrays become open contours with free ends.
    params : SnakeParams, optional
        Default parameters for contours that carry none (004 V-E values).
    tension : {'explicit', 'split'}
        ``'explicit'`` (default, as eq. 11): the whole tension of eq. 7 is evaluated
        at time t. ``'split'``: its linear part ``a_i r_i`` joins the constant matrix
        (implicit) and only the bounded remainder ``-a_i l_i r_i / ||r_i||`` stays
        explicit. Same equations and equilibria, unconditionally stable tension;
        with zero rest lengths it is the classical membrane of Kass et al.
    max_step : float, optional
        Cap on any node's displacement per step in pixels (as scikit-image's
        ``max_px_move``); off by default.

    Examples
    --------
    >>> import numpy as np
    >>> from trackers.potentials import gaussian_potential
    >>> from trackers.sampling import force_field
    >>> yy, xx = np.mgrid[:64, :64]
    >>> img = ((xx - 32) ** 2 + (yy - 32) ** 2 < 15 ** 2).astype(float)
    >>> t = np.linspace(0, 2 * np.pi, 60, endpoint=False)
    >>> init = np.c_[32 + 18 * np.cos(t), 32 + 18 * np.sin(t)]
    >>> params = SnakeParams(p=paper_equivalent_strength(2.0))
    >>> system = ContourSystem([Contour(init, closed=True)], params)
    >>> res = system.relax(force_field(gaussian_potential(img, 2.0)))
    >>> r = np.hypot(*(system.positions - 32).T)
    >>> bool(abs(r.mean() - 15) < 0.6 and res.converged)
    True
    """

    def __init__(self, contours: Sequence, params: SnakeParams | None = None, *,
                 tension: str = "explicit", max_step: float | None = None):
        if tension not in ("explicit", "split"):
            raise ValueError(f"tension must be 'explicit' or 'split', got {tension!r}")
        self.split = tension == "split"
        if max_step is not None and (not np.isfinite(max_step) or max_step <= 0):
            raise ValueError(f"max_step must be a positive number or None, got {max_step}")
        self.max_step = float(max_step) if max_step is not None else 0.0
        if params is None:
            params = SnakeParams()
        if not isinstance(params, SnakeParams):
            raise ValueError(f"params must be a SnakeParams, got {type(params).__name__}")
        if isinstance(contours, Contour | np.ndarray):
            contours = [contours]
        contours = [c if isinstance(c, Contour) else Contour(np.asarray(c, float))
                    for c in contours]
        if not contours:
            raise ValueError("a ContourSystem needs at least one contour")
        self.params = params
        self.names = []
        pts_list, starts = [], [0]
        for k, c in enumerate(contours):
            name = c.name or f"contour{k}"
            pts = np.asarray(c.points, dtype=np.float64)
            if pts.ndim != 2 or pts.shape[1] != 2:
                raise ValueError(f"contour {name!r}: points must have shape (n, 2), "
                                 f"got {pts.shape}")
            need = 5 if c.closed else 3
            if len(pts) < need:
                raise ValueError(f"contour {name!r} has {len(pts)} nodes; the rigidity "
                                 f"stencil of eq. 9 needs at least {need} for "
                                 f"{'a closed' if c.closed else 'an open'} contour")
            if not np.isfinite(pts).all():
                raise ValueError(f"contour {name!r} has NaN or infinite node coordinates")
            if c.closed and c.fixed_ends:
                raise ValueError(f"contour {name!r}: a closed contour has no ends to fix")
            if int(c.field) < 0:
                raise ValueError(f"contour {name!r}: field must be >= 0, got {c.field}")
            self.names.append(name)
            pts_list.append(pts)
            starts.append(starts[-1] + len(pts))
        self.contours = contours
        self.starts = np.asarray(starts, dtype=np.int64)
        N = int(self.starts[-1])
        self.n_nodes = N
        self.X = np.vstack(pts_list)
        self.nxt = np.full(N, -1, np.int64)
        self.prv = np.full(N, -1, np.int64)
        self.normal_only = np.zeros(N, np.bool_)
        self.a_s = np.zeros(N)
        self.nu_s = np.zeros(N)
        self.b_n = np.zeros(N)
        self.p_n = np.zeros(N)
        self.fidx = np.zeros(N, np.int64)
        self.node_contour = np.zeros(N, np.int64)
        self.kappa = np.zeros(N)
        self.anchor = np.zeros((N, 2))
        self.rest = np.zeros(N)
        self.closed = np.array([c.closed for c in contours], bool)
        self.frozen = np.zeros(len(contours), np.bool_)
        for k, c in enumerate(contours):
            s, e = int(self.starts[k]), int(self.starts[k + 1])
            n = e - s
            prm = c.params or params
            name = self.names[k]
            idx = np.arange(s, e)
            self.node_contour[s:e] = k
            self.fidx[s:e] = int(c.field)
            nx = idx + 1
            if c.closed:
                nx[-1] = s
            else:
                nx[-1] = -1
            self.nxt[s:e] = nx
            pv = idx - 1
            pv[0] = e - 1 if c.closed else -1
            self.prv[s:e] = pv
            self.normal_only[s:e] = bool(c.normal_forces)
            a = _per_node(c.a, prm.a, n, "a", name)
            nu = _per_node(c.nu, prm.nu, n, "nu", name)
            b = _per_node(c.b, prm.b, n, "b", name)
            p = _per_node(c.p, prm.p, n, "p", name)
            if not self.split:
                self._check_stability(a, b, prm, name)
            if not c.closed:
                a[-1] = 0.0
                nu[-1] = 0.0
                b[0] = b[-1] = 0.0  # no stencil centred on a free end (natural boundary)
            self.a_s[s:e] = a
            self.nu_s[s:e] = nu
            self.b_n[s:e] = b
            self.p_n[s:e] = p
            self.rest[s:e] = self._initial_rest(c, self.X[s:e], name)
            # a node's spring and a fixed end share the implicit anchor term: the
            # spring is kappa (x - target) on the matrix's diagonal and the right side
            self.kappa[s:e] = _per_node(c.spring, 0.0, n, "spring", name)
            self.anchor[s:e] = self.X[s:e]
            if c.fixed_ends:
                self.kappa[[s, e - 1]] = _ANCHOR
        self.gdt = np.array([float((c.params or params).gamma / (c.params or params).dt)
                             for c in contours])
        self.dts = np.array([float((c.params or params).dt) for c in contours])
        if np.ptp(self.gdt) > 1e-12 * self.gdt.max() or np.ptp(self.dts) > 0:
            raise ValueError("all contours of one system must share gamma and dt "
                             "(they are integrated together)")
        self._factor()
        self._field_block = np.empty(0, np.float32)   # see relax()

    # ------------------------------------------------------------------ setup
    @staticmethod
    def _initial_rest(c, pts, name):
        seg = np.empty(len(pts))
        np.hypot(pts[1:, 0] - pts[:-1, 0], pts[1:, 1] - pts[:-1, 1], out=seg[:-1])
        seg[-1] = np.hypot(*(pts[0] - pts[-1])) if c.closed else 0.0
        if c.rest_lengths is None:
            return seg
        rl = np.asarray(c.rest_lengths, dtype=np.float64)
        if rl.ndim == 0:
            rl = np.full(len(pts), float(rl))
        if rl.shape != (len(pts),) or not np.isfinite(rl).all() or (rl < 0).any():
            raise ValueError(f"contour {name!r}: rest_lengths must be a non-negative scalar "
                             f"or have {len(pts)} entries")
        return rl.copy()

    @staticmethod
    def _check_stability(a, b, prm, name):
        # Von Neumann bound of explicit tension + implicit rigidity on a uniform chain:
        # the amplification (g/dt - a s) / (g/dt + b s^2), s in [0, 4], must stay > -1.
        # A node's rigidity comes from the stencils centred on it and its neighbours.
        s = np.linspace(0.0, 4.0, 41)[None, :]
        gdt = prm.gamma / prm.dt
        b_eff = np.maximum(b, np.maximum(np.r_[b[1:], 0.0], np.r_[0.0, b[:-1]]))
        val = b_eff[:, None] * s**2 - a[:, None] * s + 2 * gdt
        if (val <= 0).any():
            warnings.warn(f"contour {name!r}: tension a is too large for gamma/dt and b "
                          "(explicit tension may oscillate); lower a or raise gamma/dt or b",
                          RuntimeWarning, stacklevel=3)

    def _factor(self):
        global _FACTORIZATIONS
        N = self.n_nodes
        gdt = float(self.gdt[0])
        A = np.zeros((3, N))  # upper banded: A[2 + i - j, j] = A_ij for i <= j
        A[2] = gdt + self.kappa
        coef = np.array([1.0, -2.0, 1.0])
        wraps = []
        for k in range(len(self.contours)):
            s, e = int(self.starts[k]), int(self.starts[k + 1])
            inner = np.arange(s + 1, e - 1)  # stencils that do not wrap around
            bj = self.b_n[inner]
            for u in range(3):
                for v in range(u, 3):
                    i = inner - 1 + u
                    j = inner - 1 + v
                    np.add.at(A, (2 + i - j, j), bj * coef[u] * coef[v])
            if self.split:
                # linear part a_i r_i of the tension: a weighted graph Laplacian
                sp = np.arange(s, e - 1)
                a = self.a_s[sp]
                np.add.at(A, (2, sp), a)
                np.add.at(A, (2, sp + 1), a)
                np.add.at(A, (1, sp + 1), -a)
            if self.closed[k]:
                nodes = np.array([[e - 1, s, s + 1], [e - 2, e - 1, s], [e - 1, s, s]])
                coefs = np.array([coef, coef, [1.0, -1.0, 0.0]])
                w = np.array([self.b_n[s], self.b_n[e - 1],
                              self.a_s[e - 1] if self.split else 0.0])
                wraps.append((k, nodes, coefs, w))
        self._cb = cholesky_banded(A, lower=False)
        _FACTORIZATIONS += 1
        zc = np.zeros((N, 3))
        corr_idx, corr_coef, corr_M, corr_range = [], [], [], []
        for k, nodes, coefs, w in wraps:
            s, e = int(self.starts[k]), int(self.starts[k + 1])
            U = np.zeros((N, 3))
            for col in range(3):
                np.add.at(U[:, col], nodes[col], coefs[col])
            Z = cho_solve_banded((self._cb, False), U)
            zc[s:e] = Z[s:e]
            C = np.diag(w)
            M = np.linalg.solve(np.eye(3) + C @ (U.T @ Z), C)
            corr_idx.append(nodes)
            corr_coef.append(coefs)
            corr_M.append(M)
            corr_range.append((s, e))
        self._zc = zc
        self._cidx = np.asarray(corr_idx, np.int64).reshape(-1, 3, 3)
        self._ccoef = np.asarray(corr_coef, np.float64).reshape(-1, 3, 3)
        self._cM = np.asarray(corr_M, np.float64).reshape(-1, 3, 3)
        self._crange = np.asarray(corr_range, np.int64).reshape(-1, 2)

    # ------------------------------------------------------------------ state
    @property
    def n_contours(self) -> int:
        return len(self.contours)

    @property
    def positions(self) -> np.ndarray:
        """Copy of all node positions, (N, 2) in (x, y) pixels."""
        return self.X.copy()

    def contour_slice(self, k: int) -> slice:
        """Slice of the nodes of contour ``k`` (an index or a name) in :attr:`positions`."""
        k = self._index(k)
        return slice(int(self.starts[k]), int(self.starts[k + 1]))

    def contour_points(self, k) -> np.ndarray:
        """Copy of the nodes of contour ``k`` (index or name), (n_k, 2)."""
        return self.X[self.contour_slice(k)].copy()

    def rest_lengths(self, k) -> np.ndarray:
        """Copy of the current rest lengths of contour ``k``."""
        return self.rest[self.contour_slice(k)].copy()

    def _index(self, k):
        if isinstance(k, str):
            if k not in self.names:
                raise ValueError(f"no contour named {k!r}; choose from {self.names}")
            return self.names.index(k)
        k = int(k)
        if not 0 <= k < self.n_contours:
            raise ValueError(f"contour index {k} out of range 0..{self.n_contours - 1}")
        return k

    def set_contour(self, k, points, *, reset_rest: bool = True) -> None:
        """Move contour ``k`` (index or name) to new node positions.

        The number of nodes must not change (the factored matrix depends on it).
        With ``reset_rest`` the rest lengths become the new node separations.
        Fixed end anchors move with the ends.
        """
        k = self._index(k)
        sl = self.contour_slice(k)
        pts = np.asarray(points, dtype=np.float64)
        if pts.shape != (sl.stop - sl.start, 2):
            raise ValueError(f"contour {self.names[k]!r} has {sl.stop - sl.start} nodes; "
                             f"got points of shape {pts.shape}")
        if not np.isfinite(pts).all():
            raise ValueError(f"contour {self.names[k]!r}: points contain NaN or infinity")
        self.X[sl] = pts
        if self.contours[k].fixed_ends:
            self.anchor[[sl.start, sl.stop - 1]] = pts[[0, -1]]
        if reset_rest:
            c = self.contours[k]
            self.rest[sl] = self._initial_rest(c, pts, self.names[k])

    def set_targets(self, k, points) -> None:
        """Move the targets of contour ``k``'s springs (see ``Contour.spring``).

        The stiffnesses are part of the factored matrix; the targets are not, so
        this never refactors. Fixed ends keep their anchors.
        """
        k = self._index(k)
        sl = self.contour_slice(k)
        pts = np.asarray(points, dtype=np.float64)
        if pts.shape != (sl.stop - sl.start, 2) or not np.isfinite(pts).all():
            raise ValueError(f"contour {self.names[k]!r}: targets must be a finite "
                             f"({sl.stop - sl.start}, 2) array, got shape {pts.shape}")
        if self.contours[k].fixed_ends:
            pts = pts.copy()
            pts[[0, -1]] = self.anchor[[sl.start, sl.stop - 1]]
        self.anchor[sl] = pts

    def set_strength(self, k, p) -> None:
        """Change the image-force strength ``p`` of contour ``k`` (scalar or per node).

        ``p`` is not part of the factored matrix, so this never refactors.
        """
        k = self._index(k)
        sl = self.contour_slice(k)
        self.p_n[sl] = _per_node(p, 0.0, sl.stop - sl.start, "p", self.names[k])

    def strength(self, k) -> np.ndarray:
        """Copy of the per-node image-force strengths of contour ``k``."""
        return self.p_n[self.contour_slice(k)].copy()

    def outside_fields(self, shapes, origin) -> np.ndarray:
        """Per node, whether it lies outside the field its contour uses.

        Parameters
        ----------
        shapes : sequence of (H, W)
            Shape of each field.
        origin : array_like, (K, 2)
            Image position (x, y) of each field's ``[0, 0]``.

        Returns
        -------
        ndarray of bool, (n_nodes,)
            :meth:`relax` refuses to start while any is true (frozen contours'
            nodes are never outside: they read no field).
        """
        g = np.c_[np.asarray(origin, dtype=np.float64).reshape(-1, 2),
                  np.asarray(shapes, dtype=np.float64).reshape(-1, 2)][self.fidx]
        rel = self.X - g[:, :2]
        return (((rel[:, 0] < 0) | (rel[:, 1] < 0) | (rel[:, 0] > g[:, 3] - 1)
                 | (rel[:, 1] > g[:, 2] - 1)) & ~self.frozen[self.node_contour])

    def freeze(self, k, frozen: bool = True) -> None:
        """Hold contour ``k`` (index or name) out of :meth:`relax` (or let it back in).

        A frozen contour's nodes and rest lengths stay as they are (:meth:`set_contour`
        still moves them), it reads no field (its field may be any 2x2 array) and its
        nodes count in no movement test: a contour nothing reads costs nothing.

        Examples
        --------
        >>> import numpy as np
        >>> a = np.c_[np.linspace(2, 12, 6), np.full(6, 5.0)]
        >>> system = ContourSystem([a, a + [0, 4]])
        >>> system.freeze(1)
        >>> P = np.tile(np.arange(16.0)[:, None], (1, 16))   # pulls every node up
        >>> _ = system.relax(potentials=[P, np.zeros((2, 2))], max_iter=5)
        >>> bool(system.contour_points(0)[0, 1] < 5), system.contour_points(1)[0].tolist()
        (True, [2.0, 9.0])
        """
        self.frozen[self._index(k)] = bool(frozen)

    # ------------------------------------------------------------------ dynamics
    def relax(self, forces=None, *, potentials=None, origin=(0.0, 0.0), user_forces=None,
              tol: float = 1e-3, max_iter: int = 1000, min_iter: int = 1,
              criterion: str = "max") -> RelaxResult:
        """Integrate eq. 11 until no node moves more than ``tol`` pixels in a step.

        Parameters
        ----------
        forces : array_like, (H, W, 2) or (K, H, W, 2), optional
            Image force fields ``-grad P`` (:func:`trackers.sampling.force_field`
            with ``p=1``); each contour uses field ``Contour.field`` and its own
            strength ``p``.
        potentials : array_like (H, W), (K, H, W) or a sequence of K 2-D arrays, optional
            Instead of ``forces``: the potentials themselves; ``-grad P`` is taken by
            central differences at the four pixels around each node and interpolated
            bilinearly (the same numbers as ``force_field``, without computing the
            field everywhere). A sequence may hold fields of different shapes.
        origin : (x, y) or sequence of K (x, y)
            Image position of pixel ``[0, 0]`` of the fields (the corner of an ROI),
            one for all or one per field.
        user_forces : array_like, (N, 2), optional
            Extra forces ``f^u`` on every node (eq. 12), constant during the call.
        tol : float
            Movement threshold in pixels that defines equilibrium.
        max_iter, min_iter : int
            Bounds on the number of time steps.
        criterion : {'max', 'rms', 'each'}
            Equilibrium when the largest ('max') or the root-mean-square ('rms')
            node displacement of the last step is below ``tol``. 'rms' ignores a few
            nodes creeping along a weak feature (real video). 'each' stops every
            contour on the first step its own largest displacement is below ``tol``
            (and the whole when all have stopped), so that a contour that settles
            does not go on creeping while a slower one is still moving.

        Returns
        -------
        RelaxResult

        Raises
        ------
        ValueError
            For bad fields or user forces, or when a node starts outside its field.
        """
        if (forces is None) == (potentials is None):
            raise ValueError("give exactly one of forces or potentials")
        checked = False
        if forces is not None:
            F = np.asarray(forces)
            if F.ndim == 3:
                F = F[None]
            if F.ndim != 4 or F.shape[-1] != 2 or F.shape[1] < 2 or F.shape[2] < 2:
                raise ValueError(f"forces must have shape (H, W, 2) or (K, H, W, 2) with "
                                 f"H, W >= 2, got {np.shape(forces)}")
            shapes = [F.shape[1:3]] * F.shape[0]
            data = np.ascontiguousarray(F, dtype=np.float32).reshape(
                F.shape[0], F.shape[1], 2 * F.shape[2])
            from_potential = False
        else:
            if isinstance(potentials, np.ndarray) and potentials.ndim in (2, 3):
                plist = [potentials] if potentials.ndim == 2 else list(potentials)
            else:
                plist = [np.asarray(q) for q in potentials]
            shapes = []
            for q in plist:
                if np.ndim(q) != 2 or q.shape[0] < 2 or q.shape[1] < 2:
                    raise ValueError(f"each potential must be 2-D and at least 2x2, got "
                                     f"shape {np.shape(q)}")
                shapes.append(q.shape)
            if len({tuple(sh) for sh in shapes}) == 1:
                data = np.ascontiguousarray(np.stack(plist) if len(plist) > 1
                                            else np.asarray(plist[0])[None],
                                            dtype=np.float32)
            else:
                # one (K, hm, wm) block with each field in its corner: the kernel reads
                # field k only inside its own shape (fgeom), so the rest is left as it
                # is. The block lives in an array the system keeps (a tracker passes
                # fields of new shapes every frame; a fresh block each call cost more
                # than its copy), and each field is checked before it is copied in
                hm = max(sh[0] for sh in shapes)
                wm = max(sh[1] for sh in shapes)
                for q in plist:
                    if not np.isfinite(q).all():
                        raise ValueError("forces / potentials contain NaN or infinite values")
                size = len(plist) * hm * wm
                if self._field_block.size < size:
                    self._field_block = np.empty(size, np.float32)
                data = self._field_block[:size].reshape(len(plist), hm, wm)
                for k, q in enumerate(plist):
                    data[k, :q.shape[0], :q.shape[1]] = q
                checked = True
            from_potential = True
        K = len(shapes)
        need = int(self.fidx.max()) + 1
        if need > K:
            raise ValueError(f"a contour uses field {need - 1} but only {K} were given")
        org = np.asarray(origin, dtype=np.float64)
        if org.shape == (2,):
            org = np.tile(org, (K, 1))
        if org.shape != (K, 2) or not np.isfinite(org).all():
            raise ValueError(f"origin must be (x, y) or one (x, y) per field ({K}), got "
                             f"shape {np.shape(origin)}")
        fgeom = np.empty((K, 4))
        fgeom[:, :2] = org
        fgeom[:, 2:] = np.asarray(shapes, dtype=np.float64)
        if not checked and not np.isfinite(data).all():
            raise ValueError("forces / potentials contain NaN or infinite values")
        i = _first_outside(self.X, self.fidx, fgeom, self.frozen, self.node_contour)
        if i >= 0:
            k = int(self.node_contour[i])
            ox, oy, Hk, Wk = fgeom[self.fidx[i]]
            raise ValueError(f"node {i - int(self.starts[k])} of contour {self.names[k]!r} "
                             f"at (x={self.X[i, 0]:.2f}, y={self.X[i, 1]:.2f}) lies outside the"
                             f" image (x in [{ox:g}, {ox + Wk - 1:g}], y in [{oy:g}, "
                             f"{oy + Hk - 1:g}])")
        if user_forces is None:
            user = np.zeros((self.n_nodes, 2))
        else:
            user = np.asarray(user_forces, dtype=np.float64)
            if user.shape != (self.n_nodes, 2) or not np.isfinite(user).all():
                raise ValueError(f"user_forces must be a finite ({self.n_nodes}, 2) array, got "
                                 f"shape {user.shape}")
            user = np.ascontiguousarray(user)
        tol = float(tol)
        if not np.isfinite(tol) or tol < 0:
            raise ValueError(f"tol must be >= 0, got {tol}")
        max_iter, min_iter = int(max_iter), int(min_iter)
        if max_iter < 1 or min_iter < 0:
            raise ValueError("max_iter must be >= 1 and min_iter >= 0")
        if criterion not in ("max", "rms", "each"):
            raise ValueError(f"criterion must be 'max', 'rms' or 'each', got {criterion!r}")
        outside = np.zeros(self.n_contours, np.bool_)
        it, move, rms = _relax_kernel(self.X, self.rest, self.nxt, self.a_s, self.nu_s, self.p_n,
                                 self.fidx, user, self.kappa, self.anchor, self.node_contour,
                                 self._cb, self._zc, self._cidx, self._ccoef, self._cM,
                                 self._crange, data, fgeom, from_potential,
                                 float(self.gdt[0]), float(self.dts[0]), tol, min_iter,
                                 max_iter, outside, self.split, self.max_step, self.prv,
                                 self.normal_only, criterion == "rms", self.starts,
                                 criterion == "each", self.frozen)
        if not np.isfinite(self.X).all():
            raise FloatingPointError("contour positions became non-finite; the parameters "
                                     "are unstable for this potential (lower p or a)")
        # ('each': the last step's largest move over the contours still moving, below
        # tol only when the last of them stopped)
        conv = (rms if criterion == "rms" else move) < tol
        return RelaxResult(int(it), float(move), bool(conv), outside, float(rms))

    def step(self, forces=None, n: int = 1, **kwargs) -> RelaxResult:
        """Take exactly ``n`` time steps (no equilibrium test). See :meth:`relax`."""
        return self.relax(forces, tol=0.0, max_iter=n, min_iter=n, **kwargs)

    def solve(self, rhs) -> np.ndarray:
        """Apply ``A^{-1}`` (the factored matrix of eq. 11) to ``rhs`` of shape (N, 2).

        Exposed for tests and for users who integrate their own forces.
        """
        R = np.array(rhs, dtype=np.float64)
        if R.shape != (self.n_nodes, 2):
            raise ValueError(f"rhs must have shape ({self.n_nodes}, 2), got {R.shape}")
        _solve_inplace(self._cb, R, self._zc, self._cidx, self._ccoef, self._cM, self._crange,
                       self.starts, np.zeros_like(self.frozen), self.node_contour)
        return R

    def matrix(self) -> np.ndarray:
        """Dense matrix ``gamma/dt I + K`` of eq. 11 (+ end anchors, + the tension
        Laplacian with ``tension='split'``), for inspection."""
        N = self.n_nodes
        A = np.diag(self.gdt[0] + self.kappa)
        for k in range(self.n_contours):
            s, e = int(self.starts[k]), int(self.starts[k + 1])
            for j in range(s, e):
                if self.b_n[j] == 0:
                    continue
                if self.closed[k]:
                    nb = [s + (j - s - 1) % (e - s), j, s + (j - s + 1) % (e - s)]
                elif s < j < e - 1:
                    nb = [j - 1, j, j + 1]
                else:
                    continue
                d = np.zeros(N)
                np.add.at(d, nb, [1.0, -2.0, 1.0])
                A += self.b_n[j] * np.outer(d, d)
            if self.split:
                for i in range(s, e):
                    j = int(self.nxt[i])
                    if j >= 0:
                        d = np.zeros(N)
                        d[i] += 1.0
                        d[j] -= 1.0
                        A += self.a_s[i] * np.outer(d, d)
        return A
