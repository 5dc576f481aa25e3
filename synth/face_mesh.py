"""The face mesh container: :class:`FaceMesh` and the names it is indexed by.

What a generated face is, independently of how it is made (:mod:`synth.mesh`): the
read-only skin surface with its texture coordinates, :class:`Region` codes, landmarks,
feature curves and inner parts, the names of its landmarks and feature curves, the
inner-part material codes, and the uv helpers that embed a feature curve in the
surface (:func:`locate_uv`, :func:`resample_polyline_uv`, also used by the renderer's
ground truth). Coordinates are those of :mod:`synth.mesh`.
"""

from __future__ import annotations

import enum
import functools
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

__all__ = [
    "Region",
    "FaceMesh",
    "vertex_normals",
    "locate_uv",
    "resample_polyline_uv",
    "FIDUCIALS",
    "LANDMARK_NAMES",
    "FEATURE_CURVE_NAMES",
    "INNER_EYE",
    "INNER_MOUTH",
    "INNER_TEETH",
    "IRIS_RADIUS_UV",
    "PUPIL_RADIUS_UV",
]

#: Inner-part material codes (``FaceMesh.inner_material``).
INNER_EYE, INNER_MOUTH, INNER_TEETH = 1, 2, 3
#: On an eyeball, ``inner_uv`` is the frontal projection ``0.5 + 0.5 * (dx, -dy)`` of the unit
#: direction from the eyeball centre; the iris is where the distance of ``inner_uv`` from
#: (0.5, 0.5) is below ``IRIS_RADIUS_UV`` on the front hemisphere, the pupil below
#: ``PUPIL_RADIUS_UV``.  Back-hemisphere vertices get uv on the rim (radius 0.5).
IRIS_RADIUS_UV = 0.23
PUPIL_RADIUS_UV = 0.09

#: The 11 fiducial points of Terzopoulos & Waters (1993), section V-D.
FIDUCIALS = (
    "brow_inner_l", "brow_mid_l", "brow_outer_l",
    "brow_inner_r", "brow_mid_r", "brow_outer_r",
    "mouth_corner_l", "mouth_corner_r",
    "furrow_top_l", "furrow_top_r",
    "chin",
)
#: Every landmark name of :attr:`FaceMesh.landmarks`.
LANDMARK_NAMES = FIDUCIALS + (
    "nasion", "nose_tip", "subnasale",
    "eye_centre_l", "eye_centre_r", "eye_inner_l", "eye_inner_r", "eye_outer_l", "eye_outer_r",
    "lip_upper_centre", "lip_lower_centre",
    "hairline_centre", "hairline_l", "hairline_r",
    "jaw_angle_l", "jaw_angle_r", "alar_l", "alar_r",
)
#: Every key of :attr:`FaceMesh.feature_curves`.
FEATURE_CURVE_NAMES = (
    "hairline", "brow_l", "brow_r", "furrow_l", "furrow_r", "nostril_l", "nostril_r",
    "upper_lip", "lower_lip", "mouth_line", "chin_boss", "eye_l", "eye_r",
)


class Region(enum.IntEnum):
    """Anatomical region of a skin vertex (``FaceMesh.region``)."""

    SCALP = 0       # above the hairline (painted as hair)
    FOREHEAD = 1
    TEMPLE = 2
    BROW = 3        # eyebrow band and glabella
    EYELID = 4      # skin around the eye openings
    NOSE = 5
    CHEEK = 6
    NASOLABIAL = 7  # band along the nasolabial furrow
    UPPER_LIP = 8   # between the nose and the mouth line (incl. the upper seam row)
    LOWER_LIP = 9   # between the mouth line and the mentolabial sulcus
    CHIN = 10
    JAW = 11        # lower sides of the face, over the mandible


