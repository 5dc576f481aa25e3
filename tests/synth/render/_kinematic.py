"""A kinematic test driver on the real FaceMesh (not physics): smooth displacement fields per
'muscle' plus a rigid jaw rotation, with the FaceModel calls the sequence generator uses."""

import numpy as np

from synth.mesh import generate_face_mesh


def _rot_x(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


class KinematicFace:
    muscle_names = ("frontalis_inner_l", "frontalis_inner_r", "zygomaticus_major_l",
                    "zygomaticus_major_r")

    def __init__(self, shape=None):
        self.mesh = generate_face_mesh(shape)
        self._c = np.zeros(len(self.muscle_names))
        self._jaw = 0.0
        v = self.mesh.vertices
        lm = self.mesh.landmarks
        fields = []
        for name in self.muscle_names:
            if name.startswith("frontalis"):
                side = name[-1]
                centre = v[lm[f"brow_mid_{side}"]]
                d = np.array([0.0, 0.8, 0.0])
                sigma = 2.0
            else:
                side = name[-1]
                centre = v[lm[f"mouth_corner_{side}"]]
                sx = 1.0 if side == "l" else -1.0
                d = np.array([0.6 * sx, 0.6, 0.0])
                sigma = 1.5
            w = np.exp(-((v - centre) ** 2).sum(1) / (2 * sigma ** 2))
            fields.append(w[:, None] * d)
        self._fields = np.array(fields)

    def set_contractions(self, values=None, *, jaw_rotation=0.0):
        values = values or {}
        self._c = np.array([float(values.get(n, 0.0)) for n in self.muscle_names])
        self._jaw = float(jaw_rotation)

    def _jaw_apply(self, pts, weight):
        R = _rot_x(self._jaw)
        p = np.asarray(self.mesh.jaw_pivot)
        rotated = (pts - p) @ R.T + p
        return pts + weight[:, None] * (rotated - pts)

    def equilibrate(self, **kw):
        v = self.mesh.vertices + np.tensordot(self._c, self._fields, axes=1)
        self.current = self._jaw_apply(v, np.asarray(self.mesh.jaw_weight))
        return self.current

    def inner_vertices(self):
        return self._jaw_apply(np.asarray(self.mesh.inner_vertices),
                               np.asarray(self.mesh.inner_jaw_weight))

    def landmark_positions(self):
        return self.mesh.landmark_positions(self.current)
