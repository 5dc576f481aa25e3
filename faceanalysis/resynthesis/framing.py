"""Where the face model appears in the picture: the similarity that maps the model's head
reference frame onto the tracked head frame of each frame."""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np

log = logging.getLogger(__name__)


# ----------------------------------------------------------------------------- framing
def rotation_2d(theta: float) -> np.ndarray:
    c, s = math.cos(theta), math.sin(theta)
    return np.array([[c, -s], [s, c]])


@dataclass(frozen=True)
class Framing:
    """Model-to-image similarity of one frame: ``img = T + k R(roll) (x, -y)``.

    ``k`` in px/cm, ``roll`` in radians (clockwise on screen, the head frame's), ``T`` the
    image position (px) of the model origin.
    """

    k: float
    roll: float
    T: tuple

    def apply(self, points) -> np.ndarray:
        """Image positions (K, 2) of model points (K, 2 or 3) (orthographic)."""
        p = np.asarray(points, dtype=float)
        q = np.c_[p[:, 0], -p[:, 1]]
        return np.asarray(self.T) + self.k * q @ rotation_2d(self.roll).T

    def invert(self, image_points) -> np.ndarray:
        """Model (x, y) of image points (K, 2)."""
        q = (np.asarray(image_points, dtype=float) - np.asarray(self.T)) @ rotation_2d(self.roll)
        q = q / self.k
        return np.c_[q[:, 0], -q[:, 1]]

    def scaled(self, factor: float) -> Framing:
        """The same framing in an image resized by ``factor`` (pixel centres scale about
        -0.5)."""
        T = (np.asarray(self.T) + 0.5) * factor - 0.5
        return Framing(self.k * factor, self.roll, (float(T[0]), float(T[1])))

    def camera_pose(self, width: int, height: int):
        """A :class:`synth.render.Camera` and :class:`HeadPose` that render this framing."""
        from synth.render import Camera, HeadPose

        cx, cy = (width - 1) / 2.0, (height - 1) / 2.0
        lx = (cx - self.T[0]) / self.k
        ly = (self.T[1] - cy) / self.k
        cam = Camera(width=int(width), height=int(height), kind="orthographic", scale=self.k,
                     focal=self.k * 60.0, distance=60.0, look_at=(lx, ly, 0.0))
        pose = HeadPose(roll=math.degrees(self.roll), centre=(0.0, 0.0, 0.0))
        return cam, pose


def head_reference(mesh) -> tuple[np.ndarray, float]:
    """Model-space head-frame origin (x, y) and scale (cm, origin to nostrils) of ``mesh``."""
    from synth.personalize import head_frame_points

    origin, nose = head_frame_points(mesh)
    return origin[:2].copy(), float(np.hypot(*(nose[:2] - origin[:2])))


def framing_from_head(head, origin_cm, scale_cm) -> Framing:
    """The similarity that puts the model's head frame onto an image head frame (x, y, s, r)."""
    hx, hy, hs, hr = (float(v) for v in head)
    k = hs / scale_cm
    T = np.array([hx, hy]) - k * rotation_2d(hr) @ np.array([origin_cm[0], -origin_cm[1]])
    return Framing(k, hr, (float(T[0]), float(T[1])))


def transfer_head_motion(heads, source_neutral, target_neutral) -> np.ndarray:
    """Head frames (T, 4) of a target that moves as the source moves from its neutral frame.

    Translation, scale ratio and roll change of each source head frame (x, y, scale, roll)
    relative to ``source_neutral`` are applied to ``target_neutral``; translations are
    rotated and scaled into the target's frame.

    Examples
    --------
    >>> h = np.array([[100.0, 80.0, 50.0, 0.0], [110.0, 80.0, 55.0, 0.1]])
    >>> transfer_head_motion(h, h[0], np.array([40.0, 30.0, 25.0, 0.0])).round(3).tolist()
    [[40.0, 30.0, 25.0, 0.0], [45.0, 30.0, 27.5, 0.1]]
    """
    h = np.asarray(heads, dtype=float)
    s0 = np.asarray(source_neutral, dtype=float)
    t0 = np.asarray(target_neutral, dtype=float)
    k = t0[2] / s0[2]
    d = (h[:, :2] - s0[:2]) @ rotation_2d(t0[3] - s0[3]).T * k
    return np.c_[t0[:2] + d, t0[2] * h[:, 2] / s0[2], t0[3] + (h[:, 3] - s0[3])]
