"""Procedural skin texture painted in the mesh's canonical uv space.

The texture is an RGB float32 image ``tex[v * H, u * W]`` (u right, v down, both in [0, 1];
texel centres at ``(i + 0.5) / W``). It is made of

- a skin tone modulated by multi-octave value noise from coarse blotches down to fine
  pores, never repeating (each octave is an independent random lattice), so that optical
  flow has texture to lock onto everywhere on the face;
- the features that the trackers of 004 follow, painted with strong contrast along the
  mesh's ``feature_curves`` (uv polylines): hair above the hairline, dark eyebrow bands
  whose centre line is the ``brow_*`` curve, nasolabial furrow lines, dark nostrils, red
  lips darker than the skin, a dark mouth line, a shaded chin boss and lined eyes.

Colours, brow darkness and thickness, lip colour and the noise differ per identity seed;
everything is deterministic given the seed. Painted textures are cached per
(seed, size, curves).
"""

from __future__ import annotations

import functools
import hashlib
from dataclasses import asdict, dataclass

import cv2
import numpy as np

__all__ = ["TextureParams", "texture_params", "paint_skin_texture", "FEATURE_CURVES"]

FEATURE_CURVES = ("hairline", "brow_l", "brow_r", "furrow_l", "furrow_r", "nostril_l",
                  "nostril_r", "upper_lip", "lower_lip", "mouth_line", "chin_boss", "eye_l",
                  "eye_r")

_SKIN_TONES = np.array([[0.93, 0.76, 0.65], [0.87, 0.68, 0.56], [0.80, 0.60, 0.47],
                        [0.70, 0.50, 0.38], [0.58, 0.41, 0.30], [0.86, 0.70, 0.62]])
_HAIR = np.array([[0.10, 0.07, 0.05], [0.20, 0.13, 0.08], [0.30, 0.18, 0.10],
                  [0.06, 0.05, 0.05], [0.35, 0.22, 0.12]])


@dataclass(frozen=True)
class TextureParams:
    """Per-identity appearance (RGB in [0, 1]; lengths in uv units)."""

    skin: tuple
    hair: tuple
    lip: tuple
    brow_darkness: float      # 0..1 blend toward the hair colour at the band centre
    brow_thickness: float     # full band width, uv units
    furrow_darkness: float
    noise_amplitude: float    # relative brightness variation of the skin noise
    noise_seed: int

    def as_dict(self) -> dict:
        d = asdict(self)
        return {k: (list(v) if isinstance(v, tuple) else v) for k, v in d.items()}


def texture_params(seed: int) -> TextureParams:
    """Appearance parameters of identity ``seed`` (deterministic).

    Examples
    --------
    >>> texture_params(3) == texture_params(3), texture_params(3) == texture_params(4)
    (True, False)
    """
    if not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed={seed!r} must be a non-negative integer")
    rng = np.random.default_rng([int(seed), 0x7e47])
    i = rng.integers(len(_SKIN_TONES))
    j = rng.integers(len(_SKIN_TONES))
    w = rng.uniform(0, 1)
    skin = (1 - w) * _SKIN_TONES[i] + w * _SKIN_TONES[j]
    skin = np.clip(skin * rng.uniform(0.95, 1.05, 3), 0.2, 0.97)
    hair = np.clip(_HAIR[rng.integers(len(_HAIR))] * rng.uniform(0.8, 1.2), 0.02, 0.4)
    lip = np.clip(skin * np.array([0.82, 0.48, 0.48]) * rng.uniform(0.85, 1.05)
                  + np.array([0.06, 0.0, 0.02]), 0.05, 0.9)
    return TextureParams(skin=tuple(float(v) for v in skin),
                         hair=tuple(float(v) for v in hair),
                         lip=tuple(float(v) for v in lip),
                         brow_darkness=float(rng.uniform(0.88, 0.97)),
                         brow_thickness=float(rng.uniform(0.026, 0.034)),
                         furrow_darkness=float(rng.uniform(0.35, 0.5)),
                         noise_amplitude=float(rng.uniform(0.8, 1.2)),
                         noise_seed=int(rng.integers(2**31)))


