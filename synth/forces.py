"""Forces and energies of the tissue lattice: biphasic springs, volume preservation, skull
non-penetration, plus the external (muscle) load.

Every term is conservative, so the lattice has a potential energy ``E(x)`` whose negative
gradient is the force; the equilibrium solver minimises it and the explicit integrators
use the forces.

* Biphasic springs (004 eqs. 1-2).  Eq. 2 switches the stiffness from ``alpha`` to ``beta``
  at the elongation threshold ``e^c``; Fig. 2 of 004 puts ``e^c`` at the intersection of the
  two lines, so the force is read as continuous and piecewise linear::

      |s| = alpha * e                          |e| <= e^c
      |s| = alpha * e^c + beta * (e - e^c)     e >  e^c
      |s| = -alpha * e^c + beta * (e + e^c)    e < -e^c

  The compressive branch plays the role of the compression penalty of 000 (section 4): a
  strongly compressed spring stiffens too, which keeps elements from collapsing.

* Volume preservation, the ``Q`` term of 004 III-A: ``bulk / 2 * V0 * ((V - V0) / V0)**2``
  per prism (three tetrahedra, 000 section 6), force ``-dQ/dx``.
* Skull non-penetration (000 section 7): a fascia node whose height above the (jaw-rotated)
  skull plane under it drops below the margin is pushed back out along the skull normal by
  a stiff penalty.  As a fail-safe, a node that still ends up below the bone surface itself
  is projected back onto it.
* Lip contact: the two rows of the mouth seam are not joined (the mouth opens), so the upper
  lip is kept from passing through the lower one by the same kind of one-sided penalty.

The hot loops are Numba kernels (``cache=True``); :func:`spring_forces_numpy` is the
vectorised NumPy reference used by the tests and the benchmark.
"""

from __future__ import annotations

import numba
import numpy as np

from .lattice import PRISM_QUADS, Lattice, rotate_about_jaw

__all__ = [
    "TissueSystem",
    "spring_forces",
    "spring_forces_numpy",
    "volume_forces",
    "skull_forces",
]


@numba.njit(cache=True, nogil=True)
def _spring_kernel(x, springs, rest_length, k_low, k_high, switch, out):  # pragma: no cover
    energy = 0.0
    for s in range(springs.shape[0]):
        i = springs[s, 0]
        j = springs[s, 1]
        rx = x[j, 0] - x[i, 0]
        ry = x[j, 1] - x[i, 1]
        rz = x[j, 2] - x[i, 2]
        l = np.sqrt(rx * rx + ry * ry + rz * rz)
        e = l - rest_length[s]
        kl = k_low[s]
        ec = switch[s]
        if e > ec:
            d = e - ec
            fm = kl * ec + k_high[s] * d
            energy += 0.5 * kl * ec * ec + kl * ec * d + 0.5 * k_high[s] * d * d
        elif e < -ec:
            d = e + ec
            fm = -kl * ec + k_high[s] * d
            energy += 0.5 * kl * ec * ec - kl * ec * d + 0.5 * k_high[s] * d * d
        else:
            fm = kl * e
            energy += 0.5 * kl * e * e
        if l > 1e-12:
            c = fm / l
        else:
            c = 0.0
        fx = c * rx
        fy = c * ry
        fz = c * rz
        out[i, 0] += fx
        out[i, 1] += fy
        out[i, 2] += fz
        out[j, 0] -= fx
        out[j, 1] -= fy
        out[j, 2] -= fz
    return energy


@numba.njit(cache=True, nogil=True, inline="always", fastmath=True)
def _cross(ax, ay, az, bx, by, bz):  # pragma: no cover
    return ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx


@numba.njit(cache=True, nogil=True, fastmath=True)
def _volume_kernel(x, prisms, quads, rest_volume, bulk, out):  # pragma: no cover
    energy = 0.0
    g = np.zeros((6, 3))
    q = np.zeros((6, 3))
    for e in range(prisms.shape[0]):
        cx = 0.0
        cy = 0.0
        cz = 0.0
        for a in range(6):
            n = prisms[e, a]
            cx += x[n, 0]
            cy += x[n, 1]
            cz += x[n, 2]
        cx /= 6.0
        cy /= 6.0
        cz /= 6.0
        for a in range(6):
            n = prisms[e, a]
            q[a, 0] = x[n, 0] - cx
            q[a, 1] = x[n, 1] - cy
            q[a, 2] = x[n, 2] - cz
        # triangles (0, 1, 2) and (3, 5, 4): det(i, j, k) / 6
        vol = 0.0
        for t in range(2):
            i = 0 if t == 0 else 3
            j = 1 if t == 0 else 5
            k = 2 if t == 0 else 4
            jk = _cross(q[j, 0], q[j, 1], q[j, 2], q[k, 0], q[k, 1], q[k, 2])
            ki = _cross(q[k, 0], q[k, 1], q[k, 2], q[i, 0], q[i, 1], q[i, 2])
            ij = _cross(q[i, 0], q[i, 1], q[i, 2], q[j, 0], q[j, 1], q[j, 2])
            vol += (q[i, 0] * jk[0] + q[i, 1] * jk[1] + q[i, 2] * jk[2]) / 6.0
            for c in range(3):
                g[i, c] = jk[c] / 6.0
                g[j, c] = ki[c] / 6.0
                g[k, c] = ij[c] / 6.0
        # bilinear quads: s . (d1 x d2) / 24
        for f in range(3):
            i0 = quads[f, 0]
            i1 = quads[f, 1]
            i2 = quads[f, 2]
            i3 = quads[f, 3]
            sx = q[i0, 0] + q[i1, 0] + q[i2, 0] + q[i3, 0]
            sy = q[i0, 1] + q[i1, 1] + q[i2, 1] + q[i3, 1]
            sz = q[i0, 2] + q[i1, 2] + q[i2, 2] + q[i3, 2]
            d1x = q[i2, 0] - q[i0, 0]
            d1y = q[i2, 1] - q[i0, 1]
            d1z = q[i2, 2] - q[i0, 2]
            d2x = q[i3, 0] - q[i1, 0]
            d2y = q[i3, 1] - q[i1, 1]
            d2z = q[i3, 2] - q[i1, 2]
            c12 = _cross(d1x, d1y, d1z, d2x, d2y, d2z)
            c2s = _cross(d2x, d2y, d2z, sx, sy, sz)
            cs1 = _cross(sx, sy, sz, d1x, d1y, d1z)
            vol += (sx * c12[0] + sy * c12[1] + sz * c12[2]) / 24.0
            for c in range(3):
                g[i0, c] += (c12[c] - c2s[c]) / 24.0
                g[i2, c] += (c12[c] + c2s[c]) / 24.0
                g[i1, c] += (c12[c] - cs1[c]) / 24.0
                g[i3, c] += (c12[c] + cs1[c]) / 24.0
        v0 = rest_volume[e]
        strain = (vol - v0) / v0
        energy += 0.5 * bulk[e] * v0 * strain * strain
        cf = bulk[e] * strain
        for a in range(6):
            n = prisms[e, a]
            out[n, 0] -= cf * g[a, 0]
            out[n, 1] -= cf * g[a, 1]
            out[n, 2] -= cf * g[a, 2]
    return energy


@numba.njit(cache=True, nogil=True)
def _skull_kernel(x, nodes, bone, normal, margin, k, out):  # pragma: no cover
    energy = 0.0
    for q in range(nodes.shape[0]):
        i = nodes[q]
        b = bone[q]
        h = ((x[i, 0] - x[b, 0]) * normal[q, 0] + (x[i, 1] - x[b, 1]) * normal[q, 1]
             + (x[i, 2] - x[b, 2]) * normal[q, 2]) - margin[q]
        if h < 0.0:
            energy += 0.5 * k[q] * h * h
            c = -k[q] * h
            out[i, 0] += c * normal[q, 0]
            out[i, 1] += c * normal[q, 1]
            out[i, 2] += c * normal[q, 2]
    return energy


@numba.njit(cache=True, nogil=True)
def _contact_kernel(x, pairs, normal, k, out):  # pragma: no cover
    energy = 0.0
    for q in range(pairs.shape[0]):
        a = pairs[q, 0]
        b = pairs[q, 1]
        h = ((x[a, 0] - x[b, 0]) * normal[q, 0] + (x[a, 1] - x[b, 1]) * normal[q, 1]
             + (x[a, 2] - x[b, 2]) * normal[q, 2])
        if h < 0.0:
            energy += 0.5 * k[q] * h * h
            c = -k[q] * h
            for ax in range(3):
                out[a, ax] += c * normal[q, ax]
                out[b, ax] -= c * normal[q, ax]
    return energy


