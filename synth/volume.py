"""Volume preservation of the tissue lattice: the ``Q`` term of 004 III-A.

Energy per prism (three tetrahedra, 000 section 6), with ``J = V / V0``: 004's
``bulk / 2 * V0 * (J - 1)**2`` where the element grows, and ``bulk / 2 * V0 * (J - 1)**2 / J``
where it shrinks, which has the same value, slope and stiffness at rest (``J = 1``) but resists
being squeezed ever harder (its force grows as ``1 / J**2``) so that no element collapses; below
``J = 0.02`` it continues as its quadratic expansion there (finite for an inverted element).
Force ``-dQ/dx`` (see :mod:`synth.forces`). Its Numba kernel is most of this module:
it is written out coordinate by coordinate over blocks of prisms so that its arithmetic
runs in SIMD loops, which is why it stands apart from the other, short terms.
"""

from __future__ import annotations

import numba
import numpy as np

from .lattice import PRISM_QUADS, Lattice

__all__ = ["volume_forces"]


#: prisms per block of :func:`_volume_kernel` (its arithmetic runs in SIMD loops over a block)
_VB = 64

#: volume ratio below which the compression energy continues as its quadratic expansion
_J_MIN = 0.02
# its value, slope and curvature there, per unit of bulk * V0
_E0 = 0.5 * (_J_MIN - 1.0) ** 2 / _J_MIN
_G1 = 0.5 * (1.0 - 1.0 / _J_MIN ** 2)
_G2 = 1.0 / _J_MIN ** 3


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
            J = vol / v0
            if J >= 1.0:
                strain = J - 1.0
                energy += 0.5 * bulk[e] * v0 * strain * strain
                dedv = bulk[e] * strain
            elif J > _J_MIN:
                energy += 0.5 * bulk[e] * v0 * (J - 1.0) * (J - 1.0) / J
                dedv = 0.5 * bulk[e] * (1.0 - 1.0 / (J * J))
            else:
                d = J - _J_MIN
                energy += bulk[e] * v0 * (_E0 + _G1 * d + 0.5 * _G2 * d * d)
                dedv = bulk[e] * (_G1 + _G2 * d)
            cf = dedv * (1.0 / 24.0)
            for k in range(6):
                n = prisms[e, k]
                for c in range(3):
                    r = (3 * k + c) * _VB + t
                    out[n, c] -= cf * (gt[r] + gq[r])
    return energy


def volume_forces(x: np.ndarray, lattice: Lattice, out: np.ndarray | None = None):
    """Volume-restoration forces ``q_i = -dQ/dx_i`` (004 III-A).  Returns ``(forces, energy)``."""
    x = np.ascontiguousarray(x, dtype=np.float64)
    if out is None:
        out = np.zeros_like(x)
    e = _volume_kernel(x, lattice.prisms, PRISM_QUADS, lattice.rest_volume, lattice.bulk, out)
    return out, e