def vertex_normals(vertices, triangles) -> np.ndarray:
    """Area-weighted unit vertex normals of a triangle mesh.

    Parameters
    ----------
    vertices : (N, 3) array_like
        Vertex positions.
    triangles : (M, 3) array_like of int
        Counter-clockwise (seen from outside) vertex indices.

    Returns
    -------
    normals : (N, 3) ndarray
        Unit normals; vertices that belong to no triangle get (0, 0, 0).

    Examples
    --------
    >>> v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], float)
    >>> vertex_normals(v, [[0, 1, 2]])[0]
    array([0., 0., 1.])
    """
    v = np.asarray(vertices, dtype=np.float64)
    t = np.asarray(triangles)
    if v.ndim != 2 or v.shape[1] != 3:
        raise ValueError(f"vertices must have shape (N, 3), got {v.shape}")
    if t.ndim != 2 or t.shape[1] != 3 or (t.size and not np.issubdtype(t.dtype, np.integer)):
        raise ValueError(f"triangles must be an (M, 3) integer array, got {t.shape} {t.dtype}")
    if t.size and (t.min() < 0 or t.max() >= len(v)):
        raise ValueError("triangles refer to vertices that do not exist")
    fn = np.cross(v[t[:, 1]] - v[t[:, 0]], v[t[:, 2]] - v[t[:, 0]])  # 2 * area * unit normal
    n = np.zeros_like(v)
    for c in range(3):
        for k in range(3):
            n[:, c] += np.bincount(t[:, k], weights=fn[:, c], minlength=len(v))
    length = np.linalg.norm(n, axis=1)
    np.divide(n, length[:, None], out=n, where=length[:, None] > 0)
    return n


def _readonly(a: np.ndarray) -> np.ndarray:
    a = np.ascontiguousarray(a)
    a.setflags(write=False)
    return a