@numba.njit(cache=True, nogil=True)
def _skull_project(x, nodes, bone, normal, margin):  # pragma: no cover
    moved = 0
    for q in range(nodes.shape[0]):
        i = nodes[q]
        b = bone[q]
        h = ((x[i, 0] - x[b, 0]) * normal[q, 0] + (x[i, 1] - x[b, 1]) * normal[q, 1]
             + (x[i, 2] - x[b, 2]) * normal[q, 2]) - margin[q]
        if h < 0.0:
            x[i, 0] -= h * normal[q, 0]
            x[i, 1] -= h * normal[q, 1]
            x[i, 2] -= h * normal[q, 2]
            moved += 1
    return moved


def spring_forces(x: np.ndarray, lattice: Lattice, out: np.ndarray | None = None):
    """Net biphasic spring force on every node (Numba kernel).

    Parameters
    ----------
    x : (n, 3) array
        Node positions.
    lattice : Lattice
    out : (n, 3) array, optional
        Accumulator; forces are **added** to it.  A new zero array when omitted.

    Returns
    -------
    forces : (n, 3) array
    energy : float
        Elastic energy of the springs.

    Examples
    --------
    >>> from synth.lattice import build_lattice
    >>> from synth.mesh import generate_face_mesh
    >>> lat = build_lattice(generate_face_mesh(resolution=0.35))
    >>> f, e = spring_forces(lat.rest, lat)
    >>> float(abs(f).max()), float(e)
    (0.0, 0.0)
    """
    x = np.ascontiguousarray(x, dtype=np.float64)
    if out is None:
        out = np.zeros_like(x)
    e = _spring_kernel(x, lattice.springs, lattice.rest_length, lattice.k_low, lattice.k_high,
                       lattice.switch, out)
    return out, e


def spring_forces_numpy(x: np.ndarray, lattice: Lattice):
    """Vectorised NumPy version of :func:`spring_forces` (reference implementation).

    Returns ``(forces, energy)``.
    """
    x = np.asarray(x, dtype=np.float64)
    i, j = lattice.springs[:, 0], lattice.springs[:, 1]
    r = x[j] - x[i]
    l = np.sqrt(np.einsum("ij,ij->i", r, r))
    e = l - lattice.rest_length
    ec = lattice.switch
    kl, kh = lattice.k_low, lattice.k_high
    el = np.clip(e, -ec, ec)            # the small-strain part
    d = e - el                          # beyond the threshold (either sign)
    fm = kl * el + kh * d
    energy = float(np.sum(0.5 * kl * el * el + kl * el * d + 0.5 * kh * d * d))
    f = r * (fm / np.maximum(l, 1e-12))[:, None]
    n = x.shape[0]
    out = np.empty_like(x)
    for c in range(3):
        out[:, c] = np.bincount(i, weights=f[:, c], minlength=n) - np.bincount(
            j, weights=f[:, c], minlength=n)
    return out, energy


def volume_forces(x: np.ndarray, lattice: Lattice, out: np.ndarray | None = None):
    """Volume-restoration forces ``q_i = -dQ/dx_i`` (004 III-A).  Returns ``(forces, energy)``."""
    x = np.ascontiguousarray(x, dtype=np.float64)
    if out is None:
        out = np.zeros_like(x)
    e = _volume_kernel(x, lattice.prisms, PRISM_QUADS, lattice.rest_volume, lattice.bulk, out)
    return out, e


def skull_forces(x: np.ndarray, lattice: Lattice, normals: np.ndarray | None = None,
                 out: np.ndarray | None = None):
    """Skull non-penetration penalty forces on the fascia nodes.  Returns ``(forces, energy)``.

    ``normals`` are the current outward skull normals (rest normals when omitted).
    """
    x = np.ascontiguousarray(x, dtype=np.float64)
    if out is None:
        out = np.zeros_like(x)
    n = lattice.skull_normal if normals is None else np.ascontiguousarray(normals)
    e = _skull_kernel(x, lattice.skull_nodes, lattice.skull_bone, n, lattice.skull_margin,
                      lattice.skull_k, out)
    return out, e


