"""What the snake solver takes and returns: parameters, contours, relaxation results.

:class:`SnakeParams` (tension, rigidity, viscoelasticity, damping, image-force strength;
the paper's values by default), :class:`Contour` (one contour's nodes, topology and
per-node overrides) and :class:`RelaxResult` (what a relaxation did). The solver itself,
:class:`~trackers.snakes.ContourSystem`, is in :mod:`trackers.snakes`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["SnakeParams", "Contour", "RelaxResult"]


def _per_node(value, default, n, what, name):
    if value is None:
        value = default
    arr = np.asarray(value, dtype=np.float64)
    if arr.ndim == 0:
        arr = np.full(n, float(arr))
    if arr.shape != (n,):
        raise ValueError(f"contour {name!r}: {what} must be a scalar or have {n} entries, "
                         f"got shape {arr.shape}")
    if not np.isfinite(arr).all() or (arr < 0).any():
        raise ValueError(f"contour {name!r}: {what} must be finite and >= 0")
    return arr


@dataclass(frozen=True)
class SnakeParams:
    """Physical parameters of a deformable contour (defaults: 004 V-E).

    Attributes
    ----------
    gamma : float
        Damping coefficient (eq. 10). With ``dt = 1``, ``gamma/dt = 0.5`` as in 004.
    dt : float
        Time step of the semi-implicit Euler scheme.
    a : float
        Tension (eq. 7).
    b : float
        Rigidity (eq. 9).
    nu : float
        Viscoelasticity of the rest lengths (eq. 8); 0 keeps them constant.
    p : float
        Strength of the image force (eq. 12), for potentials in 8-bit units.
    """

    gamma: float = 0.5
    dt: float = 1.0
    a: float = 1.0
    b: float = 0.5
    nu: float = 0.2
    p: float = 0.001

    def __post_init__(self):
        for name in ("gamma", "dt"):
            v = getattr(self, name)
            if not np.isfinite(v) or v <= 0:
                raise ValueError(f"SnakeParams.{name} must be positive, got {v}")
        for name in ("a", "b", "nu", "p"):
            v = getattr(self, name)
            if not np.isfinite(v) or v < 0:
                raise ValueError(f"SnakeParams.{name} must be finite and >= 0, got {v}")


@dataclass
class Contour:
    """One contour of a :class:`ContourSystem`.

    Attributes
    ----------
    points : array_like, (n, 2)
        Initial node positions (x, y) in image pixels. Open contours need at least
        3 nodes (one rigidity stencil), closed ones at least 5 (the wrapped
        five-node stencil of eq. 9 must not overlap itself).
    closed : bool
        Join the last node back to the first.
    fixed_ends : bool
        Hold the two end nodes of an open contour where they are (otherwise free).
    params : SnakeParams, optional
        Per-contour parameters (else the system's).
    a, b, nu, p : float or array_like (n,), optional
        Per-node overrides: ``a[i]`` and ``nu[i]`` belong to the spring from node
        ``i`` to the next (the last entry is unused for open contours), ``b[i]`` to
        the rigidity stencil centred on node ``i``, ``p[i]`` to node ``i``.
    rest_lengths : float or array_like, optional
        Initial rest lengths ``l_i``; default the initial node separations (004 V-E).
    field : int
        Index of the force field (in the stack given to :meth:`ContourSystem.relax`)
        that acts on this contour, so that e.g. brows follow a valley potential and
        the hairline an edge potential within one system.
    name : str
    normal_forces : bool
        Keep only the image-force component normal to the contour (the tangent is
        taken from the two neighbours). Eq. 12 applies the whole force (False, the
        default); along an uneven ravine its tangential part slides the nodes toward
        the deepest spot and, with viscoelastic rest lengths, shrinks the contour.
    spring : float or array_like (n,)
        Stiffness of a spring from each node to a target position (an external force
        of eq. 12, ``spring * (target - x)``, integrated implicitly so that a stiff
        spring is as stable as a weak one); the targets start at the initial nodes
        and are moved with :meth:`ContourSystem.set_targets`. 0 (default): no spring.
    """

    points: np.ndarray
    closed: bool = False
    fixed_ends: bool = False
    params: SnakeParams | None = None
    a: object = None
    b: object = None
    nu: object = None
    p: object = None
    rest_lengths: object = None
    field: int = 0
    name: str = ""
    normal_forces: bool = False
    spring: object = 0.0


@dataclass
class RelaxResult:
    """What :meth:`ContourSystem.relax` did.

    Attributes
    ----------
    iterations : int
        Time steps taken.
    max_move : float
        Largest node displacement (pixels) in the last step.
    converged : bool
        Whether the movement threshold was reached before ``max_iter``.
    outside : ndarray of bool, (n_contours,)
        Contours with a node that left the force field (its force was taken as 0).
    rms_move : float
        Root-mean-square node displacement in the last step.
    """

    iterations: int
    max_move: float
    converged: bool
    outside: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))
    rms_move: float = float("nan")
