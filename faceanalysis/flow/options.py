"""The flow commands' choices and defaults, without the flow itself: a command line offers
them before OpenCV loads (:mod:`.dense` and :mod:`.recognition` use them)."""

from __future__ import annotations

__all__ = ["FLOW_METHODS", "REST_LOOKBACK"]

#: Optical-flow methods, first = default.
FLOW_METHODS = ("dis", "farneback", "tvl1")

#: Frames before the classified range searched for the rest frame by default.
REST_LOOKBACK = 240
