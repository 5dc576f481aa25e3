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
    """Volume term; ``quads`` must be :data:`~synth.lattice.PRISM_QUADS` (the faces are
    unrolled: triangles (0, 1, 2), (3, 5, 4) and the three bilinear side quads)."""
    energy = 0.0
    for e in range(prisms.shape[0]):
        n0 = prisms[e, 0]
        n1 = prisms[e, 1]
        n2 = prisms[e, 2]
        n3 = prisms[e, 3]
        n4 = prisms[e, 4]
        n5 = prisms[e, 5]
        cx = (x[n0, 0] + x[n1, 0] + x[n2, 0] + x[n3, 0] + x[n4, 0] + x[n5, 0]) * (1.0 / 6.0)
        cy = (x[n0, 1] + x[n1, 1] + x[n2, 1] + x[n3, 1] + x[n4, 1] + x[n5, 1]) * (1.0 / 6.0)
        cz = (x[n0, 2] + x[n1, 2] + x[n2, 2] + x[n3, 2] + x[n4, 2] + x[n5, 2]) * (1.0 / 6.0)
        q0x = x[n0, 0] - cx
        q0y = x[n0, 1] - cy
        q0z = x[n0, 2] - cz
        q1x = x[n1, 0] - cx
        q1y = x[n1, 1] - cy
        q1z = x[n1, 2] - cz
        q2x = x[n2, 0] - cx
        q2y = x[n2, 1] - cy
        q2z = x[n2, 2] - cz
        q3x = x[n3, 0] - cx
        q3y = x[n3, 1] - cy
        q3z = x[n3, 2] - cz
        q4x = x[n4, 0] - cx
        q4y = x[n4, 1] - cy
        q4z = x[n4, 2] - cz
        q5x = x[n5, 0] - cx
        q5y = x[n5, 1] - cy
        q5z = x[n5, 2] - cz
        vol6 = 0.0
        jkx = q1y * q2z - q1z * q2y
        jky = q1z * q2x - q1x * q2z
        jkz = q1x * q2y - q1y * q2x
        kix = q2y * q0z - q2z * q0y
        kiy = q2z * q0x - q2x * q0z
        kiz = q2x * q0y - q2y * q0x
        ijx = q0y * q1z - q0z * q1y
        ijy = q0z * q1x - q0x * q1z
        ijz = q0x * q1y - q0y * q1x
        vol6 += q0x * jkx + q0y * jky + q0z * jkz
        g0x = 4.0 * jkx
        g1x = 4.0 * kix
        g2x = 4.0 * ijx
        g0y = 4.0 * jky
        g1y = 4.0 * kiy
        g2y = 4.0 * ijy
        g0z = 4.0 * jkz
        g1z = 4.0 * kiz
        g2z = 4.0 * ijz
        jkx = q5y * q4z - q5z * q4y
        jky = q5z * q4x - q5x * q4z
        jkz = q5x * q4y - q5y * q4x
        kix = q4y * q3z - q4z * q3y
        kiy = q4z * q3x - q4x * q3z
        kiz = q4x * q3y - q4y * q3x
        ijx = q3y * q5z - q3z * q5y
        ijy = q3z * q5x - q3x * q5z
        ijz = q3x * q5y - q3y * q5x
        vol6 += q3x * jkx + q3y * jky + q3z * jkz
        g3x = 4.0 * jkx
        g5x = 4.0 * kix
        g4x = 4.0 * ijx
        g3y = 4.0 * jky
        g5y = 4.0 * kiy
        g4y = 4.0 * ijy
        g3z = 4.0 * jkz
        g5z = 4.0 * kiz
        g4z = 4.0 * ijz
        vol24 = 4.0 * vol6
        sx = q0x + q3x + q4x + q1x
        d1x = q4x - q0x
        d2x = q1x - q3x
        sy = q0y + q3y + q4y + q1y
        d1y = q4y - q0y
        d2y = q1y - q3y
        sz = q0z + q3z + q4z + q1z
        d1z = q4z - q0z
        d2z = q1z - q3z
        c12x = d1y * d2z - d1z * d2y
        c12y = d1z * d2x - d1x * d2z
        c12z = d1x * d2y - d1y * d2x
        c2sx = d2y * sz - d2z * sy
        c2sy = d2z * sx - d2x * sz
        c2sz = d2x * sy - d2y * sx
        cs1x = sy * d1z - sz * d1y
        cs1y = sz * d1x - sx * d1z
        cs1z = sx * d1y - sy * d1x
        vol24 += sx * c12x + sy * c12y + sz * c12z
        g0x += c12x - c2sx
        g4x += c12x + c2sx
        g3x += c12x - cs1x
        g1x += c12x + cs1x
        g0y += c12y - c2sy
        g4y += c12y + c2sy
        g3y += c12y - cs1y
        g1y += c12y + cs1y
        g0z += c12z - c2sz
        g4z += c12z + c2sz
        g3z += c12z - cs1z
        g1z += c12z + cs1z
        sx = q1x + q4x + q5x + q2x
        d1x = q5x - q1x
        d2x = q2x - q4x
        sy = q1y + q4y + q5y + q2y
        d1y = q5y - q1y
        d2y = q2y - q4y
        sz = q1z + q4z + q5z + q2z
        d1z = q5z - q1z
        d2z = q2z - q4z
        c12x = d1y * d2z - d1z * d2y
        c12y = d1z * d2x - d1x * d2z
        c12z = d1x * d2y - d1y * d2x
        c2sx = d2y * sz - d2z * sy
        c2sy = d2z * sx - d2x * sz
        c2sz = d2x * sy - d2y * sx
        cs1x = sy * d1z - sz * d1y
        cs1y = sz * d1x - sx * d1z
        cs1z = sx * d1y - sy * d1x
        vol24 += sx * c12x + sy * c12y + sz * c12z
        g1x += c12x - c2sx
        g5x += c12x + c2sx
        g4x += c12x - cs1x
        g2x += c12x + cs1x
        g1y += c12y - c2sy
        g5y += c12y + c2sy
        g4y += c12y - cs1y
        g2y += c12y + cs1y
        g1z += c12z - c2sz
        g5z += c12z + c2sz
        g4z += c12z - cs1z
        g2z += c12z + cs1z
        sx = q2x + q5x + q3x + q0x
        d1x = q3x - q2x
        d2x = q0x - q5x
        sy = q2y + q5y + q3y + q0y
        d1y = q3y - q2y
        d2y = q0y - q5y
        sz = q2z + q5z + q3z + q0z
        d1z = q3z - q2z
        d2z = q0z - q5z
        c12x = d1y * d2z - d1z * d2y
        c12y = d1z * d2x - d1x * d2z
        c12z = d1x * d2y - d1y * d2x
        c2sx = d2y * sz - d2z * sy
        c2sy = d2z * sx - d2x * sz
        c2sz = d2x * sy - d2y * sx
        cs1x = sy * d1z - sz * d1y
        cs1y = sz * d1x - sx * d1z
        cs1z = sx * d1y - sy * d1x
        vol24 += sx * c12x + sy * c12y + sz * c12z
        g2x += c12x - c2sx
        g3x += c12x + c2sx
        g5x += c12x - cs1x
        g0x += c12x + cs1x
        g2y += c12y - c2sy
        g3y += c12y + c2sy
        g5y += c12y - cs1y
        g0y += c12y + cs1y
        g2z += c12z - c2sz
        g3z += c12z + c2sz
        g5z += c12z - cs1z
        g0z += c12z + cs1z
        vol = vol24 * (1.0 / 24.0)
        v0 = rest_volume[e]
        strain = (vol - v0) / v0
        energy += 0.5 * bulk[e] * v0 * strain * strain
        cf = bulk[e] * strain * (1.0 / 24.0)
        out[n0, 0] -= cf * g0x
        out[n0, 1] -= cf * g0y
        out[n0, 2] -= cf * g0z
        out[n1, 0] -= cf * g1x
        out[n1, 1] -= cf * g1y
        out[n1, 2] -= cf * g1z
        out[n2, 0] -= cf * g2x
        out[n2, 1] -= cf * g2y
        out[n2, 2] -= cf * g2z
        out[n3, 0] -= cf * g3x
        out[n3, 1] -= cf * g3y
        out[n3, 2] -= cf * g3z
        out[n4, 0] -= cf * g4x
        out[n4, 1] -= cf * g4y
        out[n4, 2] -= cf * g4z
        out[n5, 0] -= cf * g5x
        out[n5, 1] -= cf * g5y
        out[n5, 2] -= cf * g5z
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
        self._fixed_index = np.flatnonzero(lattice.fixed)
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
        fx = self._fixed_index
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
def _ldl_solve3(q, rp, rj, rv, lp, li, lx, dinv, perm, work, out):  # pragma: no cover
    """Solve A z = q for 3 right-hand sides (rows of q are nodes) with a symmetric factor
    ``P A P^T = L D L^T``: the strictly lower part of ``L`` by rows (``rp``, ``rj``, ``rv``)
    for the forward sweep and by columns (``lp``, ``li``, ``lx``) for the backward one, so
    both sweeps gather (dot products, no scattered stores); ``dinv = 1 / diag(D)``; row ``i``
    of ``A`` is row ``perm[i]`` of the factor."""
    n = q.shape[0]
    for i in range(n):
        r = perm[i]
        work[r, 0] = q[i, 0]
        work[r, 1] = q[i, 1]
        work[r, 2] = q[i, 2]
    for i in range(n):
        y0 = work[i, 0]
        y1 = work[i, 1]
        y2 = work[i, 2]
        for k in range(rp[i], rp[i + 1]):
            j = rj[k]
            v = rv[k]
            y0 -= v * work[j, 0]
            y1 -= v * work[j, 1]
            y2 -= v * work[j, 2]
        work[i, 0] = y0
        work[i, 1] = y1
        work[i, 2] = y2
    for j in range(n - 1, -1, -1):
        d = dinv[j]
        y0 = work[j, 0] * d
        y1 = work[j, 1] * d
        y2 = work[j, 2] * d
        for k in range(lp[j], lp[j + 1]):
            i = li[k]
            v = lx[k]
            y0 -= v * work[i, 0]
            y1 -= v * work[i, 1]
            y2 -= v * work[i, 2]
        work[j, 0] = y0
        work[j, 1] = y1
        work[j, 2] = y2
    for i in range(n):
        r = perm[i]
        out[i, 0] = work[r, 0]
        out[i, 1] = work[r, 1]
        out[i, 2] = work[r, 2]


