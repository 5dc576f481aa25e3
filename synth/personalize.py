"""Landmark-driven personalisation of the face model (Kähler, seed 001, chapter 8).

A generic head is deformed to an individual by a smooth warp of space that carries a few
source landmarks ``p_i`` on the model onto target positions ``q_i`` (001, eq. 8.1)::

    f(p) = sum_i c_i phi(|p - p_i|) + R p + t,     phi(r) = r,

with ``sum_i c_i = 0`` and ``sum_i c_i p_i^T = 0`` (the radial part carries no affine
component). ``phi(r) = r`` is the 3-D biharmonic kernel that minimises bending energy
(Bookstein's thin-plate spline in three dimensions). The warp is applied to the *whole*
structure (001, section 8.3.2): skin vertices, the bone layer under them (the tissue depth is
re-measured between the warped skin and the warped bone), the muscles (defined on the skin in
canonical uv, 001's "muscle grids painted onto the skin", they are lifted again onto the warped
surface), the inner parts (eyeballs, mouth cavity, teeth) and the jaw hinge. The warped model
is a regular :class:`~synth.model.FaceModel` and stays animatable.

:func:`fit_landmark_warp` builds a warp; :func:`warp_mesh` applies it to a
:class:`~synth.face_mesh.FaceMesh`; :func:`personalize_model` builds the warped FaceModel.

Coordinates are model space (cm; x = subject's left, y up, z toward the viewer).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

__all__ = ["LandmarkWarp", "fit_landmark_warp", "warp_mesh", "personalize_model",
           "personalize_in_plane", "head_frame_points", "check_warp"]

#: Blends of a warp with its best affine part tried in turn by :func:`personalize_in_plane`,
#: from the warp itself to the affine part alone.
WARP_BLENDS = (1.0, 0.75, 0.5, 0.25, 0.0)


@dataclass(frozen=True, eq=False)
class LandmarkWarp:
    """A radial-basis warp of 3-D space (001, eq. 8.1), callable on (K, 3) points.

    Attributes
    ----------
    source : (N, 3) array
        Source landmarks ``p_i``.
    weights : (N, 3) array
        Radial weights ``c_i``.
    affine : (4, 3) array
        ``[R^T; t]``: the affine part is ``p @ affine[:3] + affine[3]``.
    kernel : str
        ``'linear'`` (``phi(r) = r``, 001) or ``'gaussian'``.
    width : float
        Width of the Gaussian kernel (cm); unused by the linear kernel.
    """

    source: np.ndarray
    weights: np.ndarray
    affine: np.ndarray
    kernel: str = "linear"
    width: float = 3.0

    def _phi(self, r: np.ndarray) -> np.ndarray:
        if self.kernel == "linear":
            return r
        return np.exp(-0.5 * (r / self.width) ** 2)

    def __call__(self, points) -> np.ndarray:
        """Warp (K, 3) points; returns a new (K, 3) array."""
        p = np.asarray(points, dtype=np.float64)
        if p.ndim != 2 or p.shape[1] != 3:
            raise ValueError(f"points must have shape (K, 3), got {p.shape}")
        r = np.linalg.norm(p[:, None, :] - self.source[None, :, :], axis=2)
        return self._phi(r) @ self.weights + p @ self.affine[:3] + self.affine[3]

    def jacobian(self, points, *, h: float = 1e-4) -> np.ndarray:
        """(K, 3, 3) Jacobian of the warp at ``points`` (central differences, step ``h`` cm)."""
        p = np.asarray(points, dtype=np.float64)
        out = np.empty((len(p), 3, 3))
        for j in range(3):
            e = np.zeros(3)
            e[j] = h
            out[:, :, j] = (self(p + e) - self(p - e)) / (2 * h)
        return out


def fit_landmark_warp(source, target, *, kernel: str = "linear", width: float = 3.0
                      ) -> LandmarkWarp:
    """Solve 001's linear system ``A X = B`` for the warp taking ``source`` to ``target``.

    Parameters
    ----------
    source, target : (N, 3) array_like
        Corresponding landmarks (cm). At least 4, not coplanar.
    kernel : {'linear', 'gaussian'}
        ``phi(r) = r`` (001, Bookstein) or ``exp(-r^2 / (2 width^2))``.
    width : float
        Gaussian width in cm.

    Returns
    -------
    LandmarkWarp
        Interpolates exactly: ``warp(source) == target``.

    Raises
    ------
    ValueError
        Shapes differ, values are not finite, fewer than 4 landmarks, coplanar or
        coincident landmarks (singular system).

    Examples
    --------
    >>> p = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 1]])
    >>> q = p * 2.0 + [0.0, 0.0, 0.5]
    >>> w = fit_landmark_warp(p, q)
    >>> bool(np.allclose(w(p), q)), bool(np.allclose(w([[0.5, 0.5, 0.5]]), [[1, 1, 1.5]]))
    (True, True)
    """
    if kernel not in ("linear", "gaussian"):
        raise ValueError(f"unknown kernel {kernel!r}; choose from 'linear', 'gaussian'")
    if not (np.isfinite(width) and width > 0):
        raise ValueError(f"width must be a positive number, got {width!r}")
    p = np.asarray(source, dtype=np.float64)
    q = np.asarray(target, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3 or q.shape != p.shape:
        raise ValueError(f"source {p.shape} and target {q.shape} must both have shape (N, 3)")
    if len(p) < 4:
        raise ValueError(f"a landmark warp needs at least 4 landmarks, got {len(p)}")
    if not (np.isfinite(p).all() and np.isfinite(q).all()):
        raise ValueError("landmarks must be finite")
    n = len(p)
    tmp = LandmarkWarp(p, np.zeros((n, 3)), np.zeros((4, 3)), kernel, float(width))
    P = tmp._phi(np.linalg.norm(p[:, None] - p[None], axis=2))
    Q = np.c_[p, np.ones(n)]
    if np.linalg.matrix_rank(Q) < 4:
        raise ValueError("landmarks are coplanar: the affine part of the warp is undefined")
    A = np.zeros((n + 4, n + 4))
    A[:n, :n] = P
    A[:n, n:] = Q
    A[n:, :n] = Q.T
    B = np.zeros((n + 4, 3))
    B[:n] = q
    try:
        X = np.linalg.solve(A, B)          # LU with partial pivoting, as in 001
    except np.linalg.LinAlgError:
        raise ValueError("the landmark warp system is singular (coincident landmarks?)") \
            from None
    if not np.isfinite(X).all():
        raise ValueError("the landmark warp system is singular (coincident landmarks?)")
    return LandmarkWarp(p, X[:n], X[n:], kernel, float(width))


def head_frame_points(mesh) -> tuple[np.ndarray, np.ndarray]:
    """Model-space points that define the head reference frame of ``mesh``.

    Returns the arc-length centroid of the central hairline (3-D, the head frame's origin)
    and the midpoint of the nostrils (the point whose distance from the origin is the head
    frame's scale), as :func:`synth.render.groundtruth.head_frame` measures them.
    """
    from synth.render.groundtruth import _frame_points

    hair, nose = _frame_points(mesh)
    seg = np.linalg.norm(np.diff(hair, axis=0), axis=1)
    if seg.sum() > 1e-12:
        origin = (0.5 * (hair[1:] + hair[:-1]) * seg[:, None]).sum(axis=0) / seg.sum()
    else:
        origin = hair.mean(axis=0)
    return origin, np.asarray(nose, dtype=np.float64)


def check_warp(warp: LandmarkWarp, points) -> float:
    """Smallest Jacobian determinant of ``warp`` over ``points``.

    A warp that folds space over itself (a mirror image somewhere: determinant <= 0) cannot
    be used to deform a model.
    """
    J = warp.jacobian(points)
    return float(np.linalg.det(J).min())


def warp_mesh(mesh, warp: LandmarkWarp, *, lattice=None):
    """The :class:`~synth.face_mesh.FaceMesh` deformed by ``warp`` (a new mesh; uv unchanged).

    Skin vertices, inner parts, eyeball centres and the jaw pivot are warped; the tissue
    thickness becomes the depth, along the warped surface's inward extrusion direction,
    between the warped skin and the warped bone layer of ``lattice`` (the rest lattice of
    ``mesh``; built when omitted), so that the skull moves with the warp (001, 8.3.2).

    Raises
    ------
    ValueError
        If the warp folds space at a vertex (Jacobian determinant <= 0) or produces
        non-finite positions.
    """
    from synth.lattice import build_lattice

    if lattice is None:
        lattice = build_lattice(mesh)
    V = np.asarray(mesh.vertices, dtype=np.float64)
    n = len(V)
    bone = np.asarray(lattice.rest, dtype=np.float64)[3 * n: 4 * n]
    det = check_warp(warp, np.vstack([V, bone]))
    if not det > 0:
        raise ValueError(f"the landmark warp folds the face (Jacobian determinant {det:.3g} "
                         "<= 0): the target landmarks are inconsistent")
    Vw = warp(V)
    bone_w = warp(bone)
    inner = np.asarray(mesh.inner_vertices, dtype=np.float64)
    inner_w = warp(inner) if len(inner) else inner.copy()
    eyes = np.asarray(mesh.eyeball_centres, dtype=np.float64)
    eyes_w = warp(eyes)
    pivot_w = warp(np.asarray(mesh.jaw_pivot, dtype=np.float64)[None])[0]
    scale = float(np.cbrt(np.linalg.det(warp.jacobian(eyes)).mean()))
    if not all(np.isfinite(a).all() for a in (Vw, bone_w, inner_w, eyes_w, pivot_w)):
        raise ValueError("the landmark warp produced non-finite positions")
    # tissue depth along the inward direction the lattice will extrude along
    draft = replace(mesh, vertices=Vw, inner_vertices=inner_w, eyeball_centres=eyes_w,
                    jaw_pivot=pivot_w, eyeball_radius=float(mesh.eyeball_radius) * scale,
                    mirror_map=None)
    inward = np.asarray(build_lattice(draft).inward, dtype=np.float64)
    depth = np.einsum("ij,ij->i", bone_w - Vw, inward)
    old = np.asarray(mesh.tissue_thickness, dtype=np.float64)
    thickness = np.clip(depth, 0.3 * old, 3.0 * old)
    return replace(draft, tissue_thickness=thickness)


def personalize_model(model, source, target, *, kernel: str = "linear", width: float = 3.0,
                      **model_options):
    """A FaceModel whose rest geometry is ``model``'s warped so that ``source`` -> ``target``.

    Parameters
    ----------
    model : FaceModel
        The generic model (not modified).
    source, target : (N, 3) array_like
        Landmarks on the model at rest and where they should go (cm).
    kernel, width
        See :func:`fit_landmark_warp`.
    **model_options
        Passed to :class:`~synth.model.FaceModel` (e.g. ``volume_preservation``).

    Returns
    -------
    model : FaceModel
        Built from the warped mesh with ``model``'s muscles (re-lifted onto the warped skin).
    warp : LandmarkWarp

    Examples
    --------
    >>> from synth.model import FaceModel
    >>> generic = FaceModel.default()
    >>> lm = generic.landmark_positions()
    >>> names = ["brow_mid_l", "brow_mid_r", "mouth_corner_l", "mouth_corner_r", "chin",
    ...          "nose_tip"]
    >>> p = np.array([lm[k] for k in names])
    >>> q = p.copy(); q[2, 0] += 0.3; q[3, 0] -= 0.3          # a wider mouth
    >>> personal, warp = personalize_model(generic, p, q)
    >>> moved = personal.landmark_positions()["mouth_corner_l"]
    >>> bool(np.allclose(moved, q[2]))
    True
    """
    from synth.model import FaceModel

    warp = fit_landmark_warp(source, target, kernel=kernel, width=width)
    mesh = warp_mesh(model.mesh, warp, lattice=model.lattice)
    return FaceModel(mesh, muscles=model.muscles, **model_options), warp


def personalize_in_plane(model, source, xy, *, kernel: str = "linear", width: float = 3.0):
    """``model`` warped so that its points ``source`` land on ``xy`` in the image plane.

    Depth is not observed: each point keeps the model's, scaled by the subject's overall
    size in the plane (the square root of the determinant of the best affine map of the
    x-y; keeping depth unscaled where the face is narrower would tilt short muscles such as
    the corrugator into the skull). The head frame's points (:func:`head_frame_points`)
    stay where they are, their depth scaled alike. Where the warp gives no valid model (it
    folds the face, or leaves a muscle without tissue to pull) it is blended toward the
    best 3-D affine map of the same correspondences (:data:`WARP_BLENDS`).

    Parameters
    ----------
    model : FaceModel
        Not modified.
    source : (N, 3) array_like
        Points on ``model`` at rest (cm).
    xy : (N, 2) array_like
        Where their x-y should go (cm).
    kernel, width
        See :func:`fit_landmark_warp`.

    Returns
    -------
    model : FaceModel
    warp : LandmarkWarp
    blend : float
        The share of the warp beyond its affine part that was kept (1: all of it).

    Raises
    ------
    ValueError
        Shapes that do not match, or no blend down to the affine map gives a valid model.

    Examples
    --------
    >>> from synth.model import FaceModel
    >>> generic = FaceModel.default()
    >>> lm = generic.landmark_positions()
    >>> names = ["brow_mid_l", "brow_mid_r", "mouth_corner_l", "mouth_corner_r", "chin",
    ...          "nose_tip"]
    >>> p = np.array([lm[k] for k in names])
    >>> xy = 1.1 * p[:, :2]                               # a face a tenth larger
    >>> personal, warp, blend = personalize_in_plane(generic, p, xy)
    >>> blend, bool(np.allclose(personal.landmark_positions()["chin"][:2], xy[4]))
    (1.0, True)
    """
    src = np.asarray(source, dtype=np.float64)
    target_xy = np.asarray(xy, dtype=np.float64)
    if src.ndim != 2 or src.shape[1] != 3 or target_xy.shape != (len(src), 2):
        raise ValueError(f"source must have shape (N, 3) and xy (N, 2), got {src.shape} and "
                         f"{target_xy.shape}")
    a, *_ = np.linalg.lstsq(np.c_[src[:, :2], np.ones(len(src))], target_xy, rcond=None)
    depth_scale = float(np.sqrt(abs(np.linalg.det(a[:2]))))
    frame = np.array(head_frame_points(model.mesh))
    points = np.vstack([src, frame])
    target = np.vstack([np.c_[target_xy, depth_scale * src[:, 2]],
                        np.c_[frame[:, :2], depth_scale * frame[:, 2]]])
    design = np.c_[points, np.ones(len(points))]
    affine = design @ np.linalg.lstsq(design, target, rcond=None)[0]
    last = None
    for blend in WARP_BLENDS:
        try:
            personal, warp = personalize_model(model, points, affine + blend * (target - affine),
                                               kernel=kernel, width=width)
        except ValueError as exc:
            last = exc
            continue
        return personal, warp, blend
    raise ValueError(f"no warp, down to an affine one, gives a valid model ({last})")
