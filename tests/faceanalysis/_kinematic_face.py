"""A kinematic face for tests of the analysis while the physics model is elsewhere.

The real generic mesh (:func:`synth.mesh.generate_face_mesh`) moved by one smooth
displacement field per observed muscle and a rigid jaw rotation: enough to render
synthetic face videos with :func:`synth.render.sequence.synthesize` and to tabulate a
fiducial response with :func:`faceanalysis.estimation.model_response.tabulate_response`. Not
physics: fields are Gaussian bumps around the landmark each muscle moves.
"""

from __future__ import annotations

import numpy as np

from synth.mesh import generate_face_mesh

# muscle -> (landmark stem, displacement in cm at full contraction for the subject's
# left side; x is mirrored for the right side), Gaussian width in cm
_FIELDS = {
    "frontalis_inner": ("brow_inner", (0.0, 0.7, 0.0), 1.5),
    "frontalis_major": ("brow_mid", (0.0, 0.8, 0.0), 1.8),
    "frontalis_outer": ("brow_outer", (0.0, 0.7, 0.0), 1.5),
    "corrugator": ("brow_inner", (-0.4, -0.2, 0.0), 1.2),
    "zygomaticus_major": ("mouth_corner", (0.5, 0.6, 0.0), 1.5),
    "depressor_anguli": ("mouth_corner", (0.1, -0.6, 0.0), 1.3),
    "levator_labii_nasi": ("furrow_top", (0.0, 0.5, 0.0), 1.2),
}


def _rot_x(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


class KinematicFace:
    """FaceModel-like: ``mesh``, ``muscle_names``, ``set_contractions``, ``equilibrate``,
    ``inner_vertices``, ``landmark_positions``, ``reset``."""

    def __init__(self, shape=None):
        self.mesh = generate_face_mesh(shape)
        v = self.mesh.vertices
        names, fields = [], []
        for muscle, (stem, d, sigma) in _FIELDS.items():
            for side, sx in (("l", 1.0), ("r", -1.0)):
                centre = v[self.mesh.landmarks[f"{stem}_{side}"]]
                w = np.exp(-((v - centre) ** 2).sum(1) / (2 * sigma ** 2))
                names.append(f"{muscle}_{side}")
                fields.append(w[:, None] * np.array([d[0] * sx, d[1], d[2]]))
        self.muscle_names = tuple(names)
        self._fields = np.array(fields)
        self.reset()

    def reset(self) -> None:
        self._c = np.zeros(len(self.muscle_names))
        self._jaw = 0.0
        self.current = self.mesh.vertices.copy()

    def set_contractions(self, values=None, *, jaw_rotation: float = 0.0) -> None:
        values = values or {}
        self._c = np.array([float(values.get(n, 0.0)) for n in self.muscle_names])
        self._jaw = float(jaw_rotation)

    def _jaw_apply(self, pts, weight):
        p = np.asarray(self.mesh.jaw_pivot)
        rotated = (pts - p) @ _rot_x(self._jaw).T + p
        return pts + np.asarray(weight)[:, None] * (rotated - pts)

    def equilibrate(self, **kwargs) -> np.ndarray:
        v = self.mesh.vertices + np.tensordot(self._c, self._fields, axes=1)
        self.current = self._jaw_apply(v, self.mesh.jaw_weight)
        return self.current

    def inner_vertices(self) -> np.ndarray:
        return self._jaw_apply(np.asarray(self.mesh.inner_vertices), self.mesh.inner_jaw_weight)

    def landmark_positions(self) -> dict:
        return self.mesh.landmark_positions(self.current)
