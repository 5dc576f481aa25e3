"""Cameras and head pose: model space (cm) to image space (px).

Model space: centimetres, x = the subject's left (image right in a frontal view), y = up,
z = toward the viewer. Image space: pixels, x to the right, y down, origin at the centre of
the top-left pixel.

A point ``p`` of the head is first moved by the head pose,

    w = R(roll, yaw, pitch) @ (p - centre) + centre + translation,

and then projected by the camera. The camera looks along -z at ``look_at`` (a model-space
point that lands on the image centre ``((W-1)/2, (H-1)/2)``) from a distance ``distance``
(cm). ``depth`` is the distance from the camera plane, ``distance - (w_z - look_at_z)``:
positive, larger = farther.

- orthographic: ``x = cx + scale * (w_x - look_x)``, ``y = cy - scale * (w_y - look_y)``
  (``scale`` in px/cm, the analysis's assumption, 004 V-D);
- perspective: ``x = cx + focal * (w_x - look_x) / depth``, likewise for y (``focal`` in px).

Head pose angles are in degrees. ``roll`` is the in-plane rotation as seen in the image:
a positive roll turns the head clockwise on screen (x toward +y in image coordinates), so
that the projected model x axis has the image angle ``atan2(dy, dx) = +roll``. ``yaw`` turns
the head about the vertical axis (positive: the face turns toward the subject's left, i.e.
toward image right), ``pitch`` about the horizontal axis (positive: the chin goes up).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

__all__ = ["Camera", "HeadPose", "default_camera", "project", "pose_matrix",
           "apply_pose", "DEFAULT_HEAD_CENTRE", "DEFAULT_LOOK_AT"]

#: Point (cm, model space) about which the head rotates: roughly the centre of the skull,
#: behind the eyes and a little below them.
DEFAULT_HEAD_CENTRE = (0.0, -2.0, -8.0)
#: Model-space point put at the image centre by default: the middle of the head surface
#: (from the hair above the hairline, ~9 cm above the eyes, to the chin, ~12 cm below).
DEFAULT_LOOK_AT = (0.0, -1.6, 0.0)
#: Hairline-to-chin height (cm) used to choose a default scale.
_FACE_HEIGHT_CM = 18.0
_FACE_WIDTH_CM = 14.0


@dataclass(frozen=True)
class Camera:
    """A pinhole or orthographic camera looking along -z.

    Parameters
    ----------
    width, height : int
        Image size in pixels.
    kind : {'orthographic', 'perspective'}
        Projection.
    scale : float
        Orthographic scale in px/cm (ignored by perspective cameras).
    focal : float
        Perspective focal length in px (ignored by orthographic cameras).
    distance : float
        Distance (cm) from the camera to ``look_at`` along z. Orthographic cameras use it
        only to make depth positive.
    look_at : tuple of 3 floats
        Model-space point (cm) that lands on the image centre.
    """

    width: int = 256
    height: int = 256
    kind: str = "orthographic"
    scale: float = 256 * 0.75 / _FACE_HEIGHT_CM
    focal: float = 256 * 0.75 / _FACE_HEIGHT_CM * 60.0
    distance: float = 60.0
    look_at: tuple = DEFAULT_LOOK_AT

    def __post_init__(self):
        if self.kind not in ("orthographic", "perspective"):
            raise ValueError(f"camera kind {self.kind!r} is not one of "
                             "'orthographic', 'perspective'")
        if int(self.width) < 1 or int(self.height) < 1:
            raise ValueError(f"camera size {self.width}x{self.height} must be positive")
        if not (self.scale > 0 and self.focal > 0 and self.distance > 0):
            raise ValueError("camera scale, focal and distance must be positive")

    @property
    def perspective(self) -> bool:
        return self.kind == "perspective"

    @property
    def centre(self) -> tuple[float, float]:
        """Image centre (x, y) in pixels."""
        return ((self.width - 1) / 2.0, (self.height - 1) / 2.0)

    def scaled(self, factor: float) -> Camera:
        """The same view at ``factor`` times the resolution (used for supersampling)."""
        return replace(self, width=int(round(self.width * factor)),
                       height=int(round(self.height * factor)),
                       scale=self.scale * factor, focal=self.focal * factor)

    def px_per_cm(self, depth: float | np.ndarray | None = None):
        """Image scale (px/cm) of a small object at ``depth`` (perspective) or everywhere."""
        if not self.perspective:
            return self.scale
        d = self.distance if depth is None else depth
        return self.focal / d

    def as_dict(self) -> dict:
        return {"width": int(self.width), "height": int(self.height), "kind": self.kind,
                "scale": float(self.scale), "focal": float(self.focal),
                "distance": float(self.distance), "look_at": [float(v) for v in self.look_at]}


def default_camera(width: int = 256, height: int = 256, *, kind: str = "orthographic",
                   fill: float = 0.75, distance: float = 60.0) -> Camera:
    """A camera in which the face (hairline to chin) fills ``fill`` of the image.

    Parameters
    ----------
    width, height : int
        Image size in pixels.
    kind : {'orthographic', 'perspective'}
        Projection.
    fill : float
        Fraction of the image height (or width, if that is the tighter fit) that the
        ~18 cm x 14 cm face occupies.
    distance : float
        Camera distance in cm (perspective: sets the strength of the perspective).

    Returns
    -------
    Camera

    Examples
    --------
    >>> cam = default_camera(256, 256)
    >>> round(cam.scale, 2)
    10.67
    """
    if not 0 < fill <= 4:
        raise ValueError(f"fill={fill} must be in (0, 4]")
    scale = fill * min(height / _FACE_HEIGHT_CM, width / _FACE_WIDTH_CM)
    return Camera(width=int(width), height=int(height), kind=kind, scale=scale,
                  focal=scale * distance, distance=distance)


@dataclass(frozen=True)
class HeadPose:
    """Rigid head pose: rotation (degrees) about ``centre`` then translation (cm).

    Parameters
    ----------
    roll, yaw, pitch : float
        Degrees; see the module docstring for the signs.
    translation : tuple of 3 floats
        cm in model space (x right on screen, y up, z toward the camera).
    centre : tuple of 3 floats
        Centre of rotation (cm, model space).
    """

    roll: float = 0.0
    yaw: float = 0.0
    pitch: float = 0.0
    translation: tuple = (0.0, 0.0, 0.0)
    centre: tuple = field(default=DEFAULT_HEAD_CENTRE)

    @property
    def is_identity(self) -> bool:
        return (self.roll == 0 and self.yaw == 0 and self.pitch == 0
                and not any(self.translation))

    def as_dict(self) -> dict:
        return {"roll": float(self.roll), "yaw": float(self.yaw), "pitch": float(self.pitch),
                "translation": [float(v) for v in self.translation],
                "centre": [float(v) for v in self.centre]}


def pose_matrix(pose: HeadPose) -> np.ndarray:
    """The 3x3 rotation of ``pose`` in model space.

    Examples
    --------
    >>> R = pose_matrix(HeadPose(roll=90))
    >>> np.round(R @ [1.0, 0, 0], 6)   # the subject's left goes down on screen
    array([ 0., -1.,  0.])
    """
    r = math.radians(-pose.roll)   # model y is up, image y is down: clockwise on screen
    y = math.radians(pose.yaw)
    p = math.radians(-pose.pitch)  # chin up = top of the head moves back
    cr, sr = math.cos(r), math.sin(r)
    cy, sy = math.cos(y), math.sin(y)
    cp, sp = math.cos(p), math.sin(p)
    rz = np.array([[cr, -sr, 0.0], [sr, cr, 0.0], [0.0, 0.0, 1.0]])
    ry = np.array([[cy, 0.0, sy], [0.0, 1.0, 0.0], [-sy, 0.0, cy]])
    rx = np.array([[1.0, 0.0, 0.0], [0.0, cp, -sp], [0.0, sp, cp]])
    return rz @ ry @ rx


def apply_pose(points: np.ndarray, pose: HeadPose | None) -> np.ndarray:
    """Move model-space ``points`` (K, 3) by the head pose; returns a new (K, 3) array."""
    pts = np.asarray(points, dtype=np.float64)
    if pose is None or pose.is_identity:
        return pts.copy()
    c = np.asarray(pose.centre, dtype=np.float64)
    R = pose_matrix(pose)
    return (pts - c) @ R.T + c + np.asarray(pose.translation, dtype=np.float64)


def project(points: np.ndarray, camera: Camera, pose: HeadPose | None = None
            ) -> tuple[np.ndarray, np.ndarray]:
    """Project model-space points into the image.

    Parameters
    ----------
    points : (K, 3) array_like
        Model-space points in cm.
    camera : Camera
    pose : HeadPose, optional
        Head pose applied first (identity if None).

    Returns
    -------
    xy : (K, 2) ndarray
        Image coordinates (px; x right, y down, origin at the top-left pixel's centre).
    depth : (K,) ndarray
        Distance (cm) from the camera plane; larger is farther.

    Examples
    --------
    >>> cam = default_camera(256, 256)
    >>> xy, depth = project([[0.0, -1.6, 0.0], [1.0, -1.6, 0.0]], cam)
    >>> xy.round(3).tolist()
    [[127.5, 127.5], [138.167, 127.5]]
    """
    pts = np.asarray(points, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise ValueError(f"points must have shape (K, 3), got {pts.shape}")
    if not isinstance(camera, Camera):
        raise ValueError(f"camera must be a Camera, got {type(camera).__name__}")
    return project_posed(apply_pose(pts, pose), camera)


def project_posed(world: np.ndarray, camera: Camera) -> tuple[np.ndarray, np.ndarray]:
    """Image xy and depth of points already posed in world space (see :func:`project`)."""
    lx, ly, lz = (float(v) for v in camera.look_at)
    cx, cy = camera.centre
    depth = camera.distance - (world[:, 2] - lz)
    if camera.perspective:
        if np.any(depth <= 1e-6):
            raise ValueError("a point lies behind the perspective camera")
        f = camera.focal / depth
    else:
        f = camera.scale
    xy = np.empty((len(world), 2))
    xy[:, 0] = cx + f * (world[:, 0] - lx)
    xy[:, 1] = cy - f * (world[:, 1] - ly)
    return xy, depth
