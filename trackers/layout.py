"""The nine facial contours of 004 (V-D) and where to put them on a first frame.

Contours, in this order (``_l`` is the subject's left, on the image's right):

============  =======  ========  ====================================================
name          shape    potential what it follows
============  =======  ========  ====================================================
hairline      open     edge      boundary between forehead skin and hair
brow_l/_r     open     valley    centre line of the eyebrow band (its fiducials are
                                 the inner end, the arc-length middle, the outer end)
furrow_l/_r   open     valley    centre line of the nasolabial furrow (top end = fiducial)
nose_tip      open     valley    the dark nostrils under the nose tip
upper_lip     open     valley    the mouth line, where the upper lip meets the lower
                                 lip; its two ends are the mouth corners (commissures)
lower_lip     open     edge      the lower border of the lower lip
chin_boss     closed   valley    outline of the chin boss; its centroid is the chin
============  =======  ========  ====================================================

Dark lines and bands are tracked on their centre line with the valley potential
(:func:`trackers.potentials.valley_potential`); boundaries with the edge potential of
eq. 13. Both choices are stored per contour (``kind``, ``sigma``) and can be edited.

Placement. :func:`detect_layout` finds the face with OpenCV's bundled Haar cascade
(``haarcascade_frontalface_default``) and the eyes with ``haarcascade_eye``; a
template of the nine curves, written in a frame attached to the eyes (origin midway
between the eye centres, unit = inter-eye distance, x toward the image's right,
y down), is mapped onto the image by the similarity that carries the template eyes
onto the detected ones (or onto the eyes the template expects inside the face box
when the eyes are not found). Each contour is then moved rigidly, within a small
window, to where its mean potential is lowest (:func:`refine_layout`); the nose
window reaches :data:`NOSE_REACH_UP` higher, since real faces' nostrils lie well
above the template's, and takes the topmost strong ravine in it, and the contours
below follow the nose (furrows, mouth line) and the lower lip (chin). The layout
can be saved to JSON, corrected by hand and loaded back (the paper placed its
contours with the mouse).
"""

from __future__ import annotations

import json
import threading
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from trackers.polyline import resample_polyline
from trackers.potentials import potentials_in_boxes, to_gray
from trackers.sampling import sample_bilinear

__all__ = [
    "CONTOUR_NAMES",
    "LayoutContour",
    "FaceLayout",
    "TEMPLATE",
    "layout_from_eyes",
    "detect_layout",
    "refine_layout",
]

CONTOUR_NAMES = ("hairline", "brow_l", "brow_r", "furrow_l", "furrow_r", "nose_tip",
                 "upper_lip", "lower_lip", "chin_boss")
KINDS = ("edge", "valley", "dark_below")


def _parabola(x0, x1, pts, n=25):
    """Quadratic through three (x, y) points, sampled on [x0, x1]."""
    pts = np.asarray(pts, float)
    c = np.polyfit(pts[:, 0], pts[:, 1], 2)
    x = np.linspace(x0, x1, n)
    return np.c_[x, np.polyval(c, x)]


def _mirror(curve):
    return np.asarray(curve, float)[::-1] * [-1.0, 1.0]


def _build_template():
    brow_l = _parabola(0.26, 0.85, [(0.26, -0.22), (0.59, -0.30), (0.85, -0.21)])
    furrow_l = np.array([(0.358, 0.835), (0.436, 1.02), (0.515, 1.225), (0.576, 1.428),
                         (0.602, 1.595)])
    xm = np.linspace(-0.434, 0.434, 25)
    t = np.linspace(0, 2 * np.pi, 40, endpoint=False)
    xl = np.linspace(-0.30, 0.30, 19)
    return {
        "hairline": _parabola(-0.76, 0.76, [(-0.76, -0.808), (0.0, -1.024), (0.76, -0.808)],
                              41),
        "brow_l": brow_l,
        "brow_r": _mirror(brow_l)[::-1],  # inner end first for both brows
        "furrow_l": furrow_l,
        "furrow_r": _mirror(furrow_l)[::-1],  # top end first for both furrows
        "nose_tip": _parabola(-0.17, 0.17, [(-0.17, 1.0), (0.0, 1.03), (0.17, 1.0)], 11),
        "upper_lip": np.c_[xm, 1.36 - 0.022 * (xm / 0.434) ** 2],
        "lower_lip": np.c_[xl, 1.36 + 0.176 * np.sqrt(1 - (xl / 0.434) ** 2)],
        "chin_boss": np.c_[0.262 * np.cos(t), 1.829 + 0.148 * np.sin(t)],
    }


