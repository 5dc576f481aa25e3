"""Skull non-penetration and lip contact: the one-sided penalties of the tissue lattice.

A fascia node whose height above the (jaw-rotated) skull plane under it drops below the
margin is pushed back out along the skull normal (000 section 7); the upper lip is kept
from passing through the lower one by the same kind of penalty; and, as a fail-safe, a
node that still ends up below the bone is projected back onto it (see
:mod:`synth.forces`). Kernels used by :class:`~synth.forces.TissueSystem`, and
:func:`skull_forces` for the skull term alone.
"""

from __future__ import annotations

import numba
import numpy as np

from .lattice import Lattice

__all__ = ["skull_forces"]


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
