"""Rigid anchors for the head frame: the two irises.

004 takes the head reference frame from the hairline contour, "assuming a frontal view
and relatively stable hairline". Expressions move that hairline, though (the frontalis
pulls the scalp's edge up by ~2 mm in surprise) and the nostrils that give the frame's
scale (~3 mm in surprise or happiness), so a frame taken from those contours on every
frame moves with the expression and biases every fiducial displacement measured in it.
The eyeballs sit in the skull: their irises move with the head, not with the facial
muscles (lids may cover part of them; gaze shifts are the exception in real video).

:class:`IrisAnchors` locates both irises on the reference frame, keeps a small masked
template of each and finds them again on later frames by normalised cross-correlation
with sub-pixel peaks. The similarity (translation, in-plane rotation, scale) that
carries the reference irises onto the current ones moves the reference head frame
(:meth:`IrisAnchors.similarity`). When an iris is not found (closed eye, occlusion,
turned head), the tracker falls back on the contours (see
:class:`~trackers.tracking.Tracker`).

All points are image pixels (x right, y down).
"""

from __future__ import annotations

import cv2
import numba
import numpy as np

from trackers.potentials import to_gray
from trackers.sampling import bilinear_nb

__all__ = ["IrisAnchors", "find_iris", "similarity_from_pairs"]


def _crop(gray, cx, cy, half):
    """Window of ``gray`` centred near (cx, cy); returns the crop and its origin."""
    H, W = gray.shape
    x0 = max(int(np.floor(cx - half)), 0)
    y0 = max(int(np.floor(cy - half)), 0)
    x1 = min(int(np.ceil(cx + half)) + 1, W)
    y1 = min(int(np.ceil(cy + half)) + 1, H)
    return gray[y0:y1, x0:x1], x0, y0


def find_iris(gray, guess, radius: float, *, search: float | None = None,
              min_contrast: float = 12.0):
    """Centre of the dark iris disk nearest to ``guess``.

    The image is blurred at half the iris radius; the iris is the spot within
    ``search`` pixels of ``guess`` that is darkest relative to the mean of the two
    points two radii to its left and right (the sclera; an eyebrow or a lid line is
    as dark there), with a parabolic sub-pixel peak.

    Parameters
    ----------
    gray : ndarray (H, W)
        Grey image.
    guess : (x, y)
        Rough eye centre, e.g. from the face layout.
    radius : float
        Iris radius in pixels (about 0.09 of the inter-eye distance).
    search : float, optional
        Half-size of the search window (default ``2.5 * radius``).
    min_contrast : float
        Least difference in grey levels between the sides and the iris; below it
        no iris is reported.

    Returns
    -------
    ndarray (2,) or None

    Examples
    --------
    >>> import numpy as np, cv2
    >>> img = np.full((60, 80), 220, np.uint8)
    >>> _ = cv2.circle(img, (41, 30), 5, 60, -1)
    >>> find_iris(img, (38, 28), 5.0).round().tolist()
    [41.0, 30.0]
    """
    g = np.asarray(gray, np.float32)
    if g.ndim != 2:
        raise ValueError(f"gray must be 2-D, got shape {g.shape}")
    if not np.isfinite(radius) or radius <= 0.5:
        raise ValueError(f"radius must be > 0.5 px, got {radius}")
    search = 2.5 * radius if search is None else float(search)
    r = float(radius)
    crop, x0, y0 = _crop(g, guess[0], guess[1], search + 2.5 * r + 2)
    if crop.shape[0] < 2 * r or crop.shape[1] < 2 * r:
        return None
    blur = cv2.GaussianBlur(crop, (0, 0), max(0.5 * r, 0.7))
    yy, xx = np.mgrid[: crop.shape[0], : crop.shape[1]]
    xx = xx + x0
    yy = yy + y0
    win = (np.abs(xx - guess[0]) <= search) & (np.abs(yy - guess[1]) <= search)
    if not win.any():
        return None
    # an iris is darker than the sclera on its left and right; an eyebrow or a lid
    # line is as dark beside itself along the line
    sh = int(round(2.0 * r))
    side = np.full_like(blur, np.inf)
    if blur.shape[1] > 2 * sh:
        side[:, sh:-sh] = 0.5 * (blur[:, :-2 * sh] + blur[:, 2 * sh:])
    k = np.argmin(np.where(win & np.isfinite(side), blur - side, np.inf))
    if not np.isfinite(blur.flat[k] - side.flat[k]):
        return None
    i, j = np.unravel_index(k, blur.shape)
    resp = np.where(np.isfinite(side), blur - side, 0.0)
    if -resp[i, j] < min_contrast:
        return None
    dx, dy = _subpixel(-resp, i, j)
    c = np.array([xx[i, j] + dx, yy[i, j] + dy], float)
    return c


