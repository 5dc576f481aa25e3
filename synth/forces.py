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

* Volume preservation, the ``Q`` term of 004 III-A: ``bulk / 2 * V0 * (J - 1)**2``, ``J = V / V0``
  per prism (three tetrahedra, 000 section 6; divided by ``J`` under compression, see
  :mod:`synth.volume`), force ``-dQ/dx``.
* Skull non-penetration (000 section 7): a fascia node whose height above the (jaw-rotated)
  skull plane under it drops below the margin is pushed back out along the skull normal by
  a stiff penalty.  As a fail-safe, a node that still ends up below the bone surface itself
  is projected back onto it.
* Lip contact: the two rows of the mouth seam are not joined (the mouth opens), so the upper
  lip is kept from passing through the lower one by the same kind of one-sided penalty.

The hot loops are Numba kernels (``cache=True``); :func:`~synth.springs.spring_forces_numpy` is
the vectorised NumPy reference used by the tests and the benchmark.

Each term has its own module: :mod:`synth.springs`, :mod:`synth.volume` and
:mod:`synth.skull` (skull and lip penalties). This module sums them with the external load
in :class:`TissueSystem`; the equilibrium solver's compiled loop is in :mod:`synth.lbfgs`.
"""

from __future__ import annotations

import numba
import numpy as np

from .lattice import PRISM_QUADS, Lattice, rotate_about_jaw
from .skull import _contact_kernel, _skull_kernel, _skull_project
from .springs import _spring_kernel
from .volume import _volume_kernel

__all__ = ["TissueSystem"]


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
