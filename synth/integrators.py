"""Time integration and equilibrium solvers for the tissue lattice.

* :func:`rk2_step`: the paper's explicit second-order Runge-Kutta (midpoint) step of
  ``m x'' + gamma x' + g + q = f`` (004 eq. 4), with slightly over-damped ``gamma``.
* :func:`verlet_step`: leapfrog (velocity) Verlet with the same damping (001 ch. 6).
* :class:`EquilibriumSolver`: a fast, unconditionally stable quasi-static solver for the
  per-frame equilibrium.  The lattice energy is minimised by L-BFGS whose initial inverse
  Hessian is ``A^{-1}``, ``A`` being the constant, rotation-invariant projective-dynamics
  matrix (spring Laplacian + scalar Gram form of the volume term) on the free nodes.  ``A``
  is factored once per lattice (SuperLU) and reused for every iteration of every frame; an
  Armijo line search makes every iteration lower the energy (no time step, hence no
  stability limit); the curvature pairs and the previous equilibrium carry over from frame
  to frame.  The loop runs compiled (Numba), triangular solves included.

The explicit methods and the solver minimise / integrate the same forces (the same skull and
lip penalties), so their equilibria agree.

All steppers refuse to return garbage: a step that produces non-finite positions, or a
runaway that leaves the physical range, raises :class:`SimulationError` naming the
parameters.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from .forces import TissueSystem

__all__ = [
    "SimulationError",
    "DynamicState",
    "damping_coefficients",
    "stable_timestep",
    "rk2_step",
    "verlet_step",
    "EquilibriumSolver",
    "isotropic_matrix",
    "rest_stiffness_matrix",
    "lowest_frequency",
]

#: nodes farther than this from their rest positions (cm) mean the simulation has blown up
RUNAWAY_DISTANCE = 30.0


class SimulationError(FloatingPointError):
    """A simulation step diverged (non-finite values or runaway energy)."""


class DynamicState:
    """Positions and velocities of all nodes (a small mutable record)."""

    __slots__ = ("x", "v", "t")

    def __init__(self, x: np.ndarray, v: np.ndarray | None = None, t: float = 0.0):
        self.x = np.array(x, dtype=np.float64)
        self.v = np.zeros_like(self.x) if v is None else np.array(v, dtype=np.float64)
        self.t = float(t)


def _volume_gradients(lattice, x=None) -> np.ndarray:
    """(e, 6, 3) gradients of the prism volumes at ``x`` (rest when omitted)."""
    from .lattice import PRISM_QUADS

    x = lattice.rest if x is None else x
    p = x[lattice.prisms]
    p = p - p.mean(axis=1, keepdims=True)
    grad = np.zeros_like(p)
    for (i, j, k) in ((0, 1, 2), (3, 5, 4)):
        grad[:, i] += np.cross(p[:, j], p[:, k]) / 6.0
        grad[:, j] += np.cross(p[:, k], p[:, i]) / 6.0
        grad[:, k] += np.cross(p[:, i], p[:, j]) / 6.0
    for q in PRISM_QUADS:
        s = p[:, q].sum(axis=1)
        d1 = p[:, q[2]] - p[:, q[0]]
        d2 = p[:, q[3]] - p[:, q[1]]
        c12, c2s, cs1 = np.cross(d1, d2), np.cross(d2, s), np.cross(s, d1)
        grad[:, q[0]] += (c12 - c2s) / 24.0
        grad[:, q[2]] += (c12 + c2s) / 24.0
        grad[:, q[1]] += (c12 - cs1) / 24.0
        grad[:, q[3]] += (c12 + cs1) / 24.0
    return grad


def rest_stiffness_matrix(lattice, *, phase: str = "low", volume: bool = True,
                          skull: bool = True, isotropic: bool = False) -> sp.csr_matrix:
    """Tangent stiffness (Hessian of the lattice energy) at rest, ``3n x 3n`` over all nodes.

    Parameters
    ----------
    lattice : Lattice
    phase : {'low', 'high'}
        Spring stiffness used: small-strain ``k_low`` (the true rest Hessian) or the
        large-strain ``k_high`` (an upper bound anywhere on the extension branch).
    volume : bool
        Add the Gauss-Newton Hessian ``bulk / V0 * g g^T`` of the volume term.
    skull : bool
        Add the skull penalty stiffness on the fascia nodes (isotropically).
    isotropic : bool
        Use ``k I`` per spring instead of ``k n n^T`` (the projective-dynamics Laplacian,
        which bounds the spring Hessian in any configuration).

    Returns
    -------
    scipy.sparse.csr_matrix, node-major (``3 * node + axis``).
    """
    if phase not in ("low", "high"):
        raise ValueError(f"phase must be 'low' or 'high', got {phase!r}")
    n = lattice.n_nodes
    i = lattice.springs[:, 0].astype(np.int64)
    j = lattice.springs[:, 1].astype(np.int64)
    k = lattice.k_low if phase == "low" else lattice.k_high
    if isotropic:
        blk = k[:, None, None] * np.eye(3)[None]
    else:
        r = lattice.rest[j] - lattice.rest[i]
        u = r / np.linalg.norm(r, axis=1, keepdims=True)
        blk = k[:, None, None] * u[:, :, None] * u[:, None, :]
    a3 = np.arange(3)
    rows, cols, vals = [], [], []
    for (p, q, sgn) in ((i, i, 1.0), (j, j, 1.0), (i, j, -1.0), (j, i, -1.0)):
        rows.append((3 * p[:, None, None] + a3[None, :, None]).repeat(3, 2).ravel())
        cols.append((3 * q[:, None, None] + a3[None, None, :]).repeat(3, 1).ravel())
        vals.append((sgn * blk).ravel())
    if volume:
        g = _volume_gradients(lattice).reshape(len(lattice.prisms), 18)
        c = lattice.bulk / lattice.rest_volume
        dof = (3 * lattice.prisms.astype(np.int64)[:, :, None] + a3).reshape(-1, 18)
        rows.append(np.repeat(dof, 18, axis=1).ravel())
        cols.append(np.tile(dof, (1, 18)).ravel())
        vals.append((c[:, None, None] * g[:, :, None] * g[:, None, :]).ravel())
    if skull:
        nodes = lattice.skull_nodes.astype(np.int64)
        dof = (3 * nodes[:, None] + a3).ravel()
        rows.append(dof)
        cols.append(dof)
        vals.append(np.repeat(lattice.skull_k, 3))
        if lattice.contact_pairs is not None and len(lattice.contact_pairs):
            for c in range(2):
                dof = (3 * lattice.contact_pairs[:, c].astype(np.int64)[:, None] + a3).ravel()
                rows.append(dof)
                cols.append(dof)
                vals.append(np.repeat(2.0 * lattice.contact_k, 3))
    mat = sp.coo_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                        shape=(3 * n, 3 * n))
    return mat.tocsr()


def isotropic_matrix(lattice, *, phase: str = "low", volume_weight: float = 1.0):
    """``n x n`` node matrix: spring Laplacian plus the scalar Gram form of the volume term
    (``bulk / V0 * g_a . g_b``); as ``A kron I3`` it is a rotation-invariant approximation of
    the lattice stiffness (projective dynamics)."""
    n = lattice.n_nodes
    i = lattice.springs[:, 0].astype(np.int64)
    j = lattice.springs[:, 1].astype(np.int64)
    k = lattice.k_low if phase == "low" else lattice.k_high
    rows = [i, j, i, j]
    cols = [i, j, j, i]
    vals = [k, k, -k, -k]
    if volume_weight > 0:
        g = _volume_gradients(lattice)
        c = volume_weight * lattice.bulk / lattice.rest_volume
        gram = c[:, None, None] * np.einsum("eak,ebk->eab", g, g)
        pr = lattice.prisms.astype(np.int64)
        rows.append(np.repeat(pr, 6, axis=1).ravel())
        cols.append(np.tile(pr, (1, 6)).ravel())
        vals.append(gram.ravel())
    mat = sp.coo_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                        shape=(n, n))
    return mat.tocsr()


def _node_stiffness(lattice) -> np.ndarray:
    """Gershgorin bound of the stiffness seen by every node (large-strain springs, volume,
    skull)."""
    kmat = rest_stiffness_matrix(lattice, phase="high", isotropic=True, skull=True)
    row = np.asarray(abs(kmat).sum(axis=1)).ravel()
    return row.reshape(-1, 3).max(axis=1)


def lowest_frequency(lattice) -> float:
    """Angular frequency (rad/s) of the softest vibration mode of the lattice at rest,
    from the generalised eigenproblem ``K v = omega^2 M v`` on the free nodes."""
    free = np.flatnonzero(~lattice.fixed)
    dof = (3 * free[:, None] + np.arange(3)).ravel()
    k = rest_stiffness_matrix(lattice, phase="low", skull=False)[dof][:, dof].tocsc()
    m = sp.diags(np.repeat(lattice.mass[free], 3))
    val = spla.eigsh(k, k=1, M=m, sigma=0.0, which="LM", return_eigenvectors=False)
    return float(np.sqrt(max(val[0], 1e-12)))


def damping_coefficients(lattice, ratio: float = 1.1) -> np.ndarray:
    """Velocity damping ``gamma_i = 2 ratio omega_min m_i`` per node (004 III-B): with
    ``ratio`` slightly above 1 the dominant (softest) mode of the tissue is slightly
    over-damped, so the lattice settles in a few of its periods without ringing."""
    if not ratio > 0:
        raise ValueError(f"ratio must be > 0, got {ratio}")
    return 2.0 * ratio * lowest_frequency(lattice) * np.asarray(lattice.mass)


def stable_timestep(lattice, damping: np.ndarray | None = None, safety: float = 0.2) -> float:
    """A time step (s) inside the stability region of :func:`rk2_step` for this lattice.

    ``safety / omega_max`` with ``omega_max`` the Gershgorin bound of the highest frequency at
    rest (large-strain springs and volume term); the midpoint rule amplifies lightly damped
    oscillations by ``(omega dt)**4 / 8`` per step, which the damping absorbs for
    ``omega dt <~ 0.3``. The default leaves room for the volume term's stiffening under
    compression (``1 / J**3``, :mod:`synth.volume`): a sudden jaw opening squeezes elements
    near the jaw to a fraction of their volume for a few steps.  Also keeps
    ``gamma dt / m < 1``."""
    free = ~lattice.fixed
    m = lattice.mass[free]
    k = _node_stiffness(lattice)[free]
    dt = safety / float(np.sqrt((k / m).max()))
    if damping is not None:
        g = np.asarray(damping)[free]
        dt = min(dt, 0.5 * float((m / np.maximum(g, 1e-300)).min()))
    return dt


def _check(x, v, system: TissueSystem, *, where: str, dt=None, extra: str = "") -> None:
    bad = not np.all(np.isfinite(x)) or (v is not None and not np.all(np.isfinite(v)))
    if not bad:
        disp = np.abs(x - system.lattice.rest).max()
        if disp <= RUNAWAY_DISTANCE:
            return
        reason = f"runaway: a node moved {disp:.3g} cm from rest (limit {RUNAWAY_DISTANCE} cm)"
    else:
        reason = "non-finite positions or velocities"
    parts = [f"{where} diverged ({reason})"]
    if dt is not None:
        parts.append(f"dt={dt:.3g} s (stable_timestep={stable_timestep(system.lattice):.3g} s)")
    parts.append(f"jaw_rotation={system.jaw_rotation:.3g} rad, max |f_ext|="
                 f"{np.abs(system.f_ext).max():.3g}")
    if extra:
        parts.append(extra)
    raise SimulationError("; ".join(parts))


def rk2_step(system: TissueSystem, state: DynamicState, dt: float,
             damping: np.ndarray) -> DynamicState:
    """One explicit midpoint Runge-Kutta step of ``m x'' + gamma x' = F(x)`` (004 eq. 4).

    Fixed nodes take their prescribed positions and zero velocity; fascia nodes that end a
    step inside the skull are projected out and lose their inward velocity.

    Parameters
    ----------
    system : TissueSystem
    state : DynamicState
        Updated in place and returned.
    dt : float
        Time step in seconds (see :func:`stable_timestep`).
    damping : (n,) array
        Damping coefficients ``gamma_i``.

    Returns
    -------
    DynamicState

    Raises
    ------
    SimulationError
        If the step produces non-finite values or a runaway.
    """
    if not (np.isfinite(dt) and dt > 0):
        raise ValueError(f"dt must be finite and > 0, got {dt}")
    m = system.lattice.mass[:, None]
    g = np.asarray(damping)[:, None]
    x, v = state.x, state.v
    system.apply_boundary(x)
    v[system.fixed] = 0.0
    f, _ = system.forces(x)
    a = (f - g * v) / m
    xm = x + 0.5 * dt * v
    vm = v + 0.5 * dt * a
    vm[system.fixed] = 0.0
    system.apply_boundary(xm)
    _project_with_velocity(system, xm, vm)
    f2, _ = system.forces(xm)
    a2 = (f2 - g * vm) / m
    x += dt * vm
    v += dt * a2
    v[system.fixed] = 0.0
    system.apply_boundary(x)
    _project_with_velocity(system, x, v)
    state.t += dt
    _check(x, v, system, where="rk2_step", dt=dt)
    return state


def verlet_step(system: TissueSystem, state: DynamicState, dt: float,
                damping: np.ndarray) -> DynamicState:
    """One damped velocity-Verlet (leapfrog) step; one force evaluation per step (001 6.3.2).

    The damping force uses the half-step velocity.  Same conventions as :func:`rk2_step`.
    """
    if not (np.isfinite(dt) and dt > 0):
        raise ValueError(f"dt must be finite and > 0, got {dt}")
    m = system.lattice.mass[:, None]
    g = np.asarray(damping)[:, None]
    x, v = state.x, state.v
    system.apply_boundary(x)
    f, _ = system.forces(x)
    # semi-implicit treatment of the damping keeps the over-damped limit stable
    v[:] = (v * (1.0 - 0.5 * dt * g / m) + dt * f / m) / (1.0 + 0.5 * dt * g / m)
    v[system.fixed] = 0.0
    x += dt * v
    system.apply_boundary(x)
    _project_with_velocity(system, x, v)
    state.t += dt
    _check(x, v, system, where="verlet_step", dt=dt)
    return state


def _project_with_velocity(system: TissueSystem, x, v, lip_slack: float = 0.05) -> None:
    """Fail-safe behind the penalties: nodes that went through the skull, or lips crossed
    deeper than ``lip_slack``, are put back and lose their approaching velocity."""
    lat = system.lattice
    p = system.contact_pairs
    if len(p):
        nrm = system.contact_normal
        h = np.einsum("ij,ij->i", x[p[:, 0]] - x[p[:, 1]], nrm) + lip_slack
        bad = h < 0
        if np.any(bad):
            a, b, nb = p[bad, 0], p[bad, 1], nrm[bad]
            fa = ~system.fixed[a]
            fb = ~system.fixed[b]
            x[a] -= (0.5 * h[bad] * fa)[:, None] * nb
            x[b] += (0.5 * h[bad] * fb)[:, None] * nb
            rel = np.einsum("ij,ij->i", v[a] - v[b], nb)
            approach = np.minimum(rel, 0.0)
            v[a] -= (0.5 * approach * fa)[:, None] * nb
            v[b] += (0.5 * approach * fb)[:, None] * nb
    h = system.skull_heights(x)
    below = h < 0
    if np.any(below):
        nodes = lat.skull_nodes[below]
        nrm = system.skull_normal[below]
        x[nodes] -= h[below, None] * nrm
        vn = np.einsum("ij,ij->i", v[nodes], nrm)
        v[nodes] -= np.minimum(vn, 0.0)[:, None] * nrm


def _symmetric_factor(matrix, lu):
    """``(rp, rj, rv, lp, li, lx, dinv, perm)``: ``P A P^T = L D L^T`` from a SuperLU
    factorisation of the symmetric positive definite ``matrix`` taken with diagonal pivots
    (then ``U = D L^T``), or from a refactorisation of the symmetrically permuted matrix when
    SuperLU pivoted off the diagonal.  Only the strictly lower part of ``L`` is kept, by rows
    (CSR) and by columns (CSC), with 16- or 32-bit indices and single precision values: the
    factor only preconditions L-BFGS, and the triangular solves are bound by memory traffic
    on large lattices."""
    perm = np.asarray(lu.perm_c, dtype=np.int64)     # matrix row i = factor row perm[i]
    if not np.array_equal(lu.perm_r, perm):
        p = np.argsort(perm)
        lu = spla.splu(matrix[p][:, p].tocsc(), permc_spec="NATURAL", diag_pivot_thresh=0.0,
                       options={"SymmetricMode": True})
        ident = np.arange(len(p))
        if not (np.array_equal(lu.perm_r, ident) and np.array_equal(lu.perm_c, ident)):
            raise SimulationError("the preconditioner matrix is not symmetric positive definite")
    lf = sp.tril(lu.L.tocsc(), k=-1).tocsc()
    lf.sort_indices()
    diag = lu.U.diagonal()
    # 16-bit row indices where they fit: the solves are bound by memory traffic
    itype = np.uint16 if matrix.shape[0] <= np.iinfo(np.uint16).max + 1 else np.int32
    lr = lf.tocsr()
    lr.sort_indices()
    return (lr.indptr.astype(np.int64), lr.indices.astype(itype), lr.data.astype(np.float32),
            lf.indptr.astype(np.int64), lf.indices.astype(itype), lf.data.astype(np.float32),
            (1.0 / diag).astype(np.float64), np.asarray(perm, dtype=np.int64))


class EquilibriumSolver:
    """Prefactored, unconditionally stable quasi-static solver (per-frame equilibrium).

    Minimises the lattice energy ``E(x)`` (springs + volume + skull - muscle work) over the free
    nodes by L-BFGS whose initial inverse Hessian is ``A^{-1}`` with ``A`` the constant,
    rotation-invariant projective-dynamics matrix (spring Laplacian plus the scalar Gram form
    of the volume term, :func:`isotropic_matrix`).  ``A`` is an ``n x n`` node matrix (one
    factor serves x, y and z), factored once per lattice with SuperLU (minimum-degree ordering,
    kept as ``P A P^T = L D L^T``: one single-precision factor with 16-bit row indices where
    they fit) and reused for every iteration of every frame.  An Armijo line search makes every
    iteration lower the energy (no time step, so no stability limit); each frame starts from
    the previous equilibrium, with the curvature pairs (single precision) of earlier frames.
    The iteration is bound by memory traffic on large lattices, hence the compact storage.

    Parameters
    ----------
    system : TissueSystem
    history : int
        Number of L-BFGS correction pairs (>= 0; 0 gives preconditioned gradient descent,
        i.e. the plain local-global iteration with a line search).
    phase : {'low', 'high'}
        Spring stiffness used in ``A``.
    volume_weight : float
        Weight of the volume term in ``A``.
    """

    def __init__(self, system: TissueSystem, *, history: int = 8, phase: str = "low",
                 volume_weight: float = 1.0):
        if history < 0:
            raise ValueError(f"history must be >= 0, got {history}")
        if phase not in ("low", "high"):
            raise ValueError(f"phase must be 'low' or 'high', got {phase!r}")
        if not volume_weight >= 0:
            raise ValueError(f"volume_weight must be >= 0, got {volume_weight}")
        self.system = system
        self.history = int(history)
        lat = system.lattice
        free = system.free
        a = isotropic_matrix(lat, phase=phase, volume_weight=volume_weight)
        a = a[free][:, free].tocsc()
        a = a + sp.diags(np.full(a.shape[0], 1e-9 * a.diagonal().mean()))
        self.matrix = a.tocsc()
        lu = spla.splu(self.matrix, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
                       options={"SymmetricMode": True})
        self._factor = _symmetric_factor(self.matrix, lu)
        # 16-bit node indices for the force kernels where they fit (less memory traffic)
        itype = np.uint16 if lat.n_nodes <= np.iinfo(np.uint16).max + 1 else np.int32
        self._springs = np.ascontiguousarray(lat.springs, dtype=itype)
        self._prisms = np.ascontiguousarray(lat.prisms, dtype=itype)
        self._free = np.ascontiguousarray(free, dtype=np.int64)
        nf = len(free)
        m = max(self.history, 1)
        # curvature pairs in single precision: half the memory traffic of the two-loop
        # recursion on large lattices (dot products are accumulated in double precision)
        self._s = np.zeros((m, nf, 3), dtype=np.float32)
        self._y = np.zeros((m, nf, 3), dtype=np.float32)
        self._rho = np.zeros(m)
        self._state = np.zeros(2, dtype=np.int64)
        self.last_iterations = 0

    def reset_history(self) -> None:
        """Forget the L-BFGS curvature pairs (e.g. after a large jump in the load)."""
        self._state[:] = 0

    def solve(self, x0: np.ndarray, *, tol: float = 3e-4, max_iter: int = 1000) -> np.ndarray:
        """Relax the lattice to equilibrium, starting from ``x0`` (not modified).

        The iteration runs in one compiled (Numba) loop.

        Parameters
        ----------
        x0 : (n, 3) array
            Starting positions (e.g. the previous frame's equilibrium).
        tol : float
            Stop when the largest nodal component of the quasi-Newton step is below ``tol`` cm.
        max_iter : int
            Iteration cap; reaching it raises :class:`SimulationError`.

        Returns
        -------
        x : (n, 3) array
            Equilibrium positions.
        """
        from .lattice import PRISM_QUADS
        from .lbfgs import _lbfgs_kernel

        if not (np.isfinite(tol) and tol > 0):
            raise ValueError(f"tol must be finite and > 0, got {tol}")
        sysm = self.system
        lat = sysm.lattice
        x = np.array(x0, dtype=np.float64)
        sysm.apply_boundary(x)
        sysm.project_skull(x)
        args = (self._springs, lat.rest_length, lat.k_low, lat.k_high, lat.switch, self._prisms,
                PRISM_QUADS, lat.rest_volume, lat.bulk, sysm.volume_preservation,
                lat.skull_nodes, lat.skull_bone, sysm.skull_normal, lat.skull_margin,
                lat.skull_k, sysm.contact_pairs, sysm.contact_normal, lat.contact_k,
                sysm.f_ext, sysm.fixed)
        if self.history == 0:
            self._state[:] = 0
        it, step, _, status = _lbfgs_kernel(x, self._free, args, self._factor,
                                            self._s[: max(self.history, 1)],
                                            self._y[: max(self.history, 1)], self._rho,
                                            self._state, float(tol), int(max_iter))
        if self.history == 0:
            self._state[:] = 0
        if status == 1:
            raise SimulationError(
                f"EquilibriumSolver did not converge in max_iter={max_iter} iterations "
                f"(last update {step:.3g} cm > tol={tol:.3g} cm; jaw_rotation="
                f"{sysm.jaw_rotation:.3g} rad, max |f_ext|={np.abs(sysm.f_ext).max():.3g})")
        if status == 2:
            _check(x + np.nan, None, sysm, where="EquilibriumSolver (line search)")
        sysm.project_skull(x)
        self.last_iterations = int(it)
        _check(x, None, sysm, where="EquilibriumSolver")
        return x

