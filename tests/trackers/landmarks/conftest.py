"""Fixtures of the landmark tests: the model files (downloaded on a fresh machine) and a face.

Tests that need the models skip, with the reason, where they cannot be obtained (no network
and no local wheel).
"""

import numpy as np
import pytest


@pytest.fixture(scope="session")
def models():
    from trackers.landmarks import ensure_models

    try:
        return ensure_models()
    except (RuntimeError, FileNotFoundError) as exc:
        pytest.skip(f"the MediaPipe face models cannot be obtained here: {exc}")


@pytest.fixture(scope="session")
def face(models):
    """A 192x192 RGB render of the face model and its true mouth corners (subject's right,
    left), small and coarse so that it renders in about a second."""
    from synth.render.sequence import synthesize

    seq = synthesize(frames=1, size=192, seed=3, flow=False, texture_size=256, supersample=1)
    t = seq.truth.iloc[0]
    corners = np.array([[t.fid_mouth_corner_r_x, t.fid_mouth_corner_r_y],
                        [t.fid_mouth_corner_l_x, t.fid_mouth_corner_l_y]])
    return seq.images[0], corners


def scene(face_img, *, big=True, small=True):
    """A 360x640 frame on the render's background: the face at the left (192 px) and a
    smaller copy (120 px) at the right."""
    import cv2

    canvas = np.full((360, 640, 3), face_img[0, 0], np.uint8)
    if big:
        canvas[60:252, 40:232] = face_img
    if small:
        canvas[100:220, 420:540] = cv2.resize(face_img, (120, 120), interpolation=cv2.INTER_AREA)
    return canvas


def far_scene(face_img, *, size=(1280, 720), side=128):
    """A wide frame on the render's background with the face shrunk to ``side`` pixels
    (its face about 6 % of the frame's width: beyond the short-range detector), and the
    factor and offset that map the render's pixels into it."""
    import cv2

    w, h = size
    canvas = np.full((h, w, 3), face_img[0, 0], np.uint8)
    x0, y0 = w // 2, h // 3
    canvas[y0:y0 + side, x0:x0 + side] = cv2.resize(face_img, (side, side),
                                                    interpolation=cv2.INTER_AREA)
    return canvas, side / face_img.shape[1], np.array([x0, y0], float)
