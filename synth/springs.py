"""Biphasic springs of the tissue lattice (004 eqs. 1-2): forces and elastic energy.

The piecewise-linear spring law (stiffness ``alpha`` up to the elongation threshold
``e^c``, ``beta`` beyond it, in stretch and in compression) is described in
:mod:`synth.forces`. Here: the Numba kernel that :class:`~synth.forces.TissueSystem`
sums with the other terms, :func:`spring_forces` for the springs alone, and
:func:`spring_forces_numpy`, the vectorised NumPy reference used by the tests and the
benchmark.
"""

from __future__ import annotations

import numba
import numpy as np

from .lattice import Lattice

__all__ = ["spring_forces", "spring_forces_numpy"]


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
