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


def _polyline(img, pts, value, thickness, closed=False):
    import cv2

    p = np.round(np.asarray(pts) * 16).astype(np.int32).reshape(-1, 1, 2)
    cv2.polylines(img, [p], closed, value, thickness, cv2.LINE_AA, shift=4)


def draw_face(size=(256, 256), eyes=((96.0, 105.0), (159.0, 105.0)), *, brow_raise=0.0,
              jaw=0.0, noise=0.0, rng=None, irises=False, hair_raise=0.0, nose_drop=0.0,
              lid_open=0.0):
    """A cartoon face drawn from the layout template, and its true fiducials.

    Features: hair above the hairline (edge), brows (thick dark bands), furrows and the
    chin-boss outline (thin dark lines), nostrils, lips with a dark mouth line.
    ``brow_raise`` and ``jaw`` are in inter-eye units. With ``irises`` the eyes are drawn
    (white almond, dark iris of radius 0.08, lids opened by ``lid_open``); ``hair_raise``
    and ``nose_drop`` move the hairline up and the nostrils down (in inter-eye units),
    as the face model's expressions do.
    """
    import cv2

    from trackers.layout import TEMPLATE

    W, H = size
    eye_r, eye_l = (np.asarray(e, float) for e in eyes)
    d = eye_l - eye_r
    iod = float(np.hypot(*d))
    c, s = d / iod
    R = iod * np.array([[c, -s], [s, c]])
    o = 0.5 * (eye_r + eye_l)

    def tf(p, shift=(0.0, 0.0)):
        return (np.asarray(p, float) + shift) @ R.T + o

    img = np.full((H, W), 190, np.uint8)
    hair = np.vstack([tf(TEMPLATE["hairline"], (0, -hair_raise)),
                      tf([[1.2, -2.5], [-1.2, -2.5]])])
    cv2.fillPoly(img, [np.round(hair * 16).astype(np.int32)], 50, cv2.LINE_AA, shift=4)
    brows = {}
    for side in ("l", "r"):
        b = tf(TEMPLATE[f"brow_{side}"], (0, -brow_raise))
        brows[side] = b
        _polyline(img, b, 60, max(3, int(round(0.08 * iod))))
        _polyline(img, tf(TEMPLATE[f"furrow_{side}"]), 120, 2)
        sx = 1 if side == "l" else -1
        ctr = tf([[0.11 * sx, 1.0 + nose_drop]])[0]
        cv2.ellipse(img, (int(round(ctr[0] * 16)), int(round(ctr[1] * 16))),
                    (int(0.05 * iod * 16), int(0.025 * iod * 16)), 0, 0, 360, 45, -1,
                    cv2.LINE_AA, shift=4)
    mouth = TEMPLATE["upper_lip"] + [0, 0.5 * jaw]
    lower = TEMPLATE["lower_lip"] + [0, jaw]
    lips = np.vstack([tf(TEMPLATE["upper_lip"] + [0, -0.09]), tf(lower[::-1])])
    cv2.fillPoly(img, [np.round(lips * 16).astype(np.int32)], 120, cv2.LINE_AA, shift=4)
    _polyline(img, tf(mouth), 35, 2)
    _polyline(img, tf(TEMPLATE["chin_boss"] + [0, jaw]), 120, 2, closed=True)
    if irises:
        for e in (-0.5, 0.5):
            t = np.linspace(0, 2 * np.pi, 60)
            h = 0.07 + lid_open
            almond = tf(np.c_[e + 0.2 * np.cos(t), h * np.sin(t) * (1 + 0.2 * np.cos(t))])
            inside = np.zeros_like(img)
            cv2.fillPoly(inside, [np.round(almond * 16).astype(np.int32)], 255, cv2.LINE_AA,
                         shift=4)
            eye = np.full_like(img, 235)
            ctr = tf([[e, 0.0]])[0]
            cv2.circle(eye, (int(round(ctr[0] * 16)), int(round(ctr[1] * 16))),
                       int(round(0.08 * iod * 16)), 70, -1, cv2.LINE_AA, shift=4)
            # the lids (the almond's outline) cover the top and bottom of the iris
            w = inside.astype(np.float32) / 255
            img = np.round(w * eye + (1 - w) * img).astype(np.uint8)
            _polyline(img, almond, 90, 1, closed=True)
    img = cv2.GaussianBlur(img, (0, 0), 0.7)
    if noise:
        rng = rng or np.random.default_rng(0)
        img = np.clip(img + rng.normal(0, noise, img.shape), 0, 255).astype(np.uint8)
    m = tf(mouth)
    truth = {
        "brow_inner_l": brows["l"][0], "brow_outer_l": brows["l"][-1],
        "brow_inner_r": brows["r"][0], "brow_outer_r": brows["r"][-1],
        "mouth_corner_l": m[-1], "mouth_corner_r": m[0],
        "furrow_top_l": tf(TEMPLATE["furrow_l"][:1])[0],
        "furrow_top_r": tf(TEMPLATE["furrow_r"][:1])[0],
        "chin": tf([[0.0, 1.829 + jaw]])[0],
    }
    return img, truth


@pytest.fixture
def face():
    return draw_face()
