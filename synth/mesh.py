"""Procedural generic face mesh: a deterministic, mirror-symmetric skin surface.

The face is built over a *canonical* 2-D design plane (centimetres of the default face,
``X`` = subject's left, ``Y`` = up, origin between the eye centres).  A graded point set,
dense around the eyes and the mouth, is triangulated there (Delaunay, with the eye margins,
the mouth line and the outline kept as edges), the eye openings are cut out and the mouth line
is split into two coinciding rows of vertices so that the lips can part.  The identity
(:class:`~synth.face_shape.FaceShape`) then warps the plane and lifts it into 3-D: a head-like
cylinder whose sides curve back, plus smooth relief for the brow ridge, eye sockets and lids,
nose and alar wings, cheeks, nasolabial folds, lips, chin boss and jaw.

Because the topology and the texture coordinates come from the canonical plane only, every
identity made at the same ``resolution`` has the same triangles, the same ``uv`` and the same
landmark indices; only positions (and thickness) change.

Coordinates (model space): centimetres, ``x`` = subject's left, ``y`` = up, ``z`` = toward the
viewer; origin at the midpoint between the two eye centres.

Parts (each its own module): the identity :class:`~synth.face_shape.FaceShape`; the mesh
container :class:`~synth.face_mesh.FaceMesh` with its names and uv helpers; the canonical
plane and feature curves (:mod:`synth.mesh_plane`); its triangulation
(:mod:`synth.mesh_topology`); regions, tissue, 3-D geometry and inner parts
(:mod:`synth.mesh_geometry`). This module puts them together: :func:`generate_face_mesh`.
"""

from __future__ import annotations

import functools
import math

import numpy as np

from synth.face_mesh import FaceMesh, _readonly
from synth.face_shape import FaceShape, _as_shape
from synth.mesh_geometry import _embed, _fit_eyes, _inner_parts, _jaw_weight, _regions, _thickness
from synth.mesh_plane import _feature_curves, _to_uv
from synth.mesh_topology import _layout

__all__ = ["generate_face_mesh", "MAX_RESOLUTION"]

#: Largest accepted ``resolution`` (about 100,000 skin vertices).
MAX_RESOLUTION = 8.0


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
