"""Quasi-static sensitivity of the face model's equilibrium to its controls.

At an equilibrium the net force on every free node vanishes, ``f(x, c) = 0``. A small change
of the controls ``c`` (muscle contractions, the jaw) moves it by

    dx/dc = K^{-1} df/dc,        K = -df/dx,

``K`` the tangent stiffness of the free nodes at the equilibrium (the Hessian of the lattice
energy). This is the Jacobian through the model itself that Sifakis et al. (2005) use to fit
muscle activations to markers: it includes every nonlinearity of the equilibrium (biphasic
springs in their current phase, volume preservation, skull and lip contact), which a
tabulated response only approximates.

``K`` is assembled from the force kernels by central differences, many columns per force
evaluation: nodes that share no spring, element or lip contact with a common node get the
same colour (a distance-2 colouring of the coupling graph), so two evaluations per colour and
axis give all their columns (about 200 on the default lattice). At rest the lips touch and
the fascia lies on the skull's margin, where the one-sided penalties switch on: a central
difference takes the mean of the two sides' stiffness, which predicts a small contraction's
motion from rest far better than either side's alone. A muscle's ``df/dc`` is its nodal force
at unit contraction (the load is linear in the contraction); the jaw's moves the mandible's
fixed nodes, the skull normals and the muscles it carries, and
is differenced in the same way.
"""

from __future__ import annotations

import weakref

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

__all__ = ["tangent_stiffness", "equilibrium_sensitivity", "stiffness_factor", "JAW"]

#: The jaw's control name (as in :meth:`synth.FaceModel.set_contractions`).
JAW = "jaw_rotation"

#: Finite-difference step of the stiffness's columns, cm (positions are O(10) cm: the
#: rounding error of a force difference is ~1e-10 relative to the step's 1e-6).
STIFFNESS_STEP = 1e-6

#: Finite-difference step of the jaw's load, radians.
JAW_STEP = 1e-6

_colourings: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def _coupling(system) -> sp.csr_matrix:
    """Boolean node x node matrix: nodes whose forces depend on each other's positions (a
    shared spring, element or lip contact), the diagonal included."""
    lat = system.lattice
    n = lat.n_nodes
    rows, cols = [lat.springs[:, 0], lat.springs[:, 1]], [lat.springs[:, 1], lat.springs[:, 0]]
    p = lat.prisms
    for a in range(p.shape[1]):
        for b in range(p.shape[1]):
            rows.append(p[:, a])
            cols.append(p[:, b])
    cp = np.asarray(system.contact_pairs).reshape(-1, 2)
    rows += [cp[:, 0], cp[:, 1], np.arange(n)]
    cols += [cp[:, 1], cp[:, 0], np.arange(n)]
    r, c = np.concatenate(rows), np.concatenate(cols)
    return sp.csr_matrix((np.ones(len(r), bool), (r, c)), shape=(n, n))


def _colouring(system):
    """Per colour, the (row node, free column) pairs of the stiffness's nonzero 3x3 blocks,
    and the stiffness's sparse structure: where each difference's values go in its CSC data
    and, for the symmetrisation, where each entry's transpose lies. Cached per lattice (its
    topology does not change)."""
    lat = system.lattice
    cached = _colourings.get(lat)
    if cached is not None:
        return cached
    free = system.free
    a = _coupling(system)
    af = a[:, free].tocsc().astype(np.int32)
    share = (af.T @ af).tocsr()          # free columns that touch a common row
    colour = np.full(len(free), -1)
    for j in range(len(free)):           # greedy, in node order
        taken = colour[share.indices[share.indptr[j]:share.indptr[j + 1]]]
        used = np.zeros(len(free) + 1, bool)
        used[taken[taken >= 0]] = True
        colour[j] = int(np.argmin(used))
    position = np.full(lat.n_nodes, -1)
    position[free] = np.arange(len(free))
    groups = []
    for k in range(colour.max() + 1):
        cols = np.flatnonzero(colour == k)
        sub = af[:, cols]
        row_nodes = sub.indices
        col_of = np.repeat(cols, np.diff(sub.indptr))
        keep = position[row_nodes] >= 0            # rows of free nodes only
        groups.append((free[cols], row_nodes[keep], position[row_nodes[keep]], col_of[keep]))
    # the entries in the order tangent_stiffness computes them: colour, axis, row axis
    rows, cols = [], []
    for _, _, row_pos, col in groups:
        for d in range(3):
            for e in range(3):
                rows.append(3 * row_pos + e)
                cols.append(3 * col + d)
    rows, cols = np.concatenate(rows), np.concatenate(cols)
    nf = 3 * len(free)
    pattern = sp.csc_matrix((np.arange(1, len(rows) + 1, dtype=np.float64), (rows, cols)),
                            shape=(nf, nf))
    pattern.sort_indices()
    order = pattern.data.astype(np.int64) - 1          # CSC slot -> computed entry
    flipped = pattern.T.tocsc()
    flipped.sort_indices()
    # the coupling is symmetric, so the transpose has the same structure: slot q of the
    # transpose holds the entry computed for the mirrored slot
    mirror = np.empty(len(order), np.int64)
    mirror[order] = np.arange(len(order))
    transpose = mirror[flipped.data.astype(np.int64) - 1]
    cached = (position, groups, (pattern.indices.copy(), pattern.indptr.copy(), order,
                                 transpose))
    _colourings[lat] = cached
    return cached


