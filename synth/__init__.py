"""Physics-based anatomical face model and headless renderer with exact ground truth.

``synth`` knows nothing about trackers or the analysis pipeline.
"""

from __future__ import annotations

import importlib

# Public name -> the module that defines it: loaded on first use, so that importing one
# module of the package (its files, the face's shape) does not load the simulation and
# the renderer.
_EXPORTS: dict[str, str] = {
    "SimulationError": "synth.integrators",
    "Lattice": "synth.lattice",
    "build_lattice": "synth.lattice",
    "FaceModel": "synth.model",
    "MuscleSet": "synth.muscles",
    "load_muscles": "synth.muscles",
    "Camera": "synth.render",
    "HeadPose": "synth.render",
    "Light": "synth.render",
    "Renderer": "synth.render",
    "RenderResult": "synth.render",
    "default_camera": "synth.render",
    "paint_skin_texture": "synth.render",
    "project": "synth.render",
    "render_sequence": "synth.render",
    "synthesize": "synth.render",
}

__all__ = [*_EXPORTS]


def __getattr__(name: str):
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value         # later look-ups skip this function
    return value


def __dir__() -> list[str]:
    return sorted(__all__)