def similarity_from_pairs(src, dst):
    """Similarity ``z -> a z + b`` (complex numbers) that carries 2 points onto 2 points.

    Examples
    --------
    >>> a, b = similarity_from_pairs([[0, 0], [1, 0]], [[1, 1], [1, 3]])
    >>> a, b
    (2j, (1+1j))
    """
    s = np.asarray(src, float)
    d = np.asarray(dst, float)
    zs = s[:, 0] + 1j * s[:, 1]
    zd = d[:, 0] + 1j * d[:, 1]
    if abs(zs[1] - zs[0]) < 1e-9:
        raise ValueError("the two source points coincide")
    a = complex((zd[1] - zd[0]) / (zs[1] - zs[0]))
    return a, complex(zd[0] - a * zs[0])


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _lk_nb(win, rows, cols, J, tm, x, y, h):
    """Inverse-compositional Lucas-Kanade for a translation with gain and bias
    normalisation and robust (Cauchy) weights; returns the refined (x, y) or the
    start when it wanders off by more than 1.5 px."""
    n = rows.shape[0]
    tsd = 0.0
    for i in range(n):
        tsd += tm[i] * tm[i]
    tsd = np.sqrt(tsd / n)
    w = np.empty(n)
    e = np.empty(n)
    px = x
    py = y
    for _ in range(8):
        s = 0.0
        for i in range(n):
            w[i] = bilinear_nb(win, cols[i] + px - h, rows[i] + py - h, 0.0, 0.0)
            if np.isnan(w[i]):
                return x, y
            s += w[i]
        mean = s / n
        v = 0.0
        for i in range(n):
            w[i] -= mean
            v += w[i] * w[i]
        sd = np.sqrt(v / n)
        if sd < 1e-6:
            break
        for i in range(n):
            e[i] = w[i] * (tsd / sd) - tm[i]
        c = 2.5 * max(np.median(np.abs(e)) * 1.4826, 1.0)
        a11 = 0.0
        a12 = 0.0
        a22 = 0.0
        b1 = 0.0
        b2 = 0.0
        for i in range(n):
            r = e[i] / c
            wt = 1.0 / (1.0 + r * r)
            a11 += wt * J[i, 0] * J[i, 0]
            a12 += wt * J[i, 0] * J[i, 1]
            a22 += wt * J[i, 1] * J[i, 1]
            b1 += wt * J[i, 0] * e[i]
            b2 += wt * J[i, 1] * e[i]
        det = a11 * a22 - a12 * a12
        if abs(det) < 1e-9:
            break
        dx = (a22 * b1 - a12 * b2) / det
        dy = (a11 * b2 - a12 * b1) / det
        px -= dx
        py -= dy
        if abs(px - x) > 1.5 or abs(py - y) > 1.5:
            return x, y
        if dx * dx + dy * dy < 1e-6:
            break
    return px, py


def _subpixel(resp, i, j):
    """Parabolic sub-pixel offsets around the integer peak (row i, column j)."""
    def off(m, c, p):
        den = m - 2 * c + p
        return 0.0 if den >= 0 else float(np.clip(0.5 * (m - p) / den, -0.5, 0.5))
    H, W = resp.shape
    dx = off(resp[i, j - 1], resp[i, j], resp[i, j + 1]) if 0 < j < W - 1 else 0.0
    dy = off(resp[i - 1, j], resp[i, j], resp[i + 1, j]) if 0 < i < H - 1 else 0.0
    return dx, dy


