"""Procedural generic face mesh: a deterministic, mirror-symmetric skin surface.

The face is built over a *canonical* 2-D design plane (centimetres of the default face,
``X`` = subject's left, ``Y`` = up, origin between the eye centres).  A graded point set,
dense around the eyes and the mouth, is triangulated there (Delaunay, with the eye margins,
the mouth line and the outline kept as edges), the eye openings are cut out and the mouth line
is split into two coinciding rows of vertices so that the lips can part.  The identity
(:class:`FaceShape`) then warps the plane and lifts it into 3-D: a head-like cylinder whose sides
curve back, plus smooth relief for the brow ridge, eye sockets and lids, nose and alar wings,
cheeks, nasolabial folds, lips, chin boss and jaw.

Because the topology and the texture coordinates come from the canonical plane only, every
identity made at the same ``resolution`` has the same triangles, the same ``uv`` and the same
landmark indices; only positions (and thickness) change.

Coordinates (model space): centimetres, ``x`` = subject's left, ``y`` = up, ``z`` = toward the
viewer; origin at the midpoint between the two eye centres.
"""

from __future__ import annotations

import enum
import functools
import math
from dataclasses import dataclass, field, fields

import numpy as np
from matplotlib.path import Path as _MplPath
from scipy.interpolate import PchipInterpolator
from scipy.spatial import Delaunay, cKDTree

__all__ = [
    "Region",
    "FaceShape",
    "FaceMesh",
    "generate_face_mesh",
    "vertex_normals",
    "FIDUCIALS",
    "LANDMARK_NAMES",
    "FEATURE_CURVE_NAMES",
    "INNER_EYE",
    "INNER_MOUTH",
    "INNER_TEETH",
    "IRIS_RADIUS_UV",
    "PUPIL_RADIUS_UV",
    "MAX_RESOLUTION",
]

#: Inner-part material codes (``FaceMesh.inner_material``).
INNER_EYE, INNER_MOUTH, INNER_TEETH = 1, 2, 3
#: On an eyeball, ``inner_uv`` is the frontal projection ``0.5 + 0.5 * (dx, -dy)`` of the unit
#: direction from the eyeball centre; the iris is where the distance of ``inner_uv`` from
#: (0.5, 0.5) is below ``IRIS_RADIUS_UV`` on the front hemisphere, the pupil below
#: ``PUPIL_RADIUS_UV``.  Back-hemisphere vertices get uv on the rim (radius 0.5).
IRIS_RADIUS_UV = 0.23
PUPIL_RADIUS_UV = 0.09
#: Largest accepted ``resolution`` (about 100,000 skin vertices).
MAX_RESOLUTION = 8.0

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


# ----------------------------------------------------------------------------------------------
# Identity
# ----------------------------------------------------------------------------------------------

_SHAPE_MIN, _SHAPE_MAX = 0.5, 1.6


@dataclass(frozen=True, init=False)
class FaceShape:
    """Identity of a generated face: dimensionless multipliers, 1.0 = the default face.

    Parameters
    ----------
    face_width, face_length : float
        Overall width and (hairline-to-chin) length.
    forehead_height, brow_height : float
        Hairline-to-brow height and brow-to-eye distance.
    brow_prominence : float
        Forward bulge of the brow ridge.
    eye_spacing, eye_size : float
        Distance between the eye centres and size of the eye openings and eyeballs.
    nose_length, nose_width, nose_protrusion : float
        Nasion-to-tip length, alar width, forward projection of the nose.
    mouth_width, upper_lip_thickness, lower_lip_thickness : float
        Width of the mouth, height and volume of the upper and lower lip.
    chin_height, jaw_width, cheek_fullness : float
        Mouth-to-chin height, width of the lower face, volume and tissue depth of the cheeks.

    Every value must lie in [0.5, 1.6]; parameters are keyword-only.  Unknown names or values
    out of range raise ``ValueError``.

    Examples
    --------
    >>> FaceShape(nose_length=1.1).nose_length
    1.1
    >>> FaceShape.random(3) == FaceShape.random(3)
    True
    """

    face_width: float = 1.0
    face_length: float = 1.0
    forehead_height: float = 1.0
    brow_height: float = 1.0
    brow_prominence: float = 1.0
    eye_spacing: float = 1.0
    eye_size: float = 1.0
    nose_length: float = 1.0
    nose_width: float = 1.0
    nose_protrusion: float = 1.0
    mouth_width: float = 1.0
    upper_lip_thickness: float = 1.0
    lower_lip_thickness: float = 1.0
    chin_height: float = 1.0
    jaw_width: float = 1.0
    cheek_fullness: float = 1.0

    def __init__(self, **params: float) -> None:
        names = [f.name for f in fields(self)]
        unknown = sorted(set(params) - set(names))
        if unknown:
            raise ValueError(
                f"unknown FaceShape parameter(s) {unknown}; valid names are {names}"
            )
        bad = []
        for name in names:
            value = params.get(name, 1.0)
            try:
                value = float(value)
            except (TypeError, ValueError):
                bad.append(f"{name}={value!r}")
                continue
            if not (math.isfinite(value) and _SHAPE_MIN <= value <= _SHAPE_MAX):
                bad.append(f"{name}={value!r}")
            object.__setattr__(self, name, value)
        if bad:
            raise ValueError(
                f"FaceShape parameter(s) out of range [{_SHAPE_MIN}, {_SHAPE_MAX}]: "
                + ", ".join(bad)
            )

    @classmethod
    def names(cls) -> tuple[str, ...]:
        """Names of all shape parameters, in declaration order."""
        return tuple(f.name for f in fields(cls))

    def as_dict(self) -> dict[str, float]:
        """The parameters as a plain ``{name: value}`` dictionary."""
        return {name: getattr(self, name) for name in self.names()}

    @classmethod
    def random(cls, seed: int, *, spread: float = 1.0) -> FaceShape:
        """A plausible random identity, deterministic per ``seed``.

        Each multiplier is ``1 + spread * 0.075 * g`` with ``g`` a standard normal clipped to
        [-2, 2], so at ``spread=1`` every parameter stays within +-15 % of the default.
        Width-like parameters are mildly correlated (a wide face tends to have a wide jaw).

        Parameters
        ----------
        seed : int
            Seed of the generator (``numpy.random.default_rng``).
        spread : float, optional
            Scale of the variation, in [0, 4]; 0 gives the default face.

        Returns
        -------
        FaceShape

        Examples
        --------
        >>> s = FaceShape.random(0)
        >>> all(0.85 <= v <= 1.15 for v in s.as_dict().values())
        True
        """
        if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)):
            raise ValueError(f"seed must be an integer, got {seed!r}")
        spread = float(spread)
        if not (math.isfinite(spread) and 0.0 <= spread <= 4.0):
            raise ValueError(f"spread must be in [0, 4], got {spread!r}")
        rng = np.random.default_rng(int(seed))
        names = cls.names()
        g = np.clip(rng.standard_normal(len(names)), -2.0, 2.0)
        common = float(np.clip(rng.standard_normal(), -2.0, 2.0))
        values = {}
        for k, name in enumerate(names):
            z = g[k]
            if name in ("face_width", "jaw_width", "mouth_width", "nose_width"):
                z = float(np.clip(0.6 * z + 0.8 * common, -2.0, 2.0))
            value = 1.0 + spread * 0.075 * z
            values[name] = float(np.clip(value, _SHAPE_MIN, _SHAPE_MAX))
        return cls(**values)