#: Template curves in the eye frame (origin between the eye centres, unit = inter-eye
#: distance, x toward the image's right, y down). Brows and furrows start at their
#: inner / top end.
TEMPLATE: dict[str, np.ndarray] = _build_template()

#: Per-contour defaults: (closed, kind, sigma in inter-eye units, search window (x, y)
#: in inter-eye units, ends, parent). ``ends`` (one mode for both ends, or a pair
#: (first end, last end)): 'free' (left to the snake), 'tip' (relocated on the end of
#: the line each frame), 'centre' (the tip moved back by the line's half-width, i.e.
#: the end of a thick band's centre line), 'line' (the end of a thin line's centre
#: line, found on the step of the grey level along the line: for line ends beyond
#: which the ravine runs on, as the furrows' tops run into the shading beside the
#: nose) or 'corner' (the farthest end of the dark region within 45 degrees of the
#: end tangent: the commissure, also when the open mouth makes the contour follow its
#: lower border). The furrows' lower ends stay 'tip': when the jaw opens the lower
#: furrow stretches and fades, and the grey step then cuts it short. The search of a
#: contour is centred on the template moved by its parent's offset (the mouth follows
#: the nose, the chin follows the lower lip), in this order. The chin's window is
#: +-0.1: at +-0.2 it reached the dark shadow under the lower lip on real faces.
CONTOUR_DEFAULTS = {
    "hairline": (False, "edge", 0.022, (0.0, 0.30), "free", None),
    "brow_l": (False, "valley", 0.035, (0.06, 0.12), "centre", None),
    "brow_r": (False, "valley", 0.035, (0.06, 0.12), "centre", None),
    "nose_tip": (False, "valley", 0.035, (0.05, 0.25), "free", None),
    "furrow_l": (False, "valley", 0.022, (0.08, 0.10), ("line", "tip"), "nose_tip"),
    "furrow_r": (False, "valley", 0.022, (0.08, 0.10), ("line", "tip"), "nose_tip"),
    "upper_lip": (False, "valley", 0.022, (0.05, 0.15), "tip", "nose_tip"),
    "lower_lip": (False, "edge", 0.022, (0.0, 0.10), "free", "upper_lip"),
    "chin_boss": (True, "valley", 0.022, (0.05, 0.10), "free", "lower_lip"),
}
ENDS = ("free", "tip", "centre", "line", "corner")

#: How far above the template's nostrils (inter-eye units) :func:`refine_layout`
#: looks for them. The template has the face model's lower face (nostrils 1.0
#: inter-eye distances below the eyes); on real faces, and more so on one that looks
#: down, they lie 0.55-0.6 below, where a symmetric window never reaches: the nose
#: contour then settled on the mouth line and every lower contour, which follows it,
#: one feature low.
NOSE_REACH_UP = 0.55

#: The nose contour goes to the topmost ravine whose mean potential reaches this share
#: of the lowest one in its window: between the lower eyelids and the nostrils a face
#: has no horizontal dark line, and the mouth line below is often as dark as the
#: nostrils.
NOSE_RAVINE_SHARE = 0.6

#: Where the eye centres lie inside a Haar ``frontalface_default`` box, as fractions of
#: its width / height (x from the box's left, y from its top).
FACE_BOX_EYES = ((0.30, 0.395), (0.685, 0.395))


