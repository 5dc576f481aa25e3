"""Layered soft-tissue lattice assembled from an epidermal triangle mesh.

The lattice follows Terzopoulos & Waters (1993, section III-A and III-D) and Lee,
Terzopoulos & Waters (1993, section 4): every skin vertex of a :class:`~synth.face_mesh.FaceMesh`
is extruded along its inward rest normal into four node layers,

=====  ==============  ========================================================
layer  name            position (fraction of the local tissue thickness)
=====  ==============  ========================================================
0      ``epidermis``   0 (the mesh vertices themselves)
1      ``dermis``      dermal / fatty interface, ``layer_depths[1]``
2      ``fascia``      top of the muscle layer, ``layer_depths[2]``
3      ``bone``        skull surface, ``layer_depths[3]`` (fixed; may rotate with the jaw)
=====  ==============  ========================================================

Every skin triangle therefore yields three stacked triangular prisms (elements): the
cutaneous (dermal), subcutaneous (fatty) and muscle layers.  Springs run along the triangle
edges inside layers 0-2, vertically between layers, and across the quadrilateral side faces
of every prism (two diagonals per face, 004 Fig. 3), so the elements resist shear.

Spring stiffnesses come from per-layer moduli, calibrated so that the lattice energy
approximates that of a continuum: a spring that shares the volume ``V_s`` of its
elements has stiffness ``k = E V_s / l0**2``; the epidermis and the fascia add a thin membrane
(``k += E_m t_m A_s / l0**2``).  Finer meshes therefore give the same deformation.

Node index of vertex ``v`` in layer ``l`` is ``l * n_vertices + v``.  The outline of the mesh
is glued to the skull (all its layers fixed); the mouth seam is not joined, and its vertex
pairs become one-sided lip contacts (the upper lip stays above the lower one).

Units: centimetres, kPa for moduli, forces in kPa·cm² (0.1 N), masses such that time is in
seconds (``density=1e-4`` is 1 g/cm³ in these units).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = [
    "LAYER_NAMES",
    "ELEMENT_LAYER_NAMES",
    "DEFAULT_LAYER_DEPTHS",
    "DEFAULT_STIFFNESS",
    "Lattice",
    "build_lattice",
    "mesh_vertex_normals",
    "prism_volumes",
    "rotate_about_jaw",
]

LAYER_NAMES = ("epidermis", "dermis", "fascia", "bone")
ELEMENT_LAYER_NAMES = ("dermis", "subcutaneous", "muscle")
DEFAULT_LAYER_DEPTHS = (0.0, 0.25, 0.6, 1.0)

#: Young's-modulus-like stiffness of every spring class, in kPa, as
#: ``(low-strain, high-strain, strain threshold)`` of the biphasic law (004 eqs. 1-2).
#: The ratios follow Lee et al. (000, section 4: epidermis 60, dermal-fatty 30 / 70,
#: fascia 80, muscle 10); the subcutaneous fat is the most deformable layer (004 III-A).
DEFAULT_STIFFNESS: dict[str, tuple[float, float, float]] = {
    "epidermis": (60.0, 120.0, 0.15),
    "dermis": (30.0, 70.0, 0.20),
    "subcutaneous": (10.0, 25.0, 0.50),
    "fascia": (80.0, 160.0, 0.15),
    "muscle": (10.0, 25.0, 0.50),
}

#: Membrane thickness (cm) of the epidermis and the fascia sheets.
DEFAULT_MEMBRANE_THICKNESS = {"epidermis": 0.05, "fascia": 0.05}

# spring classes
SPRING_CLASSES = ("epidermis", "dermis", "subcutaneous", "fascia", "muscle")


@dataclass(frozen=True, eq=False)
class Lattice:
    """Topology and rest state of a tissue lattice (see :func:`build_lattice`).

    All arrays are read-only views; per-spring and per-element parameters are plain arrays
    indexed like ``springs`` and ``prisms`` so that kernels can be vectorised.
    """

    rest: np.ndarray            #: (n, 3) rest positions of all nodes
    layer: np.ndarray           #: (n,) int8 node layer (0 epidermis .. 3 bone)
    n_vertices: int             #: skin vertices per layer; node = layer * n_vertices + vertex
    springs: np.ndarray         #: (s, 2) int32 node pairs
    rest_length: np.ndarray     #: (s,) rest lengths (cm)
    k_low: np.ndarray           #: (s,) small-strain stiffness (force / cm)
    k_high: np.ndarray          #: (s,) large-strain stiffness (force / cm)
    switch: np.ndarray          #: (s,) elongation threshold e^c (cm) between the phases
    spring_class: np.ndarray    #: (s,) int8 index into ``SPRING_CLASSES``
    fixed: np.ndarray           #: (n,) bool, nodes whose position is prescribed
    jaw_weight: np.ndarray      #: (n,) in [0, 1], share of the jaw rotation each node follows
    jaw_pivot: np.ndarray       #: (3,) point on the hinge axis (axis = +x)
    prisms: np.ndarray          #: (e, 6) int32 nodes (top a, b, c, bottom a', b', c')
    element_layer: np.ndarray   #: (e,) int8 index into ``ELEMENT_LAYER_NAMES``
    rest_volume: np.ndarray     #: (e,) rest volumes (cm³), positive
    bulk: np.ndarray            #: (e,) volume-preservation modulus per element (kPa)
    mass: np.ndarray            #: (n,) lumped nodal masses
    skull_nodes: np.ndarray     #: (f,) fascia nodes that must stay outside the skull
    skull_bone: np.ndarray      #: (f,) bone node under each of them
    skull_normal: np.ndarray    #: (f, 3) outward skull normal at that bone node (rest)
    skull_margin: np.ndarray    #: (f,) minimum fascia height above the skull (cm)
    skull_k: np.ndarray         #: (f,) penalty stiffness of the non-penetration constraint
    inward: np.ndarray          #: (n_vertices, 3) unit inward direction used for extrusion
    contact_pairs: np.ndarray = None   #: (c, 2) (upper-lip node, lower-lip node) seam pairs
    contact_normal: np.ndarray = None  #: (c, 3) direction from the lower to the upper lip
    contact_k: np.ndarray = None       #: (c,) penalty stiffness keeping the lips apart
    info: dict = field(default_factory=dict)

    def __repr__(self) -> str:
        # the per-node and per-spring arrays print tens of kB
        return (f"<Lattice: {self.n_nodes} nodes ({self.n_vertices} a layer), "
                f"{self.n_springs} springs, {self.n_elements} elements>")

    @property
    def n_nodes(self) -> int:
        """Number of nodes (all layers)."""
        return self.rest.shape[0]

    @property
    def n_springs(self) -> int:
        """Number of springs."""
        return self.springs.shape[0]

    @property
    def n_elements(self) -> int:
        """Number of prism elements."""
        return self.prisms.shape[0]

    def layer_nodes(self, name: str) -> np.ndarray:
        """Node indices of one layer (``'epidermis'``, ``'dermis'``, ``'fascia'``, ``'bone'``)."""
        if name not in LAYER_NAMES:
            raise ValueError(f"unknown layer {name!r}; choose from {', '.join(LAYER_NAMES)}")
        l = LAYER_NAMES.index(name)
        return np.arange(l * self.n_vertices, (l + 1) * self.n_vertices)


def mesh_vertex_normals(vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Area-weighted unit vertex normals of a triangle mesh (counter-clockwise = outward).

    Parameters
    ----------
    vertices : (N, 3) array
    triangles : (M, 3) int array

    Returns
    -------
    normals : (N, 3) array of unit vectors (zero rows for unreferenced vertices).

    Examples
    --------
    >>> v = np.array([[0., 0, 0], [1, 0, 0], [0, 1, 0]])
    >>> mesh_vertex_normals(v, np.array([[0, 1, 2]]))[0]
    array([0., 0., 1.])
    """
    v = np.asarray(vertices, dtype=np.float64)
    t = np.asarray(triangles, dtype=np.int64)
    fn = np.cross(v[t[:, 1]] - v[t[:, 0]], v[t[:, 2]] - v[t[:, 0]])
    n = np.zeros_like(v)
    for c in range(3):
        np.add.at(n, t[:, c], fn)
    norm = np.linalg.norm(n, axis=1, keepdims=True)
    return np.divide(n, norm, out=np.zeros_like(n), where=norm > 0)