@numba.njit(cache=True, nogil=True)
def _total_kernel(x, springs, rest_length, k_low, k_high, switch, prisms, quads, rest_volume,
                  bulk, use_volume, sk_nodes, sk_bone, sk_normal, sk_margin, sk_k, c_pairs,
                  c_normal, c_k, f_ext, fixed, out):  # pragma: no cover
    out[:] = 0.0
    energy = _spring_kernel(x, springs, rest_length, k_low, k_high, switch, out)
    if use_volume:
        energy += _volume_kernel(x, prisms, quads, rest_volume, bulk, out)
    energy += _skull_kernel(x, sk_nodes, sk_bone, sk_normal, sk_margin, sk_k, out)
    energy += _contact_kernel(x, c_pairs, c_normal, c_k, out)
    for i in range(x.shape[0]):
        if fixed[i]:
            out[i, 0] = 0.0
            out[i, 1] = 0.0
            out[i, 2] = 0.0
        else:
            out[i, 0] += f_ext[i, 0]
            out[i, 1] += f_ext[i, 1]
            out[i, 2] += f_ext[i, 2]
            energy -= f_ext[i, 0] * x[i, 0] + f_ext[i, 1] * x[i, 1] + f_ext[i, 2] * x[i, 2]
    return energy


class TissueSystem:
    """The lattice plus its current boundary conditions and load.

    Holds the prescribed positions of the fixed nodes (bone, glued outline; the mandible
    nodes rotated by the jaw), the current skull normals and the external nodal forces
    (muscles).  :meth:`forces` returns the net force on the free nodes and the total
    potential energy ``E(x) = springs + volume + skull - f_ext . x``.

    Parameters
    ----------
    lattice : Lattice
    volume_preservation : bool
        Include the volume term (default True).
    """

    def __init__(self, lattice: Lattice, *, volume_preservation: bool = True):
        self.lattice = lattice
        self.volume_preservation = bool(volume_preservation)
        self.fixed = np.ascontiguousarray(lattice.fixed)
        self.free = np.flatnonzero(~lattice.fixed)
        self.f_ext = np.zeros_like(lattice.rest)
        self.jaw_rotation = 0.0
        self.prescribed = lattice.rest.copy()
        self.skull_normal = np.array(lattice.skull_normal)
        self._bone_jaw = lattice.jaw_weight[lattice.skull_bone]
        self.contact_pairs = np.ascontiguousarray(lattice.contact_pairs)
        self.contact_normal = np.array(lattice.contact_normal)
        self._contact_jaw = 0.5 * lattice.jaw_weight[lattice.contact_pairs].sum(axis=1) \
            if len(lattice.contact_pairs) else np.zeros(0)

    def set_jaw(self, angle: float) -> None:
        """Rotate the mandible-carried fixed nodes and skull normals by ``angle`` radians."""
        lat = self.lattice
        self.jaw_rotation = float(angle)
        fx = np.flatnonzero(lat.fixed)
        self.prescribed = lat.rest.copy()
        self.prescribed[fx] = rotate_about_jaw(lat.rest[fx], lat.jaw_weight[fx], lat.jaw_pivot,
                                               angle)
        self.skull_normal = rotate_about_jaw(lat.skull_normal, self._bone_jaw,
                                             np.zeros(3), angle)
        if len(self.contact_pairs):
            self.contact_normal = rotate_about_jaw(lat.contact_normal, self._contact_jaw,
                                                   np.zeros(3), angle)

    def set_external(self, f_ext: np.ndarray) -> None:
        """Set the external nodal forces (n, 3) (muscle load); fixed nodes ignore theirs."""
        f = np.array(f_ext, dtype=np.float64)
        if f.shape != self.lattice.rest.shape:
            raise ValueError(f"f_ext must have shape {self.lattice.rest.shape}, got {f.shape}")
        self.f_ext = f

    def apply_boundary(self, x: np.ndarray) -> None:
        """Write the prescribed positions of the fixed nodes into ``x`` (in place)."""
        fx = self.fixed
        x[fx] = self.prescribed[fx]

    def forces(self, x: np.ndarray, out: np.ndarray | None = None, *, skull: bool = True):
        """Net force on every node (zero on fixed nodes) and the potential energy.

        ``skull=False`` leaves out the skull penalty (the explicit integrators enforce
        non-penetration by projection instead).

        Returns
        -------
        forces : (n, 3) array
        energy : float
        """
        lat = self.lattice
        if out is None:
            out = np.empty_like(lat.rest)
        nodes = lat.skull_nodes if skull else lat.skull_nodes[:0]
        pairs = self.contact_pairs if skull else self.contact_pairs[:0]
        e = _total_kernel(x, lat.springs, lat.rest_length, lat.k_low, lat.k_high, lat.switch,
                          lat.prisms, PRISM_QUADS, lat.rest_volume, lat.bulk,
                          self.volume_preservation, nodes, lat.skull_bone,
                          self.skull_normal, lat.skull_margin, lat.skull_k, pairs,
                          self.contact_normal, lat.contact_k, self.f_ext, self.fixed, out)
        return out, e

    def project_skull(self, x: np.ndarray, *, lip_slack: float = 0.05) -> int:
        """Fail-safe for the penalties (in place): fascia nodes that went *through* the skull
        (below the bone surface, not just inside the margin) are put back on it, and lips
        crossed by more than ``lip_slack`` cm are separated to that depth.  In normal
        operation the penalties keep every node clear and nothing moves.

        Returns the number of nodes moved."""
        lat = self.lattice
        moved = int(_skull_project(x, lat.skull_nodes, lat.skull_bone, self.skull_normal,
                                   np.zeros_like(lat.skull_margin)))
        if len(self.contact_pairs):
            p = self.contact_pairs
            h = np.einsum("ij,ij->i", x[p[:, 0]] - x[p[:, 1]], self.contact_normal) + lip_slack
            bad = h < 0
            if np.any(bad):
                shift = 0.5 * h[bad, None] * self.contact_normal[bad]
                free = ~self.fixed
                a, b = p[bad, 0], p[bad, 1]
                x[a] -= shift * free[a, None]
                x[b] += shift * free[b, None]
                moved += int(bad.sum())
        return moved

    def skull_heights(self, x: np.ndarray) -> np.ndarray:
        """Signed height of every constrained fascia node above its skull plane (cm)."""
        lat = self.lattice
        d = x[lat.skull_nodes] - x[lat.skull_bone]
        return np.einsum("ij,ij->i", d, self.skull_normal)


