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
from llvmlite import ir as llvm_ir
from numba import types
from numba.core import cgutils
from numba.extending import intrinsic

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


#: prisms per block of :func:`_volume_kernel` (its arithmetic runs in SIMD loops over a block)
_VB = 64


@numba.njit(cache=True, nogil=True)
def _volume_kernel(x, prisms, quads, rest_volume, bulk, out):  # pragma: no cover
    """Volume term; ``quads`` must be :data:`~synth.lattice.PRISM_QUADS` (the faces are
    unrolled: triangles (0, 1, 2), (3, 5, 4) and the three bilinear side quads).

    Blocks of ``_VB`` prisms: their node positions are gathered into (coordinate, prism)
    rows, the volume gradients computed by two loops over the block that the compiler turns
    into SIMD code (one loop would be too large for it: the triangles, then the side quads;
    all 18 inputs as contiguous rows), and the forces scattered to the nodes.  No fastmath:
    SIMD and scalar iterations then round alike, so the result does not depend on how the
    compiler vectorised (or inlined) the loops, e.g. fresh compile vs. cached one."""
    ne = prisms.shape[0]
    p = np.empty(18 * _VB)
    q = np.empty(18 * _VB)
    gt = np.empty(19 * _VB)
    gq = np.empty(19 * _VB)
    energy = 0.0
    for e0 in range(0, ne, _VB):
        nb = min(_VB, ne - e0)
        for t in range(nb):
            for k in range(6):
                n = prisms[e0 + t, k]
                p[3 * k * _VB + t] = x[n, 0]
                p[(3 * k + 1) * _VB + t] = x[n, 1]
                p[(3 * k + 2) * _VB + t] = x[n, 2]
        # end faces (triangles); positions relative to the centroid
        for t in range(nb):
            p0x = p[0 * _VB + t]
            p0y = p[1 * _VB + t]
            p0z = p[2 * _VB + t]
            p1x = p[3 * _VB + t]
            p1y = p[4 * _VB + t]
            p1z = p[5 * _VB + t]
            p2x = p[6 * _VB + t]
            p2y = p[7 * _VB + t]
            p2z = p[8 * _VB + t]
            p3x = p[9 * _VB + t]
            p3y = p[10 * _VB + t]
            p3z = p[11 * _VB + t]
            p4x = p[12 * _VB + t]
            p4y = p[13 * _VB + t]
            p4z = p[14 * _VB + t]
            p5x = p[15 * _VB + t]
            p5y = p[16 * _VB + t]
            p5z = p[17 * _VB + t]
            cx = (p0x + p1x + p2x + p3x + p4x + p5x) * (1.0 / 6.0)
            cy = (p0y + p1y + p2y + p3y + p4y + p5y) * (1.0 / 6.0)
            cz = (p0z + p1z + p2z + p3z + p4z + p5z) * (1.0 / 6.0)
            q0x = p0x - cx
            q0y = p0y - cy
            q0z = p0z - cz
            q1x = p1x - cx
            q1y = p1y - cy
            q1z = p1z - cz
            q2x = p2x - cx
            q2y = p2y - cy
            q2z = p2z - cz
            q3x = p3x - cx
            q3y = p3y - cy
            q3z = p3z - cz
            q4x = p4x - cx
            q4y = p4y - cy
            q4z = p4z - cz
            q5x = p5x - cx
            q5y = p5y - cy
            q5z = p5z - cz
            q[0 * _VB + t] = q0x
            q[1 * _VB + t] = q0y
            q[2 * _VB + t] = q0z
            q[3 * _VB + t] = q1x
            q[4 * _VB + t] = q1y
            q[5 * _VB + t] = q1z
            q[6 * _VB + t] = q2x
            q[7 * _VB + t] = q2y
            q[8 * _VB + t] = q2z
            q[9 * _VB + t] = q3x
            q[10 * _VB + t] = q3y
            q[11 * _VB + t] = q3z
            q[12 * _VB + t] = q4x
            q[13 * _VB + t] = q4y
            q[14 * _VB + t] = q4z
            q[15 * _VB + t] = q5x
            q[16 * _VB + t] = q5y
            q[17 * _VB + t] = q5z
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
            gt[18 * _VB + t] = 4.0 * vol6
            gt[0 * _VB + t] = g0x
            gt[1 * _VB + t] = g0y
            gt[2 * _VB + t] = g0z
            gt[3 * _VB + t] = g1x
            gt[4 * _VB + t] = g1y
            gt[5 * _VB + t] = g1z
            gt[6 * _VB + t] = g2x
            gt[7 * _VB + t] = g2y
            gt[8 * _VB + t] = g2z
            gt[9 * _VB + t] = g3x
            gt[10 * _VB + t] = g3y
            gt[11 * _VB + t] = g3z
            gt[12 * _VB + t] = g4x
            gt[13 * _VB + t] = g4y
            gt[14 * _VB + t] = g4z
            gt[15 * _VB + t] = g5x
            gt[16 * _VB + t] = g5y
            gt[17 * _VB + t] = g5z
        # bilinear side quads
        for t in range(nb):
            q0x = q[0 * _VB + t]
            q0y = q[1 * _VB + t]
            q0z = q[2 * _VB + t]
            q1x = q[3 * _VB + t]
            q1y = q[4 * _VB + t]
            q1z = q[5 * _VB + t]
            q2x = q[6 * _VB + t]
            q2y = q[7 * _VB + t]
            q2z = q[8 * _VB + t]
            q3x = q[9 * _VB + t]
            q3y = q[10 * _VB + t]
            q3z = q[11 * _VB + t]
            q4x = q[12 * _VB + t]
            q4y = q[13 * _VB + t]
            q4z = q[14 * _VB + t]
            q5x = q[15 * _VB + t]
            q5y = q[16 * _VB + t]
            q5z = q[17 * _VB + t]
            vol24 = 0.0
            g0x = 0.0
            g0y = 0.0
            g0z = 0.0
            g1x = 0.0
            g1y = 0.0
            g1z = 0.0
            g2x = 0.0
            g2y = 0.0
            g2z = 0.0
            g3x = 0.0
            g3y = 0.0
            g3z = 0.0
            g4x = 0.0
            g4y = 0.0
            g4z = 0.0
            g5x = 0.0
            g5y = 0.0
            g5z = 0.0
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
            gq[18 * _VB + t] = vol24
            gq[0 * _VB + t] = g0x
            gq[1 * _VB + t] = g0y
            gq[2 * _VB + t] = g0z
            gq[3 * _VB + t] = g1x
            gq[4 * _VB + t] = g1y
            gq[5 * _VB + t] = g1z
            gq[6 * _VB + t] = g2x
            gq[7 * _VB + t] = g2y
            gq[8 * _VB + t] = g2z
            gq[9 * _VB + t] = g3x
            gq[10 * _VB + t] = g3y
            gq[11 * _VB + t] = g3z
            gq[12 * _VB + t] = g4x
            gq[13 * _VB + t] = g4y
            gq[14 * _VB + t] = g4z
            gq[15 * _VB + t] = g5x
            gq[16 * _VB + t] = g5y
            gq[17 * _VB + t] = g5z
        for t in range(nb):
            e = e0 + t
            vol = (gt[18 * _VB + t] + gq[18 * _VB + t]) * (1.0 / 24.0)
            v0 = rest_volume[e]
            strain = (vol - v0) / v0
            energy += 0.5 * bulk[e] * v0 * strain * strain
            cf = bulk[e] * strain * (1.0 / 24.0)
            for k in range(6):
                n = prisms[e, k]
                for c in range(3):
                    r = (3 * k + c) * _VB + t
                    out[n, c] -= cf * (gt[r] + gq[r])
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

