"""Tabulate a face model's fiducial response (see :mod:`faceanalysis.estimation.response`).

The table costs one equilibrium per muscle and level, so it is cached on disk,
keyed by a hash of everything that determines it (model geometry, muscle
parameters, controls, levels, toolkit version).
"""

from __future__ import annotations

import logging

import numpy as np

from faceanalysis._version import __version__
from faceanalysis.estimation.mesh_points import MESH_POINT_PREFIX, surface_points
from faceanalysis.estimation.response import FiducialResponse
from faceanalysis.io.cache import cache_dir, digest_of, source_digest
from faceanalysis.io.outputs import atomic_path
from faceanalysis.io.table import FIDUCIALS
from faceanalysis.tracking import CURVE_POINTS

log = logging.getLogger(__name__)

#: Controls estimated by default: every muscle whose action on the measurement points
#: is distinct from the others' (their full-contraction signatures have cosine < 0.95
#: with every other control's on the generic face). 004 (V-D) reads frontalis,
#: zygomaticus major, depressor labii, levator labii alaeque nasi and the jaw; the
#: others are added because leaving out a muscle that moves the points makes the
#: estimator blame its motion on the muscles it does estimate. Near twins are left
#: out: zygomaticus minor (cosine 0.98 with major) and buccinator (0.98 with risorius).
OBSERVED_CONTROLS: tuple[str, ...] = (
    *(f"frontalis_{part}_{s}" for part in ("inner", "major", "outer") for s in "lr"),
    *(f"{m}_{s}" for m in ("corrugator", "orbicularis_oculi", "zygomaticus_major",
                           "levator_labii_nasi", "levator_labii", "depressor_anguli",
                           "depressor_labii", "mentalis", "risorius") for s in "lr"),
    "orbicularis_oris",
    "jaw_rotation",
)

#: Largest jaw rotation tabulated, radians (about 20 degrees: a wide-open mouth).
JAW_MAX = 0.35


def _model_key(model, controls: tuple[str, ...], n_levels: int, jaw_max: float,
               n_samples: int, points: tuple[str, ...] = ()) -> str:
    return digest_of([
        __version__.encode(),
        np.ascontiguousarray(model.mesh.vertices, dtype=np.float64).tobytes(),
        np.ascontiguousarray(model.mesh.triangles).tobytes(),
        repr(getattr(model, "parameters_digest", lambda: "")()).encode(),
        repr((controls, n_levels, jaw_max, n_samples, points or MEASUREMENT_POINTS,
              sorted(CURVE_POINTS.items()))).encode(),
        # the physics code: a solver change makes the table stale
        source_digest(("synth",), ("faceanalysis.estimation.model_response",
                                    "faceanalysis.estimation.response",
                                    "faceanalysis.estimation.mesh_points")).encode(),
    ])


#: Measurement points: the 11 fiducials of 004, the centre of the lower lip's lower
#: border, which the lower-lip snake tracks and which no fiducial observes (it is what
#: tells depressor labii, mentalis and orbicularis oris apart from the jaw), and the
#: :data:`CURVE_POINTS`.
MEASUREMENT_POINTS: tuple[str, ...] = (*FIDUCIALS, "lip_lower_centre", *CURVE_POINTS)


