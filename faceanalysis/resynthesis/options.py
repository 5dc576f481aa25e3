"""The resynthesis's choices, without the renderer: a command line offers them before the
face model loads (:mod:`.render` and :mod:`.export` use them)."""

from __future__ import annotations

__all__ = ["MESH_FORMATS", "SHADINGS", "VIEWS"]

#: Views of :func:`~faceanalysis.resynthesis.pipeline.resynthesize`: yaw of the head in degrees.
VIEWS: dict[str, float] = {"front": 0.0, "three-quarter": 40.0, "profile": 90.0}

#: Shadings of :func:`~faceanalysis.resynthesis.pipeline.resynthesize`.
SHADINGS: tuple[str, ...] = ("textured", "plain", "wireframe")

#: Per-frame mesh formats of ``export_meshes`` (a path ending in ``.npz`` writes one file).
MESH_FORMATS: tuple[str, ...] = ("obj", "ply")
