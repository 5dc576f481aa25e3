"""The estimators' names and what each needs, without the estimators themselves.

A command line offers and checks them before any estimator loads (``faceanalysis --help``
imports no numerical library); :data:`faceanalysis.estimation.registry.ESTIMATORS` holds
the functions behind them, in this order.
"""

from __future__ import annotations

__all__ = ["ESTIMATOR_NAMES", "MESH_ESTIMATORS", "TEMPORAL_ESTIMATORS", "VIDEO_ESTIMATORS"]

#: Every estimator, in the order they are offered.
ESTIMATOR_NAMES = ("joint", "mesh", "model", "fused", "tw93", "flow")

#: The estimators that read the landmark tracker's face mesh.
MESH_ESTIMATORS = ("mesh", "model", "fused")

#: The estimators that read the video's frames a second time (its dense flow).
VIDEO_ESTIMATORS = ("fused", "flow")

#: The estimators with the temporal prior (their ``temporal`` option).
TEMPORAL_ESTIMATORS = ("joint", "mesh", "model", "fused")
