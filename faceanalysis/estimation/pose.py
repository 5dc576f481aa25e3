"""Head pose correction: take the apparent motion of a turned or bowed head out of the points.

The estimators read the measurement points in the 2-D head frame
(:func:`faceanalysis.tracking.to_head_frame`), which removes the head's translation,
in-plane rotation (roll) and scale, but not its rotation out of the image plane. When the
head bows (pitch) or turns (yaw), points at different depths move differently in the
image: the chin, in front of the eyes, rises against them as the face turns down, the
lips slide sideways against the brows as it turns. Left in the displacements, this motion
is read as an expression.

With the landmark tracker every frame has a pitch and yaw (``Tracks.pose``, degrees,
relative to the tracker's first frame). :func:`pose_displacements` predicts the x-y
motion that the rotation since the neutral frame gives the face model's 3-D rest points
(:func:`rest_points_3d`), and :func:`correct_pose` subtracts it from the measured
displacements, both in model centimetres (x = the subject's left, y up, z toward the
viewer). Frames without a pose (the snakes tracker, lost frames) are left as they are.

The rotation is about a centre at the depth of the points' centroid plus
``centre_depth``: the head frame follows the rigid landmarks (eye corners, nose
bridge), whose centroid lies about that deep, so the points' motion relative to them
is what is left in the head frame (see :data:`CENTRE_DEPTH` for the measurement).
"""

from __future__ import annotations

import functools

import numpy as np

__all__ = ["CENTRE_DEPTH", "correct_pose", "head_frame_points", "pose_displacements",
           "rest_points_3d"]

#: Depth (cm, model z: toward the viewer) of the rotation centre relative to the centroid
#: of the measurement points' rest positions. Chosen by measurement (see the module
#: docstring and ``docs``); 0 rotates about the points' own centroid.
CENTRE_DEPTH = 0.0


