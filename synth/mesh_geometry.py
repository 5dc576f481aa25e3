"""What the identity does to the design plane: regions, tissue, 3-D shape, eyes, inner parts.

Per vertex of the canonical plane (:mod:`synth.mesh_plane`): its anatomical
:class:`~synth.face_mesh.Region`, the jaw weight and the soft-tissue thickness; the
identity's (:class:`~synth.face_shape.FaceShape`) in-plane warp and relief lifted onto
a head-like cylinder (``_embed``), the lids fitted over the eyeballs, and the inner
parts behind the skin (eyeballs, mouth cavity, teeth). :func:`~synth.mesh.
generate_face_mesh` puts these together with the topology of :mod:`synth.mesh_topology`.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.interpolate import PchipInterpolator

from synth.face_mesh import INNER_EYE, INNER_MOUTH, INNER_TEETH, Region
from synth.face_shape import FaceShape
from synth.mesh_plane import (
    _FURROW,
    ALAR,
    EYE_C,
    LL_H,
    MOUTH_W,
    MOUTH_Y,
    UL_H,
    UL_PEAK,
    Y_BOT,
    Y_CHIN,
    Y_HAIR,
    Y_NASION,
    Y_SUBNASALE,
    Y_SULCUS,
    Y_TIP,
    Y_TOP,
    _brow_y,
    _hairline_y,
    _lower_lip_y,
    _mouth_y,
    _seg_dist,
    _smoothstep,
    _upper_lip_y,
)

# ----------------------------------------------------------------------------------------------
# Regions, weights, thickness (canonical)
# ----------------------------------------------------------------------------------------------


def _regions(P: np.ndarray, lower: np.ndarray) -> np.ndarray:
    X, Y = P[:, 0], P[:, 1]
    ax = np.abs(X)
    r = np.full(len(P), int(Region.CHEEK), dtype=np.int8)
    ym = _mouth_y(ax)
    furrow_d, _ = _seg_dist(np.stack([ax, Y], 1), _FURROW)
    # furrow side: points medial to the furrow (inside the muzzle)
    fx = np.interp(-Y, -_FURROW[:, 1], _FURROW[:, 0])
    medial = ax < fx
    r[(Y < -4.5) & (ax > 4.5)] = Region.JAW
    r[(Y < -6.5) & (ax > 3.6)] = Region.JAW
    r[(Y > 0.8) & (ax > 5.2)] = Region.TEMPLE
    r[Y > 2.6] = Region.FOREHEAD
    eye_e = ((ax - EYE_C) / 2.3) ** 2 + ((Y - 0.1) / 1.35) ** 2
    r[eye_e < 1.0] = Region.EYELID
    brow_band = (np.abs(Y - _brow_y(ax)) < 0.55) & (ax < 5.6)
    glabella = (ax < 1.2) & (Y > 0.9) & (Y < 2.4)
    r[brow_band | glabella] = Region.BROW
    nose_half = np.interp(Y, [Y_SUBNASALE - 0.1, -5.0, Y_TIP, -2.0, Y_NASION, 1.0],
                          [0.9, 1.9, 1.3, 0.8, 0.7, 0.0])
    r[(Y >= Y_SUBNASALE - 0.1) & (Y <= 1.0) & (ax < nose_half)] = Region.NOSE
    r[(furrow_d < 0.45) & (Y < -4.2) & (Y > -9.0)] = Region.NASOLABIAL
    lip_up = (ym <= Y) & (Y < Y_SUBNASALE - 0.1) & medial & ~lower
    lip_lo = ((ym > Y) | lower) & (Y > Y_SULCUS) & (ax < MOUTH_W + 0.9)
    lip_up |= (ym - 1e-9 <= Y) & (ax <= MOUTH_W + 1e-9) & (ym + 0.4 > Y) & ~lower
    r[lip_lo & ~(furrow_d < 0.45)] = Region.LOWER_LIP
    r[lip_up] = Region.UPPER_LIP
    r[lower] = Region.LOWER_LIP
    r[(Y <= Y_SULCUS) & (ax < 3.4)] = Region.CHIN
    r[_hairline_y(ax) < Y] = Region.SCALP
    return r


def _jaw_weight(P: np.ndarray, lower: np.ndarray) -> np.ndarray:
    X, Y = P[:, 0], P[:, 1]
    ax = np.abs(X)
    # jaw boundary: the mouth line, rising from the corners to the jaw angle region
    yj = np.where(ax <= MOUTH_W, _mouth_y(ax),
                  _mouth_y(MOUTH_W) + 2.2 * _smoothstep(MOUTH_W, 7.5, ax))
    w = _smoothstep(-0.9, 0.9, yj - Y)
    # lips: the lower lip rides on the mandible, the upper lip on the maxilla; both halves
    # meet at 0.5 in the corners (the shared commissure vertices)
    ramp = 0.5 + 0.5 * np.clip((MOUTH_W - ax) / 0.6, 0.0, 1.0)
    on_or_below = lower | (_mouth_y(ax) - 1e-9 > Y)
    w = np.where(on_or_below & (ax <= MOUTH_W), np.maximum(w, ramp), w)
    above = ~lower & (_mouth_y(ax) - 1e-9 <= Y) & (ax <= MOUTH_W)
    w = np.where(above, np.minimum(w, 1.0 - ramp), w)
    return np.clip(w, 0.0, 1.0)


def _gauss(ax, Y, cx, cy, sx, sy):
    return np.exp(-(((ax - cx) / sx) ** 2) - ((Y - cy) / sy) ** 2)


def _thickness(P: np.ndarray, shape: FaceShape) -> np.ndarray:
    X, Y = P[:, 0], P[:, 1]
    ax = np.abs(X)
    t = np.full(len(P), 0.9)
    t -= 0.4 * _smoothstep(1.5, 3.5, Y)                                   # forehead/scalp 0.5
    t -= 0.55 * _gauss(ax, Y, EYE_C, 0.0, 1.8, 0.9)                       # eyelids ~0.35
    t += 0.75 * shape.cheek_fullness * _gauss(ax, Y, 3.8, -3.6, 1.8, 1.8)  # cheeks ~1.6
    t -= 0.55 * np.exp(-((ax / 0.9) ** 2)) * _smoothstep(-4.2, -2.5, Y) * (Y < 1.2)  # bridge
    t += 0.35 * _gauss(ax, Y, 0.0, MOUTH_Y, 2.6, 1.3)                    # lips ~1.2
    t += 0.15 * _gauss(ax, Y, 0.0, Y_CHIN, 1.8, 1.0)
    t += 0.25 * _gauss(ax, Y, 5.5, -7.0, 1.8, 2.0)                        # masseter
    return np.clip(t, 0.2, 2.5)


# ----------------------------------------------------------------------------------------------
# Geometry (depends on the shape)
# ----------------------------------------------------------------------------------------------


def _warp(P: np.ndarray, s: FaceShape) -> tuple[np.ndarray, np.ndarray]:
    """In-plane identity warp of canonical points; returns (Xs, Ys)."""
    X, Y = P[:, 0], P[:, 1]
    ax, sg = np.abs(X), np.sign(X)
    fl = s.face_length
    # vertical: monotone map through feature levels
    knots = np.array([Y_BOT, Y_CHIN, MOUTH_Y, Y_SUBNASALE, Y_TIP, 0.0, 2.1, Y_HAIR, Y_TOP])
    lengths = np.diff(knots)
    scale = np.array([
        s.chin_height * fl, s.chin_height * fl, fl, s.nose_length, s.nose_length * fl,
        s.brow_height, s.forehead_height * fl, s.forehead_height * fl,
    ])
    new = np.concatenate([[0.0], np.cumsum(lengths * scale)])
    new -= new[5]  # eye line stays at 0
    Ys = PchipInterpolator(knots, new, extrapolate=True)(Y)
    # lip heights: stretch the vermilion band around the mouth line
    ym = _mouth_y(ax)
    lat = np.exp(-((ax / (MOUTH_W + 0.6)) ** 4))
    up = np.clip((Y - ym) / UL_PEAK, 0, None)
    lo = np.clip((ym - Y) / LL_H, 0, None)
    Ys += (s.upper_lip_thickness - 1) * UL_PEAK * lat * up * np.exp(-np.maximum(up - 1, 0) ** 2 * 2)
    Ys -= (s.lower_lip_thickness - 1) * LL_H * lat * lo * np.exp(-np.maximum(lo - 1, 0) ** 2 * 2)
    # horizontal
    Xs = ax.copy()
    we = _gauss(ax, Y, EYE_C, 0.0, 2.4, 1.7)
    Xs += we * ((s.eye_spacing - 1) * EYE_C + (s.eye_size - 1) * (ax - EYE_C))
    Ys += we * (s.eye_size - 1) * Y
    wn = np.exp(-((ax / 2.6) ** 2)) * _gauss(0, Y, 0, -4.8, 1, 1.6)
    Xs += wn * (s.nose_width - 1) * ax
    wm = np.exp(-(((Y - MOUTH_Y) / 1.7) ** 2)) * np.exp(-((ax / 4.0) ** 4))
    Xs += wm * (s.mouth_width - 1) * ax
    wj = _smoothstep(-3.5, -9.5, Y)
    Xs *= 1 + (s.jaw_width - 1) * wj
    Xs *= s.face_width
    return sg * Xs, Ys


def _height(P: np.ndarray, s: FaceShape) -> np.ndarray:
    """Relief above the base cylinder, evaluated in canonical coordinates."""
    X, Y = P[:, 0], P[:, 1]
    ax = np.abs(X)
    h = np.zeros(len(P))
    # eye sockets with the lids over the eyeball
    h -= 1.15 * _gauss(ax, Y, EYE_C, 0.15, 2.0, 1.45)
    h += 0.75 * _gauss(ax, Y, EYE_C, -0.05, 1.4, 0.85)
    # upper-lid crease and lower-lid (tear trough) hint
    h -= 0.12 * _gauss(ax, Y, EYE_C, 0.95, 1.3, 0.18)
    # brow ridge and glabella
    win = _smoothstep(0.3, 1.4, ax) * (1 - _smoothstep(4.8, 6.4, ax))
    h += s.brow_prominence * 0.8 * np.exp(-(((Y - _brow_y(ax) + 0.15) / 0.85) ** 2)) * win
    h += s.brow_prominence * 0.3 * _gauss(ax, Y, 0.0, 1.45, 1.2, 0.9)
    # frontal bosses, temples, forehead recession
    h += 0.2 * _gauss(ax, Y, 2.4, 4.6, 1.8, 1.8)
    h -= 0.45 * _gauss(ax, Y, 6.4, 2.8, 1.3, 1.8)
    h -= 0.05 * np.maximum(Y - 2.0, 0.0) ** 2
    # nose: dorsum profile and width along Y
    ny = np.array([Y_SUBNASALE - 0.4, Y_SUBNASALE, -5.2, Y_TIP, -4.1, -3.0, -1.0, Y_NASION, 1.3])
    np_ = np.array([0.0, 0.55, 1.55, 2.2, 2.15, 1.6, 0.85, 0.35, 0.0])
    nw = np.array([0.7, 0.75, 0.75, 0.85, 0.8, 0.62, 0.52, 0.62, 0.8])
    prof = PchipInterpolator(ny, np_, extrapolate=False)(Y)
    prof = np.nan_to_num(prof)
    wid = np.interp(Y, ny, nw)
    h += s.nose_protrusion * prof * np.exp(-((ax / wid) ** 2))
    # alar wings and nostril hint
    h += s.nose_protrusion * 0.85 * _gauss(ax, Y, ALAR[0] - 0.2, ALAR[1], 0.55, 0.5)
    h -= 0.25 * _gauss(ax, Y, 0.62, -5.5, 0.25, 0.15)
    # cheekbones and cheeks
    h += 0.55 * _gauss(ax, Y, 4.6, -1.8, 1.4, 0.95)
    h += s.cheek_fullness * 0.85 * _gauss(ax, Y, 3.7, -3.7, 1.9, 1.7)
    # nasolabial fold: a crease along the furrow, fading at both ends
    fd, fs = _seg_dist(np.stack([ax, Y], 1), _FURROW)
    h -= 0.24 * np.exp(-((fd / 0.38) ** 2)) * np.sin(np.pi * np.clip(fs * 0.9 + 0.1, 0, 1)) ** 0.5
    # muzzle (the dental arch under the lips)
    h += 1.05 * _gauss(ax, Y, 0.0, -7.1, 3.0, 2.3)
    # philtrum
    band = _smoothstep(Y_SUBNASALE, Y_SUBNASALE - 0.3, Y) * _smoothstep(
        MOUTH_Y + UL_H - 0.1, MOUTH_Y + UL_H + 0.2, Y)
    h -= 0.09 * np.exp(-((ax / 0.28) ** 2)) * band
    # lips
    ym = _mouth_y(ax)
    # lip volumes follow the vermilion outlines and vanish smoothly at the corners
    hu = np.maximum(_upper_lip_y(ax), 0.08)
    hl = np.maximum(-_lower_lip_y(ax), 0.08)
    r = np.clip(ax / MOUTH_W, 0.0, 1.0)
    taper = (1 - r**2) ** 1.5 * (ax < MOUTH_W)
    qu = (Y - ym) / hu
    ql = (ym - Y) / hl
    h += (s.upper_lip_thickness * 0.5 * taper * np.exp(-(((qu - 0.5) / 0.55) ** 2))
          * _smoothstep(-0.7, 0.0, qu))
    h += (s.lower_lip_thickness * 0.58 * taper * np.exp(-(((ql - 0.5) / 0.6) ** 2))
          * _smoothstep(-0.7, 0.0, ql))
    # the lips roll inward towards the seam
    h -= 0.1 * taper * np.exp(-(((Y - ym) / 0.14) ** 2))
    # mentolabial sulcus and chin boss
    h -= 0.32 * _gauss(ax, Y, 0.0, Y_SULCUS, 1.9, 0.45)
    h += 0.7 * _gauss(ax, Y, 0.0, Y_CHIN, 1.6, 1.0)
    # lower face recedes; jaw sides recede further
    h -= 0.035 * np.maximum(-7.0 - Y, 0.0) ** 2
    h -= 0.8 * _smoothstep(-4.0, -11.0, Y) * (ax / 7.0) ** 2
    return h


def _embed(P: np.ndarray, s: FaceShape) -> np.ndarray:
    """3-D positions of canonical points for identity ``s`` (before the origin shift)."""
    Xs, Ys = _warp(P, s)
    h = _height(P, s)
    R = 8.2 * s.face_width * (1 - 0.14 * _smoothstep(-3.0, -12.0, Ys / s.face_length))
    R = R * (1 + (s.jaw_width - 1) * _smoothstep(-3.5, -9.5, P[:, 1]))
    depth = 1.25
    th = Xs / R
    x = R * np.sin(th)
    z = -depth * R * (1 - np.cos(th))
    # normal of the elliptic cylinder x = R sin th, z = -k R (1 - cos th)
    nx, nz = depth * np.sin(th), np.cos(th)
    nn = np.hypot(nx, nz)
    x += h * nx / nn
    z += h * nz / nn
    return np.stack([x, Ys, z], axis=1)


EYE_APEX_LIFT = 0.8    # lids over the cornea in front of the socket surface (cm)
EYE_LID = 0.08         # lid skin in front of the eyeball (cm)
EYE_CAP = 0.92         # lid margins lie within this fraction of the eyeball radius
EYE_BLEND = 0.6        # softness of the lid crease where the lids leave the eyeball (cm)


def _smooth_max(a, b, k):
    """Polynomial smooth maximum: equals max(a, b) where |a - b| >= k."""
    h = np.clip(0.5 + 0.5 * (b - a) / k, 0.0, 1.0)
    return a * (1 - h) + b * h + k * h * (1 - h) * 0.5


def _fit_eyes(v: np.ndarray, P: np.ndarray, margin_l: np.ndarray,
              s: FaceShape) -> tuple[np.ndarray, float]:
    """Push the left eye's lids out over an eyeball (in place); returns (centre, radius).

    The eyeball is a sphere whose front pole (the pupil) looks along +z from the middle of
    the palpebral fissure, ``EYE_APEX_LIFT`` in front of the socket surface, with a radius such
    that the lid margins lie within ``EYE_CAP`` of it.  The skin is the smooth maximum of the
    socket surface and the sphere pushed out by ``EYE_LID``: lids hug the globe near the
    opening and the upper-lid crease forms where they leave it.  Every margin vertex is
    therefore at least ``EYE_LID`` in front of the eyeball.
    """
    centre = _embed(np.array([[EYE_C, 0.0]]), s)[0]
    m = v[margin_l]
    cx = 0.5 * (m[:, 0].min() + m[:, 0].max())
    cy = centre[1]
    z_apex = centre[2] + EYE_APEX_LIFT
    R = float(np.hypot(m[:, 0] - cx, m[:, 1] - cy).max() / EYE_CAP)
    cz = z_apex - R
    left = P[:, 0] > 0
    rho2 = (v[left, 0] - cx) ** 2 + (v[left, 1] - cy) ** 2
    # the osculating paraboloid of the sphere: never behind it, and without the sphere's
    # vertical rim, so the lids leave the globe in a smooth crease
    zs = z_apex - rho2 / (2.0 * R)
    v[left, 2] = _smooth_max(v[left, 2], zs, EYE_BLEND)
    return np.array([cx, cy, cz - EYE_LID]), R


# ----------------------------------------------------------------------------------------------
# Inner parts
# ----------------------------------------------------------------------------------------------


def _sphere(centre, radius, n_lat, n_lon):
    """UV sphere with poles on the z axis (front pole first); outward triangles."""
    alphas = np.linspace(0, np.pi, n_lat + 1)[1:-1]
    phis = np.linspace(0, 2 * np.pi, n_lon, endpoint=False)
    A, F = np.meshgrid(alphas, phis, indexing="ij")
    d = np.stack([np.sin(A) * np.cos(F), np.sin(A) * np.sin(F), np.cos(A)], -1).reshape(-1, 3)
    d = np.vstack([[0, 0, 1.0], d, [0, 0, -1.0]])
    tris = []
    nr = len(alphas)
    ring = lambda i, j: 1 + i * n_lon + (j % n_lon)  # noqa: E731
    for j in range(n_lon):
        tris.append((0, ring(0, j), ring(0, j + 1)))
        tris.append((len(d) - 1, ring(nr - 1, j + 1), ring(nr - 1, j)))
    for i in range(nr - 1):
        for j in range(n_lon):
            a, b = ring(i, j), ring(i, j + 1)
            c, e = ring(i + 1, j), ring(i + 1, j + 1)
            tris.append((a, c, b))
            tris.append((b, c, e))
    tris = np.array(tris)
    v = np.asarray(centre) + radius * d
    # make sure triangles face outward
    fn = np.cross(v[tris[:, 1]] - v[tris[:, 0]], v[tris[:, 2]] - v[tris[:, 0]])
    flip = np.einsum("ij,ij->i", fn, v[tris].mean(1) - centre) < 0
    tris[flip] = tris[flip][:, [0, 2, 1]]
    rxy = np.linalg.norm(d[:, :2], axis=1)
    front = d[:, 2] >= 0
    uv = np.where(front[:, None], 0.5 + 0.5 * d[:, :2] * [1, -1],
                  0.5 + 0.5 * d[:, :2] * [1, -1] / np.maximum(rxy, 1e-12)[:, None])
    uv[-1] = (0.5, 1.0)
    return v, tris, uv


def _grid_surface(fn, nu, nv):
    """Regular (nv, nu) grid surface from ``fn(s, t) -> (n, 3)``; triangles face +z."""
    s = np.linspace(-1, 1, nu)
    t = np.linspace(-1, 1, nv)
    S, T = np.meshgrid(s, t)
    v = fn(S.ravel(), T.ravel())
    idx = np.arange(nu * nv).reshape(nv, nu)
    a, b, c, d = idx[:-1, :-1], idx[:-1, 1:], idx[1:, :-1], idx[1:, 1:]
    tris = np.vstack([np.stack([a, b, d], -1).reshape(-1, 3),
                      np.stack([a, d, c], -1).reshape(-1, 3)])
    fn_ = np.cross(v[tris[:, 1]] - v[tris[:, 0]], v[tris[:, 2]] - v[tris[:, 0]])
    flip = fn_[:, 2] < 0
    tris[flip] = tris[flip][:, [0, 2, 1]]
    uv = np.stack([(S.ravel() + 1) / 2, (1 - T.ravel()) / 2], 1)
    return v, tris, uv, T.ravel()


def _inner_parts(s: FaceShape, resolution: float, shift: np.ndarray, centre_l: np.ndarray,
                 r: float):
    parts_v, parts_t, parts_m, parts_uv, parts_w = [], [], [], [], []

    def push(v, t, material, uv, w):
        off = sum(len(p) for p in parts_v)
        parts_v.append(v)
        parts_t.append(t + off)
        parts_m.append(np.full(len(t), material, dtype=np.int8))
        parts_uv.append(uv)
        parts_w.append(w)

    centre_r = centre_l * [-1, 1, 1]
    n_lat = int(max(10, round(14 * math.sqrt(resolution))))
    n_lon = int(max(16, round(24 * math.sqrt(resolution))))
    for c in (centre_l, centre_r):
        v, t, uv = _sphere(c, r, n_lat, n_lon)
        push(v, t, INNER_EYE, uv, np.zeros(len(v)))

    nu = int(max(9, round(13 * math.sqrt(resolution)))) | 1
    nv = int(max(7, round(9 * math.sqrt(resolution)))) | 1

    # mouth cavity: a bowl behind the lips; rim 1.1 cm under the skin, 3 cm deep
    def cavity(S, T):
        can = np.stack([S * (MOUTH_W + 0.9), MOUTH_Y + np.where(T > 0, 1.7, 2.1) * T], 1)
        p = _embed(can, s) - shift
        p[:, 2] -= 1.1 + 3.0 * (1 - S**2) * (1 - T**2)
        return p

    v, t, uv, T = _grid_surface(cavity, nu, nv)
    w = np.where(T < 0, 1.0, np.where(T > 0, 0.0, 0.5))
    push(v, t, INNER_MOUTH, uv, w)

    # teeth: an upper and a lower strip behind the lips
    for upper in (True, False):
        def strip(S, T, upper=upper):
            y0, y1 = (MOUTH_Y + 0.95, MOUTH_Y - 0.12) if upper else (MOUTH_Y + 0.05, MOUTH_Y - 0.9)
            can = np.stack([S * (MOUTH_W - 0.2), y0 + (T + 1) / 2 * (y1 - y0)], 1)
            p = _embed(can, s) - shift
            p[:, 2] -= (0.85 if upper else 0.95) + 1.2 * S**2
            return p

        v, t, uv, _ = _grid_surface(strip, nu, 3)
        push(v, t, INNER_TEETH, uv, np.full(len(v), 0.0 if upper else 1.0))

    return (np.vstack(parts_v), np.vstack(parts_t).astype(np.int32), np.concatenate(parts_m),
            np.vstack(parts_uv), np.concatenate(parts_w), np.stack([centre_l, centre_r]), r)