@dataclass
class LayoutContour:
    """One contour of a :class:`FaceLayout`.

    Attributes
    ----------
    points : ndarray (n, 2)
        Node positions (x, y) in image pixels.
    closed : bool
    kind : {'edge', 'valley'}
        Potential the contour follows.
    sigma : float
        Width of that potential, pixels.
    ends : {'free', 'tip', 'centre', 'line', 'corner'} or a pair of them
        How the tracker treats the ends of an open contour each frame (one mode for
        both, or (first end, last end)): left to the snake, relocated on the end of
        the line, relocated on the end of the line's centre line (tip moved back by
        the half-width, for thick bands), relocated on the end of a thin line's
        centre line found on the step of the grey level along it (for line ends
        beyond which the potential's ravine runs on), or relocated on the farthest
        end of the dark region within 45 degrees of the end tangent (mouth corners).
    """

    points: np.ndarray
    closed: bool = False
    kind: str = "valley"
    sigma: float = 2.0
    ends: str | tuple[str, str] = "free"

    def __post_init__(self):
        self.points = np.asarray(self.points, dtype=np.float64)
        if self.points.ndim != 2 or self.points.shape[1] != 2 or len(self.points) < 3:
            raise ValueError(f"contour points must have shape (n >= 3, 2), got "
                             f"{self.points.shape}")
        if not np.isfinite(self.points).all():
            raise ValueError("contour points contain NaN or infinite coordinates")
        if self.kind not in KINDS:
            raise ValueError(f"kind must be one of {KINDS}, got {self.kind!r}")
        if not np.isfinite(self.sigma) or self.sigma <= 0:
            raise ValueError(f"sigma must be positive, got {self.sigma}")
        self.closed = bool(self.closed)
        if isinstance(self.ends, (list, tuple)):
            if len(self.ends) != 2 or any(e not in ENDS for e in self.ends):
                raise ValueError(f"ends must be one of {ENDS} or a pair of them, got "
                                 f"{self.ends!r}")
            self.ends = tuple(self.ends) if self.ends[0] != self.ends[1] else self.ends[0]
        elif self.ends not in ENDS:
            raise ValueError(f"ends must be one of {ENDS} or a pair of them, got "
                             f"{self.ends!r}")
        if self.closed:
            self.ends = "free"

    @property
    def end_modes(self) -> tuple[str, str]:
        """(first end, last end) modes."""
        return self.ends if isinstance(self.ends, tuple) else (self.ends, self.ends)


