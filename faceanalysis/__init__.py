"""Facial motion analysis: from a face video to muscle contractions and back.

``import faceanalysis as fa`` is all a user needs::

    result = fa.analyze("clip.mp4")          # track, calibrate, estimate
    result.save("results/")                  # contractions.csv, analysis.json, plot
    table = fa.read_contractions("results/contractions.csv")
    fa.resynthesize(table, output="resynth.mp4")
    fa.evaluate("seq/truth.csv", "results/contractions.csv")

The names below are loaded on first use, so ``import faceanalysis`` stays cheap.

The toolkit has three packages: :mod:`trackers` (deformable contours and fiducial
points on any image sequence), :mod:`synth` (a physics-based anatomical face model and a
headless renderer with exact ground truth) and :mod:`faceanalysis`, which composes them.
Inside :mod:`faceanalysis` imports go one way, from the top down:

``cli`` > ``batch`` > ``evaluation`` > ``resynthesis`` > ``analysis`` > ``estimation`` >
``flow`` > ``tracking`` > ``viz`` > ``io``.
"""

from __future__ import annotations

import importlib

from faceanalysis._version import __version__
from faceanalysis.errors import FaceAnalysisError

# Public name -> the module that defines it.
_EXPORTS: dict[str, str] = {
    # analysis
    "analyze": "faceanalysis.analysis.pipeline",
    "analyze_to_folder": "faceanalysis.analysis.pipeline",
    "reestimate": "faceanalysis.analysis.pipeline",
    "Analysis": "faceanalysis.analysis.results",
    # tracking and input/output
    "track": "faceanalysis.tracking",
    "Tracks": "faceanalysis.tracking",
    "open_video": "faceanalysis.io.video",
    "Frames": "faceanalysis.io.video",
    "read_contractions": "faceanalysis.io.table",
    "write_contractions": "faceanalysis.io.table",
    "read_analysis": "faceanalysis.io.report",
    "FIDUCIALS": "faceanalysis.io.table",
    "MUSCLES": "faceanalysis.io.table",
    "JAW": "faceanalysis.io.table",
    "ESTIMATORS": "faceanalysis.estimation.registry",
    # figures
    "plot_contractions": "faceanalysis.viz.plots",
    "draw_overlay": "faceanalysis.viz.overlay",
    # flow
    "video_face_flow": "faceanalysis.flow.dense",
    "default_templates": "faceanalysis.flow.templates",
    "make_templates": "faceanalysis.flow.templates",
    "classify_video": "faceanalysis.flow.recognition",
    # resynthesis and evaluation
    "resynthesize": "faceanalysis.resynthesis.pipeline",
    "evaluate": "faceanalysis.evaluation.scores",
    "run_suite": "faceanalysis.evaluation.suite",
    "validate": "faceanalysis.evaluation.validation",
    "run_demo": "faceanalysis.evaluation.demo",
    # many videos
    "run_batch": "faceanalysis.batch",
}

__all__ = ["__version__", "FaceAnalysisError", *_EXPORTS]


def __getattr__(name: str):
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'faceanalysis' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value         # later look-ups skip this function
    return value


def __dir__() -> list[str]:
    # the public names only (not ``importlib`` or ``annotations``): what tab completion offers
    return sorted(__all__)
