"""Deformable contours (snakes), image potentials, face layout and fiducial points.

``trackers`` works on any image sequence and knows nothing about the face model.
"""