def _unique_edges(triangles: np.ndarray) -> np.ndarray:
    e = np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]])
    e = np.sort(e, axis=1)
    return np.unique(e, axis=0)


# Volume of the prism (a, b, c, a', b', c') = local (0..5) with bilinear side faces, by the
# divergence theorem: the top and bottom triangles contribute det/6, and the flux integral of a
# bilinear quadrilateral (p0, p1, p2, p3) is exactly (p0 + p1 + p2 + p3) . (d1 x d2) / 8 with
# diagonals d1 = p2 - p0, d2 = p3 - p1.  The result is independent of the vertex labelling,
# so mirror-image elements have identical volume functions.
PRISM_QUADS = np.array([[0, 3, 4, 1], [1, 4, 5, 2], [2, 5, 3, 0]], dtype=np.int64)


def prism_volumes(x: np.ndarray, prisms: np.ndarray) -> np.ndarray:
    """Volumes of prism elements (bilinear side faces) at node positions ``x``."""
    p = x[prisms]                      # (e, 6, 3)
    p = p - p.mean(axis=1, keepdims=True)
    vol = np.einsum("ij,ij->i", p[:, 0], np.cross(p[:, 1], p[:, 2]))
    vol += np.einsum("ij,ij->i", p[:, 3], np.cross(p[:, 5], p[:, 4]))
    for q in PRISM_QUADS:
        s = p[:, q].sum(axis=1)
        vol += 0.25 * np.einsum("ij,ij->i", s, np.cross(p[:, q[2]] - p[:, q[0]],
                                                        p[:, q[3]] - p[:, q[1]]))
    return vol / 6.0


