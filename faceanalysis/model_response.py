"""Tabulate a face model's fiducial response (see :mod:`faceanalysis.response`).

The table costs one equilibrium per muscle and level, so it is cached on disk,
keyed by a hash of everything that determines it (model geometry, muscle
parameters, controls, levels, toolkit version).
"""

from __future__ import annotations

import hashlib
import logging
import os
from pathlib import Path

import numpy as np

from faceanalysis._version import __version__
from faceanalysis.outputs import atomic_path
from faceanalysis.response import FiducialResponse
from faceanalysis.table import FIDUCIALS

log = logging.getLogger(__name__)

#: Controls estimated by default: the muscles whose action the 11 fiducials observe
#: (004 V-D reads frontalis, zygomaticus major, depressor labii, levator labii
#: alaeque nasi and the jaw from them; corrugator and depressor anguli move the
#: same points in directions no other muscle does).
OBSERVED_CONTROLS: tuple[str, ...] = (
    *(f"frontalis_{part}_{s}" for part in ("inner", "major", "outer") for s in "lr"),
    *(f"corrugator_{s}" for s in "lr"),
    *(f"zygomaticus_major_{s}" for s in "lr"),
    *(f"depressor_anguli_{s}" for s in "lr"),
    *(f"levator_labii_nasi_{s}" for s in "lr"),
    "jaw_rotation",
)

#: Largest jaw rotation tabulated, radians (about 20 degrees: a wide-open mouth).
JAW_MAX = 0.35


def cache_dir() -> Path:
    """Folder for cached tables: ``$FACEANALYSIS_CACHE`` or ``~/.cache/faceanalysis``."""
    root = os.environ.get("FACEANALYSIS_CACHE")
    return Path(root) if root else Path.home() / ".cache" / "faceanalysis"


def _model_key(model, controls: tuple[str, ...], n_levels: int, jaw_max: float) -> str:
    h = hashlib.sha1()
    h.update(__version__.encode())
    h.update(np.ascontiguousarray(model.mesh.vertices, dtype=np.float64).tobytes())
    h.update(np.ascontiguousarray(model.mesh.triangles).tobytes())
    h.update(repr(getattr(model, "parameters_digest", lambda: "")()).encode())
    h.update(repr((controls, n_levels, jaw_max)).encode())
    return h.hexdigest()[:16]


def _fiducial_xy(model) -> np.ndarray:
    positions = model.landmark_positions()
    return np.array([positions[name][:2] for name in FIDUCIALS], dtype=float)


def tabulate_response(model, controls: tuple[str, ...] = OBSERVED_CONTROLS, *,
                      n_levels: int = 6, jaw_max: float = JAW_MAX) -> FiducialResponse:
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
    model.set_contractions(None)
    model.equilibrate()
    rest = _fiducial_xy(model)
    disp = np.zeros((len(controls), n_levels, len(FIDUCIALS), 2))
    upper = np.array([jaw_max if c == "jaw_rotation" else 1.0 for c in controls])
    for m, name in enumerate(controls):
        for k, level in enumerate(levels[1:], start=1):
            if name == "jaw_rotation":
                model.set_contractions(None, jaw_rotation=level * jaw_max)
            else:
                model.set_contractions({name: level})
            model.equilibrate()
            disp[m, k] = _fiducial_xy(model) - rest
    model.reset()
    return FiducialResponse(tuple(controls), FIDUCIALS, rest, disp, upper, levels)


def model_response(model=None, controls: tuple[str, ...] = OBSERVED_CONTROLS, *,
                   n_levels: int = 6, jaw_max: float = JAW_MAX,
                   use_cache: bool = True) -> FiducialResponse:
    """The fiducial response of ``model`` (default: the generic face), cached on disk."""
    if model is None:
        from synth import FaceModel

        model = FaceModel.default()
    key = _model_key(model, tuple(controls), n_levels, jaw_max)
    path = cache_dir() / f"response-{key}.npz"
    if use_cache and path.is_file():
        try:
            return FiducialResponse.load(path)
        except (OSError, ValueError, KeyError) as exc:   # a damaged cache is rebuilt
            log.warning("ignoring unreadable response cache %s (%s)", path, exc)
    response = tabulate_response(model, tuple(controls), n_levels=n_levels, jaw_max=jaw_max)
    if use_cache:
        try:
            with atomic_path(path) as tmp:
                response.save(tmp)
        except OSError as exc:                            # read-only home: run uncached
            log.debug("could not cache the response table: %s", exc)
    return response