# ---------------------------------------------------------------------------------------------
# Numba L-BFGS loop (the whole iteration runs compiled; Python only sets it up)
# ---------------------------------------------------------------------------------------------

@numba.njit(cache=True, nogil=True)
def _lu_solve3(q, lp, li, lx, up, ui, ux, udiag, perm_r, perm_c, work, out):  # pragma: no cover
    """Solve A z = q for 3 right-hand sides (rows of q are nodes) with SuperLU factors
    ``Pr A Pc = L U`` (L unit lower, U upper, both CSC)."""
    n = q.shape[0]
    for i in range(n):
        r = perm_r[i]
        work[r, 0] = q[i, 0]
        work[r, 1] = q[i, 1]
        work[r, 2] = q[i, 2]
    for j in range(n):
        y0 = work[j, 0]
        y1 = work[j, 1]
        y2 = work[j, 2]
        for k in range(lp[j], lp[j + 1]):
            i = li[k]
            if i > j:
                v = lx[k]
                work[i, 0] -= v * y0
                work[i, 1] -= v * y1
                work[i, 2] -= v * y2
    for j in range(n - 1, -1, -1):
        d = udiag[j]
        y0 = work[j, 0] / d
        y1 = work[j, 1] / d
        y2 = work[j, 2] / d
        work[j, 0] = y0
        work[j, 1] = y1
        work[j, 2] = y2
        for k in range(up[j], up[j + 1]):
            i = ui[k]
            if i < j:
                v = ux[k]
                work[i, 0] -= v * y0
                work[i, 1] -= v * y1
                work[i, 2] -= v * y2
    for i in range(n):
        c = perm_c[i]
        out[i, 0] = work[c, 0]
        out[i, 1] = work[c, 1]
        out[i, 2] = work[c, 2]


