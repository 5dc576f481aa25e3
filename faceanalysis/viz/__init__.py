"""Figures: the contraction time-series plot (:mod:`.plots`) and frame overlays of
contours, fiducials and head frame (:mod:`.overlay`)."""