def model_points(model, vertices: np.ndarray, points=MEASUREMENT_POINTS) -> np.ndarray:
    """Orthographic x-y (cm) of the measurement ``points`` on the skin ``vertices`` of
    ``model`` (landmarks of its mesh, :data:`CURVE_POINTS` on its feature curves, or
    face-mesh landmarks ``mesh_<i>`` on the skin point under them,
    :func:`~faceanalysis.estimation.mesh_points.surface_points`), shape (P, 2)."""
    from trackers.fiducials import arc_point

    mesh = model.mesh
    v = np.asarray(vertices, dtype=np.float64)
    if v.shape != np.shape(mesh.vertices):
        raise ValueError(f"vertices must have shape {np.shape(mesh.vertices)}, got {v.shape}")
    out = np.empty((len(points), 2))
    curves: dict[str, np.ndarray] = {}                 # each curve once per call
    surface = None
    for j, name in enumerate(points):
        if name.startswith(MESH_POINT_PREFIX):
            if surface is None:
                surface = surface_points([p for p in points if p.startswith(MESH_POINT_PREFIX)])
            verts, bary = surface[name]
            out[j] = bary @ v[verts, :2]
        elif name in CURVE_POINTS:
            curve, fraction = CURVE_POINTS[name]
            if curve not in curves:
                curves[curve] = mesh.curve_positions(curve, v)[:, :2]
            out[j] = arc_point(curves[curve], fraction)
        elif name in mesh.landmarks:
            out[j] = v[mesh.landmarks[name], :2]
        else:
            raise ValueError(f"the face model has no measurement point {name!r}")
    return out


def equilibrium_points(model, controls, values, points=MEASUREMENT_POINTS, *,
                       tol: float | None = None) -> np.ndarray:
    """Equilibrate ``model`` at ``values`` of ``controls`` (muscles and/or
    ``"jaw_rotation"``; unlisted muscles at rest) and return the orthographic x-y of
    ``points`` (cm), shape (P, 2). ``tol``: the solver's tolerance (cm; default its own,
    whose equilibria depend on where it starts by up to a few hundredths of a
    millimetre)."""
    muscles = {n: float(v) for n, v in zip(controls, values) if n != "jaw_rotation"}
    jaw = float(dict(zip(controls, values)).get("jaw_rotation", 0.0))
    model.set_contractions(muscles or None, jaw_rotation=jaw)
    skin = (model.equilibrate() if tol is None
            else model.equilibrate(tol=tol, max_iter=50000))
    return model_points(model, skin, points)


def _interaction_pairs(main: np.ndarray, threshold: float) -> np.ndarray:
    """Pairs of controls whose full responses both move some fiducial by > threshold cm."""
    moves = np.linalg.norm(main, axis=-1) > threshold          # (M, F)
    m = main.shape[0]
    return np.array([(a, b) for a in range(m) for b in range(a + 1, m)
                     if np.any(moves[a] & moves[b])], dtype=np.intp).reshape(-1, 2)