@numba.njit(cache=True, nogil=True)
def _lbfgs_kernel(x, free, forces_args, factor, s_hist, y_hist, rho, state, tol,
                  max_iter):  # pragma: no cover
    """Minimise the lattice energy over the free nodes, in place on ``x``.

    ``state`` = [n_pairs, head] of the ring buffer of curvature pairs (updated).
    Returns (iterations, last step, energy, status) with status 0 = converged,
    1 = iteration cap, 2 = non-finite energy / line search failure, 3 = stopped at the
    floating-point floor of the energy (converged as far as arithmetic allows)."""
    (springs, rest_length, k_low, k_high, switch, prisms, quads, rest_volume, bulk,
     use_volume, sk_nodes, sk_bone, sk_normal, sk_margin, sk_k, c_pairs, c_normal, c_k,
     f_ext, fixed) = forces_args
    lp, li, lx, up, ui, ux, udiag, perm_r, perm_c = factor
    nf = free.shape[0]
    m = s_hist.shape[0]
    fbuf = np.empty_like(x)
    g = np.empty((nf, 3))
    gn = np.empty((nf, 3))
    q = np.empty((nf, 3))
    z = np.empty((nf, 3))
    work = np.empty((nf, 3))
    xf = np.empty((nf, 3))
    alphas = np.empty(m)
    energy = _total_kernel(x, springs, rest_length, k_low, k_high, switch, prisms, quads,
                           rest_volume, bulk, use_volume, sk_nodes, sk_bone, sk_normal,
                           sk_margin, sk_k, c_pairs, c_normal, c_k, f_ext, fixed, fbuf)
    for a in range(nf):
        for c in range(3):
            g[a, c] = -fbuf[free[a], c]
    it = 0
    step = np.inf
    status = 0
    while True:
        n_pairs = state[0]
        head = state[1]
        # two-loop recursion, newest pair first; H0 = A^{-1}
        for a in range(nf):
            for c in range(3):
                q[a, c] = g[a, c]
        for t in range(n_pairs):
            k = (head - 1 - t) % m
            dot = 0.0
            for a in range(nf):
                for c in range(3):
                    dot += s_hist[k, a, c] * q[a, c]
            ak = rho[k] * dot
            alphas[t] = ak
            for a in range(nf):
                for c in range(3):
                    q[a, c] -= ak * y_hist[k, a, c]
        _lu_solve3(q, lp, li, lx, up, ui, ux, udiag, perm_r, perm_c, work, z)
        for t in range(n_pairs - 1, -1, -1):
            k = (head - 1 - t) % m
            dot = 0.0
            for a in range(nf):
                for c in range(3):
                    dot += y_hist[k, a, c] * z[a, c]
            bk = rho[k] * dot
            coef = alphas[t] - bk
            for a in range(nf):
                for c in range(3):
                    z[a, c] += coef * s_hist[k, a, c]
        slope = 0.0
        for a in range(nf):
            for c in range(3):
                slope -= g[a, c] * z[a, c]           # p = -z
        if slope >= 0.0:
            state[0] = 0
            _lu_solve3(g, lp, li, lx, up, ui, ux, udiag, perm_r, perm_c, work, z)
            slope = 0.0
            for a in range(nf):
                for c in range(3):
                    slope -= g[a, c] * z[a, c]
        step = 0.0
        for a in range(nf):
            for c in range(3):
                v = abs(z[a, c])
                if v > step:
                    step = v
        if step <= tol:
            break
        it += 1
        if it > max_iter:
            status = 1
            break
        for a in range(nf):
            for c in range(3):
                xf[a, c] = x[free[a], c]
        alpha = 1.0
        ok = False
        en = energy
        for _ in range(30):
            for a in range(nf):
                for c in range(3):
                    x[free[a], c] = xf[a, c] - alpha * z[a, c]
            en = _total_kernel(x, springs, rest_length, k_low, k_high, switch, prisms, quads,
                               rest_volume, bulk, use_volume, sk_nodes, sk_bone, sk_normal,
                               sk_margin, sk_k, c_pairs, c_normal, c_k, f_ext, fixed, fbuf)
            if np.isfinite(en) and en <= energy + 1e-4 * alpha * slope:
                ok = True
                break
            alpha *= 0.5
        if not ok:
            for a in range(nf):
                for c in range(3):
                    x[free[a], c] = xf[a, c]
            # no decrease found: either the energy is at its floating-point floor (the
            # expected decrease is below round-off; converged) or something went wrong
            if -slope <= 1e-11 * (abs(energy) + 1.0) and np.isfinite(energy):
                status = 3
            else:
                status = 2
            break
        for a in range(nf):
            for c in range(3):
                gn[a, c] = -fbuf[free[a], c]
        # curvature pair s = alpha p = -alpha z, y = gn - g
        k = state[1]
        sy = 0.0
        yy = 0.0
        for a in range(nf):
            for c in range(3):
                sv = -alpha * z[a, c]
                yv = gn[a, c] - g[a, c]
                s_hist[k, a, c] = sv
                y_hist[k, a, c] = yv
                sy += sv * yv
                yy += yv * yv
        if m > 0 and sy > 1e-12 * yy:
            rho[k] = 1.0 / sy
            state[1] = (k + 1) % m
            if state[0] < m:
                state[0] += 1
        for a in range(nf):
            for c in range(3):
                g[a, c] = gn[a, c]
        energy = en
    return it, step, energy, status
