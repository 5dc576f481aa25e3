"""The physics-based face model: mesh + tissue lattice + muscles + jaw + solvers.

>>> from synth.model import FaceModel
>>> model = FaceModel.default()
>>> model.set_contractions({"zygomaticus_major_l": 1.0, "zygomaticus_major_r": 1.0})
>>> skin = model.equilibrate()
>>> skin.shape == model.mesh.vertices.shape
True

A model owns the rest :class:`~synth.face_mesh.FaceMesh`, the :class:`~synth.lattice.Lattice`
assembled under it, the muscle force fields read from a muscle file and the current state
(node positions, velocities, contractions and jaw rotation).  ``equilibrate`` relaxes the
lattice to the equilibrium of the current contractions (prefactored implicit solver by
default, or the paper's explicit RK2 dynamics run to rest); ``step`` advances the dynamics
by one time step; ``simulate`` drives a whole contraction time series.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import numpy as np

from .facs import JAW
from .files import write_bytes_atomic
from .forces import TissueSystem
from .integrators import (
    DynamicState,
    EquilibriumSolver,
    SimulationError,
    damping_coefficients,
    rk2_step,
    stable_timestep,
    verlet_step,
)
from .lattice import Lattice, build_lattice, prism_volumes, rotate_about_jaw
from .muscles import MuscleSet, load_muscles, muscle_force_basis

__all__ = ["FaceModel", "DEFAULT_RESOLUTION", "MAX_JAW_ROTATION", "JAW"]

#: Mesh resolution of :meth:`FaceModel.default` (and of ``build`` when none is given): about
#: 330 skin vertices, 1,700 prism elements and 8,300 springs (004: ~960 elements, ~6,500
#: springs).
DEFAULT_RESOLUTION = 0.4
#: Largest jaw rotation accepted (radians), "fully open".
MAX_JAW_ROTATION = 0.5

_METHODS_EQ = ("implicit", "rk2", "verlet")
_METHODS_STEP = ("rk2", "verlet")


class FaceModel:
    """Physics-based face: trilayer tissue lattice driven by linear, sphincter and sheet muscles.

    Parameters
    ----------
    mesh : FaceMesh
        The rest skin surface (see :func:`synth.mesh.generate_face_mesh`).
    muscles : MuscleSet, str or Path, optional
        Muscles, or the muscle file to read (the shipped one when omitted).
    volume_preservation : bool
        Include the volume-preservation term (004 Q term).
    **lattice_options
        Passed to :func:`synth.lattice.build_lattice` (stiffness, bulk_modulus, ...).

    Attributes
    ----------
    mesh : FaceMesh
    lattice : Lattice
    muscles : MuscleSet
    muscle_names : tuple of str
    """

    def __init__(self, mesh, *, muscles=None, volume_preservation: bool = True,
                 **lattice_options):
        self.mesh = mesh
        self.lattice: Lattice = build_lattice(mesh, **lattice_options)
        if muscles is None or isinstance(muscles, (str, Path)):
            muscles = load_muscles(muscles)
        if not isinstance(muscles, MuscleSet):
            raise ValueError(f"muscles must be a MuscleSet or a muscle file path, got "
                             f"{type(muscles).__name__}")
        self.muscles = muscles
        self.muscle_names: tuple[str, ...] = muscles.names
        self._force_nodes, self._basis = muscle_force_basis(muscles, mesh, self.lattice)
        self.system = TissueSystem(self.lattice, volume_preservation=volume_preservation)
        self._solver: EquilibriumSolver | None = None
        self._damping: np.ndarray | None = None
        self._dt: float | None = None
        self.reset()

    # ------------------------------------------------------------------ construction
    @classmethod
    def build(cls, shape=None, *, resolution: float = DEFAULT_RESOLUTION, muscles=None,
              **options) -> FaceModel:
        """A model of the identity ``shape`` (:class:`~synth.face_shape.FaceShape`; the default face
        when omitted) at mesh ``resolution``, with the given muscles (file, set or default).

        Examples
        --------
        >>> from synth.face_shape import FaceShape
        >>> m = FaceModel.build(FaceShape.random(3), resolution=0.35)
        >>> len(m.muscle_names)
        29
        """
        from .mesh import generate_face_mesh

        return cls(generate_face_mesh(shape, resolution=resolution), muscles=muscles,
                   **options)

    @classmethod
    def default(cls) -> FaceModel:
        """The generic face at :data:`DEFAULT_RESOLUTION` with the shipped muscles."""
        return cls.build()

    # ------------------------------------------------------------------ state
    def reset(self) -> None:
        """Back to rest: zero contractions, closed jaw, rest positions, zero velocities."""
        self._contractions = np.zeros(len(self.muscle_names))
        self._jaw = 0.0
        self._x = np.array(self.lattice.rest)
        self._v = np.zeros_like(self._x)
        self._t = 0.0
        self._history: list = []          # recent (controls, equilibrium) for the predictor
        if self._solver is not None:
            self._solver.reset_history()
        self._apply_controls(previous_jaw=0.0)

    @property
    def contractions(self) -> dict[str, float]:
        """Current contractions ``{muscle: value}`` (a copy)."""
        return {n: float(c) for n, c in zip(self.muscle_names, self._contractions)}

    @property
    def jaw_rotation(self) -> float:
        """Current jaw rotation (radians)."""
        return self._jaw

    @property
    def time(self) -> float:
        """Simulated time of the dynamics (s)."""
        return self._t

    def _check_value(self, name: str, value) -> float:
        # float() reads "0.5" and True as numbers: a column read as text or a flag passed
        # by mistake would go through as a contraction
        if isinstance(value, (str, bytes, bool, np.bool_)):
            raise ValueError(f"contraction of {name!r} must be a number, got {value!r}")
        try:
            x = float(value)
        except (TypeError, ValueError):
            raise ValueError(f"contraction of {name!r} must be a number, got {value!r}") from None
        if not np.isfinite(x) or x < 0.0 or x > 1.0:
            raise ValueError(f"contraction of {name!r} must be in [0, 1], got {value!r}")
        return x

    @staticmethod
    def _check_jaw(value) -> float:
        if isinstance(value, (str, bytes, bool, np.bool_)):
            raise ValueError(f"jaw_rotation must be a number, got {value!r}")
        try:
            x = float(value)
        except (TypeError, ValueError):
            raise ValueError(f"jaw_rotation must be a number, got {value!r}") from None
        if not np.isfinite(x) or x < 0.0 or x > MAX_JAW_ROTATION:
            raise ValueError(f"jaw_rotation must be in [0, {MAX_JAW_ROTATION}] radians, "
                             f"got {value!r}")
        return x

    def set_contractions(self, values=None, *, jaw_rotation: float | None = None) -> None:
        """Set every muscle's contraction (unlisted muscles relax to 0) and the jaw.

        Parameters
        ----------
        values : dict, array, pandas Series or None
            ``{muscle: c}`` (may also hold ``"jaw_rotation"``), or an array of
            ``len(muscle_names)`` contractions in :attr:`muscle_names` order, or ``None``
            (all relaxed).  Contractions lie in [0, 1].
        jaw_rotation : float, optional
            Jaw opening in radians, in [0, :data:`MAX_JAW_ROTATION`]; 0 (closed) unless given
            here or in ``values``.

        Raises
        ------
        ValueError
            Unknown muscle names (all of them are named, with the valid names), values outside
            [0, 1] or non-finite (the muscle is named), a wrong array length, or a jaw given
            twice.

        Examples
        --------
        >>> m = FaceModel.default()
        >>> m.set_contractions({"frontalis_major_l": 0.5}, jaw_rotation=0.1)
        >>> m.contractions["frontalis_major_l"], m.jaw_rotation
        (0.5, 0.1)
        """
        c = np.zeros(len(self.muscle_names))
        jaw = None
        if values is None:
            pass
        elif isinstance(values, Mapping) or hasattr(values, "to_dict") and not isinstance(
                values, np.ndarray):
            items = dict(values.items()) if isinstance(values, Mapping) else values.to_dict()
            unknown = [k for k in items if k != JAW and k not in self.muscle_names]
            if unknown:
                raise ValueError(f"unknown muscle name(s) {unknown}; valid names: "
                                 f"{', '.join(self.muscle_names)}, {JAW}")
            index = {n: i for i, n in enumerate(self.muscle_names)}
            for k, val in items.items():
                if k == JAW:
                    jaw = self._check_jaw(val)
                else:
                    c[index[k]] = self._check_value(k, val)
        else:
            arr = np.asarray(values)
            if arr.ndim != 1 or arr.shape[0] != len(self.muscle_names):
                raise ValueError(f"a contraction array must have shape ({len(self.muscle_names)},)"
                                 f" (one value per muscle in muscle_names order), got "
                                 f"{arr.shape}")
            for k, name in enumerate(self.muscle_names):
                c[k] = self._check_value(name, arr[k])
        if jaw_rotation is not None:
            if jaw is not None:
                raise ValueError("jaw_rotation given both in values and as a keyword")
            jaw = self._check_jaw(jaw_rotation)
        previous = self._jaw
        self._contractions = c
        self._jaw = 0.0 if jaw is None else jaw
        self._apply_controls(previous_jaw=previous)

    def set_action_units(self, aus: Mapping, *, emphasis: float = 1.0) -> None:
        """Set the contractions from FACS action-unit intensities (via :mod:`synth.facs`).

        ``aus`` maps AU numbers or names (``12``, ``"AU12"``, ``"AU12_r"``...) to intensities
        (see :func:`synth.facs.aus_to_contractions`)."""
        from .facs import aus_to_contractions

        self.set_contractions(aus_to_contractions(aus, emphasis=emphasis))

    def set_expression(self, name: str, *, emphasis: float = 1.0) -> None:
        """Set the contractions of a primary expression (``'happiness'``, ...; synth.facs)."""
        from .facs import aus_to_contractions, expression_aus

        self.set_contractions(aus_to_contractions(expression_aus(name, emphasis=emphasis)))

    def muscle_load(self, contractions: np.ndarray, jaw_rotation: float) -> np.ndarray:
        """The muscles' nodal forces (n_nodes, 3) at ``contractions`` (one per
        :attr:`muscle_names`) with the jaw at ``jaw_rotation`` (radians): linear in the
        contractions; the muscles over the mandible turn with it."""
        f = np.zeros(self.lattice.rest.shape)
        if len(self._force_nodes):
            nodal = np.tensordot(np.asarray(contractions, dtype=float), self._basis, axes=1)
            if jaw_rotation != 0.0:
                w = self.lattice.jaw_weight[self._force_nodes]
                nodal = rotate_about_jaw(nodal, w, np.zeros(3), jaw_rotation)
            f[self._force_nodes] = nodal
        return f

    def _apply_controls(self, previous_jaw: float) -> None:
        self.system.set_external(self.muscle_load(self._contractions, self._jaw))
        if previous_jaw != self._jaw or self.system.jaw_rotation != self._jaw:
            self.system.set_jaw(self._jaw)
            # warm start: carry the jaw-borne tissue along with the rotation
            lat = self.lattice
            self._x = rotate_about_jaw(self._x, lat.jaw_weight, lat.jaw_pivot,
                                       self._jaw - previous_jaw)
        self.system.apply_boundary(self._x)

    # ------------------------------------------------------------------ simulation
    @property
    def solver(self) -> EquilibriumSolver:
        """The prefactored equilibrium solver (built on first use)."""
        if self._solver is None:
            self._solver = EquilibriumSolver(self.system)
        return self._solver

    @property
    def damping(self) -> np.ndarray:
        """Per-node damping coefficients (slightly over-damped, 004 III-B)."""
        if self._damping is None:
            self._damping = damping_coefficients(self.lattice)
        return self._damping

    @property
    def stable_dt(self) -> float:
        """A stable explicit time step (s) for :meth:`step`."""
        if self._dt is None:
            self._dt = stable_timestep(self.lattice, self.damping)
        return self._dt

    def equilibrate(self, *, method: str = "implicit", tol: float = 3e-4,
                    max_iter: int = 5000, max_time: float = 2.0,
                    start: np.ndarray | None = None) -> np.ndarray:
        """Relax to the equilibrium of the current contractions and jaw; returns the skin.

        Parameters
        ----------
        method : {'implicit', 'rk2', 'verlet'}
            ``'implicit'``: the prefactored quasi-static solver (fast; default).
            ``'rk2'`` / ``'verlet'``: run the explicit dynamics until the largest node speed
            and the largest step are negligible.
        tol : float
            Convergence tolerance in cm (largest quasi-Newton update, or for the explicit
            methods the largest displacement over 1 ms of simulated time).
        max_iter : int
            Iteration cap of the implicit solver.
        max_time : float
            Cap on simulated seconds for the explicit methods.
        start : (n, 3) array, optional
            Node positions the implicit solver starts from (e.g. the last equilibrium
            moved by its sensitivity to the change of the controls,
            :func:`synth.sensitivity.equilibrium_sensitivity`); by default the last
            equilibrium, extrapolated along the last change of the controls.

        Returns
        -------
        (N, 3) array: the skin vertices (a copy).

        Raises
        ------
        SimulationError
            If the solver fails to converge or the dynamics diverge.
        """
        if method not in _METHODS_EQ:
            raise ValueError(f"unknown method {method!r}; choose from {', '.join(_METHODS_EQ)}")
        if not (np.isfinite(tol) and tol > 0):
            raise ValueError(f"tol must be finite and > 0, got {tol}")
        if start is not None:
            start = np.array(start, dtype=np.float64)
            if start.shape != self._x.shape or not np.isfinite(start).all():
                raise ValueError(f"start must be finite node positions of shape "
                                 f"{self._x.shape}")
            if method != "implicit":
                raise ValueError("start goes with method='implicit'")
        if method == "implicit":
            controls = np.append(self._contractions, 3.0 * self._jaw)
            if start is None:
                x0 = self._predict(controls)
            else:
                x0 = start
                self.system.apply_boundary(x0)
            self._x = self.solver.solve(x0, tol=tol, max_iter=max_iter)
            self._v[:] = 0.0
            self._history = (self._history + [(controls, self._x.copy())])[-2:]
        else:
            dt = self.stable_dt
            stepper = rk2_step if method == "rk2" else verlet_step
            state = DynamicState(self._x, self._v, self._t)
            window = max(1, int(round(1e-3 / dt)))
            n_max = int(np.ceil(max_time / dt))
            done = False
            k = 0
            while k < n_max:
                start = state.x.copy()
                for _ in range(window):
                    stepper(self.system, state, dt, self.damping)
                k += window
                if np.abs(state.x - start).max() < tol:
                    done = True
                    break
            self._x, self._v, self._t = state.x, state.v, state.t
            if not done:
                raise SimulationError(
                    f"equilibrate(method={method!r}) did not settle within max_time={max_time}"
                    f" s of simulated time (dt={dt:.3g} s, tol={tol:g} cm)")
        return self.surface_vertices

    def _predict(self, controls: np.ndarray) -> np.ndarray:
        """Starting point for the solver: the previous equilibrium, extrapolated along the
        last change when the controls keep moving in (nearly) the same direction, as they do
        in a smooth time series."""
        x0 = self._x
        if len(self._history) == 2:
            (c_prev, x_prev), (c_last, x_last) = self._history
            u = controls - c_last
            w = c_last - c_prev
            ww = float(w @ w)
            if ww > 0 and float(u @ u) > 0:
                alpha = float(u @ w) / ww
                if 0.0 < alpha <= 2.0 and np.linalg.norm(u - alpha * w) <= 0.2 * np.linalg.norm(u):
                    x0 = x_last + alpha * (x_last - x_prev)
                    self.system.apply_boundary(x0)
        return x0

    def step(self, dt: float | None = None, *, method: str = "rk2", n_steps: int = 1
             ) -> np.ndarray:
        """Advance the dynamics (004 eq. 4) by ``n_steps`` explicit steps of ``dt`` seconds.

        Parameters
        ----------
        dt : float, optional
            Time step; :attr:`stable_dt` when omitted.
        method : {'rk2', 'verlet'}
        n_steps : int

        Returns
        -------
        (N, 3) array: the skin vertices after the steps.

        Raises
        ------
        SimulationError
            If a step produces non-finite values or a runaway (the message names dt, the
            stable time step, the jaw and the load).
        """
        if method not in _METHODS_STEP:
            raise ValueError(f"unknown method {method!r}; choose from "
                             f"{', '.join(_METHODS_STEP)}")
        if n_steps < 1:
            raise ValueError(f"n_steps must be >= 1, got {n_steps}")
        dt = self.stable_dt if dt is None else float(dt)
        if not (np.isfinite(dt) and dt > 0):
            raise ValueError(f"dt must be finite and > 0, got {dt}")
        stepper = rk2_step if method == "rk2" else verlet_step
        state = DynamicState(self._x, self._v, self._t)
        self._history = []
        try:
            for _ in range(n_steps):
                stepper(self.system, state, dt, self.damping)
        finally:
            if np.all(np.isfinite(state.x)) and np.all(np.isfinite(state.v)):
                self._x, self._v, self._t = state.x, state.v, state.t
        return self.surface_vertices

    def simulate(self, contractions, *, fps: float = 30.0, method: str = "implicit",
                 tol: float = 3e-4, strict: bool = True, reset: bool = True) -> np.ndarray:
        """Drive a contraction time series and return the skin trajectories.

        Parameters
        ----------
        contractions : pandas.DataFrame
            One row per frame, one column per muscle (missing muscles stay relaxed) and
            optionally ``jaw_rotation`` (radians).
        fps : float
            Frame rate; with ``method='rk2'`` or ``'verlet'`` the dynamics run for 1/fps
            seconds per frame (the tissue lags), with ``'implicit'`` every frame is the
            equilibrium of its contractions (warm-started from the previous frame).
        method : {'implicit', 'rk2', 'verlet'}
        tol : float
            Tolerance of the implicit solver (cm).
        strict : bool
            Raise ``ValueError`` on columns that are neither muscles nor ``jaw_rotation``;
            when False such columns (frame, timestamp, AUxx_r, ...) are ignored.
        reset : bool
            Start from rest (default) or from the current state.

        Returns
        -------
        (T, N, 3) array of skin vertex positions.
        """
        import pandas as pd

        if not isinstance(contractions, pd.DataFrame):
            raise ValueError("contractions must be a pandas DataFrame with one column per "
                             "muscle")
        if method not in _METHODS_EQ:
            raise ValueError(f"unknown method {method!r}; choose from {', '.join(_METHODS_EQ)}")
        if not (np.isfinite(fps) and fps > 0):
            raise ValueError(f"fps must be > 0, got {fps}")
        cols = [c for c in contractions.columns if c in self.muscle_names or c == JAW]
        other = [c for c in contractions.columns if c not in cols]
        if other and strict:
            raise ValueError(f"unknown column(s) {other}; valid: muscle names "
                             f"({', '.join(self.muscle_names)}) and {JAW} (or strict=False)")
        data = contractions[cols]
        index = {n: i for i, n in enumerate(self.muscle_names)}
        values = np.zeros((len(data), len(self.muscle_names)))
        jaw = np.zeros(len(data))
        for c in cols:
            col = data[c].to_numpy(dtype=float)
            if c == JAW:
                bad = ~np.isfinite(col) | (col < 0) | (col > MAX_JAW_ROTATION)
                if bad.any():
                    r = int(np.flatnonzero(bad)[0])
                    raise ValueError(f"{JAW} must be in [0, {MAX_JAW_ROTATION}] radians; row "
                                     f"{r} has {col[r]!r}")
                jaw = col
            else:
                bad = ~np.isfinite(col) | (col < 0) | (col > 1)
                if bad.any():
                    r = int(np.flatnonzero(bad)[0])
                    raise ValueError(f"contraction of {c!r} must be in [0, 1]; row {r} has "
                                     f"{col[r]!r}")
                values[:, index[c]] = col
        if reset:
            self.reset()
        out = np.empty((len(data), self.lattice.n_vertices, 3))
        dt_frame = 1.0 / fps
        for t in range(len(data)):
            self.set_contractions(values[t], jaw_rotation=float(jaw[t]))
            if method == "implicit":
                self.equilibrate(tol=tol)
            else:
                n = max(1, int(np.ceil(dt_frame / self.stable_dt)))
                self.step(dt_frame / n, method=method, n_steps=n)
            out[t] = self.surface_vertices
        return out

    # ------------------------------------------------------------------ observables
    @property
    def node_positions(self) -> np.ndarray:
        """(n, 3) current positions of every lattice node (a copy)."""
        return self._x.copy()

    @property
    def surface_vertices(self) -> np.ndarray:
        """(N, 3) current skin (epidermis) vertices (a copy)."""
        return self._x[: self.lattice.n_vertices].copy()

    @property
    def triangles(self) -> np.ndarray:
        """(M, 3) skin triangles (counter-clockwise seen from outside)."""
        return np.asarray(self.mesh.triangles)

    def normals(self) -> np.ndarray:
        """(N, 3) unit vertex normals of the current skin surface."""
        from .lattice import mesh_vertex_normals

        return mesh_vertex_normals(self.surface_vertices, self.mesh.triangles)

    def landmark_positions(self) -> dict[str, np.ndarray]:
        """Current 3-D position of every named landmark of the mesh."""
        v = self._x
        return {name: v[i].copy() for name, i in self.mesh.landmarks.items()}

    def inner_vertices(self) -> np.ndarray:
        """Current positions of the inner parts (eyeballs, mouth cavity, teeth): the jaw
        rotation applied to those that follow the mandible."""
        iv = np.asarray(self.mesh.inner_vertices, dtype=np.float64)
        if len(iv) == 0 or self._jaw == 0.0:
            return iv.copy()
        return rotate_about_jaw(iv, np.asarray(self.mesh.inner_jaw_weight),
                                np.asarray(self.mesh.jaw_pivot), self._jaw)

    def tissue_volume(self) -> float:
        """Total current volume of the tissue elements (cm³)."""
        return float(prism_volumes(self._x, self.lattice.prisms).sum())

    def skull_clearance(self) -> np.ndarray:
        """Height of every constrained fascia node above the skull surface under it (cm)."""
        return self.system.skull_heights(self._x)

    # ------------------------------------------------------------------ export
    def to_obj(self, path) -> Path:
        """Write the current skin surface as a Wavefront OBJ (vertices, uv, normals).

        Returns the path written."""
        path = Path(path)
        v = self.surface_vertices
        n = self.normals()
        uv = np.asarray(self.mesh.uv)
        t = np.asarray(self.mesh.triangles) + 1
        lines = ["# synth FaceModel skin (cm; x = subject's left, y = up, z = toward viewer)"]
        lines += [f"v {a:.6f} {b:.6f} {c:.6f}" for a, b, c in v]
        lines += [f"vt {a:.6f} {1.0 - b:.6f}" for a, b in uv]
        lines += [f"vn {a:.6f} {b:.6f} {c:.6f}" for a, b, c in n]
        lines += [f"f {a}/{a}/{a} {b}/{b}/{b} {c}/{c}/{c}" for a, b, c in t]
        write_bytes_atomic(path, ("\n".join(lines) + "\n").encode("ascii"))
        return path

    def to_ply(self, path) -> Path:
        """Write the current skin surface as a binary little-endian PLY (with normals).

        Returns the path written."""
        path = Path(path)
        v = self.surface_vertices.astype("<f4")
        n = self.normals().astype("<f4")
        t = np.asarray(self.mesh.triangles, dtype="<i4")
        header = (
            "ply\nformat binary_little_endian 1.0\n"
            "comment synth FaceModel skin (cm)\n"
            f"element vertex {len(v)}\n"
            "property float x\nproperty float y\nproperty float z\n"
            "property float nx\nproperty float ny\nproperty float nz\n"
            f"element face {len(t)}\nproperty list uchar int vertex_indices\nend_header\n"
        ).encode("ascii")
        vert = np.concatenate([v, n], axis=1).tobytes()
        faces = np.empty(len(t), dtype=[("n", "u1"), ("i", "<i4", (3,))])
        faces["n"] = 3
        faces["i"] = t
        write_bytes_atomic(path, header + vert + faces.tobytes())
        return path

    def __repr__(self) -> str:
        lat = self.lattice
        return (f"FaceModel({lat.n_vertices} skin vertices, {lat.n_elements} elements, "
                f"{lat.n_springs} springs, {len(self.muscle_names)} muscles)")