def tabulate_response(model, controls: tuple[str, ...] = OBSERVED_CONTROLS, *,
                      n_levels: int = 6, jaw_max: float = JAW_MAX,
                      n_samples: int = 480, seed: int = 0,
                      points: tuple[str, ...] = MEASUREMENT_POINTS) -> FiducialResponse:
    """Equilibrate ``model`` with one control at a time and record fiducial motion.

    Parameters
    ----------
    model : synth.FaceModel
        The face model (its state is reset before and after).
    controls : tuple of str
        Muscle names and/or ``"jaw_rotation"``.
    n_levels : int, keyword-only
        Number of uniform levels from 0 to full contraction (at least 2).
    jaw_max : float, keyword-only
        Jaw rotation (radians) at the top level.
    n_samples : int, keyword-only
        Random combinations of contractions at which the model is equilibrated to fit
        the pairwise interaction terms (0: additive table only).
    seed : int, keyword-only
        Seed of those combinations.
    points : tuple of str, keyword-only
        The measurement points (default :data:`MEASUREMENT_POINTS`; see
        :func:`model_points`).

    Returns
    -------
    FiducialResponse
    """
    if n_levels < 2:
        raise ValueError(f"n_levels must be >= 2, got {n_levels}")
    unknown = [c for c in controls if c != "jaw_rotation" and c not in model.muscle_names]
    if unknown:
        raise ValueError(f"unknown muscles {unknown}; the model has {list(model.muscle_names)}")
    levels = np.linspace(0.0, 1.0, n_levels)
    model.reset()
    rest = equilibrium_points(model, (), (), points)
    disp = np.zeros((len(controls), n_levels, len(points), 2))
    upper = np.array([jaw_max if c == "jaw_rotation" else 1.0 for c in controls])
    for m, name in enumerate(controls):
        for k, level in enumerate(levels[1:], start=1):
            disp[m, k] = equilibrium_points(model, (name,), (level * upper[m],), points) - rest
    additive = FiducialResponse(tuple(controls), tuple(points), rest, disp, upper, levels)
    if n_samples <= 0:
        model.reset()
        return additive
    # Interactions: equilibria at random sparse combinations (each control active with
    # probability 0.35, uniform level), minus the additive prediction, regressed by
    # ridge least squares on the products of normalised contractions of the pairs
    # that share a fiducial.
    pairs = _interaction_pairs(disp[:, -1], threshold=0.02)
    rng = np.random.default_rng(seed)
    active = rng.random((n_samples, len(controls))) < 0.35
    c = np.where(active, rng.random((n_samples, len(controls))), 0.0) * upper
    observed = np.empty((n_samples, len(points), 2))
    model.reset()
    for i in range(n_samples):
        observed[i] = equilibrium_points(model, controls, c[i], points) - rest
    model.reset()
    residual = (observed - additive.predict(c)).reshape(n_samples, -1)
    u = c / upper
    features = u[:, pairs[:, 0]] * u[:, pairs[:, 1]]               # (S, P)
    ridge = 1e-3 * n_samples
    gram = features.T @ features + ridge * np.eye(len(pairs))
    weights = np.linalg.solve(gram, features.T @ residual)         # (P, F*2)
    return FiducialResponse(tuple(controls), tuple(points), rest, disp, upper, levels, pairs,
                            weights.reshape(len(pairs), len(points), 2))


#: The generic face's responses read in this process, by their arguments: building the
#: default model to find its cache file costs more than a frame's estimate of a short clip.
_DEFAULT_RESPONSES: dict[tuple, FiducialResponse] = {}


def model_response(model=None, controls: tuple[str, ...] | None = None, *,
                   n_levels: int = 6, jaw_max: float = JAW_MAX, n_samples: int = 480,
                   points: tuple[str, ...] = MEASUREMENT_POINTS,
                   use_cache: bool = True) -> FiducialResponse:
    """The fiducial response of ``model`` (default: the generic face), cached on disk.

    ``controls`` defaults to the :data:`OBSERVED_CONTROLS` that the model has (a model
    built from a user's muscle file may lack some).
    """
    memo = (None if model is not None or not use_cache else
            (controls, n_levels, jaw_max, n_samples, tuple(points)))
    if memo is not None and memo in _DEFAULT_RESPONSES:
        return _DEFAULT_RESPONSES[memo]
    if model is None:
        from synth import FaceModel

        model = FaceModel.default()
    if controls is None:
        controls = tuple(c for c in OBSERVED_CONTROLS
                         if c == "jaw_rotation" or c in model.muscle_names)
    key = _model_key(model, tuple(controls), n_levels, jaw_max, n_samples, tuple(points))
    path = cache_dir() / f"response-{key}.npz"
    if use_cache and path.is_file():
        try:
            response = FiducialResponse.load(path)
        except (OSError, ValueError, KeyError) as exc:   # a damaged cache is rebuilt
            log.warning("ignoring unreadable response cache %s (%s)", path, exc)
        else:
            if memo is not None:
                _DEFAULT_RESPONSES[memo] = response
            return response
    response = tabulate_response(model, tuple(controls), n_levels=n_levels, jaw_max=jaw_max,
                                 n_samples=n_samples, points=tuple(points))
    if use_cache:
        try:
            with atomic_path(path) as tmp:
                response.save(tmp)
        except OSError as exc:                            # read-only home: run uncached
            log.debug("could not cache the response table: %s", exc)
    return response