#: independent vector accumulators of :func:`_row_dot4` (hides the latency of the adds)
_ROW_ACC = 4


@intrinsic
def _row_dot4(typingctx, work, idx, val, start, stop):  # pragma: no cover
    """``sum(val[k] * work[idx[k], 0:4] for k in range(start, stop))`` as a tuple of four
    floats, computed with 4-wide vector arithmetic (``work`` is C-contiguous ``(n, 4)``
    float64; one vector load per term instead of three scalar ones).  Numba does not
    vectorise the three components of a row by itself, hence the LLVM IR.  Terms go
    round-robin to ``_ROW_ACC`` accumulators, summed pairwise at the end."""
    sig = types.UniTuple(types.float64, 4)(work, idx, val, start, stop)

    def codegen(context, builder, signature, args):
        work_v, idx_v, val_v, start_v, stop_v = args
        wary = context.make_array(signature.args[0])(context, builder, work_v)
        iary = context.make_array(signature.args[1])(context, builder, idx_v)
        vary = context.make_array(signature.args[2])(context, builder, val_v)
        f64 = llvm_ir.DoubleType()
        i32 = llvm_ir.IntType(32)
        i64 = llvm_ir.IntType(64)
        vec = llvm_ir.VectorType(f64, 4)
        rows = builder.bitcast(wary.data, vec.as_pointer())
        undef = llvm_ir.Constant(vec, llvm_ir.Undefined)
        splat = llvm_ir.Constant(llvm_ir.VectorType(i32, 4), [0, 0, 0, 0])
        accs = [cgutils.alloca_once_value(builder, llvm_ir.Constant(vec, [0.0] * 4))
                for _ in range(_ROW_ACC)]
        kptr = cgutils.alloca_once_value(builder, start_v)

        def term(k):
            j = builder.load(builder.gep(iary.data, [k]))
            if j.type.width < 64:
                j = builder.zext(j, i64)          # unsigned indices (uint16)
            v = builder.load(builder.gep(vary.data, [k]))
            if v.type != f64:
                v = builder.fpext(v, f64)
            v = builder.shuffle_vector(builder.insert_element(undef, v, llvm_ir.Constant(i32, 0)),
                                       undef, splat)
            return builder.fmul(v, builder.load(builder.gep(rows, [j]), align=8))

        def add(acc, k):
            builder.store(builder.fadd(builder.load(acc), term(k)), acc)

        main_cond = builder.append_basic_block("rowdot.cond")
        main_body = builder.append_basic_block("rowdot.body")
        tail_cond = builder.append_basic_block("rowdot.tail_cond")
        tail_body = builder.append_basic_block("rowdot.tail_body")
        done = builder.append_basic_block("rowdot.done")
        builder.branch(main_cond)
        builder.position_at_end(main_cond)
        k = builder.load(kptr)
        unroll = llvm_ir.Constant(i64, _ROW_ACC)
        builder.cbranch(builder.icmp_signed("<=", builder.add(k, unroll), stop_v),
                        main_body, tail_cond)
        builder.position_at_end(main_body)
        k = builder.load(kptr)
        for u in range(_ROW_ACC):
            add(accs[u], builder.add(k, llvm_ir.Constant(i64, u)))
        builder.store(builder.add(k, unroll), kptr)
        builder.branch(main_cond)
        builder.position_at_end(tail_cond)
        k = builder.load(kptr)
        builder.cbranch(builder.icmp_signed("<", k, stop_v), tail_body, done)
        builder.position_at_end(tail_body)
        k = builder.load(kptr)
        add(accs[0], k)
        builder.store(builder.add(k, llvm_ir.Constant(i64, 1)), kptr)
        builder.branch(tail_cond)
        builder.position_at_end(done)
        sums = [builder.load(a) for a in accs]
        while len(sums) > 1:
            sums = [builder.fadd(sums[i], sums[i + 1]) for i in range(0, len(sums), 2)]
        out = [builder.extract_element(sums[0], llvm_ir.Constant(i32, c)) for c in range(4)]
        return context.make_tuple(builder, signature.return_type, out)

    return sig, codegen