def tangent_stiffness(system, x: np.ndarray, *, step: float = STIFFNESS_STEP) -> sp.csc_matrix:
    """The tangent stiffness ``K = -df/dx`` of the free nodes at ``x``.

    Parameters
    ----------
    system : synth.forces.TissueSystem
        The lattice with its boundary conditions and load (the load does not enter ``K``).
    x : ndarray, shape (n_nodes, 3)
        Node positions (the fixed ones at their prescribed places).
    step : float, keyword-only
        Central-difference step, cm.

    Returns
    -------
    scipy.sparse.csc_matrix, shape (3 n_free, 3 n_free)
        Rows and columns ordered by ``system.free``, x, y, z per node; symmetrised.

    Examples
    --------
    >>> import numpy as np
    >>> from synth import FaceModel
    >>> m = FaceModel.default()
    >>> k = tangent_stiffness(m.system, m.node_positions)
    >>> k.shape == (3 * len(m.system.free),) * 2, bool(abs(k - k.T).max() == 0)
    (True, True)
    """
    if not (np.isfinite(step) and step > 0):
        raise ValueError(f"step must be a positive number, got {step!r}")
    x = np.array(x, dtype=np.float64)
    if x.shape != system.lattice.rest.shape:
        raise ValueError(f"x must have shape {system.lattice.rest.shape}, got {x.shape}")
    _, groups, (indices, indptr, order, transpose) = _colouring(system)
    nf = len(system.free)
    buf = np.empty_like(x)
    vals = []
    for nodes, row_nodes, _, _ in groups:
        for d in range(3):
            x0 = x[nodes, d].copy()
            x[nodes, d] = x0 + step
            ahead = system.forces(x, buf)[0][row_nodes]
            x[nodes, d] = x0 - step
            behind = system.forces(x, buf)[0][row_nodes]
            x[nodes, d] = x0
            vals.append(((behind - ahead) / (2.0 * step)).T.ravel())   # -df/dx, by row axis
    data = np.concatenate(vals)[order]
    data = 0.5 * (data + data[transpose])
    return sp.csc_matrix((data, indices, indptr), shape=(3 * nf, 3 * nf))


def equilibrium_sensitivity(model, controls, *, factor=None) -> np.ndarray:
    """``dx/dc``: how the model's equilibrium moves per unit of each control.

    Parameters
    ----------
    model : synth.FaceModel
        At an equilibrium (after :meth:`~synth.FaceModel.equilibrate`); not changed.
    controls : sequence of str
        Muscle names and/or :data:`JAW` (per radian).
    factor : callable, optional
        A solver of ``K y = b`` for the free nodes (``b`` of shape (3 n_free, k)), e.g. a
        factorisation of :func:`tangent_stiffness` at a nearby equilibrium kept from an
        earlier call (the chord method); by default ``K`` is assembled and factored here.

    Returns
    -------
    ndarray, shape (len(controls), n_nodes, 3)
        The motion of every node (the fixed ones move with the jaw only).

    Examples
    --------
    A half-contracted left zygomaticus major contracted a little more, predicted and
    equilibrated:

    >>> import numpy as np
    >>> from synth import FaceModel
    >>> m = FaceModel.default()
    >>> m.set_contractions({"zygomaticus_major_l": 0.5})
    >>> _ = m.equilibrate(tol=1e-8, max_iter=50000)
    >>> before = m.node_positions
    >>> dx = equilibrium_sensitivity(m, ["zygomaticus_major_l"])[0]
    >>> m.set_contractions({"zygomaticus_major_l": 0.52})
    >>> _ = m.equilibrate(tol=1e-8, max_iter=50000)
    >>> moved = m.node_positions - before
    >>> bool(np.linalg.norm(0.02 * dx - moved) < 0.05 * np.linalg.norm(moved))
    True
    """
    controls = list(controls)
    names = list(model.muscle_names)
    unknown = [c for c in controls if c != JAW and c not in names]
    if unknown:
        raise ValueError(f"unknown controls {unknown}; choose from {', '.join(names)}, {JAW}")
    system, lat = model.system, model.lattice
    x = model.node_positions
    free = system.free
    if factor is None:
        factor = stiffness_factor(system, x)
    jaw = float(model.jaw_rotation)
    c = np.array([model.contractions[n] for n in names])
    loads = np.zeros((len(free) * 3, len(controls)))
    moved_fixed = np.zeros((len(controls),) + lat.rest.shape)
    for i, name in enumerate(controls):
        if name != JAW:
            unit = np.zeros(len(names))
            unit[names.index(name)] = 1.0
            loads[:, i] = model.muscle_load(unit, jaw)[free].ravel()
            continue
        # the jaw moves the fixed nodes it carries, the skull's and the lips' normals and
        # the muscles over the mandible: the free nodes' force change at fixed positions
        f0 = system.forces(x)[0][free].copy()
        saved = system.f_ext
        try:
            system.set_jaw(jaw + JAW_STEP)
            system.set_external(model.muscle_load(c, jaw + JAW_STEP))
            xj = x.copy()
            system.apply_boundary(xj)
            f1 = system.forces(xj)[0][free]
        finally:
            system.set_jaw(jaw)
            system.set_external(saved)
        loads[:, i] = ((f1 - f0) / JAW_STEP).ravel()
        moved_fixed[i] = (xj - x) / JAW_STEP
        moved_fixed[i][free] = 0.0
    out = moved_fixed
    solved = factor(loads)
    out[:, free] += solved.T.reshape(len(controls), len(free), 3)
    return out


def stiffness_factor(system, x: np.ndarray):
    """A solver of ``K y = b`` with ``K`` the :func:`tangent_stiffness` at ``x`` (a sparse
    LU with symmetric ordering): pass it to :func:`equilibrium_sensitivity` to reuse it."""
    k = tangent_stiffness(system, x)
    lu = spla.splu(k, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
                   options={"SymmetricMode": True})
    return lu.solve