def _as_shape(shape) -> FaceShape:
    if shape is None:
        return FaceShape()
    if isinstance(shape, FaceShape):
        return shape
    if isinstance(shape, dict):
        return FaceShape(**shape)
    raise ValueError(f"shape must be a FaceShape, a dict or None, got {type(shape).__name__}")


# ----------------------------------------------------------------------------------------------
# Mesh container
# ----------------------------------------------------------------------------------------------


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

    Made by :func:`generate_face_mesh`; arrays are read-only.  See the module docstring for
    the coordinate system.  Derived quantities (edges, normals, adjacency, mirror map) are
    cached on first use and depend on the rest geometry/topology only.

    Attributes
    ----------
    vertices : (N, 3) float64
        Rest positions of the epidermis, centimetres.
    triangles : (M, 3) int32
        Counter-clockwise seen from outside (normals point out of the face).
    uv : (N, 2) float64
        Canonical texture coordinates in [0, 1] (u right, v down): identical for every
        :class:`FaceShape` at the same resolution.
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


# ----------------------------------------------------------------------------------------------
# Canonical design plane (centimetres of the default face)
# ----------------------------------------------------------------------------------------------

X_EXT = 8.4            # u = (X + X_EXT) / (2 X_EXT)
Y_TOP = 8.8            # v = (Y_TOP - Y) / (Y_TOP - Y_BOT)
Y_BOT = -12.0

_OUTLINE_Y = np.array([-12.0, -11.85, -11.4, -10.5, -9.0, -7.4, -5.5, -3.0, 0.0, 3.0, 6.0, 8.8])
_OUTLINE_W = np.array([0.0, 1.05, 2.5, 4.0, 5.5, 6.6, 7.4, 7.8, 8.0, 8.0, 7.75, 7.3])
_hw = PchipInterpolator(_OUTLINE_Y, _OUTLINE_W)

EYE_C = 3.35           # eye centre |X|
EYE_A = 1.4            # half length of the palpebral fissure
EYE_BU = 0.5           # upper-lid height above the centre
EYE_BL = 0.4           # lower-lid depth below the centre
EYE_TILT = 0.06        # outer canthus higher by this much
MOUTH_Y = -7.6         # mouth line at the midline
MOUTH_W = 2.45         # half width of the mouth (corner |X|)
MOUTH_CURVE = 0.12     # corners higher than the centre by this much
UL_H = 0.72            # upper vermilion height at the midline (cupid's bow dip)
UL_PEAK = 0.84         # upper vermilion height at the bow peaks
LL_H = 0.95            # lower vermilion depth at the midline
Y_HAIR = 6.6           # hairline at the midline
BROW_INNER, BROW_MID, BROW_OUTER = 1.45, 3.4, 5.45   # |X| of the eyebrow's ends and middle
BROW_Y = 2.3           # eyebrow height at its middle
Y_NASION = 0.6
Y_TIP = -4.6
Y_SUBNASALE = -5.75
Y_CHIN = -10.4
Y_SULCUS = -9.15
Y_JAW_ANGLE = -7.4
ALAR = (1.55, -5.05)
FURROW_TOP = (2.05, -4.5)


def _mouth_y(ax):
    ax = np.minimum(np.abs(ax), MOUTH_W)
    return MOUTH_Y + MOUTH_CURVE * (ax / MOUTH_W) ** 2


def _brow_y(ax):
    return BROW_Y - 0.13 * (np.asarray(ax) - BROW_MID) ** 2


def _hairline_y(ax):
    ax = np.asarray(ax, dtype=float)
    return Y_HAIR - 0.045 * ax**2 - 0.9 * np.clip((ax - 5.0) / 2.0, 0, None) ** 2


def _eye_margin(t):
    """Point of the left-eye margin at angle ``t`` (0 = outer canthus, pi/2 = top)."""
    s, c = np.sin(t), np.cos(t)
    x = EYE_C + EYE_A * c
    b = np.where(s >= 0, EYE_BU, EYE_BL)
    # slightly pointed canthi
    y = b * s * (1.0 - 0.18 * c**2) + EYE_TILT * c
    return np.stack([x, y], axis=-1)


def _upper_lip_y(ax):
    """Upper vermilion border height above the mouth line (cupid's bow)."""
    ax = np.abs(ax)
    r = np.clip(ax / MOUTH_W, 0, 1)
    bow = UL_H + (UL_PEAK - UL_H) * np.sin(np.clip(ax / 0.9, 0, 1) * np.pi / 2) ** 2
    return bow * np.sqrt(np.clip(1 - r**2.2, 0, 1))


def _lower_lip_y(ax):
    r = np.clip(np.abs(ax) / MOUTH_W, 0, 1)
    return -LL_H * np.sqrt(np.clip(1 - r**2.0, 0, 1)) * (1 - 0.1 * r)


_FURROW = np.array([FURROW_TOP, (2.5, -5.5), (2.95, -6.6), (3.3, -7.7), (3.45, -8.6)])


def _smoothstep(e0, e1, x):
    t = np.clip((np.asarray(x, dtype=float) - e0) / (e1 - e0), 0.0, 1.0)
    return t * t * (3 - 2 * t)


def _resample(poly: np.ndarray, spacing: float, *, closed: bool = False) -> np.ndarray:
    """Points at equal arc length along a dense polyline, both ends included."""
    if closed:
        poly = np.vstack([poly, poly[:1]])
    seg = np.linalg.norm(np.diff(poly, axis=0), axis=1)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    n = max(1, int(math.ceil(s[-1] / spacing - 1e-9)))
    target = np.linspace(0.0, s[-1], n + 1)
    out = np.stack([np.interp(target, s, poly[:, 0]), np.interp(target, s, poly[:, 1])], axis=1)
    return out[:-1] if closed else out


def _seg_dist(p: np.ndarray, poly: np.ndarray) -> np.ndarray:
    """Distance of points ``p`` (n, 2) to an open polyline, and the arc parameter in [0, 1]."""
    best = np.full(len(p), np.inf)
    best_s = np.zeros(len(p))
    lengths = np.linalg.norm(np.diff(poly, axis=0), axis=1)
    total = lengths.sum()
    acc = 0.0
    for a, b, ln in zip(poly[:-1], poly[1:], lengths):
        d = b - a
        t = np.clip(((p - a) @ d) / (d @ d), 0, 1)
        dist = np.linalg.norm(p - (a + t[:, None] * d), axis=1)
        better = dist < best
        best[better] = dist[better]
        best_s[better] = (acc + t[better] * ln) / total
        acc += ln
    return best, best_s


# ----------------------------------------------------------------------------------------------
# Topology (depends on the resolution only)
# ----------------------------------------------------------------------------------------------

_FIXED, _RING, _GRID = 0, 1, 2   # point kinds: constraint (never moved/removed), ring, grid