@dataclass
class FaceLayout:
    """Nine named contours placed on a frame, plus what they were placed from.

    Attributes
    ----------
    contours : dict name -> LayoutContour
        Keys are :data:`CONTOUR_NAMES` (all nine).
    image_size : (width, height)
    eyes : ndarray (2, 2) or None
        Eye centres used for the placement: row 0 the subject's right eye (image
        left), row 1 the subject's left eye.
    face_box : (x, y, w, h) or None
    source : str
        'detected', 'eyes', 'file' or a user note.
    """

    contours: dict
    image_size: tuple
    eyes: np.ndarray | None = None
    face_box: tuple | None = None
    source: str = ""
    meta: dict = field(default_factory=dict)

    def __post_init__(self):
        missing = [n for n in CONTOUR_NAMES if n not in self.contours]
        if missing:
            raise ValueError(f"layout lacks contours {missing}")
        extra = [n for n in self.contours if n not in CONTOUR_NAMES]
        if extra:
            raise ValueError(f"unknown contours {extra}; choose from {CONTOUR_NAMES}")
        self.contours = {n: self.contours[n] for n in CONTOUR_NAMES}
        w, h = (int(v) for v in self.image_size)
        if w < 3 or h < 3:
            raise ValueError(f"image_size must be (width, height) >= 3, got {self.image_size}")
        self.image_size = (w, h)
        for name, c in self.contours.items():
            if not isinstance(c, LayoutContour):
                raise ValueError(f"contour {name!r} must be a LayoutContour")
            p = c.points
            if (p[:, 0] < 0).any() or (p[:, 1] < 0).any() or (p[:, 0] > w - 1).any() \
                    or (p[:, 1] > h - 1).any():
                raise ValueError(f"contour {name!r} has nodes outside the {w}x{h} image")
        if self.eyes is not None:
            self.eyes = np.asarray(self.eyes, float).reshape(2, 2)

    @property
    def inter_eye(self) -> float:
        """Inter-eye distance in pixels (from the eyes, else from the brows)."""
        if self.eyes is not None:
            return float(np.hypot(*(self.eyes[1] - self.eyes[0])))
        bl = self.contours["brow_l"].points.mean(0)
        br = self.contours["brow_r"].points.mean(0)
        return float(np.hypot(*(bl - br)) / 1.12)

    # -------------------------------------------------------------- JSON
    def to_dict(self) -> dict:
        return {
            "format": "trackers.FaceLayout/1",
            "image_size": list(self.image_size),
            "eyes": None if self.eyes is None else self.eyes.round(3).tolist(),
            "face_box": None if self.face_box is None else [int(v) for v in self.face_box],
            "source": self.source,
            "contours": {
                n: {"closed": c.closed, "kind": c.kind, "sigma": round(float(c.sigma), 4),
                    "ends": list(c.ends) if isinstance(c.ends, tuple) else c.ends,
                    "points": c.points.round(3).tolist()}
                for n, c in self.contours.items()},
        }

    def to_json(self, path=None) -> str:
        """Serialise (and write to ``path`` when given). Coordinates are (x, y) pixels."""
        text = json.dumps(self.to_dict(), indent=1)
        if path is not None:
            Path(path).write_text(text)
        return text

    @classmethod
    def from_json(cls, source) -> FaceLayout:
        """Load a layout from a JSON string or a file path.

        Raises
        ------
        FileNotFoundError
            When a path is given that does not exist.
        ValueError
            When the content is not a valid layout (the message names the problem).
        """
        text = None
        if isinstance(source, Path) or (isinstance(source, str)
                                        and not source.lstrip().startswith("{")):
            p = Path(source)
            if not p.is_file():
                raise FileNotFoundError(f"layout file not found: {p}")
            text = p.read_text()
            where = str(p)
        else:
            text = source
            where = "layout JSON"
        try:
            d = json.loads(text)
        except json.JSONDecodeError as exc:
            raise ValueError(f"{where}: not valid JSON ({exc})") from None
        if not isinstance(d, dict) or "contours" not in d or "image_size" not in d:
            raise ValueError(f"{where}: expected an object with 'image_size' and 'contours'")
        try:
            contours = {}
            for name, c in d["contours"].items():
                dflt = CONTOUR_DEFAULTS.get(name, (False, "valley", 0.03, None, "free", None))
                contours[name] = LayoutContour(
                    np.asarray(c["points"], float), bool(c.get("closed", dflt[0])),
                    c.get("kind", dflt[1]), float(c.get("sigma", 2.0)),
                    c.get("ends", dflt[4]))
            return cls(contours, tuple(d["image_size"]), d.get("eyes"),
                       tuple(d["face_box"]) if d.get("face_box") else None,
                       d.get("source", "file") or "file")
        except (KeyError, TypeError, ValueError) as exc:
            raise ValueError(f"{where}: {exc}") from None


def _eye_similarity(eye_r, eye_l):
    """2x3 matrix taking eye-frame coordinates to image pixels."""
    eye_r = np.asarray(eye_r, float)
    eye_l = np.asarray(eye_l, float)
    d = eye_l - eye_r
    iod = float(np.hypot(*d))
    if not np.isfinite(iod) or iod < 2:
        raise ValueError(f"eye centres {eye_r.tolist()} and {eye_l.tolist()} are too close")
    c, s = d / iod
    R = iod * np.array([[c, -s], [s, c]])
    return np.c_[R, 0.5 * (eye_r + eye_l)]