@dataclass(frozen=True, eq=False)
class FaceMesh:
    """Rest skin surface of a face plus the inner parts a renderer draws.

    Made by :func:`~synth.mesh.generate_face_mesh`; arrays are read-only.  See :mod:`synth.mesh`
    for the coordinate system.  Derived quantities (edges, normals, adjacency, mirror map) are
    cached on first use and depend on the rest geometry/topology only.

    Attributes
    ----------
    vertices : (N, 3) float64
        Rest positions of the epidermis, centimetres.
    triangles : (M, 3) int32
        Counter-clockwise seen from outside (normals point out of the face).
    uv : (N, 2) float64
        Canonical texture coordinates in [0, 1] (u right, v down): identical for every
        :class:`~synth.face_shape.FaceShape` at the same resolution.
    region : (N,) int8
        :class:`Region` codes.
    landmarks : dict[str, int]
        Vertex index per name in :data:`LANDMARK_NAMES`.  ``eye_centre_*`` is the vertex on the
        upper-lid margin straight above the centre of the eye opening (the centre itself lies in
        the hole); ``lip_upper_centre`` / ``lip_lower_centre`` are the midpoints of the upper /
        lower vermilion borders; ``mouth_corner_*`` are the ends of the mouth seam (shared by
        both lips); ``furrow_top_*`` the upper ends of the nasolabial furrows, beside the alar
        wings; ``chin`` the centre of the chin boss.
    tissue_thickness : (N,) float64
        Soft-tissue depth (cm) from skin to bone along the inward rest normal.
    jaw_weight : (N,) float64
        1 where the bone underneath is the mandible, 0 on the skull, smooth in between.
    jaw_pivot : (3,) float64
        A point on the jaw hinge axis (axis = +x); positive rotation opens the mouth.
    boundary : (N,) bool
        Outline vertices glued to the skull.
    mouth_seam : (K, 2) int
        (upper-lip vertex, lower-lip vertex) pairs that coincide at rest.
    feature_curves : dict[str, (K, 2) ndarray]
        uv polylines of painted features (:data:`FEATURE_CURVE_NAMES`); closed outlines
        (lips, eyes, nostrils) repeat their first point at the end.
    inner_vertices, inner_triangles, inner_material, inner_uv, inner_jaw_weight
        Eyeballs (material 1), mouth cavity (2) and teeth (3) behind the skin; triangles face
        the viewer / outward.
    eyeball_centres : (2, 3) float64
        Centres of the left and right eyeball (rows: ``_l``, ``_r``).
    eyeball_radius : float
        Radius of both eyeballs.
    mirror_map : (N,) int or None
        Index of each vertex's mirror image; use :attr:`mirror_index`.
    resolution : float
        The resolution the mesh was made at.
    """

    vertices: np.ndarray
    triangles: np.ndarray
    uv: np.ndarray
    region: np.ndarray
    landmarks: dict
    tissue_thickness: np.ndarray
    jaw_weight: np.ndarray
    jaw_pivot: np.ndarray
    boundary: np.ndarray
    mouth_seam: np.ndarray
    feature_curves: dict
    inner_vertices: np.ndarray
    inner_triangles: np.ndarray
    inner_material: np.ndarray
    inner_uv: np.ndarray
    inner_jaw_weight: np.ndarray
    eyeball_centres: np.ndarray = field(default_factory=lambda: np.zeros((2, 3)))
    eyeball_radius: float = 0.0
    mirror_map: np.ndarray | None = None
    resolution: float = 1.0

    # -- sizes ---------------------------------------------------------------------------------
    @property
    def n_vertices(self) -> int:
        """Number of skin vertices."""
        return len(self.vertices)

    @property
    def n_triangles(self) -> int:
        """Number of skin triangles."""
        return len(self.triangles)

    # -- cached topology -----------------------------------------------------------------------
    @functools.cached_property
    def edges(self) -> np.ndarray:
        """(E, 2) int array of unique undirected edges, ``edges[:, 0] < edges[:, 1]``, sorted."""
        t = self.triangles
        e = np.concatenate([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]])
        e = np.sort(e, axis=1)
        return _readonly(np.unique(e, axis=0).astype(np.int64))

    @functools.cached_property
    def boundary_edges(self) -> np.ndarray:
        """(B, 2) directed edges used by exactly one triangle (outline, eye margins, lips)."""
        t = self.triangles
        e = np.concatenate([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]])
        key = np.sort(e, axis=1)
        _, inv, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
        return _readonly(e[counts[inv.ravel()] == 1].astype(np.int64))

    @functools.cached_property
    def face_normals(self) -> np.ndarray:
        """(M, 3) unit normals of the rest triangles."""
        v, t = self.vertices, self.triangles
        n = np.cross(v[t[:, 1]] - v[t[:, 0]], v[t[:, 2]] - v[t[:, 0]])
        return _readonly(n / np.linalg.norm(n, axis=1, keepdims=True))

    @functools.cached_property
    def triangle_areas(self) -> np.ndarray:
        """(M,) rest triangle areas (cm^2)."""
        v, t = self.vertices, self.triangles
        n = np.cross(v[t[:, 1]] - v[t[:, 0]], v[t[:, 2]] - v[t[:, 0]])
        return _readonly(0.5 * np.linalg.norm(n, axis=1))

    @functools.cached_property
    def vertex_normals(self) -> np.ndarray:
        """(N, 3) area-weighted unit normals of the rest surface (pointing out of the face)."""
        return _readonly(vertex_normals(self.vertices, self.triangles))

    @functools.cached_property
    def mirror_index(self) -> np.ndarray:
        """(N,) index of the vertex at the mirror image (x -> -x) of each vertex.

        Midline vertices map to themselves; the map is an involution.  On the default face
        ``vertices[mirror_index] == vertices * (-1, 1, 1)`` exactly.
        """
        if self.mirror_map is not None:
            return _readonly(np.asarray(self.mirror_map, dtype=np.int64))
        # fall back: geometric matching, breaking seam ties by region
        m = self.vertices * np.array([-1.0, 1.0, 1.0])
        tree = cKDTree(self.vertices)
        _, idx = tree.query(m, k=2)
        out = idx[:, 0].copy()
        wrong = self.region[out] != self.region
        out[wrong] = idx[wrong, 1]
        return _readonly(out.astype(np.int64))

    def landmark_positions(self, vertices=None) -> dict[str, np.ndarray]:
        """Positions of all landmarks, from ``vertices`` (default: the rest vertices)."""
        v = self.vertices if vertices is None else np.asarray(vertices, dtype=np.float64)
        if v.shape != self.vertices.shape:
            raise ValueError(f"vertices must have shape {self.vertices.shape}, got {v.shape}")
        return {name: v[i].copy() for name, i in self.landmarks.items()}

    @functools.cached_property
    def _curve_embeddings(self) -> dict:
        return {}

    def curve_embedding(self, name: str) -> tuple[np.ndarray, np.ndarray]:
        """The feature curve ``name`` as material points of the surface.

        The uv polyline (:attr:`feature_curves`) is resampled every 0.002 uv units and each
        sample is located in the uv triangulation (:func:`locate_uv`), so that the curve
        follows the skin as the vertices move (cached per curve; it depends on the topology
        and uv only).

        Returns
        -------
        vertices : (K, 3) int array
            Corners of the triangle holding each sample (samples outside the mesh dropped).
        weights : (K, 3) float array
            Barycentric weights of each sample in its triangle.
        """
        if name not in self.feature_curves:
            raise ValueError(f"unknown feature curve {name!r}; choose from "
                             f"{', '.join(self.feature_curves)}")
        hit = self._curve_embeddings.get(name)
        if hit is None:
            q = resample_polyline_uv(np.asarray(self.feature_curves[name], dtype=np.float64))
            tri, bary = locate_uv(q, self.uv, self.triangles)
            found = tri >= 0
            hit = (_readonly(np.asarray(self.triangles, dtype=np.int64)[tri[found]]),
                   _readonly(bary[found]))
            self._curve_embeddings[name] = hit
        return hit

    def curve_positions(self, name: str, vertices=None) -> np.ndarray:
        """(K, 3) points of the feature curve ``name`` on the surface ``vertices`` (default:
        the rest vertices), in order along the curve (see :meth:`curve_embedding`).

        Examples
        --------
        >>> from synth.mesh import generate_face_mesh
        >>> mesh = generate_face_mesh(resolution=0.4)
        >>> p = mesh.curve_positions("furrow_l")
        >>> bool(p[0, 1] > p[-1, 1])      # the nasolabial furrow runs down from its top
        True
        """
        v = self.vertices if vertices is None else np.asarray(vertices, dtype=np.float64)
        if v.shape != self.vertices.shape:
            raise ValueError(f"vertices must have shape {self.vertices.shape}, got {v.shape}")
        idx, w = self.curve_embedding(name)
        return np.einsum("kj,kjd->kd", w, v[idx])

    def region_mask(self, *regions: Region) -> np.ndarray:
        """(N,) bool: vertices in any of ``regions``."""
        return np.isin(self.region, [int(r) for r in regions])