@dataclass
class _Layout:
    P: np.ndarray              # (N, 2) canonical positions (seam duplicates included)
    triangles: np.ndarray
    mirror: np.ndarray
    seam: np.ndarray
    boundary: np.ndarray
    landmarks: dict
    lower: np.ndarray          # (N,) bool: lower-lip copies and vertices below the mouth line
    eye_margin_l: np.ndarray   # vertex indices of the left eye margin, in order


def _outline_half(h: float) -> tuple[np.ndarray, np.ndarray]:
    """Half outline (X >= 0) from the top midline to the chin bottom; and its closed polygon."""
    top = np.array([[0.0, Y_TOP], [float(_hw(Y_TOP)), Y_TOP]])
    ys1 = np.linspace(Y_TOP, Y_JAW_ANGLE, 600)
    ys2 = np.linspace(Y_JAW_ANGLE, Y_BOT, 600)
    side1 = np.stack([_hw(ys1), ys1], axis=1)
    side2 = np.stack([_hw(ys2), ys2], axis=1)
    side2[-1, 0] = 0.0
    pts = np.vstack([
        _resample(top, h),
        _resample(side1, h)[1:],
        _resample(side2, h)[1:],
    ])
    pts[np.abs(pts[:, 0]) < 1e-12, 0] = 0.0
    dense = np.vstack([top, side1[1:], side2[1:]])
    return pts, dense