def layout_from_eyes(eye_r, eye_l, image_size, *, spacing: float | None = None,
                     source: str = "eyes") -> FaceLayout:
    """Place the template by the two eye centres.

    Parameters
    ----------
    eye_r, eye_l : (x, y)
        Centres of the subject's right eye (image left) and left eye (image right).
    image_size : (width, height)
    spacing : float, optional
        Node spacing in pixels (default 3 % of the inter-eye distance, at least 1).

    Returns
    -------
    FaceLayout
        Contours clipped to the image.

    Examples
    --------
    >>> lay = layout_from_eyes((96, 105), (159, 105), (256, 256))
    >>> [round(v) for v in lay.contours["upper_lip"].points[0]]
    [100, 189]
    """
    M = _eye_similarity(eye_r, eye_l)
    iod = float(np.hypot(*M[:, 0]))
    w, h = (int(v) for v in image_size)
    if spacing is None:
        spacing = max(1.0, 0.03 * iod)
    contours = {}
    for name in CONTOUR_NAMES:
        closed, kind, sig, _, ends, _ = CONTOUR_DEFAULTS[name]
        pts = TEMPLATE[name] @ M[:, :2].T + M[:, 2]
        pts = resample_polyline(pts, spacing=spacing, closed=closed)
        pts = np.clip(pts, 0, [w - 1, h - 1])
        contours[name] = LayoutContour(pts, closed, kind, max(0.8, sig * iod), ends)
    return FaceLayout(contours, (w, h), np.array([eye_r, eye_l], float), None, source)


def refine_layout(frame, layout: FaceLayout, *, channel_order: str = "rgb",
                  step: float = 1.0, names=None) -> FaceLayout:
    """Move each contour rigidly to the lowest mean potential within its search window.

    The windows are those of :data:`CONTOUR_DEFAULTS`, centred on the template moved by
    the contour's parent's offset. The nose's reaches :data:`NOSE_REACH_UP` above the
    template, and the nose goes to the topmost run of offsets whose potential reaches
    :data:`NOSE_RAVINE_SHARE` of the window's lowest (the nostrils, not the mouth line
    below them).

    Parameters
    ----------
    frame : array_like
        The frame the layout was placed on.
    layout : FaceLayout
    channel_order : {'rgb', 'bgr'}
    step : float
        Grid step of the search, pixels.
    names : sequence of str, optional
        Search only these contours (the others stay where they are); default all.

    Returns
    -------
    FaceLayout
        A new layout (the input is not modified).
    """
    if names is not None:
        unknown = sorted(set(names) - set(CONTOUR_NAMES))
        if unknown:
            raise ValueError(f"unknown contours {unknown}; choose from "
                             f"{', '.join(CONTOUR_NAMES)}")
    gray = to_gray(frame, channel_order=channel_order)
    H, W = gray.shape
    if tuple(layout.image_size) != (W, H):
        raise ValueError(f"frame is {W}x{H} but the layout was made for "
                         f"{layout.image_size[0]}x{layout.image_size[1]}")
    iod = layout.inter_eye
    out = {}
    offsets = {}
    cache = {}
    order = [n for n in CONTOUR_DEFAULTS if n in layout.contours]
    for name in order:
        c = layout.contours[name]
        if names is not None and name not in names:
            out[name] = c
            continue
        win, parent = CONTOUR_DEFAULTS[name][3], CONTOUR_DEFAULTS[name][5]
        rx, ry = win[0] * iod, win[1] * iod
        base = np.asarray(offsets.get(parent, (0.0, 0.0)), float)
        # a bright-to-dark edge is searched for by the dark line (or region) below it:
        # the upper lip's lower border is found on the mouth line, not on the lip's
        # upper border (which has the same polarity)
        kind = "valley" if c.kind == "dark_below" else c.kind
        key = (kind, round(c.sigma, 3))
        if key not in cache:
            cache[key] = potentials_in_boxes(gray, [(kind, c.sigma)], [(0, 0, W, H)])[0]
        P = cache[key]
        dxs = np.arange(-rx, rx + 1e-9, step) if rx > 0 else np.zeros(1)
        up = NOSE_REACH_UP * iod if name == "nose_tip" else ry
        dys = np.arange(-ry, ry + 1e-9, step) if ry > 0 else np.zeros(1)
        if up > ry:
            # the same grid extended upwards (the offsets found inside +-ry stay exact)
            dys = np.r_[-np.arange(step, up - ry + 1e-9, step)[::-1] - ry, dys]
        # all offsets at once (row-major over dy then dx, as a double loop would go)
        off = np.stack(np.meshgrid(dxs, dys), axis=-1).reshape(-1, 2)
        lo = c.points.min(axis=0) + base
        hi = c.points.max(axis=0) + base
        ok = ((lo[0] + off[:, 0] >= 0) & (lo[1] + off[:, 1] >= 0)
              & (hi[0] + off[:, 0] <= W - 1) & (hi[1] + off[:, 1] <= H - 1))
        best_d = base
        if ok.any():
            off = off[ok]
            q = (c.points[None, :, :] + (base + off)[:, None, :]).reshape(-1, 2)
            v = sample_bilinear(P, q).reshape(len(off), -1).mean(axis=1)
            if name == "nose_tip":
                v = np.where(_topmost_ravine(off[:, 1], v, NOSE_RAVINE_SHARE), v, np.inf)
            # prefer the smallest move among equally good ones
            v = v + 1e-6 * (off ** 2).sum(axis=1)
            best_d = base + off[int(np.argmin(v))]
        offsets[name] = best_d
        out[name] = LayoutContour(c.points + best_d, c.closed, c.kind, c.sigma, c.ends)
    return FaceLayout(out, layout.image_size, layout.eyes, layout.face_box,
                      layout.source, dict(layout.meta))