@numba.njit(cache=True, nogil=True)
def _ldl_solve3(q, rp, rj, rv, lp, li, lx, dinv, perm, work, out):  # pragma: no cover
    """Solve A z = q for 3 right-hand sides (rows of q are nodes) with a symmetric factor
    ``P A P^T = L D L^T``: the strictly lower part of ``L`` by rows (``rp``, ``rj``, ``rv``)
    for the forward sweep and by columns (``lp``, ``li``, ``lx``) for the backward one, so
    both sweeps gather (dot products, no scattered stores); ``dinv = 1 / diag(D)``; row ``i``
    of ``A`` is row ``perm[i]`` of the factor.  ``work`` is ``(n, 4)`` (C order): a padded
    row is one vector load in :func:`_row_dot4`."""
    n = q.shape[0]
    if work.shape[0] < n or work.shape[1] != 4:
        raise ValueError("_ldl_solve3: work must have shape (n, 4)")
    for i in range(n):
        r = perm[i]
        work[r, 0] = q[i, 0]
        work[r, 1] = q[i, 1]
        work[r, 2] = q[i, 2]
        work[r, 3] = 0.0
    for i in range(n):
        a0, a1, a2, _ = _row_dot4(work, rj, rv, rp[i], rp[i + 1])
        work[i, 0] -= a0
        work[i, 1] -= a1
        work[i, 2] -= a2
    for j in range(n - 1, -1, -1):
        a0, a1, a2, _ = _row_dot4(work, li, lx, lp[j], lp[j + 1])
        d = dinv[j]
        work[j, 0] = work[j, 0] * d - a0
        work[j, 1] = work[j, 1] * d - a1
        work[j, 2] = work[j, 2] * d - a2
    for i in range(n):
        r = perm[i]
        out[i, 0] = work[r, 0]
        out[i, 1] = work[r, 1]
        out[i, 2] = work[r, 2]