@functools.lru_cache(maxsize=8)
def _layout(resolution: float) -> _Layout:
    h0 = 0.56 / resolution           # grid spacing away from the features
    e_eye = 0.17 / resolution         # spacing along the eye margin
    e_mouth = 0.16 / resolution       # spacing along the mouth line
    growth = 1.3

    pts: list[np.ndarray] = []
    kinds: list[np.ndarray] = []
    tags: dict[str, object] = {}

    def add(p, kind):
        start = sum(len(q) for q in pts)
        p = np.atleast_2d(np.asarray(p, dtype=float))
        pts.append(p)
        kinds.append(np.full(len(p), kind))
        return np.arange(start, start + len(p))

    # outline ----------------------------------------------------------------------------
    outline, outline_dense = _outline_half(0.9 * h0)
    idx_outline = add(outline, _FIXED)
    domain_half = _MplPath(np.vstack([outline_dense, [[0.0, Y_BOT]]]))

    # eye margin and rings (left eye) ------------------------------------------------------
    tq = [np.linspace(q * np.pi / 2, (q + 1) * np.pi / 2, 400) for q in range(4)]
    margin = np.vstack([_resample(_eye_margin(t), e_eye)[:-1] for t in tq])
    idx_margin = add(margin, _FIXED)
    tags["eye_outer"], tags["eye_centre"] = idx_margin[0], None
    n_q = [len(_resample(_eye_margin(t), e_eye)) - 1 for t in tq]
    tags["eye_centre"] = idx_margin[n_q[0]]
    tags["eye_inner"] = idx_margin[n_q[0] + n_q[1]]
    eye_zone = None
    spacing, d = e_eye, 0.0
    tt = np.linspace(0, 2 * np.pi, 1600, endpoint=False)
    while spacing < 0.95 * h0:
        gap = 0.9 * spacing
        if d + gap > 1.45:
            break
        d += gap
        spacing *= growth
        base = _eye_margin(tt)
        c = np.array([EYE_C, 0.0])
        dirs = base - c
        # offset outward: inflate the ellipse-like margin by d in both axes
        ring = c + dirs * 0.0
        ring[:, 0] = EYE_C + (EYE_A + d) * np.cos(tt)
        bb = np.where(np.sin(tt) >= 0, EYE_BU, EYE_BL) + d
        ring[:, 1] = bb * np.sin(tt) * (1 - 0.18 * np.cos(tt) ** 2 * EYE_A / (EYE_A + d)) \
            + EYE_TILT * np.cos(tt)
        rp = _resample(ring, min(spacing, h0), closed=True)
        rp = rp[rp[:, 0] > 0.25 * h0]
        add(rp, _RING)
        eye_zone = ring
    eye_zone_path = _MplPath(eye_zone) if eye_zone is not None else None

    # mouth seam and rings (X >= 0 half) ---------------------------------------------------
    xs = _resample(np.stack([np.linspace(0, MOUTH_W, 400), np.zeros(400)], 1), e_mouth)[:, 0]
    seam = np.stack([xs, _mouth_y(xs)], axis=1)
    seam[0, 0] = 0.0
    idx_seam = add(seam, _FIXED)
    spacing, d = e_mouth, 0.0
    mouth_zone = None
    while spacing < 0.95 * h0:
        gap = 0.9 * spacing
        if d + gap > 1.5:
            break
        d += gap
        spacing *= growth
        rings = []
        for lo, hi in ((0.0, np.pi / 2), (np.pi / 2, np.pi), (np.pi, 1.5 * np.pi),
                       (1.5 * np.pi, 2 * np.pi)):
            if lo >= np.pi / 2 and hi <= 1.5 * np.pi:
                continue  # X < 0 quarters come from the mirror
            t = np.linspace(lo, hi, 400)
            x = (MOUTH_W + d) * np.cos(t)
            # lower rings a little further apart (lower lip is taller)
            k = 1.0 if lo < np.pi else 1.1
            y = _mouth_y(x) + k * d * np.sin(t)
            q = _resample(np.stack([x, y], 1), min(spacing, h0))
            rings.append(q)
        rp = np.vstack(rings)
        rp[np.abs(rp[:, 0]) < 1e-9, 0] = 0.0
        rp = np.unique(np.round(rp, 12), axis=0)
        add(rp, _RING)
        t = np.linspace(0, 2 * np.pi, 800, endpoint=False)
        x = (MOUTH_W + d) * np.cos(t)
        y = _mouth_y(x) + np.where(np.sin(t) >= 0, 1.0, 1.1) * d * np.sin(t)
        mouth_zone = np.stack([x, y], 1)
    mouth_zone_path = _MplPath(mouth_zone) if mouth_zone is not None else None

    # grid: hex lattice with vertical columns, symmetric about X = 0 -------------------------
    dx = h0 * math.sqrt(3) / 2
    cols = np.arange(0, int(X_EXT / dx) + 2)
    gx, gy = [], []
    for j in cols:
        y = np.arange(Y_BOT - h0, Y_TOP + h0, h0) + (0.5 * h0 if j % 2 else 0.0)
        gx.append(np.full(len(y), j * dx))
        gy.append(y)
    grid = np.stack([np.concatenate(gx), np.concatenate(gy)], 1)
    grid = grid[domain_half.contains_points(grid, radius=-1e-9) | (grid[:, 0] == 0)]
    grid = grid[(grid[:, 1] < Y_TOP - 0.4 * h0) & (grid[:, 1] > Y_BOT + 0.4 * h0)]
    grid = grid[grid[:, 0] <= _hw(grid[:, 1]) - 0.45 * h0]
    special = np.vstack(pts)
    keep = cKDTree(special).query(grid)[0] > 0.7 * h0
    if eye_zone_path is not None:
        keep &= ~eye_zone_path.contains_points(grid)
    if mouth_zone_path is not None:
        keep &= ~mouth_zone_path.contains_points(grid)
    add(grid[keep], _GRID)

    P = np.vstack(pts)
    kind = np.concatenate(kinds)

    # landmarks away from constraints: move the nearest free point onto them ---------------
    free_lm = {
        "brow_inner": (BROW_INNER, float(_brow_y(BROW_INNER))),
        "brow_mid": (BROW_MID, float(_brow_y(BROW_MID))),
        "brow_outer": (BROW_OUTER, float(_brow_y(BROW_OUTER))),
        "furrow_top": FURROW_TOP,
        "chin": (0.0, Y_CHIN),
        "nasion": (0.0, Y_NASION),
        "nose_tip": (0.0, Y_TIP),
        "subnasale": (0.0, Y_SUBNASALE),
        "lip_upper_centre": (0.0, MOUTH_Y + UL_H),
        "lip_lower_centre": (0.0, MOUTH_Y - LL_H),
        "hairline_centre": (0.0, Y_HAIR),
        "hairline": (5.3, float(_hairline_y(5.3))),
        "alar": ALAR,
    }
    lm_half: dict[str, int] = {}
    movable = kind != _FIXED
    for name, q in free_lm.items():
        q = np.asarray(q, dtype=float)
        cand = np.flatnonzero(movable)
        if q[0] == 0.0:
            cand = cand[P[cand, 0] == 0.0] if np.any(P[cand, 0] == 0.0) else cand
        j = cand[np.argmin(np.linalg.norm(P[cand] - q, axis=1))]
        P[j] = q
        kind[j] = _FIXED
        movable[j] = False
        lm_half[name] = int(j)
    # jaw angle: the outline point nearest to the outline at Y_JAW_ANGLE
    oi = idx_outline[np.argmin(np.abs(P[idx_outline, 1] - Y_JAW_ANGLE))]
    lm_half["jaw_angle"] = int(oi)
    lm_half["mouth_corner"] = int(idx_seam[-1])
    lm_half["eye_centre"] = int(tags["eye_centre"])
    lm_half["eye_inner"] = int(tags["eye_inner"])
    lm_half["eye_outer"] = int(tags["eye_outer"])

    # Gabriel filter: keep constraint segments as Delaunay edges ---------------------------
    segs = []
    m = idx_margin
    segs.append(np.stack([m, np.roll(m, -1)], 1))
    segs.append(np.stack([idx_seam[:-1], idx_seam[1:]], 1))
    segs.append(np.stack([idx_outline[:-1], idx_outline[1:]], 1))
    segs = np.vstack(segs)
    mid = 0.5 * (P[segs[:, 0]] + P[segs[:, 1]])
    rad = 0.5 * np.linalg.norm(P[segs[:, 1]] - P[segs[:, 0]], axis=1)
    tree = cKDTree(P)
    drop = np.zeros(len(P), dtype=bool)
    for c, r in zip(mid, rad):
        for j in tree.query_ball_point(c, 1.08 * r):
            if kind[j] != _FIXED:
                drop[j] = True
    # also drop free points that crowd each other (closer than 0.35 of the local spacing)
    keep_idx = np.flatnonzero(~drop)
    remap = np.full(len(P), -1)
    remap[keep_idx] = np.arange(len(keep_idx))
    P, kind = P[keep_idx], kind[keep_idx]
    idx_outline, idx_margin, idx_seam = remap[idx_outline], remap[idx_margin], remap[idx_seam]
    lm_half = {k: int(remap[v]) for k, v in lm_half.items()}
    if (idx_outline < 0).any() or (idx_margin < 0).any() or (idx_seam < 0).any():
        raise RuntimeError("internal error: a constraint point was removed")

    # triangulate the half ---------------------------------------------------------------------
    dl = Delaunay(P)
    if len(dl.coplanar):
        raise RuntimeError("internal error: degenerate point set in the face triangulation")
    tri = dl.simplices.astype(np.int64)
    cen = P[tri].mean(axis=1)
    inside = domain_half.contains_points(cen)
    eye_path = _MplPath(P[idx_margin])
    inside &= ~eye_path.contains_points(cen)
    a = P[tri[:, 1]] - P[tri[:, 0]]
    b = P[tri[:, 2]] - P[tri[:, 0]]
    area = 0.5 * (a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0])
    inside &= np.abs(area) > 1e-10
    tri, area = tri[inside], area[inside]
    tri[area < 0] = tri[area < 0][:, [0, 2, 1]]
    used = np.zeros(len(P), dtype=bool)
    used[tri.ravel()] = True
    if not used.all():
        # isolated points (inside a removed region): drop them
        keep_idx = np.flatnonzero(used)
        remap = np.full(len(P), -1)
        remap[keep_idx] = np.arange(len(keep_idx))
        P, kind = P[keep_idx], kind[keep_idx]
        tri = remap[tri]
        idx_outline, idx_margin, idx_seam = (remap[idx_outline], remap[idx_margin],
                                             remap[idx_seam])
        lm_half = {k: int(remap[v]) for k, v in lm_half.items()}

    # mirror -------------------------------------------------------------------------------------
    n_h = len(P)
    on_mid = P[:, 0] == 0.0
    off = np.flatnonzero(~on_mid)
    mirror = np.arange(n_h + len(off))
    mirror[off] = n_h + np.arange(len(off))
    mirror[n_h:] = off
    Pm = P[off] * np.array([-1.0, 1.0])
    Pf = np.vstack([P, Pm])
    tri_m = mirror[tri][:, [0, 2, 1]]
    T = np.vstack([tri, tri_m])

    # split the mouth seam -------------------------------------------------------------------
    seam_half = idx_seam[:-1]                      # exclude the corner
    seam_all = np.unique(np.concatenate([seam_half, mirror[seam_half]]))
    n_f = len(Pf)
    dup = np.full(n_f, -1)
    dup[seam_all] = n_f + np.arange(len(seam_all))
    cen = Pf[T].mean(axis=1)
    below = (cen[:, 1] < _mouth_y(cen[:, 0])) & (np.abs(cen[:, 0]) < MOUTH_W + 1.0)
    Tl = T[below]
    repl = dup[Tl] >= 0
    Tl[repl] = dup[Tl[repl]]
    T[below] = Tl
    Pf = np.vstack([Pf, Pf[seam_all]])
    mirror = np.concatenate([mirror, dup[mirror[seam_all]]])
    seam_pairs = np.stack([seam_all, dup[seam_all]], 1)
    order = np.argsort(Pf[seam_pairs[:, 0], 0], kind="stable")
    seam_pairs = seam_pairs[order]
    lower = np.zeros(len(Pf), dtype=bool)
    lower[n_f:] = True

    boundary = np.zeros(len(Pf), dtype=bool)
    boundary[idx_outline] = True
    boundary[mirror[idx_outline]] = True

    landmarks: dict[str, int] = {}
    for name, j in lm_half.items():
        if name in ("brow_inner", "brow_mid", "brow_outer", "furrow_top", "hairline",
                    "jaw_angle", "mouth_corner", "eye_centre", "eye_inner", "eye_outer",
                    "alar"):
            landmarks[name + "_l"] = int(j)
            landmarks[name + "_r"] = int(mirror[j])
        else:
            landmarks[name] = int(j)
    landmarks = {name: landmarks[name] for name in LANDMARK_NAMES}

    return _Layout(
        P=Pf, triangles=T.astype(np.int32), mirror=mirror.astype(np.int64),
        seam=seam_pairs.astype(np.int64), boundary=boundary, landmarks=landmarks,
        lower=lower, eye_margin_l=idx_margin.astype(np.int64),
    )


