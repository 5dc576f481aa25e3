"""Physics-based anatomical face model and headless renderer with exact ground truth.

``synth`` knows nothing about trackers or the analysis pipeline.
"""

from synth.integrators import SimulationError  # noqa: E402,F401
from synth.lattice import Lattice, build_lattice  # noqa: E402,F401
from synth.model import FaceModel  # noqa: E402,F401  (physics model exports)
from synth.muscles import MuscleSet, load_muscles  # noqa: E402,F401
from synth.render import (  # noqa: E402,F401  (renderer exports)
    Camera,
    HeadPose,
    Light,
    Renderer,
    RenderResult,
    default_camera,
    paint_skin_texture,
    project,
    render_sequence,
    synthesize,
)