def _lanes4(builder, ptr, i, f64):  # pragma: no cover
    """``<4 x double>`` from ``ptr[i:i + 4]`` (float or double elements)."""
    elt = ptr.type.pointee
    vp = builder.bitcast(builder.gep(ptr, [i]), llvm_ir.VectorType(elt, 4).as_pointer())
    v = builder.load(vp, align=4 if elt != f64 else 8)
    if elt != f64:
        v = builder.fpext(v, llvm_ir.VectorType(f64, 4))
    return v


def _scalar(builder, ptr, i, f64):  # pragma: no cover
    v = builder.load(builder.gep(ptr, [i]))
    return v if v.type == f64 else builder.fpext(v, f64)


def _dot_codegen(axpy):  # pragma: no cover
    """LLVM IR of :func:`_dot` / :func:`_axpy_dot`: 4-wide vector loop, lane ``k`` holding
    the partial sum of the elements ``i = k (mod 4)``, the ``n % 4`` last ones added to lane
    0, result ``(d0 + d1) + (d2 + d3)``: the four partial sums of a scalar loop, bit for bit,
    whatever the alignment of the arrays (no reassociation flags)."""
    def codegen(context, builder, signature, args):
        f64 = llvm_ir.DoubleType()
        i64 = llvm_ir.IntType(64)
        i32 = llvm_ir.IntType(32)
        vec = llvm_ir.VectorType(f64, 4)
        if axpy:
            x_v, c_v, u_v, w_v = args
            xt, _, ut, wt = signature.args
            xa = context.make_array(xt)(context, builder, x_v)
            ua = context.make_array(ut)(context, builder, u_v)
            wa = context.make_array(wt)(context, builder, w_v)
            n = cgutils.unpack_tuple(builder, xa.shape)[0]
            cvec = builder.shuffle_vector(
                builder.insert_element(llvm_ir.Constant(vec, llvm_ir.Undefined), c_v,
                                       llvm_ir.Constant(i32, 0)),
                llvm_ir.Constant(vec, llvm_ir.Undefined),
                llvm_ir.Constant(llvm_ir.VectorType(i32, 4), [0, 0, 0, 0]))
        else:
            a_v, b_v = args
            at, bt = signature.args
            aa = context.make_array(at)(context, builder, a_v)
            ba = context.make_array(bt)(context, builder, b_v)
            n = cgutils.unpack_tuple(builder, aa.shape)[0]
        acc = cgutils.alloca_once_value(builder, llvm_ir.Constant(vec, [0.0] * 4))
        kptr = cgutils.alloca_once_value(builder, llvm_ir.Constant(i64, 0))
        four = llvm_ir.Constant(i64, 4)
        bb_cond = builder.append_basic_block("vd.cond")
        bb_body = builder.append_basic_block("vd.body")
        bb_tcond = builder.append_basic_block("vd.tcond")
        bb_tbody = builder.append_basic_block("vd.tbody")
        bb_tguard = builder.append_basic_block("vd.tguard")
        bb_done = builder.append_basic_block("vd.done")
        d0 = cgutils.alloca_once_value(builder, llvm_ir.Constant(f64, 0.0))
        builder.branch(bb_cond)
        builder.position_at_end(bb_cond)
        k = builder.load(kptr)
        builder.cbranch(builder.icmp_signed("<=", builder.add(k, four), n), bb_body, bb_tcond)
        builder.position_at_end(bb_body)
        k = builder.load(kptr)
        if axpy:
            xp = builder.bitcast(builder.gep(xa.data, [k]), vec.as_pointer())
            v = builder.fadd(builder.load(xp, align=8),
                             builder.fmul(cvec, _lanes4(builder, ua.data, k, f64)))
            builder.store(v, xp, align=8)
            t = builder.fmul(_lanes4(builder, wa.data, k, f64), v)
        else:
            t = builder.fmul(_lanes4(builder, aa.data, k, f64), _lanes4(builder, ba.data, k, f64))
        builder.store(builder.fadd(builder.load(acc), t), acc)
        builder.store(builder.add(k, four), kptr)
        builder.branch(bb_cond)
        # remainder (n % 4 elements) into the first partial sum
        builder.position_at_end(bb_tcond)
        lanes = builder.load(acc)
        builder.store(builder.extract_element(lanes, llvm_ir.Constant(i32, 0)), d0)
        builder.branch(bb_tguard)
        builder.position_at_end(bb_tguard)
        k = builder.load(kptr)
        builder.cbranch(builder.icmp_signed("<", k, n), bb_tbody, bb_done)
        builder.position_at_end(bb_tbody)
        k = builder.load(kptr)
        if axpy:
            xp = builder.gep(xa.data, [k])
            v = builder.fadd(builder.load(xp), builder.fmul(c_v, _scalar(builder, ua.data, k, f64)))
            builder.store(v, xp)
            t = builder.fmul(_scalar(builder, wa.data, k, f64), v)
        else:
            t = builder.fmul(_scalar(builder, aa.data, k, f64), _scalar(builder, ba.data, k, f64))
        builder.store(builder.fadd(builder.load(d0), t), d0)
        builder.store(builder.add(k, llvm_ir.Constant(i64, 1)), kptr)
        builder.branch(bb_tguard)
        builder.position_at_end(bb_done)
        e = [builder.extract_element(lanes, llvm_ir.Constant(i32, c)) for c in range(4)]
        return builder.fadd(builder.fadd(builder.load(d0), e[1]), builder.fadd(e[2], e[3]))
    return codegen


@intrinsic
def _dot(typingctx, a, b):  # pragma: no cover
    """``a . b`` (1-D contiguous float32 / float64 arrays of equal length) in double
    precision with four interleaved partial sums, vectorised (see :func:`_dot_codegen`)."""
    return types.float64(a, b), _dot_codegen(False)


@intrinsic
def _axpy_dot(typingctx, x, c, u, w):  # pragma: no cover
    """``x += c u`` in place (``x`` float64), then return ``w . x``; one vectorised pass,
    four partial sums (see :func:`_dot_codegen`)."""
    return types.float64(x, c, u, w), _dot_codegen(True)


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
    work = np.empty((nf, 4))
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