# ----------------------------------------------------------------------------------------------
# Regions, weights, thickness (canonical)
# ----------------------------------------------------------------------------------------------


def _regions(P: np.ndarray, lower: np.ndarray) -> np.ndarray:
    X, Y = P[:, 0], P[:, 1]
    ax = np.abs(X)
    r = np.full(len(P), int(Region.CHEEK), dtype=np.int8)
    ym = _mouth_y(ax)
    furrow_d, _ = _seg_dist(np.stack([ax, Y], 1), _FURROW)
    # furrow side: points medial to the furrow (inside the muzzle)
    fx = np.interp(-Y, -_FURROW[:, 1], _FURROW[:, 0])
    medial = ax < fx
    r[(Y < -4.5) & (ax > 4.5)] = Region.JAW
    r[(Y < -6.5) & (ax > 3.6)] = Region.JAW
    r[(Y > 0.8) & (ax > 5.2)] = Region.TEMPLE
    r[Y > 2.6] = Region.FOREHEAD
    eye_e = ((ax - EYE_C) / 2.3) ** 2 + ((Y - 0.1) / 1.35) ** 2
    r[eye_e < 1.0] = Region.EYELID
    brow_band = (np.abs(Y - _brow_y(ax)) < 0.55) & (ax < 5.6)
    glabella = (ax < 1.2) & (Y > 0.9) & (Y < 2.4)
    r[brow_band | glabella] = Region.BROW
    nose_half = np.interp(Y, [Y_SUBNASALE - 0.1, -5.0, Y_TIP, -2.0, Y_NASION, 1.0],
                          [0.9, 1.9, 1.3, 0.8, 0.7, 0.0])
    r[(Y >= Y_SUBNASALE - 0.1) & (Y <= 1.0) & (ax < nose_half)] = Region.NOSE
    r[(furrow_d < 0.45) & (Y < -4.2) & (Y > -9.0)] = Region.NASOLABIAL
    lip_up = (ym <= Y) & (Y < Y_SUBNASALE - 0.1) & medial & ~lower
    lip_lo = ((ym > Y) | lower) & (Y > Y_SULCUS) & (ax < MOUTH_W + 0.9)
    lip_up |= (ym - 1e-9 <= Y) & (ax <= MOUTH_W + 1e-9) & (ym + 0.4 > Y) & ~lower
    r[lip_lo & ~(furrow_d < 0.45)] = Region.LOWER_LIP
    r[lip_up] = Region.UPPER_LIP
    r[lower] = Region.LOWER_LIP
    r[(Y <= Y_SULCUS) & (ax < 3.4)] = Region.CHIN
    r[_hairline_y(ax) < Y] = Region.SCALP
    return r


def _jaw_weight(P: np.ndarray, lower: np.ndarray) -> np.ndarray:
    X, Y = P[:, 0], P[:, 1]
    ax = np.abs(X)
    # jaw boundary: the mouth line, rising from the corners to the jaw angle region
    yj = np.where(ax <= MOUTH_W, _mouth_y(ax),
                  _mouth_y(MOUTH_W) + 2.2 * _smoothstep(MOUTH_W, 7.5, ax))
    w = _smoothstep(-0.9, 0.9, yj - Y)
    # lips: the lower lip rides on the mandible, the upper lip on the maxilla; both halves
    # meet at 0.5 in the corners (the shared commissure vertices)
    ramp = 0.5 + 0.5 * np.clip((MOUTH_W - ax) / 0.6, 0.0, 1.0)
    on_or_below = lower | (_mouth_y(ax) - 1e-9 > Y)
    w = np.where(on_or_below & (ax <= MOUTH_W), np.maximum(w, ramp), w)
    above = ~lower & (_mouth_y(ax) - 1e-9 <= Y) & (ax <= MOUTH_W)
    w = np.where(above, np.minimum(w, 1.0 - ramp), w)
    return np.clip(w, 0.0, 1.0)


def _gauss(ax, Y, cx, cy, sx, sy):
    return np.exp(-(((ax - cx) / sx) ** 2) - ((Y - cy) / sy) ** 2)


def _thickness(P: np.ndarray, shape: FaceShape) -> np.ndarray:
    X, Y = P[:, 0], P[:, 1]
    ax = np.abs(X)
    t = np.full(len(P), 0.9)
    t -= 0.4 * _smoothstep(1.5, 3.5, Y)                                   # forehead/scalp 0.5
    t -= 0.55 * _gauss(ax, Y, EYE_C, 0.0, 1.8, 0.9)                       # eyelids ~0.35
    t += 0.75 * shape.cheek_fullness * _gauss(ax, Y, 3.8, -3.6, 1.8, 1.8)  # cheeks ~1.6
    t -= 0.55 * np.exp(-((ax / 0.9) ** 2)) * _smoothstep(-4.2, -2.5, Y) * (Y < 1.2)  # bridge
    t += 0.35 * _gauss(ax, Y, 0.0, MOUTH_Y, 2.6, 1.3)                    # lips ~1.2
    t += 0.15 * _gauss(ax, Y, 0.0, Y_CHIN, 1.8, 1.0)
    t += 0.25 * _gauss(ax, Y, 5.5, -7.0, 1.8, 2.0)                        # masseter
    return np.clip(t, 0.2, 2.5)


# ----------------------------------------------------------------------------------------------
# Geometry (depends on the shape)
# ----------------------------------------------------------------------------------------------


def _warp(P: np.ndarray, s: FaceShape) -> tuple[np.ndarray, np.ndarray]:
    """In-plane identity warp of canonical points; returns (Xs, Ys)."""
    X, Y = P[:, 0], P[:, 1]
    ax, sg = np.abs(X), np.sign(X)
    fl = s.face_length
    # vertical: monotone map through feature levels
    knots = np.array([Y_BOT, Y_CHIN, MOUTH_Y, Y_SUBNASALE, Y_TIP, 0.0, 2.1, Y_HAIR, Y_TOP])
    lengths = np.diff(knots)
    scale = np.array([
        s.chin_height * fl, s.chin_height * fl, fl, s.nose_length, s.nose_length * fl,
        s.brow_height, s.forehead_height * fl, s.forehead_height * fl,
    ])
    new = np.concatenate([[0.0], np.cumsum(lengths * scale)])
    new -= new[5]  # eye line stays at 0
    Ys = PchipInterpolator(knots, new, extrapolate=True)(Y)
    # lip heights: stretch the vermilion band around the mouth line
    ym = _mouth_y(ax)
    lat = np.exp(-((ax / (MOUTH_W + 0.6)) ** 4))
    up = np.clip((Y - ym) / UL_PEAK, 0, None)
    lo = np.clip((ym - Y) / LL_H, 0, None)
    Ys += (s.upper_lip_thickness - 1) * UL_PEAK * lat * up * np.exp(-np.maximum(up - 1, 0) ** 2 * 2)
    Ys -= (s.lower_lip_thickness - 1) * LL_H * lat * lo * np.exp(-np.maximum(lo - 1, 0) ** 2 * 2)
    # horizontal
    Xs = ax.copy()
    we = _gauss(ax, Y, EYE_C, 0.0, 2.4, 1.7)
    Xs += we * ((s.eye_spacing - 1) * EYE_C + (s.eye_size - 1) * (ax - EYE_C))
    Ys += we * (s.eye_size - 1) * Y
    wn = np.exp(-((ax / 2.6) ** 2)) * _gauss(0, Y, 0, -4.8, 1, 1.6)
    Xs += wn * (s.nose_width - 1) * ax
    wm = np.exp(-(((Y - MOUTH_Y) / 1.7) ** 2)) * np.exp(-((ax / 4.0) ** 4))
    Xs += wm * (s.mouth_width - 1) * ax
    wj = _smoothstep(-3.5, -9.5, Y)
    Xs *= 1 + (s.jaw_width - 1) * wj
    Xs *= s.face_width
    return sg * Xs, Ys