def _fix_extrusion_directions(vertices, triangles, normals, seam, min_dot=0.25, n_iter=50):
    """Tilt each extrusion direction toward its worst adjacent face normal until it makes at
    least ``min_dot`` with every adjacent face normal (else the prisms there are inverted).
    Seam partners keep a common direction."""
    fn = np.cross(vertices[triangles[:, 1]] - vertices[triangles[:, 0]],
                  vertices[triangles[:, 2]] - vertices[triangles[:, 0]])
    fn /= np.maximum(np.linalg.norm(fn, axis=1, keepdims=True), 1e-300)
    n_v = len(vertices)
    vt = triangles.ravel()
    ft = np.repeat(np.arange(len(triangles)), 3)
    d = normals.copy()
    for _ in range(n_iter):
        dots = np.einsum("ij,ij->i", d[vt], fn[ft])
        order = np.lexsort((dots, vt))           # per vertex, worst face first
        first = np.ones(len(order), bool)
        first[1:] = vt[order][1:] != vt[order][:-1]
        worst_v = vt[order][first]
        worst_f = ft[order][first]
        worst_dot = dots[order][first]
        bad = worst_dot < min_dot
        if not np.any(bad):
            break
        vb, fb = worst_v[bad], worst_f[bad]
        d[vb] = d[vb] + 0.35 * fn[fb]
        if len(seam):
            avg = d[seam[:, 0]] + d[seam[:, 1]]
            d[seam[:, 0]] = avg
            d[seam[:, 1]] = avg
        d /= np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-300)
    del n_v
    return d


def _smooth_normals_radius(points, normals, sigma):
    """Gaussian-weighted average of the normals within 2.5 sigma (resolution independent)."""
    if sigma <= 0:
        return normals
    from scipy.spatial import cKDTree

    tree = cKDTree(points)
    pairs = tree.query_pairs(2.5 * sigma, output_type="ndarray")
    acc = normals.copy()
    if len(pairs):
        d2 = np.sum((points[pairs[:, 0]] - points[pairs[:, 1]]) ** 2, axis=1)
        w = np.exp(-0.5 * d2 / sigma**2)[:, None]
        np.add.at(acc, pairs[:, 0], w * normals[pairs[:, 1]])
        np.add.at(acc, pairs[:, 1], w * normals[pairs[:, 0]])
    norm = np.linalg.norm(acc, axis=1, keepdims=True)
    return np.divide(acc, norm, out=np.zeros_like(acc), where=norm > 0)