class IrisAnchors:
    """The two irises as rigid head anchors (see the module docstring).

    Parameters
    ----------
    frame : array_like
        Reference frame (grey or colour).
    eyes : array_like (2, 2)
        Rough eye centres (subject's right eye = image left first).
    channel_order : {'rgb', 'bgr'}
    min_score : float
        Least normalised cross-correlation of a match.

    Attributes
    ----------
    centres : ndarray (2, 2)
        Iris centres on the reference frame.
    radius : float
        Iris radius used, pixels.

    Raises
    ------
    ValueError
        When an iris cannot be found on the reference frame.

    Examples
    --------
    >>> import numpy as np, cv2
    >>> img = np.full((80, 120), 200, np.uint8)
    >>> for x in (40, 80):
    ...     _ = cv2.circle(img, (x, 40), 4, 50, -1)
    >>> anc = IrisAnchors(img, [(38, 41), (82, 39)])
    >>> moved = np.roll(img, (2, 3), axis=(0, 1))
    >>> a, b = anc.similarity(moved)
    >>> round(abs(a), 3), round(b.real, 2), round(b.imag, 2)
    (1.0, 3.0, 2.0)
    """

    def __init__(self, frame, eyes, *, channel_order: str = "rgb", min_score: float = 0.7):
        gray = to_gray(frame, channel_order=channel_order)
        eyes = np.asarray(eyes, float).reshape(2, 2)
        iod = float(np.hypot(*(eyes[1] - eyes[0])))
        if not np.isfinite(iod) or iod < 10:
            raise ValueError(f"eye centres {eyes.tolist()} are too close")
        if not 0 < min_score < 1:
            raise ValueError(f"min_score must be in (0, 1), got {min_score}")
        self.channel_order = channel_order
        self.min_score = float(min_score)
        self.radius = 0.085 * iod
        found = []
        for e in eyes:
            c = find_iris(gray, e, self.radius, search=0.15 * iod)
            if c is None:
                raise ValueError(f"no iris found near {np.round(e, 1).tolist()}")
            found.append(c)
        self.centres = np.array(found)
        d = self.centres[1] - self.centres[0]
        if not 0.6 * iod < np.hypot(*d) < 1.5 * iod:
            raise ValueError("the irises found are not an eye pair")
        self.half = int(np.ceil(1.5 * self.radius))
        h = self.half
        yy, xx = np.mgrid[-h:h + 1, -h:h + 1]
        # the iris and a rim of sclera on either side; lids above and below move with
        # the expression, so the mask is a horizontal ellipse
        self.mask = (((xx / (1.5 * self.radius)) ** 2 + (yy / (0.7 * self.radius)) ** 2)
                     <= 1).astype(np.float32)
        self.templates = []
        self.offsets = self.centres - np.round(self.centres)
        for c in self.centres:
            self.templates.append(self._patch(gray, c, h))
        if any(t is None for t in self.templates):
            raise ValueError("an iris lies too close to the image border")
        # inverse-compositional Lucas-Kanade (translation, gain and bias): template
        # gradients and the Gauss-Newton matrix are fixed
        sel = self.mask > 0
        self._rows, self._cols = (v.astype(np.int64) for v in np.nonzero(sel))
        self._lk = []
        for t in self.templates:
            gy, gx = np.gradient(t)
            tm = t[sel] - t[sel].mean()
            J = np.c_[gx[sel], gy[sel]]
            A = J.T @ J
            if np.linalg.cond(A) > 1e6 or tm.std() < 1.0:
                raise ValueError("an iris template has too little texture")
            self._lk.append((np.ascontiguousarray(J, np.float64),
                             np.ascontiguousarray(tm, np.float64)))
        self.last = self.centres.copy()
        self.scores = np.ones(2)

    @staticmethod
    def _patch(gray, c, h):
        """Template of half-size ``h`` around the pixel nearest to ``c`` (None at borders)."""
        x, y = int(round(c[0])), int(round(c[1]))
        H, W = gray.shape
        if x - h < 0 or y - h < 0 or x + h + 1 > W or y + h + 1 > H:
            return None
        return np.ascontiguousarray(gray[y - h:y + h + 1, x - h:x + h + 1], np.float32)

    def locate(self, frame, predicted=None, *, search: float | None = None):
        """Iris centres (2, 2) on ``frame`` (rows NaN where not found) and their scores.

        Parameters
        ----------
        frame : array_like
        predicted : array_like (2, 2), optional
            Where to search (default: the last positions found).
        search : float, optional
            Half-size of the search window, pixels (default 0.8 iris radii, at
            least 4).
        """
        img = np.asarray(frame)
        pred = self.last if predicted is None else np.asarray(predicted, float).reshape(2, 2)
        m = int(np.ceil(max(4.0, 0.8 * self.radius) if search is None else search))
        h = self.half
        out = np.full((2, 2), np.nan)
        scores = np.zeros(2)
        for k in range(2):
            cx, cy = pred[k]
            if not np.isfinite(pred[k]).all():
                continue
            x0, y0 = int(round(cx)) - h - m, int(round(cy)) - h - m
            H, W = img.shape[:2]
            if x0 < 0 or y0 < 0 or x0 + 2 * (h + m) + 1 > W or y0 + 2 * (h + m) + 1 > H:
                continue
            win = to_gray(img[y0:y0 + 2 * (h + m) + 1, x0:x0 + 2 * (h + m) + 1],
                          channel_order=self.channel_order)
            resp = cv2.matchTemplate(win, self.templates[k], cv2.TM_CCOEFF_NORMED,
                                     mask=self.mask)
            resp = np.nan_to_num(resp, nan=-1.0, posinf=-1.0, neginf=-1.0)
            i, j = np.unravel_index(int(np.argmax(resp)), resp.shape)
            scores[k] = float(resp[i, j])
            if scores[k] < self.min_score:
                continue
            dx, dy = self._refine(win, k, j + h, i + h)
            out[k] = (x0 + dx, y0 + dy) + self.offsets[k]
        found = np.isfinite(out).all(axis=1)
        self.last = np.where(found[:, None], out, pred)
        self.scores = scores
        return out, scores

    def _refine(self, win, k, x, y):
        """Sub-pixel position in ``win`` of template ``k`` whose integer match is (x, y)."""
        J, tm = self._lk[k]
        px, py = _lk_nb(np.ascontiguousarray(win, np.float32), self._rows, self._cols,
                        J, tm, float(x), float(y), self.half)
        return px, py

    def similarity(self, frame, predicted=None, *, rotation: float | None = None,
                   search: float | None = None):
        """Similarity from the reference irises to those on ``frame``.

        Parameters
        ----------
        frame : array_like
        predicted : array_like (2, 2), optional
            Where to search for the irises.
        rotation : float, optional
            In-plane rotation (radians) to use instead of the turn of the line
            between the irises (the tracker passes the turn of the line between the
            eyebrows, which is less disturbed by the lids); the translation then
            keeps the midpoint of the irises on its match.
        search : float, optional
            Half-size of the search window (see :meth:`locate`).

        Returns
        -------
        (complex, complex) or None
            ``a, b`` of ``z -> a z + b`` (points as complex ``x + 1j y``), or None when
            an iris is not found or the pair is implausible (scale change over 30 %).
        """
        pts, _ = self.locate(frame, predicted, search=search)
        if not np.isfinite(pts).all():
            return None
        a, b = similarity_from_pairs(self.centres, pts)
        if not 0.7 < abs(a) < 1.3:
            return None
        if rotation is not None:
            a, b = self.similarity_with_rotation((a, b), rotation)
        return a, b

    def similarity_with_rotation(self, sim, rotation: float):
        """``sim`` (a, b) with its rotation replaced by ``rotation`` (radians), scale
        kept and the midpoint of the reference irises still carried onto its match.

        Examples
        --------
        >>> import numpy as np
        >>> anc = IrisAnchors.__new__(IrisAnchors)
        >>> anc.centres = np.array([[0.0, 0.0], [10.0, 0.0]])
        >>> a, b = anc.similarity_with_rotation((1.0 + 0j, 2 + 1j), 0.0)
        >>> a, b
        ((1+0j), (2+1j))
        """
        a, b = sim
        m0 = complex(*self.centres.mean(axis=0))
        m1 = a * m0 + b
        a = abs(a) * complex(np.exp(1j * float(rotation)))
        return a, complex(m1 - a * m0)