def _height(P: np.ndarray, s: FaceShape) -> np.ndarray:
    """Relief above the base cylinder, evaluated in canonical coordinates."""
    X, Y = P[:, 0], P[:, 1]
    ax = np.abs(X)
    h = np.zeros(len(P))
    # eye sockets with the lids over the eyeball
    h -= 1.15 * _gauss(ax, Y, EYE_C, 0.15, 2.0, 1.45)
    h += 0.75 * _gauss(ax, Y, EYE_C, -0.05, 1.4, 0.85)
    # upper-lid crease and lower-lid (tear trough) hint
    h -= 0.12 * _gauss(ax, Y, EYE_C, 0.95, 1.3, 0.18)
    # brow ridge and glabella
    win = _smoothstep(0.3, 1.4, ax) * (1 - _smoothstep(4.8, 6.4, ax))
    h += s.brow_prominence * 0.8 * np.exp(-(((Y - _brow_y(ax) + 0.15) / 0.85) ** 2)) * win
    h += s.brow_prominence * 0.3 * _gauss(ax, Y, 0.0, 1.45, 1.2, 0.9)
    # frontal bosses, temples, forehead recession
    h += 0.2 * _gauss(ax, Y, 2.4, 4.6, 1.8, 1.8)
    h -= 0.45 * _gauss(ax, Y, 6.4, 2.8, 1.3, 1.8)
    h -= 0.05 * np.maximum(Y - 2.0, 0.0) ** 2
    # nose: dorsum profile and width along Y
    ny = np.array([Y_SUBNASALE - 0.4, Y_SUBNASALE, -5.2, Y_TIP, -4.1, -3.0, -1.0, Y_NASION, 1.3])
    np_ = np.array([0.0, 0.55, 1.55, 2.2, 2.15, 1.6, 0.85, 0.35, 0.0])
    nw = np.array([0.7, 0.75, 0.75, 0.85, 0.8, 0.62, 0.52, 0.62, 0.8])
    prof = PchipInterpolator(ny, np_, extrapolate=False)(Y)
    prof = np.nan_to_num(prof)
    wid = np.interp(Y, ny, nw)
    h += s.nose_protrusion * prof * np.exp(-((ax / wid) ** 2))
    # alar wings and nostril hint
    h += s.nose_protrusion * 0.85 * _gauss(ax, Y, ALAR[0] - 0.2, ALAR[1], 0.55, 0.5)
    h -= 0.25 * _gauss(ax, Y, 0.62, -5.5, 0.25, 0.15)
    # cheekbones and cheeks
    h += 0.55 * _gauss(ax, Y, 4.6, -1.8, 1.4, 0.95)
    h += s.cheek_fullness * 0.85 * _gauss(ax, Y, 3.7, -3.7, 1.9, 1.7)
    # nasolabial fold: a crease along the furrow, fading at both ends
    fd, fs = _seg_dist(np.stack([ax, Y], 1), _FURROW)
    h -= 0.24 * np.exp(-((fd / 0.38) ** 2)) * np.sin(np.pi * np.clip(fs * 0.9 + 0.1, 0, 1)) ** 0.5
    # muzzle (the dental arch under the lips)
    h += 1.05 * _gauss(ax, Y, 0.0, -7.1, 3.0, 2.3)
    # philtrum
    band = _smoothstep(Y_SUBNASALE, Y_SUBNASALE - 0.3, Y) * _smoothstep(
        MOUTH_Y + UL_H - 0.1, MOUTH_Y + UL_H + 0.2, Y)
    h -= 0.09 * np.exp(-((ax / 0.28) ** 2)) * band
    # lips
    ym = _mouth_y(ax)
    # lip volumes follow the vermilion outlines and vanish smoothly at the corners
    hu = np.maximum(_upper_lip_y(ax), 0.08)
    hl = np.maximum(-_lower_lip_y(ax), 0.08)
    r = np.clip(ax / MOUTH_W, 0.0, 1.0)
    taper = (1 - r**2) ** 1.5 * (ax < MOUTH_W)
    qu = (Y - ym) / hu
    ql = (ym - Y) / hl
    h += (s.upper_lip_thickness * 0.5 * taper * np.exp(-(((qu - 0.5) / 0.55) ** 2))
          * _smoothstep(-0.7, 0.0, qu))
    h += (s.lower_lip_thickness * 0.58 * taper * np.exp(-(((ql - 0.5) / 0.6) ** 2))
          * _smoothstep(-0.7, 0.0, ql))
    # the lips roll inward towards the seam
    h -= 0.1 * taper * np.exp(-(((Y - ym) / 0.14) ** 2))
    # mentolabial sulcus and chin boss
    h -= 0.32 * _gauss(ax, Y, 0.0, Y_SULCUS, 1.9, 0.45)
    h += 0.7 * _gauss(ax, Y, 0.0, Y_CHIN, 1.6, 1.0)
    # lower face recedes; jaw sides recede further
    h -= 0.035 * np.maximum(-7.0 - Y, 0.0) ** 2
    h -= 0.8 * _smoothstep(-4.0, -11.0, Y) * (ax / 7.0) ** 2
    return h


def _embed(P: np.ndarray, s: FaceShape) -> np.ndarray:
    """3-D positions of canonical points for identity ``s`` (before the origin shift)."""
    Xs, Ys = _warp(P, s)
    h = _height(P, s)
    R = 8.2 * s.face_width * (1 - 0.14 * _smoothstep(-3.0, -12.0, Ys / s.face_length))
    R = R * (1 + (s.jaw_width - 1) * _smoothstep(-3.5, -9.5, P[:, 1]))
    depth = 1.25
    th = Xs / R
    x = R * np.sin(th)
    z = -depth * R * (1 - np.cos(th))
    # normal of the elliptic cylinder x = R sin th, z = -k R (1 - cos th)
    nx, nz = depth * np.sin(th), np.cos(th)
    nn = np.hypot(nx, nz)
    x += h * nx / nn
    z += h * nz / nn
    return np.stack([x, Ys, z], axis=1)


EYE_APEX_LIFT = 0.8    # lids over the cornea in front of the socket surface (cm)
EYE_LID = 0.08         # lid skin in front of the eyeball (cm)
EYE_CAP = 0.92         # lid margins lie within this fraction of the eyeball radius
EYE_BLEND = 0.6        # softness of the lid crease where the lids leave the eyeball (cm)


