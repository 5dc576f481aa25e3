"""Synthetic images with known edges for the tracker tests."""

from __future__ import annotations

import numpy as np
import pytest


def render_ellipse(shape, cx, cy, ax, ay, *, inside=220.0, outside=30.0, ss=4):
    """Anti-aliased filled ellipse (supersampled), uint8."""
    H, W = shape
    y2, x2 = np.mgrid[: H * ss, : W * ss]
    x2 = (x2 + 0.5) / ss - 0.5
    y2 = (y2 + 0.5) / ss - 0.5
    mask = (((x2 - cx) / ax) ** 2 + ((y2 - cy) / ay) ** 2 < 1).reshape(H, ss, W, ss).mean((1, 3))
    return np.round(outside + (inside - outside) * mask).astype(np.uint8)


def ellipse_distance(points, cx, cy, ax, ay):
    """Distance from each point to the ellipse outline (dense polyline)."""
    t = np.linspace(0, 2 * np.pi, 20000)
    E = np.c_[cx + ax * np.cos(t), cy + ay * np.sin(t)]
    d2 = ((np.asarray(points)[:, None, :] - E[None]) ** 2).sum(-1)
    return np.sqrt(d2.min(1))


@pytest.fixture
def ellipse_image(rng):
    geom = dict(cx=80.3, cy=60.7, ax=50.0, ay=30.0)
    img = render_ellipse((120, 160), **geom)
    img = img.astype(np.float32) + rng.normal(0, 6, img.shape).astype(np.float32)
    return np.clip(img, 0, 255).astype(np.uint8), geom