def resample_polyline_uv(poly: np.ndarray, step: float = 0.002) -> np.ndarray:
    """Resample a uv polyline every ``step`` (uv units), keeping both ends."""
    poly = np.asarray(poly, dtype=np.float64)
    seg = np.hypot(*np.diff(poly, axis=0).T)
    s = np.r_[0.0, np.cumsum(seg)]
    t = np.linspace(0.0, s[-1], max(2, int(np.ceil(s[-1] / step)) + 1))
    return np.stack([np.interp(t, s, poly[:, 0]), np.interp(t, s, poly[:, 1])], axis=1)


def locate_uv(points, uv, triangles) -> tuple[np.ndarray, np.ndarray]:
    """Locate uv ``points`` (K, 2) in the uv triangulation (``uv`` per vertex, ``triangles``).

    Returns
    -------
    triangle : (K,) int array
        Index of the first triangle holding each point, -1 outside every triangle.
    bary : (K, 3) float array
        Barycentric weights in that triangle (NaN outside).
    """
    q = np.atleast_2d(np.asarray(points, dtype=np.float64))
    tri = np.asarray(triangles)
    uv = np.asarray(uv, dtype=np.float64)
    a = uv[tri[:, 0]]
    e1, e2 = uv[tri[:, 1]] - a, uv[tri[:, 2]] - a
    det = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]
    ok = np.abs(det) > 1e-15
    det = np.where(ok, det, 1.0)
    index = np.full(len(q), -1, dtype=np.int64)
    bary = np.full((len(q), 3), np.nan)
    chunk = max(1, 4_000_000 // max(len(tri), 1))       # bounded (K, M) temporaries
    for start in range(0, len(q), chunk):
        d = q[start:start + chunk, None, :] - a[None]
        l1 = (d[..., 0] * e2[:, 1] - d[..., 1] * e2[:, 0]) / det
        l2 = (e1[:, 0] * d[..., 1] - e1[:, 1] * d[..., 0]) / det
        inside = ok & (l1 >= -1e-9) & (l2 >= -1e-9) & (l1 + l2 <= 1 + 1e-9)
        rows = np.flatnonzero(inside.any(axis=1))
        m = inside[rows].argmax(axis=1)
        b1, b2 = l1[rows, m], l2[rows, m]
        index[start + rows] = m
        bary[start + rows] = np.stack([1.0 - b1 - b2, b1, b2], axis=1)
    return index, bary