def _smooth_max(a, b, k):
    """Polynomial smooth maximum: equals max(a, b) where |a - b| >= k."""
    h = np.clip(0.5 + 0.5 * (b - a) / k, 0.0, 1.0)
    return a * (1 - h) + b * h + k * h * (1 - h) * 0.5


def _fit_eyes(v: np.ndarray, P: np.ndarray, margin_l: np.ndarray,
              s: FaceShape) -> tuple[np.ndarray, float]:
    """Push the left eye's lids out over an eyeball (in place); returns (centre, radius).

    The eyeball is a sphere whose front pole (the pupil) looks along +z from the middle of
    the palpebral fissure, ``EYE_APEX_LIFT`` in front of the socket surface, with a radius such
    that the lid margins lie within ``EYE_CAP`` of it.  The skin is the smooth maximum of the
    socket surface and the sphere pushed out by ``EYE_LID``: lids hug the globe near the
    opening and the upper-lid crease forms where they leave it.  Every margin vertex is
    therefore at least ``EYE_LID`` in front of the eyeball.
    """
    centre = _embed(np.array([[EYE_C, 0.0]]), s)[0]
    m = v[margin_l]
    cx = 0.5 * (m[:, 0].min() + m[:, 0].max())
    cy = centre[1]
    z_apex = centre[2] + EYE_APEX_LIFT
    R = float(np.hypot(m[:, 0] - cx, m[:, 1] - cy).max() / EYE_CAP)
    cz = z_apex - R
    left = P[:, 0] > 0
    rho2 = (v[left, 0] - cx) ** 2 + (v[left, 1] - cy) ** 2
    # the osculating paraboloid of the sphere: never behind it, and without the sphere's
    # vertical rim, so the lids leave the globe in a smooth crease
    zs = z_apex - rho2 / (2.0 * R)
    v[left, 2] = _smooth_max(v[left, 2], zs, EYE_BLEND)
    return np.array([cx, cy, cz - EYE_LID]), R


# ----------------------------------------------------------------------------------------------
# Inner parts
# ----------------------------------------------------------------------------------------------


def _sphere(centre, radius, n_lat, n_lon):
    """UV sphere with poles on the z axis (front pole first); outward triangles."""
    alphas = np.linspace(0, np.pi, n_lat + 1)[1:-1]
    phis = np.linspace(0, 2 * np.pi, n_lon, endpoint=False)
    A, F = np.meshgrid(alphas, phis, indexing="ij")
    d = np.stack([np.sin(A) * np.cos(F), np.sin(A) * np.sin(F), np.cos(A)], -1).reshape(-1, 3)
    d = np.vstack([[0, 0, 1.0], d, [0, 0, -1.0]])
    tris = []
    nr = len(alphas)
    ring = lambda i, j: 1 + i * n_lon + (j % n_lon)  # noqa: E731
    for j in range(n_lon):
        tris.append((0, ring(0, j), ring(0, j + 1)))
        tris.append((len(d) - 1, ring(nr - 1, j + 1), ring(nr - 1, j)))
    for i in range(nr - 1):
        for j in range(n_lon):
            a, b = ring(i, j), ring(i, j + 1)
            c, e = ring(i + 1, j), ring(i + 1, j + 1)
            tris.append((a, c, b))
            tris.append((b, c, e))
    tris = np.array(tris)
    v = np.asarray(centre) + radius * d
    # make sure triangles face outward
    fn = np.cross(v[tris[:, 1]] - v[tris[:, 0]], v[tris[:, 2]] - v[tris[:, 0]])
    flip = np.einsum("ij,ij->i", fn, v[tris].mean(1) - centre) < 0
    tris[flip] = tris[flip][:, [0, 2, 1]]
    rxy = np.linalg.norm(d[:, :2], axis=1)
    front = d[:, 2] >= 0
    uv = np.where(front[:, None], 0.5 + 0.5 * d[:, :2] * [1, -1],
                  0.5 + 0.5 * d[:, :2] * [1, -1] / np.maximum(rxy, 1e-12)[:, None])
    uv[-1] = (0.5, 1.0)
    return v, tris, uv


def _grid_surface(fn, nu, nv):
    """Regular (nv, nu) grid surface from ``fn(s, t) -> (n, 3)``; triangles face +z."""
    s = np.linspace(-1, 1, nu)
    t = np.linspace(-1, 1, nv)
    S, T = np.meshgrid(s, t)
    v = fn(S.ravel(), T.ravel())
    idx = np.arange(nu * nv).reshape(nv, nu)
    a, b, c, d = idx[:-1, :-1], idx[:-1, 1:], idx[1:, :-1], idx[1:, 1:]
    tris = np.vstack([np.stack([a, b, d], -1).reshape(-1, 3),
                      np.stack([a, d, c], -1).reshape(-1, 3)])
    fn_ = np.cross(v[tris[:, 1]] - v[tris[:, 0]], v[tris[:, 2]] - v[tris[:, 0]])
    flip = fn_[:, 2] < 0
    tris[flip] = tris[flip][:, [0, 2, 1]]
    uv = np.stack([(S.ravel() + 1) / 2, (1 - T.ravel()) / 2], 1)
    return v, tris, uv, T.ravel()


def _inner_parts(s: FaceShape, resolution: float, shift: np.ndarray, centre_l: np.ndarray,
                 r: float):
    parts_v, parts_t, parts_m, parts_uv, parts_w = [], [], [], [], []

    def push(v, t, material, uv, w):
        off = sum(len(p) for p in parts_v)
        parts_v.append(v)
        parts_t.append(t + off)
        parts_m.append(np.full(len(t), material, dtype=np.int8))
        parts_uv.append(uv)
        parts_w.append(w)

    centre_r = centre_l * [-1, 1, 1]
    n_lat = int(max(10, round(14 * math.sqrt(resolution))))
    n_lon = int(max(16, round(24 * math.sqrt(resolution))))
    for c in (centre_l, centre_r):
        v, t, uv = _sphere(c, r, n_lat, n_lon)
        push(v, t, INNER_EYE, uv, np.zeros(len(v)))

    nu = int(max(9, round(13 * math.sqrt(resolution)))) | 1
    nv = int(max(7, round(9 * math.sqrt(resolution)))) | 1

    # mouth cavity: a bowl behind the lips; rim 1.1 cm under the skin, 3 cm deep
    def cavity(S, T):
        can = np.stack([S * (MOUTH_W + 0.9), MOUTH_Y + np.where(T > 0, 1.7, 2.1) * T], 1)
        p = _embed(can, s) - shift
        p[:, 2] -= 1.1 + 3.0 * (1 - S**2) * (1 - T**2)
        return p

    v, t, uv, T = _grid_surface(cavity, nu, nv)
    w = np.where(T < 0, 1.0, np.where(T > 0, 0.0, 0.5))
    push(v, t, INNER_MOUTH, uv, w)

    # teeth: an upper and a lower strip behind the lips
    for upper in (True, False):
        def strip(S, T, upper=upper):
            y0, y1 = (MOUTH_Y + 0.95, MOUTH_Y - 0.12) if upper else (MOUTH_Y + 0.05, MOUTH_Y - 0.9)
            can = np.stack([S * (MOUTH_W - 0.2), y0 + (T + 1) / 2 * (y1 - y0)], 1)
            p = _embed(can, s) - shift
            p[:, 2] -= (0.85 if upper else 0.95) + 1.2 * S**2
            return p

        v, t, uv, _ = _grid_surface(strip, nu, 3)
        push(v, t, INNER_TEETH, uv, np.full(len(v), 0.0 if upper else 1.0))

    return (np.vstack(parts_v), np.vstack(parts_t).astype(np.int32), np.concatenate(parts_m),
            np.vstack(parts_uv), np.concatenate(parts_w), np.stack([centre_l, centre_r]), r)