def build_lattice(mesh, *, layer_depths=DEFAULT_LAYER_DEPTHS, stiffness=None,
                  membrane_thickness=None, bulk_modulus: float = 100.0,
                  density: float = 1e-4, skull_margin: float = 0.1,
                  skull_stiffness: float = 300.0, normal_smoothing: float = 0.8) -> Lattice:
    """Assemble the trilayer tissue lattice under an epidermal triangle mesh (004 III-D).

    Parameters
    ----------
    mesh : FaceMesh
        Uses ``vertices``, ``triangles``, ``tissue_thickness``, ``jaw_weight``, ``jaw_pivot``,
        ``boundary`` and ``mouth_seam`` only.
    layer_depths : 4 floats
        Depth of the epidermis, dermal/fatty interface, fascia and bone node layers as
        fractions of the local tissue thickness; strictly increasing, first 0, last 1.
    stiffness : dict, optional
        Overrides of :data:`DEFAULT_STIFFNESS` entries ``class -> (low, high, threshold)``
        (kPa, kPa, strain).  ``high >= low > 0``.
    membrane_thickness : dict, optional
        Overrides of the epidermis / fascia membrane thickness (cm).
    bulk_modulus : float
        Stiffness of the volume-preservation term (kPa): energy
        ``bulk / 2 * V0 * (J - 1)**2`` per element, ``J = V / V0`` (004 Q term; divided by ``J``
        under compression, see :mod:`synth.volume`).
    density : float
        Mass density for the lumped nodal masses (1e-4 = 1 g/cm³ in model units).
    skull_margin : float
        Fraction of the muscle-layer thickness that the fascia keeps above the skull.
    skull_stiffness : float
        Penalty modulus (kPa) of the skull non-penetration constraint (000 section 7).
    normal_smoothing : float
        Gaussian radius (cm) over which the vertex normals are averaged before extrusion, so
        that the inner layers of strongly curved regions do not cross.  Where they still
        would, the local tissue depth is reduced (``lattice.info['depth']``).

    Returns
    -------
    Lattice

    Raises
    ------
    ValueError
        On malformed mesh fields, non-positive tissue thickness or bad parameters.

    Examples
    --------
    >>> from synth.mesh import generate_face_mesh
    >>> lat = build_lattice(generate_face_mesh(resolution=0.4))
    >>> lat.n_elements > 960 and lat.n_springs > 6500
    True
    """
    vertices = np.asarray(mesh.vertices, dtype=np.float64)
    triangles = np.asarray(mesh.triangles, dtype=np.int64)
    n_v = vertices.shape[0]
    if vertices.ndim != 2 or vertices.shape[1] != 3 or n_v < 3:
        raise ValueError(f"mesh.vertices must be (N, 3) with N >= 3, got {vertices.shape}")
    if triangles.ndim != 2 or triangles.shape[1] != 3 or len(triangles) == 0:
        raise ValueError(f"mesh.triangles must be (M, 3), got {triangles.shape}")
    if triangles.min() < 0 or triangles.max() >= n_v:
        raise ValueError("mesh.triangles index vertices outside [0, N)")
    if not np.all(np.isfinite(vertices)):
        raise ValueError("mesh.vertices contains non-finite values")
    thickness = np.asarray(mesh.tissue_thickness, dtype=np.float64)
    if thickness.shape != (n_v,) or not np.all(np.isfinite(thickness)) or thickness.min() <= 0:
        raise ValueError("mesh.tissue_thickness must be (N,) finite and > 0")
    jaw_v = np.asarray(mesh.jaw_weight, dtype=np.float64)
    if jaw_v.shape != (n_v,) or jaw_v.min() < 0 or jaw_v.max() > 1:
        raise ValueError("mesh.jaw_weight must be (N,) in [0, 1]")
    boundary = np.asarray(mesh.boundary, dtype=bool)
    if boundary.shape != (n_v,):
        raise ValueError("mesh.boundary must be (N,) bool")
    depths = np.asarray(layer_depths, dtype=np.float64)
    if depths.shape != (4,) or depths[0] != 0.0 or depths[-1] != 1.0 or np.any(
            np.diff(depths) <= 0):
        raise ValueError(f"layer_depths must be 4 increasing fractions from 0 to 1, got "
                         f"{tuple(layer_depths)}")
    stiff = dict(DEFAULT_STIFFNESS)
    for name, val in (stiffness or {}).items():
        if name not in stiff:
            raise ValueError(f"unknown stiffness class {name!r}; choose from "
                             f"{', '.join(SPRING_CLASSES)}")
        lo, hi, sw = (float(v) for v in val)
        if not (lo > 0 and hi >= lo and sw > 0):
            raise ValueError(f"stiffness[{name!r}] must be (low > 0, high >= low, threshold > 0),"
                             f" got {val}")
        stiff[name] = (lo, hi, sw)
    membrane = dict(DEFAULT_MEMBRANE_THICKNESS)
    for name, val in (membrane_thickness or {}).items():
        if name not in membrane:
            raise ValueError(f"unknown membrane {name!r}; choose from epidermis, fascia")
        if not val >= 0:
            raise ValueError(f"membrane_thickness[{name!r}] must be >= 0, got {val}")
        membrane[name] = float(val)
    for pname, val in (("bulk_modulus", bulk_modulus), ("density", density),
                       ("skull_stiffness", skull_stiffness)):
        if not (np.isfinite(val) and val > 0):
            raise ValueError(f"{pname} must be finite and > 0, got {val}")
    if not (np.isfinite(normal_smoothing) and normal_smoothing >= 0):
        raise ValueError(f"normal_smoothing must be >= 0 (cm), got {normal_smoothing}")
    if not 0 <= skull_margin < 1:
        raise ValueError(f"skull_margin must be in [0, 1), got {skull_margin}")

    edges = _unique_edges(triangles)
    normals = mesh_vertex_normals(vertices, triangles)
    seam = np.asarray(getattr(mesh, "mouth_seam", np.zeros((0, 2), int)), dtype=np.int64)
    seam = seam.reshape(-1, 2)
    if len(seam):
        avg = normals[seam[:, 0]] + normals[seam[:, 1]]
        normals[seam[:, 0]] = avg
        normals[seam[:, 1]] = avg
        normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-12)
    normals = _smooth_normals_radius(vertices, normals, normal_smoothing)
    normals = _fix_extrusion_directions(vertices, triangles, normals, seam)
    if np.any(np.linalg.norm(normals, axis=1) < 0.5):
        raise ValueError("mesh has vertices without a defined normal (unreferenced vertices?)")
    inward = -normals

    # ---- nodes: extrude; where the tissue is thicker than the local radius of curvature the
    # inner layers would fold, so the depth is reduced locally until no element is inverted
    tri = triangles
    prisms = np.concatenate([
        np.concatenate([tri + l * n_v, tri + (l + 1) * n_v], axis=1) for l in range(3)
    ]).astype(np.int64)
    depth = thickness.copy()
    for _ in range(40):
        rest = np.concatenate([vertices + inward * (depth * d)[:, None] for d in depths])
        vol = prism_volumes(rest, prisms)
        ref = np.abs(prism_volumes(np.concatenate(
            [vertices + inward * (depth * d)[:, None] * 1e-3 for d in depths]), prisms)) * 1e3
        bad = vol <= 0.05 * ref
        if not np.any(bad):
            break
        vb = np.unique(prisms[bad] % n_v)
        depth[vb] *= 0.85
    else:
        raise ValueError(f"{int(bad.sum())} tissue elements stay inverted at rest; the tissue "
                         "is much thicker than the local radius of curvature")
    n_thinned = int(np.sum(depth < thickness))
    layer = np.repeat(np.arange(4, dtype=np.int8), n_v)
    fixed = np.zeros(4 * n_v, bool)
    fixed[3 * n_v:] = True
    for l in range(3):
        fixed[l * n_v + np.flatnonzero(boundary)] = True
    jaw = np.tile(jaw_v, 4)

    # ---- elements (prisms) ----
    element_layer = np.repeat(np.arange(3, dtype=np.int8), len(tri))
    rest_volume = prism_volumes(rest, prisms)

    # ---- springs ----
    pairs = []
    cls = []
    for l in range(4):                       # in-layer triangle edges (bone: dropped below)
        pairs.append(edges + l * n_v)
        cls.append(np.full(len(edges), (0, 1, 3, 4)[l]))
    for l in range(3):                       # vertical + cross diagonals between layers
        v = np.arange(n_v)
        pairs.append(np.stack([v + l * n_v, v + (l + 1) * n_v], axis=1))
        pairs.append(np.stack([edges[:, 0] + l * n_v, edges[:, 1] + (l + 1) * n_v], axis=1))
        pairs.append(np.stack([edges[:, 1] + l * n_v, edges[:, 0] + (l + 1) * n_v], axis=1))
        cls.append(np.full(n_v + 2 * len(edges), (1, 2, 4)[l]))
    springs = np.concatenate(pairs).astype(np.int64)
    spring_class = np.concatenate(cls).astype(np.int8)
    rest_length = np.linalg.norm(rest[springs[:, 1]] - rest[springs[:, 0]], axis=1)
    if np.any(rest_length <= 1e-9):
        raise ValueError("degenerate (zero-length) springs: mesh has coincident joined vertices")

    # volume share of every spring: each prism gives V/15 to each of its 15 springs
    key_base = 4 * n_v
    s_sorted = np.sort(springs, axis=1)
    keys = s_sorted[:, 0] * key_base + s_sorted[:, 1]
    order = np.argsort(keys)
    keys_sorted = keys[order]
    local = np.array([[0, 1], [1, 2], [2, 0], [3, 4], [4, 5], [5, 3], [0, 3], [1, 4], [2, 5],
                      [0, 4], [1, 3], [1, 5], [2, 4], [2, 3], [0, 5]])
    ep = np.sort(prisms[:, local], axis=2)               # (e, 15, 2)
    ekeys = (ep[..., 0] * key_base + ep[..., 1]).ravel()
    pos = np.searchsorted(keys_sorted, ekeys)
    if np.any(pos >= len(keys_sorted)) or np.any(keys_sorted[np.minimum(pos, len(keys) - 1)]
                                                 != ekeys):
        raise ValueError("internal error: prism edge without spring")
    sidx = order[pos]
    vshare = np.bincount(sidx, weights=np.repeat(rest_volume / 15.0, 15),
                         minlength=len(springs))
    elayer_of_spring = np.full(len(springs), -1)
    elayer_of_spring[sidx] = np.repeat(element_layer, 15)

    # in-layer edges take the modulus of the layer below them (dermis under the epidermis,
    # subcutaneous under the dermis interface, muscle under the fascia) for their volume part
    vol_class_name = np.array(["dermis", "subcutaneous", "muscle"])
    vol_cls = vol_class_name[elayer_of_spring]
    k_low = np.empty(len(springs))
    k_high = np.empty(len(springs))
    switch = np.empty(len(springs))
    for name in ("dermis", "subcutaneous", "muscle"):
        m = vol_cls == name
        lo, hi, sw = stiff[name]
        k_low[m] = lo * vshare[m] / rest_length[m] ** 2
        k_high[m] = hi * vshare[m] / rest_length[m] ** 2
        switch[m] = sw * rest_length[m]
    # membranes: epidermis (class 0) and fascia (class 3) triangle edges
    tri_area = 0.5 * np.linalg.norm(np.cross(vertices[tri[:, 1]] - vertices[tri[:, 0]],
                                             vertices[tri[:, 2]] - vertices[tri[:, 0]]),
                                    axis=1)
    ekey_tri = np.sort(np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]]), axis=1)
    ekey_tri = ekey_tri[:, 0] * n_v + ekey_tri[:, 1]
    edge_keys = edges[:, 0] * n_v + edges[:, 1]
    edge_area = np.bincount(np.searchsorted(edge_keys, ekey_tri),
                            weights=np.tile(tri_area / 3.0, 3), minlength=len(edges))
    for l, name in ((0, "epidermis"), (2, "fascia")):
        sl = slice(l * len(edges), (l + 1) * len(edges))
        lo, hi, sw = stiff[name]
        a = edge_area * membrane[name]
        k_low[sl] += lo * a / rest_length[sl] ** 2
        k_high[sl] += hi * a / rest_length[sl] ** 2
        # the membrane's threshold governs these springs
        switch[sl] = sw * rest_length[sl]
    keep = ~(fixed[springs[:, 0]] & fixed[springs[:, 1]])
    springs, rest_length = springs[keep], rest_length[keep]
    k_low, k_high, switch, spring_class = k_low[keep], k_high[keep], switch[keep], \
        spring_class[keep]

    # ---- masses ----
    mass = density * np.bincount(prisms.ravel(), weights=np.repeat(rest_volume / 6.0, 6),
                                 minlength=4 * n_v)
    mass = np.maximum(mass, 1e-12)
    bulk = np.full(len(prisms), float(bulk_modulus))

    # ---- skull non-penetration (000 section 7): fascia above the bone surface ----
    free_v = np.flatnonzero(~boundary)
    skull_nodes = 2 * n_v + free_v
    skull_bone = 3 * n_v + free_v
    skull_normal = normals[free_v].copy()
    muscle_thick = (depths[3] - depths[2]) * depth[free_v]
    margin = skull_margin * muscle_thick
    # penalty stiffness: modulus * area share / muscle-layer thickness
    v_area = np.bincount(tri.ravel(), weights=np.repeat(tri_area / 3.0, 3), minlength=n_v)
    skull_k = skull_stiffness * v_area[free_v] / muscle_thick

    # ---- lip contact: the upper lip stays above the lower lip along the seam ----
    if len(seam):
        up = np.array([0.0, 1.0, 0.0])
        pairs_c, normals_c, k_c = [], [], []
        for l in range(3):
            pu, pl = seam[:, 0] + l * n_v, seam[:, 1] + l * n_v
            ok = ~(fixed[pu] & fixed[pl])
            nrm = normals[seam[:, 0]]
            d = up - (nrm @ up)[:, None] * nrm
            d /= np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-12)
            pairs_c.append(np.stack([pu, pl], axis=1)[ok])
            normals_c.append(d[ok])
            k_c.append((skull_stiffness * v_area[seam[:, 0]] / depth[seam[:, 0]])[ok])
        contact_pairs = np.concatenate(pairs_c).astype(np.int32)
        contact_normal = np.concatenate(normals_c)
        contact_k = np.concatenate(k_c)
    else:
        contact_pairs = np.zeros((0, 2), np.int32)
        contact_normal = np.zeros((0, 3))
        contact_k = np.zeros(0)

    ro = lambda a: _readonly(a)  # noqa: E731
    return Lattice(
        rest=ro(rest), layer=ro(layer), n_vertices=int(n_v),
        springs=ro(springs.astype(np.int32)), rest_length=ro(rest_length), k_low=ro(k_low),
        k_high=ro(k_high), switch=ro(switch), spring_class=ro(spring_class), fixed=ro(fixed),
        jaw_weight=ro(jaw), jaw_pivot=ro(np.asarray(mesh.jaw_pivot, dtype=np.float64).copy()),
        prisms=ro(prisms.astype(np.int32)), element_layer=ro(element_layer),
        rest_volume=ro(rest_volume), bulk=ro(bulk), mass=ro(mass),
        skull_nodes=ro(skull_nodes.astype(np.int32)), skull_bone=ro(skull_bone.astype(np.int32)),
        skull_normal=ro(skull_normal), skull_margin=ro(margin), skull_k=ro(skull_k),
        inward=ro(inward), contact_pairs=ro(contact_pairs), contact_normal=ro(contact_normal),
        contact_k=ro(contact_k),
        info={"layer_depths": tuple(float(d) for d in depths), "stiffness": stiff,
              "membrane_thickness": membrane, "bulk_modulus": float(bulk_modulus),
              "density": float(density), "depth": _readonly(depth),
              "n_thinned": n_thinned},
    )


def _readonly(a: np.ndarray) -> np.ndarray:
    a = np.ascontiguousarray(a)
    a.setflags(write=False)
    return a


def rotate_about_jaw(points: np.ndarray, weights: np.ndarray, pivot: np.ndarray,
                     angle: float) -> np.ndarray:
    """Rotate ``points`` about the hinge axis through ``pivot`` (axis +x), each by
    ``weights * angle`` radians.  Returns a new array (an exact copy for ``angle == 0``, so
    that closing the jaw brings back the rest geometry bit for bit)."""
    if angle == 0.0:
        return np.array(points, dtype=np.float64)
    p = np.asarray(points, dtype=np.float64) - pivot
    a = np.asarray(weights, dtype=np.float64) * angle
    c, s = np.cos(a), np.sin(a)
    out = np.empty_like(p)
    out[:, 0] = p[:, 0]
    out[:, 1] = c * p[:, 1] - s * p[:, 2]
    out[:, 2] = s * p[:, 1] + c * p[:, 2]
    return out + pivot
