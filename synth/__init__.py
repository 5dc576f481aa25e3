"""Physics-based anatomical face model and headless renderer with exact ground truth.

``synth`` knows nothing about trackers or the analysis pipeline.
"""