def _value_noise(rng, size: int, cells: int) -> np.ndarray:
    """Smooth random field in [-1, 1] with ``cells`` lattice cells across (cubic)."""
    g = rng.uniform(-1.0, 1.0, (cells + 3, cells + 3)).astype(np.float32)
    big = cv2.resize(g, (size * (cells + 3) // cells, size * (cells + 3) // cells),
                     interpolation=cv2.INTER_CUBIC)
    o = size * 3 // (2 * cells)
    return big[o:o + size, o:o + size]


def _curve_px(curve, size: int) -> np.ndarray:
    c = np.asarray(curve, dtype=np.float64)
    if c.ndim != 2 or c.shape[1] != 2 or len(c) < 2:
        raise ValueError(f"feature curve must have shape (K>=2, 2), got {c.shape}")
    return c * size - 0.5


def _poly(mask, pts_px, *, closed: bool, thickness: float = 0.0, fill: bool = False,
          value: float = 1.0) -> None:
    """Draw a polyline/polygon with sub-pixel precision (cv2 fixed point, 4 bits)."""
    p = np.round(pts_px * 16).astype(np.int32).reshape(-1, 1, 2)
    if fill:
        cv2.fillPoly(mask, [p], value, lineType=cv2.LINE_AA, shift=4)
    else:
        cv2.polylines(mask, [p], closed, value, thickness=max(1, int(round(thickness))),
                      lineType=cv2.LINE_AA, shift=4)


def _tapered_band(size, pts_px, width_px, taper=0.0, extend=0.0) -> np.ndarray:
    """Soft band along a polyline; its width tapers toward the last point by ``taper`` and
    it runs on ``extend`` px past the last point (along the end tangent)."""
    mask = np.zeros((size, size), np.float32)
    pts = np.asarray(pts_px, dtype=np.float64)
    if extend > 0:
        d = pts[-1] - pts[-2]
        d /= max(np.linalg.norm(d), 1e-12)
        pts = np.vstack([pts, pts[-1] + extend * d])
    seg = np.linalg.norm(np.diff(pts, axis=0), axis=1)
    s = np.concatenate([[0], np.cumsum(seg)])
    total = s[-1] if s[-1] > 0 else 1.0
    ts = np.linspace(0, total, max(2, int(total / 1.0)))
    xs = np.interp(ts, s, pts[:, 0])
    ys = np.interp(ts, s, pts[:, 1])
    frac = ts / total
    rad = 0.5 * width_px * (1.0 - taper * np.clip((frac - 0.6) / 0.4, 0, 1))
    for x, y, r in zip(xs, ys, rad):
        cv2.circle(mask, (int(round(x * 16)), int(round(y * 16))), int(round(r * 16)), 1.0,
                   -1, lineType=cv2.LINE_AA, shift=4)
    return mask


def _blend(tex, mask, colour, alpha=1.0):
    a = (np.clip(mask, 0, 1) * alpha)[..., None]
    tex *= 1 - a
    tex += a * np.asarray(colour, np.float32)


def _hash_curves(curves: dict) -> str:
    h = hashlib.sha1()
    for k in sorted(curves):
        h.update(k.encode())
        h.update(np.ascontiguousarray(curves[k], dtype=np.float64).tobytes())
    return h.hexdigest()


def paint_skin_texture(mesh_or_curves, seed: int = 0, *, size: int = 1024) -> np.ndarray:
    """Paint the skin texture of identity ``seed``.

    Parameters
    ----------
    mesh_or_curves : FaceMesh or dict
        A mesh with ``feature_curves`` or the dict of uv polylines itself (keys in
        :data:`FEATURE_CURVES`; missing ones are simply not painted).
    seed : int
        Identity seed (colours, feature strength, noise).
    size : int
        Texture side in texels.

    Returns
    -------
    (size, size, 3) float32 ndarray in [0, 1], read-only (cached; copy to modify).

    Examples
    --------
    >>> curves = {"brow_l": np.array([[0.55, 0.3], [0.65, 0.28], [0.75, 0.3]])}
    >>> tex = paint_skin_texture(curves, seed=1, size=256)
    >>> bool(tex[int(0.28 * 256), int(0.65 * 256)].mean() < tex[200, 30].mean())
    True
    """
    curves = getattr(mesh_or_curves, "feature_curves", mesh_or_curves)
    if not isinstance(curves, dict):
        raise ValueError("mesh_or_curves must be a FaceMesh or a dict of uv polylines")
    if int(size) != size or size < 64:
        raise ValueError(f"size={size} must be an integer >= 64")
    unknown = sorted(set(curves) - set(FEATURE_CURVES))
    if unknown:
        curves = {k: v for k, v in curves.items() if k in FEATURE_CURVES}
    key = _hash_curves(curves)
    return _paint_cached(int(seed), int(size), key, _Frozen(curves))


class _Frozen:
    """Hashable-by-identity wrapper so that lru_cache keys on the curve hash only."""

    def __init__(self, curves):
        self.curves = curves

    def __hash__(self):
        return 0

    def __eq__(self, other):
        return isinstance(other, _Frozen)


@functools.lru_cache(maxsize=8)
def _paint_cached(seed: int, size: int, key: str, frozen: _Frozen) -> np.ndarray:
    tex = _paint(frozen.curves, texture_params(seed), size)
    tex.setflags(write=False)
    return tex


def _paint(curves: dict, p: TextureParams, size: int) -> np.ndarray:
    rng = np.random.default_rng(p.noise_seed)
    S = size
    skin = np.asarray(p.skin, np.float32)
    # ---- skin: multi-octave value noise (blotches -> fine detail) and pores
    lum = np.zeros((S, S), np.float32)
    for cells, amp in ((4, 0.05), (12, 0.05), (40, 0.06), (110, 0.07), (260, 0.06)):
        lum += amp * _value_noise(rng, S, max(2, cells * S // 1024))
    pores = (rng.random((S, S)) < 0.02).astype(np.float32)
    pores = cv2.GaussianBlur(pores, (0, 0), 0.8 * S / 1024 + 0.3)
    lum -= 0.9 * pores
    lum *= p.noise_amplitude
    redness = 0.03 * _value_noise(rng, S, max(2, 6 * S // 1024))
    tex = np.empty((S, S, 3), np.float32)
    tex[..., 0] = skin[0] * (1 + lum + redness)
    tex[..., 1] = skin[1] * (1 + lum - 0.5 * redness)
    tex[..., 2] = skin[2] * (1 + lum - 0.5 * redness)
    px = S / 1024.0           # texel scale of the nominal 1024 texture
    hair_noise = 1 + 0.25 * _value_noise(rng, S, max(2, 300 * S // 1024))

    # ---- chin boss: soft shading under/around the chin curve
    if "chin_boss" in curves:
        c = _curve_px(curves["chin_boss"], S)
        m = np.zeros((S, S), np.float32)
        _poly(m, c, closed=False, thickness=10 * px)
        m = cv2.GaussianBlur(m, (0, 0), 5 * px)
        _blend(tex, m, skin * 0.55, 0.6)
        m2 = np.zeros((S, S), np.float32)
        _poly(m2, c, closed=False, thickness=3 * px)
        _blend(tex, cv2.GaussianBlur(m2, (0, 0), 1.2 * px), skin * 0.45, 0.6)

    # ---- nasolabial furrows
    for name in ("furrow_l", "furrow_r"):
        if name in curves:
            c = _curve_px(curves[name], S)
            m = np.zeros((S, S), np.float32)
            _poly(m, c, closed=False, thickness=7 * px)
            m = cv2.GaussianBlur(m, (0, 0), 2.0 * px)
            _blend(tex, m, skin * 0.45, p.furrow_darkness * 1.6)

    # ---- lips and mouth line
    lip = np.asarray(p.lip, np.float32)
    for name, shade in (("upper_lip", 0.92), ("lower_lip", 1.0)):
        if name in curves:
            c = _curve_px(curves[name], S)
            m = np.zeros((S, S), np.float32)
            _poly(m, c, closed=True, fill=True)
            m = cv2.GaussianBlur(m, (0, 0), 1.0 * px)
            lipc = np.empty((S, S, 3), np.float32)
            lipc[:] = lip * shade
            lipc *= (1 + 0.5 * lum)[..., None]
            a = m[..., None]
            tex[:] = tex * (1 - a) + lipc * a
            edge = np.zeros((S, S), np.float32)
            _poly(edge, c, closed=True, thickness=3 * px)
            _blend(tex, cv2.GaussianBlur(edge, (0, 0), 1.0 * px), lip * 0.7, 0.5)
    if "mouth_line" in curves:
        c = _curve_px(curves["mouth_line"], S)
        m = np.zeros((S, S), np.float32)
        _poly(m, c, closed=False, thickness=5 * px)
        _blend(tex, cv2.GaussianBlur(m, (0, 0), 1.0 * px), lip * 0.3, 0.9)

    # ---- nostrils
    for name in ("nostril_l", "nostril_r"):
        if name in curves:
            c = _curve_px(curves[name], S)
            m = np.zeros((S, S), np.float32)
            _poly(m, c, closed=True, fill=True)
            _blend(tex, cv2.GaussianBlur(m, (0, 0), 1.5 * px), skin * 0.18, 0.95)

    # ---- eyes: dark lash line around the opening
    for name in ("eye_l", "eye_r"):
        if name in curves:
            c = _curve_px(curves[name], S)
            m = np.zeros((S, S), np.float32)
            _poly(m, c, closed=True, thickness=6 * px)
            _blend(tex, cv2.GaussianBlur(m, (0, 0), 1.0 * px), np.asarray(p.hair) * 0.8, 0.9)

    # ---- eyebrows: thick tapered bands centred on the brow curve (inner end first)
    hair = np.asarray(p.hair, np.float32)
    for name in ("brow_l", "brow_r"):
        if name in curves:
            c = _curve_px(curves[name], S)
            # constant width with round caps centred on the curve's ends: the end of the
            # band's centre line (a fiducial) lies half a band width inside the band's tip
            m = _tapered_band(S, c, p.brow_thickness * S)
            m = cv2.GaussianBlur(m, (0, 0), 1.5 * px)
            hairc = (0.6 * hair)[None, None, :] * hair_noise[..., None]
            a = (m * p.brow_darkness)[..., None]
            tex[:] = tex * (1 - a) + hairc * a

    # ---- hair above the hairline
    if "hairline" in curves:
        c = _curve_px(curves["hairline"], S)
        if c[0, 0] > c[-1, 0]:
            c = c[::-1]
        poly = np.concatenate([[[-2.0, c[0, 1]], [-2.0, -2.0], [S + 1.0, -2.0],
                                [S + 1.0, c[-1, 1]]], c[::-1]])
        m = np.zeros((S, S), np.float32)
        _poly(m, poly, closed=True, fill=True)
        m = cv2.GaussianBlur(m, (0, 0), 2.0 * px)
        strands = 1 + 0.35 * _value_noise(rng, S, max(2, 200 * S // 1024)) \
            + 0.2 * _value_noise(rng, S, max(2, 40 * S // 1024))
        hairc = hair[None, None, :] * strands[..., None]
        a = m[..., None]
        tex[:] = tex * (1 - a) + hairc * a
    np.clip(tex, 0.0, 1.0, out=tex)
    return tex