def _topmost_ravine(dy: np.ndarray, v: np.ndarray, share: float) -> np.ndarray:
    """Mask of the offsets in the topmost run of rows whose best mean potential ``v``
    reaches ``share`` of the lowest (potentials are negative in a ravine).

    >>> dy = np.repeat([-2.0, -1.0, 0.0, 1.0, 2.0], 2)
    >>> v = np.array([-1, -2, -8, -7, -1, 0, -9, -10, -3, -1], float)
    >>> _topmost_ravine(dy, v, 0.6).reshape(5, 2).any(axis=1).tolist()
    [False, True, False, False, False]
    """
    rows, inv = np.unique(dy, return_inverse=True)
    best = np.full(len(rows), np.inf)
    np.minimum.at(best, inv, v)
    strong = best <= share * best.min()
    first = int(np.argmax(strong))
    # the run of strong rows that starts at the topmost one
    stop = first + (int(np.argmin(strong[first:])) if not strong[first:].all()
                    else len(rows) - first)
    return (inv >= first) & (inv < stop)


_CASCADES = threading.local()


def _cascade(name: str) -> cv2.CascadeClassifier:
    """OpenCV's Haar cascade ``name``, loaded once per thread (parsing the face cascade
    takes about 7 ms, a fifth of a re-detection; a classifier is not shared between
    threads because ``detectMultiScale`` is not documented as thread-safe)."""
    cache = getattr(_CASCADES, "by_name", None)
    if cache is None:
        cache = _CASCADES.by_name = {}
    if name not in cache:
        cascade = cv2.CascadeClassifier(cv2.data.haarcascades + name)
        if cascade.empty():
            raise RuntimeError(f"OpenCV's {name} could not be loaded")
        cache[name] = cascade
    return cache[name]


