"""Facial muscles as editable data, and the nodal forces they exert on the tissue lattice.

The muscle file (``synth/data/muscles.toml``; TOML or JSON with the same structure) lists
every muscle with its geometry in the mesh's **canonical uv coordinates** (identical for every
:class:`~synth.face_shape.FaceShape` at a given resolution, so one file serves every identity):
points are located on the rest skin surface by their uv, lifted to 3-D and pushed inward to a
depth given as a fraction of the local tissue thickness (``1`` = on the bone, the fascia depth
of the lattice by default).  Geometry is written for the subject's LEFT side; ``sides = ["l",
"r"]`` adds the mirror image ``u -> 1 - u`` as ``<name>_r``.

Muscle types
------------
``linear`` (004 eqs. 5-6; Waters 002; 003 eqs. 6-13)
    A bundle from a bony ``head`` (origin) to a skin ``tail`` (insertion).  Fascia node ``x``
    at distance ``D`` from the head and angle ``mu`` off the muscle axis is pulled toward
    the head with weight ``A(mu) R(D)``: angular fall-off ``A = cos(mu / zone_angle * pi/2)``
    and Waters' radial fall-off ``R = cos((1 - D / Rs) pi/2)`` for ``D <= Rs``,
    ``cos((D - Rs) / (Rf - Rs) pi/2)`` for ``Rs < D <= Rf`` (``fall_start`` ``Rs`` and
    ``fall_finish`` ``Rf`` are fractions of the muscle length).  With ``falloff = "radial"``
    the weight is instead the cosine radial zone of 004 eq. 6, ``cos(|tail - x| / r pi/2)``,
    ``r = radius`` times the muscle length.
``sphincter`` (002; 003 eqs. 14-17)
    An ellipse (``centre``, ``semi_axes`` in uv, optional ``angle`` in degrees) whose nodes are
    drawn toward the centre with ``cos((1 - d) pi/2)``, ``d`` the elliptical radius
    (``d <= 1``), falling off outside the ellipse to zero at ``d = outer``.
``sheet`` (003 eqs. 18-22)
    Parallel fibres from an ``attachment`` line (two uv points) to an ``insertion`` line; nodes
    are pulled along the common fibre direction with ``cos((1 - lambda**eta) pi/2)``,
    ``lambda`` the distance from the attachment line over the sheet length, falling off past
    the insertion to zero at ``lambda = outer`` and across the sheet's lateral edges.

Forces are evaluated in the rest configuration (as the blend functions of 004 are) and
applied to the fascia nodes, tangentially to the skull.  A muscle's ``force`` is its total
pull at full contraction (model units, kPa·cm² = 0.1 N), distributed over the nodes in
proportion to weight times nodal area, so it does not depend on the mesh resolution.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import numpy as np

__all__ = [
    "Muscle",
    "MuscleSet",
    "load_muscles",
    "default_muscle_file",
    "muscle_force_basis",
    "uv_to_surface",
]

MUSCLE_TYPES = ("linear", "sphincter", "sheet")
_COMMON_KEYS = {"name", "type", "sides", "force", "depth", "description"}
_TYPE_KEYS = {
    "linear": ({"head", "tail"}, {"head_depth", "zone_angle", "fall_start", "fall_finish",
                                  "falloff", "radius"}),
    "sphincter": ({"centre", "semi_axes"}, {"angle", "outer"}),
    "sheet": ({"attachment", "insertion"}, {"eta", "outer", "edge"}),
}
_DEFAULTS = {
    "head_depth": 1.0, "zone_angle": 30.0, "fall_start": 1.0, "fall_finish": 1.4,
    "falloff": "waters", "radius": 0.6, "angle": 0.0, "outer": 1.35, "eta": 1.0, "edge": 0.25,
}


@dataclass(frozen=True)
class Muscle:
    """One muscle (one side).  ``params`` holds the type-specific values, uv points as tuples."""

    name: str
    type: str
    force: float
    depth: float | None
    params: dict

    def mirrored(self, name: str) -> Muscle:
        """The mirror image ``u -> 1 - u`` under a new name."""
        p = dict(self.params)
        for key in ("head", "tail", "centre"):
            if key in p:
                p[key] = (1.0 - p[key][0], p[key][1])
        for key in ("attachment", "insertion"):
            if key in p:
                p[key] = tuple((1.0 - u, v) for u, v in p[key])
        if "angle" in p:
            p["angle"] = -p["angle"]
        return Muscle(name, self.type, self.force, self.depth, p)


@dataclass(frozen=True)
class MuscleSet:
    """An ordered, immutable collection of muscles (``names`` in file order)."""

    muscles: tuple[Muscle, ...]
    source: str = "<memory>"

    @property
    def names(self) -> tuple[str, ...]:
        """Muscle names in order."""
        return tuple(m.name for m in self.muscles)

    def __len__(self) -> int:
        return len(self.muscles)

    def __getitem__(self, name: str) -> Muscle:
        for m in self.muscles:
            if m.name == name:
                return m
        raise KeyError(name)


def default_muscle_file() -> Path:
    """Path of the muscle file shipped with the package."""
    return Path(str(resources.files("synth").joinpath("data/muscles.toml")))


def _load_toml(text: str, source: str) -> dict:
    try:
        import tomllib
    except ModuleNotFoundError:  # Python 3.10
        try:
            import tomli as tomllib  # type: ignore[no-redef]
        except ModuleNotFoundError as exc:
            raise ImportError(f"reading {source} needs Python >= 3.11 or the 'tomli' "
                              "package; or give the muscle file as JSON") from exc
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ValueError(f"{source}: not valid TOML: {exc}") from exc


def _uv(value, where: str) -> tuple[float, float]:
    try:
        u, v = (float(c) for c in value)
    except (TypeError, ValueError):
        raise ValueError(f"{where} must be a [u, v] pair of numbers, got {value!r}") from None
    if not (np.isfinite(u) and np.isfinite(v)):
        raise ValueError(f"{where} must be finite, got {value!r}")
    return u, v


def _positive(value, where: str, *, allow_zero: bool = False) -> float:
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{where} must be a number, got {value!r}") from None
    if not np.isfinite(x) or x < 0 or (x == 0 and not allow_zero):
        raise ValueError(f"{where} must be {'>= 0' if allow_zero else '> 0'}, got {value!r}")
    return x


def _parse_muscle(entry: dict, where: str) -> list[Muscle]:
    if not isinstance(entry, dict):
        raise ValueError(f"{where} must be a table, got {type(entry).__name__}")
    name = entry.get("name")
    if not isinstance(name, str) or not name.isidentifier():
        raise ValueError(f"{where}: 'name' must be an identifier string, got {name!r}")
    where = f"{where} ({name})"
    mtype = entry.get("type")
    if mtype not in MUSCLE_TYPES:
        raise ValueError(f"{where}: 'type' must be one of {', '.join(MUSCLE_TYPES)}, "
                         f"got {mtype!r}")
    required, optional = _TYPE_KEYS[mtype]
    unknown = set(entry) - _COMMON_KEYS - required - optional
    if unknown:
        raise ValueError(f"{where}: unknown keys {sorted(unknown)}; valid for {mtype}: "
                         f"{sorted(_COMMON_KEYS | required | optional)}")
    missing = (required | {"force"}) - set(entry)
    if missing:
        raise ValueError(f"{where}: missing keys {sorted(missing)}")
    force = _positive(entry["force"], f"{where}: force", allow_zero=True)
    depth = entry.get("depth")
    if depth is not None:
        depth = float(depth)
        if not 0.0 <= depth <= 1.0:
            raise ValueError(f"{where}: depth must be in [0, 1], got {entry['depth']!r}")
    p = {k: entry.get(k, _DEFAULTS[k]) for k in optional}
    if mtype == "linear":
        p["head"] = _uv(entry["head"], f"{where}: head")
        p["tail"] = _uv(entry["tail"], f"{where}: tail")
        if p["head"] == p["tail"]:
            raise ValueError(f"{where}: head and tail coincide")
        p["head_depth"] = float(p["head_depth"])
        if not 0.0 <= p["head_depth"] <= 1.0:
            raise ValueError(f"{where}: head_depth must be in [0, 1]")
        p["zone_angle"] = _positive(p["zone_angle"], f"{where}: zone_angle")
        if p["zone_angle"] > 180:
            raise ValueError(f"{where}: zone_angle must be <= 180 degrees")
        p["fall_start"] = _positive(p["fall_start"], f"{where}: fall_start")
        p["fall_finish"] = _positive(p["fall_finish"], f"{where}: fall_finish")
        if p["fall_finish"] <= p["fall_start"]:
            raise ValueError(f"{where}: fall_finish must exceed fall_start")
        if p["falloff"] not in ("waters", "radial"):
            raise ValueError(f"{where}: falloff must be 'waters' or 'radial', "
                             f"got {p['falloff']!r}")
        p["radius"] = _positive(p["radius"], f"{where}: radius")
    elif mtype == "sphincter":
        p["centre"] = _uv(entry["centre"], f"{where}: centre")
        a, b = _uv(entry["semi_axes"], f"{where}: semi_axes")
        if a <= 0 or b <= 0:
            raise ValueError(f"{where}: semi_axes must be > 0")
        p["semi_axes"] = (a, b)
        p["angle"] = float(p["angle"])
        p["outer"] = _positive(p["outer"], f"{where}: outer")
        if p["outer"] <= 1:
            raise ValueError(f"{where}: outer must be > 1")
    else:
        for key in ("attachment", "insertion"):
            pts = entry[key]
            if not isinstance(pts, list) or len(pts) != 2:
                raise ValueError(f"{where}: {key} must be two [u, v] points")
            p[key] = tuple(_uv(q, f"{where}: {key}") for q in pts)
        p["eta"] = _positive(p["eta"], f"{where}: eta")
        p["outer"] = _positive(p["outer"], f"{where}: outer")
        if p["outer"] <= 1:
            raise ValueError(f"{where}: outer must be > 1")
        p["edge"] = _positive(p["edge"], f"{where}: edge", allow_zero=True)
    base = Muscle(name, mtype, force, depth, p)
    sides = entry.get("sides")
    if sides is None:
        return [base]
    if not isinstance(sides, list) or not set(sides) <= {"l", "r"} or len(set(sides)) != len(
            sides) or not sides:
        raise ValueError(f"{where}: sides must be a list drawn from ['l', 'r'], got {sides!r}")
    out = []
    for side in sides:
        out.append(Muscle(f"{name}_l", mtype, force, depth, p) if side == "l"
                   else base.mirrored(f"{name}_r"))
    return out


def load_muscles(path: str | Path | None = None) -> MuscleSet:
    """Read a muscle file (TOML, or JSON when the name ends in ``.json``).

    Parameters
    ----------
    path : str or Path, optional
        The file; the shipped ``synth/data/muscles.toml`` when omitted.

    Returns
    -------
    MuscleSet

    Raises
    ------
    FileNotFoundError
        If the file does not exist.
    ValueError
        On malformed entries, naming the entry and the offending key.

    Examples
    --------
    >>> ms = load_muscles()
    >>> "zygomaticus_major_l" in ms.names and "orbicularis_oris" in ms.names
    True
    """
    path = default_muscle_file() if path is None else Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"muscle file not found: {path}")
    text = path.read_text(encoding="utf-8")
    if path.suffix.lower() == ".json":
        try:
            data = json.loads(text)
        except json.JSONDecodeError as exc:
            raise ValueError(f"{path}: not valid JSON: {exc}") from exc
    else:
        data = _load_toml(text, str(path))
    entries = data.get("muscle") if isinstance(data, dict) else None
    if not isinstance(entries, list) or not entries:
        raise ValueError(f"{path}: expected a list of [[muscle]] tables")
    muscles: list[Muscle] = []
    for k, entry in enumerate(entries):
        muscles.extend(_parse_muscle(entry, f"{path.name}: muscle #{k + 1}"))
    names = [m.name for m in muscles]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise ValueError(f"{path}: duplicate muscle names {dup}")
    if "jaw_rotation" in names:
        raise ValueError(f"{path}: 'jaw_rotation' is reserved for the jaw")
    return MuscleSet(tuple(muscles), source=str(path))


# ---------------------------------------------------------------------------------------------
# geometry
# ---------------------------------------------------------------------------------------------

def uv_to_surface(mesh, uv, *, values=None):
    """Locate canonical uv points on the rest mesh.

    Each point is assigned to the triangle whose uv footprint contains it (or the nearest
    one, e.g. for points inside the eye openings) and its barycentric coordinates there are
    used, unclamped, to interpolate vertex quantities linearly.

    Parameters
    ----------
    mesh : FaceMesh
    uv : (k, 2) array
    values : (N, ...) array, optional
        Per-vertex values to interpolate (``mesh.vertices`` when omitted).

    Returns
    -------
    (k, ...) array of interpolated values.

    Examples
    --------
    >>> from synth.mesh import generate_face_mesh
    >>> m = generate_face_mesh(resolution=0.35)
    >>> p = uv_to_surface(m, m.uv[m.landmarks["chin"]][None])
    >>> bool(np.allclose(p[0], m.vertices[m.landmarks["chin"]]))
    True
    """
    q = np.atleast_2d(np.asarray(uv, dtype=np.float64))
    t = np.asarray(mesh.triangles, dtype=np.int64)
    tuv = np.asarray(mesh.uv, dtype=np.float64)[t]               # (M, 3, 2)
    a, b, c = tuv[:, 0], tuv[:, 1], tuv[:, 2]
    v0, v1 = b - a, c - a
    den = v0[:, 0] * v1[:, 1] - v0[:, 1] * v1[:, 0]
    den = np.where(np.abs(den) < 1e-30, 1e-30, den)
    vals = mesh.vertices if values is None else values
    vals = np.asarray(vals, dtype=np.float64)
    out = np.empty((len(q),) + vals.shape[1:])
    for k, p in enumerate(q):
        w = p - a
        l1 = (w[:, 0] * v1[:, 1] - w[:, 1] * v1[:, 0]) / den
        l2 = (v0[:, 0] * w[:, 1] - v0[:, 1] * w[:, 0]) / den
        l0 = 1.0 - l1 - l2
        lam = np.stack([l0, l1, l2], axis=1)
        inside = lam.min(axis=1)
        best = int(np.argmax(inside))
        if inside[best] >= -1e-9:
            out[k] = np.tensordot(lam[best], vals[t[best]], axes=(0, 0))
            continue
        # outside the surface (e.g. inside an eye opening): Gaussian blend of the vertex
        # values around it, with a width set by the nearest vertex (continuous and
        # mirror-consistent)
        vuv = np.asarray(mesh.uv, dtype=np.float64)
        dist2 = np.sum((vuv - p) ** 2, axis=1)
        d0 = max(float(dist2.min()), 1e-12)
        wts = np.exp(-dist2 / (2.0 * d0))
        wts /= wts.sum()
        out[k] = np.tensordot(wts, vals, axes=(0, 0))
    return out


def _lift(mesh, lattice, uv, depth):
    """3-D points at fractional ``depth`` of the (extruded) tissue under uv points."""
    d = np.asarray(lattice.info["depth"])
    surf = uv_to_surface(mesh, uv)
    inward = uv_to_surface(mesh, uv, values=lattice.inward)
    inward /= np.linalg.norm(inward, axis=1, keepdims=True)
    th = uv_to_surface(mesh, uv, values=d[:, None])[:, 0]
    return surf + inward * (th * depth)[:, None]


def _cosine_ramp(t):
    """cos(t pi/2) on [0, 1], 1 below 0, 0 above 1."""
    return np.cos(np.clip(t, 0.0, 1.0) * (np.pi / 2))


def _weights_linear(m: Muscle, mesh, lattice, x, fascia_depth):
    p = m.params
    depth = fascia_depth if m.depth is None else m.depth
    head = _lift(mesh, lattice, [p["head"]], p["head_depth"])[0]
    tail = _lift(mesh, lattice, [p["tail"]], depth)[0]
    axis = tail - head
    length = float(np.linalg.norm(axis))
    rel = x - head
    dist = np.linalg.norm(rel, axis=1)
    cosang = rel @ axis / np.maximum(dist * length, 1e-12)
    ang = np.degrees(np.arccos(np.clip(cosang, -1.0, 1.0)))
    if p["falloff"] == "radial":                       # 004 eq. 6
        r = p["radius"] * length
        w = np.where(np.linalg.norm(x - tail, axis=1) <= r,
                     np.cos(np.linalg.norm(x - tail, axis=1) / r * np.pi / 2), 0.0)
        w = np.where(ang < 90.0, w, 0.0)             # only on the insertion side of the head
    else:                                              # Waters (002), 003 eqs. 12-13
        ang_w = np.where(ang <= p["zone_angle"], np.cos(ang / p["zone_angle"] * np.pi / 2), 0.0)
        rs, rf = p["fall_start"] * length, p["fall_finish"] * length
        rad = np.where(dist <= rs, np.cos((1.0 - dist / rs) * np.pi / 2),
                       _cosine_ramp((dist - rs) / (rf - rs)))
        rad = np.where(dist <= rf, rad, 0.0)
        w = ang_w * rad
    direction = head - x                               # 003 eq. 10
    return w, direction


def _frame_from_uv(mesh, lattice, centre_uv, depth, angle_deg, du=0.01):
    """3-D centre and unit axes of a local frame whose axes follow the uv axes."""
    ca, sa = math.cos(math.radians(angle_deg)), math.sin(math.radians(angle_deg))
    cu = np.array(centre_uv)
    a1, a2 = np.array([ca, sa]), np.array([-sa, ca])
    pts = _lift(mesh, lattice, [cu, cu + du * a1, cu - du * a1, cu + du * a2, cu - du * a2],
                depth)
    o = pts[0]
    e1 = 0.5 * (pts[1] - pts[2])
    e2 = 0.5 * (pts[3] - pts[4])
    s1, s2 = np.linalg.norm(e1) / du, np.linalg.norm(e2) / du    # cm per uv unit
    e1 /= np.linalg.norm(e1)
    e2 -= (e2 @ e1) * e1
    e2 /= np.linalg.norm(e2)
    return o, e1, e2, s1, s2


def _weights_sphincter(m: Muscle, mesh, lattice, x, fascia_depth):
    p = m.params
    depth = fascia_depth if m.depth is None else m.depth
    o, e1, e2, _, _ = _frame_from_uv(mesh, lattice, p["centre"], depth, p["angle"])
    # 3-D semi-axes: half the distance between the lifted ends of each axis
    ca, sa = math.cos(math.radians(p["angle"])), math.sin(math.radians(p["angle"]))
    cu = np.array(p["centre"])
    au, bu = p["semi_axes"]
    ends = _lift(mesh, lattice, [cu + au * np.array([ca, sa]), cu - au * np.array([ca, sa]),
                                 cu + bu * np.array([-sa, ca]), cu - bu * np.array([-sa, ca])],
                 depth)
    a = 0.5 * float(np.linalg.norm(ends[0] - ends[1]))
    b = 0.5 * float(np.linalg.norm(ends[2] - ends[3]))
    rel = x - o
    xi, yi = rel @ e1, rel @ e2
    d = np.sqrt((xi / a) ** 2 + (yi / b) ** 2)           # 003 eq. 17
    inner = np.cos((1.0 - np.minimum(d, 1.0)) * np.pi / 2)  # eq. 16
    outer = _cosine_ramp((d - 1.0) / (p["outer"] - 1.0))
    w = np.where(d <= 1.0, inner, outer)
    direction = o - x                                     # eq. 15
    return w, direction


def _weights_sheet(m: Muscle, mesh, lattice, x, fascia_depth):
    p = m.params
    depth = fascia_depth if m.depth is None else m.depth
    a1, a2 = _lift(mesh, lattice, list(p["attachment"]), depth)
    i1, i2 = _lift(mesh, lattice, list(p["insertion"]), depth)
    ac, ic = 0.5 * (a1 + a2), 0.5 * (i1 + i2)
    fibre = ac - ic
    length = float(np.linalg.norm(fibre))
    mdir = fibre / length                                 # 003 eq. 19
    lam = ((ac - x) @ mdir) / length                      # eq. 21 (distance from attachment)
    eta = p["eta"]
    lam_c = np.clip(lam, 0.0, None)
    inner = np.cos((1.0 - np.minimum(lam_c, 1.0) ** eta) * np.pi / 2)     # eq. 20, lam <= 1
    delta = p["outer"]
    beyond = np.cos(np.clip((lam_c**eta - 1.0) / (delta**eta - 1.0), 0, 1) * np.pi / 2)
    w = np.where(lam < 0, 0.0, np.where(lam <= 1.0, inner, np.where(lam <= delta, beyond, 0.)))
    # lateral extent: the strip between the attachment and insertion end points
    lat_axis = (a2 - a1) + (i2 - i1)
    lat_axis -= (lat_axis @ mdir) * mdir
    lat_axis /= np.linalg.norm(lat_axis)
    centre = 0.5 * (ac + ic)
    half = 0.25 * (abs((a2 - a1) @ lat_axis) + abs((i2 - i1) @ lat_axis))
    s = np.abs((x - centre) @ lat_axis)
    edge = p["edge"]
    if edge > 0:
        w = w * _cosine_ramp((s - half * (1 - edge)) / (2 * half * edge))
    else:
        w = np.where(s <= half, w, 0.0)
    direction = np.broadcast_to(mdir, x.shape)
    return w, direction


_WEIGHTS = {"linear": _weights_linear, "sphincter": _weights_sphincter, "sheet": _weights_sheet}


def muscle_force_basis(muscles: MuscleSet, mesh, lattice) -> tuple[np.ndarray, np.ndarray]:
    """Nodal forces of every muscle at full contraction.

    Parameters
    ----------
    muscles : MuscleSet
    mesh : FaceMesh
        The rest mesh the lattice was built from.
    lattice : Lattice

    Returns
    -------
    nodes : (k,) int array
        The free fascia nodes the muscles act on.
    basis : (n_muscles, k, 3) array
        Force on each of those nodes per muscle at contraction 1 (the load for contractions
        ``c`` is ``tensordot(c, basis, 1)``).

    Raises
    ------
    ValueError
        If a muscle reaches no free fascia node (its geometry lies off the face).
    """
    fascia = lattice.layer_nodes("fascia")
    fixed = lattice.fixed[fascia]
    nodes = fascia[~fixed]
    x = lattice.rest[nodes]
    fascia_depth = lattice.info["layer_depths"][2]
    # outward skull normal at each fascia node, to keep the pull tangential to the skull
    normal = -np.asarray(lattice.inward)[nodes - fascia[0]]
    tri = np.asarray(mesh.triangles, dtype=np.int64)
    v = np.asarray(mesh.vertices)
    area = 0.5 * np.linalg.norm(np.cross(v[tri[:, 1]] - v[tri[:, 0]],
                                         v[tri[:, 2]] - v[tri[:, 0]]), axis=1)
    v_area = np.bincount(tri.ravel(), weights=np.repeat(area / 3.0, 3), minlength=len(v))
    a = v_area[nodes - fascia[0]]
    basis = np.zeros((len(muscles), len(nodes), 3))
    for k, m in enumerate(muscles.muscles):
        for widen in range(_MAX_WIDENINGS + 1):
            w, direction = _WEIGHTS[m.type](_widened(m, widen), mesh, lattice, x,
                                             fascia_depth)
            w = np.clip(np.nan_to_num(w), 0.0, None)
            direction = np.array(direction, dtype=np.float64)
            direction -= np.einsum("ij,ij->i", direction, normal)[:, None] * normal
            norm = np.linalg.norm(direction, axis=1)
            ok = norm > 1e-9
            unit = np.zeros_like(direction)
            unit[ok] = direction[ok] / norm[ok, None]
            wa = w * a * ok
            total = wa.sum()
            if total > 0 or m.type != "linear" or not _on_face(m):
                break
        if total <= 0:
            raise ValueError(f"muscle {m.name!r} acts on no free fascia node: check its uv "
                             "geometry in the muscle file")
        basis[k] = (m.force * wa / total)[:, None] * unit
    return nodes, basis


#: How many times a linear muscle's zone may be widened (by :data:`_WIDEN_FACTOR` each)
#: when it holds no free fascia node.
_MAX_WIDENINGS = 4
_WIDEN_FACTOR = 1.4


def _on_face(m: Muscle) -> bool:
    """Whether a linear muscle's head and tail lie in the canonical uv square."""
    return all(0.0 <= c <= 1.0 for key in ("head", "tail") for c in m.params[key])


def _widened(m: Muscle, times: int) -> Muscle:
    """``m`` with its zone of influence widened ``times`` times: a short linear muscle on
    a mesh stretched by a landmark warp (a subject's brows higher above the eyes than the
    generic face's) can have its narrow cone fall between the fascia nodes; it then acts on
    the nodes nearest its axis instead of none. An unwidened muscle is returned as is."""
    if times == 0 or m.type != "linear":
        return m
    p = dict(m.params)
    f = _WIDEN_FACTOR ** times
    if p.get("falloff") == "radial":
        p["radius"] = p["radius"] * f
    else:
        p["zone_angle"] = min(p["zone_angle"] * f, 89.0)
        p["fall_finish"] = p["fall_finish"] * f
    return Muscle(m.name, m.type, m.force, m.depth, p)
