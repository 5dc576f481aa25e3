"""Lights and materials of the renderer (Lambert diffuse + Blinn-Phong specular).

Materials are small integers per triangle: ``SKIN`` (0, textured by the mesh's uv),
``EYE`` (1, the eye texture by the inner parts' uv), ``MOUTH`` (2, dark cavity) and
``TEETH`` (3), matching ``FaceMesh.inner_material`` (1, 2, 3).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Light", "SKIN", "EYE", "MOUTH", "TEETH", "FLAT_COLOURS", "SPECULAR",
           "eye_texture"]

SKIN, EYE, MOUTH, TEETH = 0, 1, 2, 3

#: albedo of the flat materials (rows indexed by material; rows 0/1 unused)
FLAT_COLOURS = np.array([[0.0, 0.0, 0.0],
                         [0.0, 0.0, 0.0],
                         [0.16, 0.05, 0.05],
                         [0.86, 0.84, 0.76]])
#: specular strength per material
SPECULAR = np.array([0.10, 0.45, 0.04, 0.25])


@dataclass(frozen=True)
class Light:
    """One directional light plus ambient.

    Parameters
    ----------
    direction : tuple of 3 floats
        Direction *toward* the light in camera space (x right on screen, y up, z toward the
        camera); normalised internally. Default: from the upper left, in front.
    colour : tuple of 3 floats
        RGB intensity multiplier (1 = unchanged albedo at normal incidence).
    ambient : float
        Fraction of the albedo lit regardless of orientation, in [0, 1].
    shininess : float
        Blinn-Phong exponent.
    specular_scale : float
        Multiplier of the per-material specular strengths.
    """

    direction: tuple = (-0.2, 0.15, 1.0)
    colour: tuple = (1.0, 1.0, 1.0)
    ambient: float = 0.55
    shininess: float = 24.0
    specular_scale: float = 1.0

    def __post_init__(self):
        d = np.asarray(self.direction, dtype=float)
        if d.shape != (3,) or not np.all(np.isfinite(d)) or np.linalg.norm(d) == 0:
            raise ValueError(f"light direction {self.direction!r} must be a non-zero 3-vector")
        if not 0.0 <= self.ambient <= 1.0:
            raise ValueError(f"ambient={self.ambient} must be in [0, 1]")
        if len(self.colour) != 3 or min(self.colour) < 0:
            raise ValueError(f"light colour {self.colour!r} must be 3 non-negative floats")
        if self.shininess <= 0:
            raise ValueError(f"shininess={self.shininess} must be positive")

    @property
    def unit_direction(self) -> np.ndarray:
        d = np.asarray(self.direction, dtype=np.float64)
        return d / np.linalg.norm(d)

    def as_dict(self) -> dict:
        return {"direction": [float(v) for v in self.direction],
                "colour": [float(v) for v in self.colour], "ambient": float(self.ambient),
                "shininess": float(self.shininess),
                "specular_scale": float(self.specular_scale)}


def eye_texture(iris_colour=(0.35, 0.22, 0.12), *, size: int = 128, iris_radius: float = 0.22,
                pupil_radius: float = 0.09, centre=(0.5, 0.5)) -> np.ndarray:
    """Texture (size, size, 3) float32 of an eye in its uv square: sclera, iris, pupil.

    The iris is a disc of radius ``iris_radius`` (uv units) about ``centre`` with radial
    streaks, a dark limbal ring and a black pupil.

    Examples
    --------
    >>> tex = eye_texture(size=64)
    >>> tex.shape, bool(tex[32, 32].max() < 0.1), bool(tex[2, 2].min() > 0.7)
    ((64, 64, 3), True, True)
    """
    if size < 8:
        raise ValueError(f"eye texture size={size} must be at least 8")
    v, u = (np.mgrid[0:size, 0:size] + 0.5) / size
    du = u - centre[0]
    dv = v - centre[1]
    rad = np.hypot(du, dv)
    ang = np.arctan2(dv, du)
    sclera = np.array([0.92, 0.90, 0.86])
    iris = np.asarray(iris_colour, dtype=float)
    streak = 0.85 + 0.15 * np.cos(ang * 23.0) * np.cos(ang * 7.0 + 1.0)
    tex = np.empty((size, size, 3))
    tex[:] = sclera
    inside = rad < iris_radius
    tex[inside] = (iris[None, :] * streak[inside][:, None])
    ring = (rad > iris_radius * 0.82) & inside
    tex[ring] *= 0.55
    tex[rad < pupil_radius] = 0.03
    return tex.astype(np.float32)