@numba.njit(cache=True, nogil=True, inline="always")
def _dot(a, b):  # pragma: no cover
    """``a . b`` with four interleaved partial sums: fast without reassociation flags, and
    the same result whatever the memory alignment of the arrays."""
    n = a.shape[0]
    d0 = 0.0
    d1 = 0.0
    d2 = 0.0
    d3 = 0.0
    i = 0
    while i + 4 <= n:
        d0 += np.float64(a[i]) * np.float64(b[i])
        d1 += np.float64(a[i + 1]) * np.float64(b[i + 1])
        d2 += np.float64(a[i + 2]) * np.float64(b[i + 2])
        d3 += np.float64(a[i + 3]) * np.float64(b[i + 3])
        i += 4
    while i < n:
        d0 += np.float64(a[i]) * np.float64(b[i])
        i += 1
    return (d0 + d1) + (d2 + d3)


@numba.njit(cache=True, nogil=True, inline="always")
def _axpy_dot(x, c, u, w):  # pragma: no cover
    """``x += c u`` in place, then return ``w . x`` (one pass; four partial sums)."""
    n = x.shape[0]
    d0 = 0.0
    d1 = 0.0
    d2 = 0.0
    d3 = 0.0
    i = 0
    while i + 4 <= n:
        v0 = x[i] + c * u[i]
        v1 = x[i + 1] + c * u[i + 1]
        v2 = x[i + 2] + c * u[i + 2]
        v3 = x[i + 3] + c * u[i + 3]
        x[i] = v0
        x[i + 1] = v1
        x[i + 2] = v2
        x[i + 3] = v3
        d0 += np.float64(w[i]) * v0
        d1 += np.float64(w[i + 1]) * v1
        d2 += np.float64(w[i + 2]) * v2
        d3 += np.float64(w[i + 3]) * v3
        i += 4
    while i < n:
        v0 = x[i] + c * u[i]
        x[i] = v0
        d0 += np.float64(w[i]) * v0
        i += 1
    return (d0 + d1) + (d2 + d3)