def rotation_matrix(pitch: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    """Rotations (..., 3, 3) in model space for ``pitch`` and ``yaw`` in degrees.

    The tracker's signs (:func:`trackers.anchored.rotation_angles`): a positive pitch
    turns the face down (the nose tip, in front, moves down: model -y), a positive yaw
    toward the image's right (the nose tip moves to model +x, the subject's left, which
    is the image's right in a frontal view).

    Examples
    --------
    >>> R = rotation_matrix(np.array(90.0), np.array(0.0))
    >>> np.round(R @ [0.0, 0.0, 1.0], 6) + 0.0     # the nose tip goes down
    array([ 0., -1.,  0.])
    >>> R = rotation_matrix(np.array(0.0), np.array(90.0))
    >>> np.round(R @ [0.0, 0.0, 1.0], 6) + 0.0     # ... or to the image's right
    array([1., 0., 0.])
    """
    p = np.radians(np.asarray(pitch, dtype=float))
    y = np.radians(np.asarray(yaw, dtype=float))
    cp, sp, cy, sy = np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    one, zero = np.ones_like(p), np.zeros_like(p)
    rx = np.stack([np.stack([one, zero, zero], -1),
                   np.stack([zero, cp, -sp], -1),
                   np.stack([zero, sp, cp], -1)], -2)
    ry = np.stack([np.stack([cy, zero, sy], -1),
                   np.stack([zero, one, zero], -1),
                   np.stack([-sy, zero, cy], -1)], -2)
    # the renderer's order (synth.render.camera.pose_matrix): pitch first, then yaw
    return ry @ rx


def pose_displacements(rest: np.ndarray, pose: np.ndarray, *,
                       reference: np.ndarray | None = None,
                       centre_depth: float = CENTRE_DEPTH) -> np.ndarray:
    """Apparent x-y motion of rigid 3-D points when the head turns by ``pose``.

    Parameters
    ----------
    rest : ndarray, shape (P, 3)
        The points at rest (cm, model space: x = the subject's left, y up, z toward the
        viewer). Non-finite points give NaN.
    pose : ndarray, shape (T, 2)
        Pitch and yaw (degrees) of each frame relative to the frame the displacements
        are measured from (see :func:`rotation_matrix` for the signs). A frame with a
        NaN angle gives NaN.
    reference : ndarray, shape (R, 3), optional
        Points that the 2-D head frame follows (the tracker's rigid landmarks, at least
        2): the 2-D similarity (translation, in-plane rotation, scale) that carries them
        from rest to their rotated x-y is taken out of the points' motion, as
        :func:`~faceanalysis.tracking.to_head_frame` takes it out of the measured points.
        The centre of rotation is then immaterial. Default: none is taken out.
    centre_depth : float, keyword-only
        Depth of the centre of rotation relative to the finite points' centroid (cm,
        negative: behind it).

    Returns
    -------
    ndarray, shape (T, P, 2)
        Orthographic x-y displacement (cm) of each point, from its rest position to
        the rotated one (seen in the reference's frame with ``reference``).

    Raises
    ------
    ValueError
        Bad shapes, a non-finite ``centre_depth``, or no finite point.

    Examples
    --------
    >>> rest = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, -1.0]])
    >>> d = pose_displacements(rest, np.array([[0.0, 30.0]]))
    >>> np.round(d[0], 6) + 0.0    # in front moves right, behind moves left
    array([[ 0.5,  0. ],
           [-0.5,  0. ]])
    >>> behind = np.array([[1.0, 0.0, -1.0], [-1.0, 0.0, -1.0]])
    >>> d = pose_displacements(rest, np.array([[0.0, 30.0]]), reference=behind)
    >>> np.round(d[0], 6) + 0.0    # seen in a frame that follows two points behind
    array([[1.154701, 0.      ],
           [0.      , 0.      ]])
    """
    rest = np.asarray(rest, dtype=float)
    pose = np.asarray(pose, dtype=float)
    if rest.ndim != 2 or rest.shape[1] != 3:
        raise ValueError(f"rest must have shape (P, 3), got {rest.shape}")
    if pose.ndim != 2 or pose.shape[1] != 2:
        raise ValueError(f"pose must have shape (T, 2) (pitch, yaw), got {pose.shape}")
    if not np.isfinite(centre_depth):
        raise ValueError(f"centre_depth must be finite, got {centre_depth}")
    finite = np.isfinite(rest).all(axis=1)
    if not finite.any():
        raise ValueError("rest has no finite point")
    centre = rest[finite].mean(axis=0) + [0.0, 0.0, centre_depth]
    R = rotation_matrix(pose[:, 0], pose[:, 1])                     # (T, 3, 3)
    moved = np.einsum("tij,pj->tpi", R, rest - centre) + centre     # (T, P, 3)
    if reference is None:
        return moved[..., :2] - rest[:, :2]
    ref = np.asarray(reference, dtype=float)
    if ref.ndim != 2 or ref.shape[1] != 3 or len(ref) < 2 or not np.isfinite(ref).all():
        raise ValueError(f"reference must be finite with shape (R >= 2, 3), got {ref.shape}")
    # least-squares similarity z -> a z + b (complex numbers) from the reference at rest
    # to its rotated x-y, then the moved points taken back through it
    z0 = ref[:, 0] + 1j * ref[:, 1]
    z1 = np.einsum("tij,rj->tri", R, ref - centre)[..., :2] + centre[:2]
    z1 = z1[..., 0] + 1j * z1[..., 1]                                # (T, R)
    c0 = z0 - z0.mean()
    a = (z1 - z1.mean(axis=1, keepdims=True)) @ c0.conj() / np.vdot(c0, c0).real
    b = z1.mean(axis=1) - a * z0.mean()
    w = (moved[..., 0] + 1j * moved[..., 1] - b[:, None]) / a[:, None]
    return np.stack([w.real, w.imag], axis=-1) - rest[:, :2]


def correct_pose(displacements: np.ndarray, pose: np.ndarray, neutral: int,
                 rest: np.ndarray, *, reference: np.ndarray | None = None,
                 centre_depth: float = CENTRE_DEPTH) -> np.ndarray:
    """Measured displacements less the apparent motion of the head's rotation.

    Parameters
    ----------
    displacements : ndarray, shape (T, P, 2)
        Measured displacements from the neutral frame, model cm
        (:meth:`~faceanalysis.estimation.calibration.Calibration.model_displacements`).
    pose : ndarray, shape (T, 2)
        Pitch and yaw of every frame, degrees, relative to any fixed frame (the
        tracker's first); NaN where unknown.
    neutral : int
        Row of the neutral frame: the rotation is taken relative to its pose.
    rest : ndarray, shape (P, 3)
        The points' 3-D rest positions, model cm (:func:`rest_points_3d`).
    reference : ndarray, shape (R, 3), optional
        The points the head frame follows (:func:`head_frame_points` for the landmark
        tracker's); see :func:`pose_displacements`.
    centre_depth : float, keyword-only
        See :func:`pose_displacements`.

    Returns
    -------
    ndarray, shape (T, P, 2)
        A new array. Frames whose pose (or the neutral frame's) is NaN are unchanged;
        with the same pose as the neutral frame, a frame is unchanged.

    Raises
    ------
    ValueError
        Shapes that do not agree, ``neutral`` out of range.

    Examples
    --------
    >>> rest = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, -1.0]])
    >>> moved = pose_displacements(rest, np.array([[0.0, 10.0]]))
    >>> pose = np.array([[5.0, 2.0], [5.0, 12.0], [np.nan, np.nan]])
    >>> disp = np.concatenate([np.zeros((1, 2, 2)), moved, moved])
    >>> out = correct_pose(disp, pose, 0, rest)
    >>> bool(np.abs(out[:2]).max() < 0.02), bool((out[2] == moved[0]).all())
    (True, True)
    """
    disp = np.asarray(displacements, dtype=float)
    pose = np.asarray(pose, dtype=float)
    rest = np.asarray(rest, dtype=float)
    if disp.ndim != 3 or disp.shape[2] != 2:
        raise ValueError(f"displacements must have shape (T, P, 2), got {disp.shape}")
    if pose.shape != (len(disp), 2):
        raise ValueError(f"pose must have shape ({len(disp)}, 2), got {pose.shape}")
    if rest.shape != (disp.shape[1], 3):
        raise ValueError(f"rest must have shape ({disp.shape[1]}, 3), got {rest.shape}")
    if not 0 <= neutral < len(disp):
        raise ValueError(f"neutral row {neutral} outside 0..{len(disp) - 1}")
    relative = pose - pose[neutral]
    # (a frame in the neutral frame's pose is left exactly as it is, not to within rounding)
    known = np.isfinite(relative).all(axis=1) & (relative != 0).any(axis=1)
    out = disp.copy()
    if known.any():
        out[known] -= pose_displacements(rest, relative[known], reference=reference,
                                         centre_depth=centre_depth)
    return out


def rest_points_3d(points, model=None) -> np.ndarray:
    """3-D rest positions (P, 3), model cm, of the measurement ``points`` on the face model.

    The x-y are those of :func:`~faceanalysis.estimation.model_response.model_points`;
    a point on a feature curve takes the depth of the curve where its x-y arc length
    puts the point. ``model`` defaults to the generic face (whose mesh alone is built,
    once per process).

    Raises
    ------
    ValueError
        A point the model does not have.
    """
    points = tuple(points)
    if model is None:
        return _generic_rest_points(points).copy()
    return _rest_points(model.mesh, points)


@functools.lru_cache(maxsize=4)
def _generic_rest_points(points: tuple[str, ...]) -> np.ndarray:
    from synth.mesh import generate_face_mesh
    from synth.model import DEFAULT_RESOLUTION

    # the generic face's mesh is what FaceModel.default() builds, without its lattice
    return _rest_points(generate_face_mesh(resolution=DEFAULT_RESOLUTION), points)


def _rest_points(mesh, points: tuple[str, ...]) -> np.ndarray:
    from faceanalysis.tracking import CURVE_POINTS

    v = np.asarray(mesh.vertices, dtype=float)
    out = np.empty((len(points), 3))
    for j, name in enumerate(points):
        if name in CURVE_POINTS:
            curve, fraction = CURVE_POINTS[name]
            c = mesh.curve_positions(curve, v)
            # the same arc length as trackers.fiducials.arc_point: along the x-y curve
            s = np.r_[0.0, np.cumsum(np.hypot(*np.diff(c[:, :2], axis=0).T))]
            out[j] = [np.interp(fraction * s[-1], s, c[:, i]) for i in range(3)]
        elif name in mesh.landmarks:
            out[j] = v[mesh.landmarks[name]]
        else:
            raise ValueError(f"the face model has no measurement point {name!r}")
    return out


#: Where the landmark tracker's rigid points (``trackers.landmark_contours.RIGID_POINTS``:
#: the four eye corners, the nasion and four points down the nose ridge), whose 2-D
#: similarity moves the head frame, lie on the face model: its eye corners, its nasion,
#: and points at these fractions of the way from the nasion to the nose tip.
_RIDGE_FRACTIONS = (0.2, 0.4, 0.6, 0.8)


def head_frame_points(model=None) -> np.ndarray:
    """3-D rest positions (9, 3), model cm, of the points the landmark head frame follows.

    See :data:`_RIDGE_FRACTIONS`; ``model`` defaults to the generic face.
    """
    rest = rest_points_3d(("eye_outer_l", "eye_inner_l", "eye_inner_r", "eye_outer_r",
                           "nasion", "nose_tip"), model)
    ridge = [rest[4] + f * (rest[5] - rest[4]) for f in _RIDGE_FRACTIONS]
    return np.vstack([rest[:5], ridge])
