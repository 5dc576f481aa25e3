"""Facial motion analysis: from a face video to muscle contractions and back.

The toolkit has three packages: :mod:`trackers` (deformable contours and fiducial
points on any image sequence), :mod:`synth` (a physics-based anatomical face model
and a headless renderer with exact ground truth) and :mod:`faceanalysis`, which
composes them into the analysis, resynthesis and evaluation pipeline.
"""

from faceanalysis._version import __version__
from faceanalysis.errors import FaceAnalysisError

__all__ = ["__version__", "FaceAnalysisError"]


def __getattr__(name):
    """Lazy exports (importing them pulls in the face model and the renderer)."""
    if name == "resynthesize":
        from faceanalysis.resynthesis.pipeline import resynthesize

        return resynthesize
    raise AttributeError(f"module 'faceanalysis' has no attribute {name!r}")