def _detect_eyes(gray_u8, box):
    x, y, w, h = box
    cascade = _cascade("haarcascade_eye.xml")
    upper = gray_u8[y:y + int(0.6 * h), x:x + w]
    found = cascade.detectMultiScale(upper, scaleFactor=1.1, minNeighbors=3,
                                     minSize=(max(4, w // 12), max(4, w // 12)),
                                     maxSize=(w // 2, w // 2))
    if len(found) < 2:
        return None
    centres = np.array([(x + ex + ew / 2, y + ey + eh / 2) for ex, ey, ew, eh in found], float)
    exp = np.array([(x + fx * w, y + fy * h) for fx, fy in FACE_BOX_EYES])
    best, pair = np.inf, None
    for i in range(len(centres)):
        for j in range(len(centres)):
            if i == j or centres[i, 0] >= centres[j, 0]:
                continue
            d = centres[j] - centres[i]
            dist = np.hypot(*d)
            if not 0.25 * w < dist < 0.6 * w or abs(d[1]) > 0.25 * dist:
                continue
            cost = np.hypot(*(centres[i] - exp[0])) + np.hypot(*(centres[j] - exp[1]))
            if cost < best:
                best, pair = cost, (centres[i], centres[j])
    if pair is None or best > 0.35 * w:
        return None
    return pair


def detect_layout(frame, *, frame_index: int = 0, channel_order: str = "rgb",
                  refine: bool = True, spacing: float | None = None,
                  min_face: int = 40) -> FaceLayout:
    """Place the nine contours automatically on a frame.

    Parameters
    ----------
    frame : array_like
        Grey or colour frame of any dtype (see :func:`trackers.potentials.to_gray`).
    frame_index : int
        Index of the frame, used in error messages.
    channel_order : {'rgb', 'bgr'}
    refine : bool
        Run :func:`refine_layout` after placing the template.
    spacing : float, optional
        Node spacing in pixels (default 3 % of the inter-eye distance).
    min_face : int
        Smallest face side searched, pixels. Faces of a quarter of the frame's short
        side and more are searched first; the smaller sizes only when none is found.

    Returns
    -------
    FaceLayout

    Raises
    ------
    ValueError
        ``no face found in frame N`` when the detector finds none (the largest face
        is used when there are several).
    """
    gray = to_gray(frame, channel_order=channel_order)
    g8 = np.clip(gray + 0.5, 0, 255).astype(np.uint8)
    g8 = cv2.equalizeHist(g8)
    cascade = _cascade("haarcascade_frontalface_default.xml")
    # faces of a quarter of the frame's short side and more first: the cascade's cost
    # is in its small scales (82 ms from 40 px on a 640x360 frame, 25 ms from 90 px),
    # and the scales it tries do not depend on the smallest one, so a face found there
    # is found alike; the small scales are searched only when none is
    big = max(int(min_face), min(g8.shape) // 4)
    faces = cascade.detectMultiScale(g8, scaleFactor=1.1, minNeighbors=4,
                                     minSize=(big, big))
    if len(faces) == 0 and big > min_face:
        faces = cascade.detectMultiScale(g8, scaleFactor=1.1, minNeighbors=4,
                                         minSize=(min_face, min_face))
    if len(faces) == 0:
        raise ValueError(f"no face found in frame {frame_index}")
    box = tuple(int(v) for v in max(faces, key=lambda f: f[2] * f[3]))
    x, y, w, h = box
    pair = _detect_eyes(g8, box)
    if pair is None:
        eye_r = (x + FACE_BOX_EYES[0][0] * w, y + FACE_BOX_EYES[0][1] * h)
        eye_l = (x + FACE_BOX_EYES[1][0] * w, y + FACE_BOX_EYES[1][1] * h)
        how = "face box"
    else:
        eye_r, eye_l = pair
        how = "face box + eyes"
    H, W = gray.shape
    layout = layout_from_eyes(eye_r, eye_l, (W, H), spacing=spacing, source="detected")
    layout.face_box = box
    layout.meta["placement"] = how
    layout.meta["frame_index"] = int(frame_index)
    if refine:
        layout = refine_layout(frame, layout, channel_order=channel_order)
    return layout