# ----------------------------------------------------------------------------------------------
# Feature curves (canonical, uv)
# ----------------------------------------------------------------------------------------------


def _to_uv(p: np.ndarray) -> np.ndarray:
    p = np.asarray(p, dtype=float)
    return np.stack([(p[:, 0] + X_EXT) / (2 * X_EXT), (Y_TOP - p[:, 1]) / (Y_TOP - Y_BOT)], 1)


@functools.lru_cache(maxsize=1)
def _feature_curves() -> dict[str, np.ndarray]:
    out = {}
    x = np.linspace(-7.0, 7.0, 57)
    xh = x[_hairline_y(np.abs(x)) > _hairline_y(7.0) - 1e-9]
    out["hairline"] = np.stack([xh, _hairline_y(np.abs(xh))], 1)
    xb = np.linspace(BROW_INNER, BROW_OUTER, 21)
    out["brow_l"] = np.stack([xb, _brow_y(xb)], 1)
    out["furrow_l"] = _resample(_FURROW, 0.2)
    t = np.linspace(0, 2 * np.pi, 25)
    out["nostril_l"] = np.stack([0.62 + 0.3 * np.cos(t), -5.5 + 0.15 * np.sin(t)], 1)
    xm = np.linspace(-MOUTH_W, MOUTH_W, 41)
    upper_top = np.stack([xm, _mouth_y(xm) + _upper_lip_y(xm)], 1)
    out["upper_lip"] = np.vstack([upper_top, np.stack([xm, _mouth_y(xm)], 1)[::-1][1:]])
    lower_bot = np.stack([xm, _mouth_y(xm) + _lower_lip_y(xm)], 1)
    out["lower_lip"] = np.vstack([np.stack([xm, _mouth_y(xm)], 1), lower_bot[::-1][1:]])
    out["mouth_line"] = np.stack([xm, _mouth_y(xm)], 1)
    tc = np.linspace(0, 2 * np.pi, 33)
    out["chin_boss"] = np.stack([1.5 * np.cos(tc), Y_CHIN + 0.8 * np.sin(tc)], 1)
    te = np.linspace(0, 2 * np.pi, 49)
    out["eye_l"] = _eye_margin(te)
    mirror = np.array([-1.0, 1.0])
    for name in ("brow", "furrow", "nostril", "eye"):
        out[f"{name}_r"] = out[f"{name}_l"] * mirror
    res = {}
    for name in FEATURE_CURVE_NAMES:
        res[name] = _readonly(_to_uv(out[name]))
    return res


# ----------------------------------------------------------------------------------------------
# Public entry point
# ----------------------------------------------------------------------------------------------


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


def _check_resolution(resolution) -> float:
    if isinstance(resolution, bool):
        raise ValueError(f"resolution must be a number, got {resolution!r}")
    try:
        r = float(resolution)
    except (TypeError, ValueError):
        raise ValueError(
            f"resolution must be a number in (0, {MAX_RESOLUTION}], got {resolution!r}"
        ) from None
    if not (math.isfinite(r) and 0.2 <= r <= MAX_RESOLUTION):
        raise ValueError(
            f"resolution must be in [0.2, {MAX_RESOLUTION}] (1.0 = default, ~1,500 vertices), "
            f"got {resolution!r}"
        )
    return r


@functools.lru_cache(maxsize=16)
def _generate(shape: FaceShape, resolution: float) -> FaceMesh:
    lay = _layout(resolution)
    P = lay.P
    v = _embed(P, shape)
    eye_c, eye_r = _fit_eyes(v, P, lay.eye_margin_l, shape)
    # origin: midpoint between the pupils (front poles of the eyeballs)
    shift = np.array([0.0, eye_c[1], eye_c[2] + eye_r])
    v -= shift
    eye_c = eye_c - shift
    # exact mirror symmetry (floating-point safety): right side copies the left side
    m = lay.mirror
    left = P[:, 0] > 0
    v[m[left]] = v[left] * np.array([-1.0, 1.0, 1.0])
    v[P[:, 0] == 0.0, 0] = 0.0
    # seam duplicates coincide exactly
    v[lay.seam[:, 1]] = v[lay.seam[:, 0]]

    region = _regions(P, lay.lower)
    thick = _thickness(P, shape)
    jw = _jaw_weight(P, lay.lower)
    # temporomandibular joint: below the eye line, ~8 cm behind the eye centres
    pivot = np.array([0.0, -2.6 * shape.face_length, -8.2 * shape.face_width])
    iv, it, im, iuv, iw, eyes, er = _inner_parts(shape, resolution, shift, eye_c, eye_r)
    uv = _to_uv(P)
    return FaceMesh(
        vertices=_readonly(v),
        triangles=_readonly(lay.triangles),
        uv=_readonly(np.clip(uv, 0.0, 1.0)),
        region=_readonly(region.astype(np.int8)),
        landmarks=dict(lay.landmarks),
        tissue_thickness=_readonly(thick),
        jaw_weight=_readonly(jw),
        jaw_pivot=_readonly(pivot),
        boundary=_readonly(lay.boundary),
        mouth_seam=_readonly(lay.seam),
        feature_curves=dict(_feature_curves()),
        inner_vertices=_readonly(iv),
        inner_triangles=_readonly(it),
        inner_material=_readonly(im),
        inner_uv=_readonly(iuv),
        inner_jaw_weight=_readonly(iw),
        eyeball_centres=_readonly(eyes),
        eyeball_radius=float(er),
        mirror_map=_readonly(lay.mirror),
        resolution=resolution,
    )


def generate_face_mesh(shape: FaceShape | dict | None = None, *,
                       resolution: float = 1.0) -> FaceMesh:
    """Generate the generic face mesh for an identity.

    Parameters
    ----------
    shape : FaceShape or dict, optional
        Identity; ``None`` is the default (mirror-symmetric) face.  A dict is passed to
        :class:`FaceShape` (unknown names raise ``ValueError``).
    resolution : float, optional
        Mesh density in [0.2, 8]; the vertex count grows roughly as ``resolution**2``
        (about 1,500 skin vertices at 1.0).

    Returns
    -------
    FaceMesh
        Read-only mesh; identical inputs return the same (cached) object.

    Examples
    --------
    >>> mesh = generate_face_mesh()
    >>> mesh.n_vertices >= 1000
    True
    >>> bool(mesh.vertices[mesh.landmarks["brow_mid_l"], 1] > 0)
    True
    """
    s = _as_shape(shape)
    r = _check_resolution(resolution)
    return _generate(s, r)