#: a converged L-BFGS step is double-checked against the preconditioned gradient step, which
#: must then be below this many times the tolerance (it is shorter than the quasi-Newton step
#: near a minimum: ``A`` over-stiffens the soft modes)
_RESTART_RATIO = 4.0


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
    rp, rj, rv, lp, li, lx, dinv, perm = factor
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
    n3 = 3 * nf
    s2 = s_hist.reshape((m, n3))
    y2 = y_hist.reshape((m, n3))
    gf = g.reshape(n3)
    qf = q.reshape(n3)
    zf = z.reshape(n3)
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
        # two-loop recursion, newest pair first; H0 = A^{-1}.  Flat views; each pass over a
        # pair's vectors also takes the dot product the next pair needs.
        for i in range(n3):
            qf[i] = gf[i]
        dot = 0.0
        if n_pairs > 0:
            dot = _dot(s2[(head - 1) % m], qf)
        for t in range(n_pairs):
            k = (head - 1 - t) % m
            ak = rho[k] * dot
            alphas[t] = ak
            # q -= ak y_k, and the next (older) pair's s . q in the same pass
            dot = _axpy_dot(qf, -ak, y2[k], s2[(head - 2 - t) % m])
        _ldl_solve3(q, rp, rj, rv, lp, li, lx, dinv, perm, work, z)
        dot = 0.0
        if n_pairs > 0:
            dot = _dot(y2[(head - n_pairs) % m], zf)
        for t in range(n_pairs - 1, -1, -1):
            k = (head - 1 - t) % m
            coef = alphas[t] - rho[k] * dot
            # z += coef s_k, and the next (newer) pair's y . z in the same pass
            dot = _axpy_dot(zf, coef, s2[k], y2[(head - t) % m])
        slope = -_dot(gf, zf)                        # p = -z
        if slope >= 0.0:
            state[0] = 0
            _ldl_solve3(g, rp, rj, rv, lp, li, lx, dinv, perm, work, z)
            slope = -_dot(gf, zf)
        step = 0.0
        for a in range(nf):
            for c in range(3):
                v = abs(z[a, c])
                if v > step:
                    step = v
        if step <= tol and state[0] > 0:
            # a short quasi-Newton step can also come from poor curvature pairs (a false
            # convergence, seen after lip / skull contact changes): accept it only if the plain
            # preconditioned step A^{-1} g is short too, else restart the pairs from that step
            _ldl_solve3(g, rp, rj, rv, lp, li, lx, dinv, perm, work, z)
            step0 = 0.0
            slope = 0.0
            for i in range(n3):
                v = abs(zf[i])
                if v > step0:
                    step0 = v
                slope -= gf[i] * zf[i]
            if step0 > _RESTART_RATIO * tol:
                state[0] = 0
                step = step0
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
        # curvature pair s = alpha p = -alpha z, y = gn - g; a pair with too little
        # curvature is skipped (and must not overwrite the oldest pair kept in the ring)
        gnf = gn.reshape(n3)
        sy = 0.0
        yy = 0.0
        for i in range(n3):
            sv = -alpha * zf[i]
            yv = gnf[i] - gf[i]
            sy += sv * yv
            yy += yv * yv
        if m > 0 and sy > 1e-12 * yy:
            # stored in the precision of the history buffers; rho from the stored values
            k = state[1]
            sy = 0.0
            for i in range(n3):
                s2[k, i] = -alpha * zf[i]
                y2[k, i] = gnf[i] - gf[i]
                sy += np.float64(s2[k, i]) * np.float64(y2[k, i])
            if sy > 0.0:
                rho[k] = 1.0 / sy
                state[1] = (k + 1) % m
                if state[0] < m:
                    state[0] += 1
        for a in range(nf):
            for c in range(3):
                g[a, c] = gn[a, c]
        energy = en
    return it, step, energy, status
