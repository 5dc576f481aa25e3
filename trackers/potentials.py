"""Image potentials whose ravines attract deformable contours (004 section V-B, V-E).

All potentials are returned in **8-bit intensity units**, whatever the input dtype
(``uint8`` as is, ``uint16`` divided by 257, other integers scaled by their maximum,
floating point and boolean images are taken to span [0, 1] and multiplied by 255).
This is what lets the paper's image-force strength ``p = 0.001`` (given for
256x256x8-bit frames) keep its meaning for other ranges.

Sign convention. A potential ``P`` is low (negative) on the features to be tracked
(its *ravines*) and contours slide downhill in it (004 V-C). The force on a node is
therefore ``-p * grad P``; eq. 12 of 004 writes ``p * grad P`` and leaves the sign
of ``P`` implicit. :func:`~trackers.sampling.force_field` returns
``-p * grad P``.

Four potentials are offered:

``gaussian_potential``
    Eq. 13, ``P = -||grad(G_sigma * I)||``: ravines on intensity *edges* (step
    boundaries such as the hairline or the outline of a lip).
``paper_potential``
    The paper's own discrete filter (004 V-E): two four-neighbour averaging steps,
    forward-difference gradient, magnitude. Its forward differences sit half a pixel
    right/below the pixel they are stored at; a contour settles ~0.5 px up-left of the
    true edge unless ``centred=True`` (which averages the 2x2 neighbourhood back onto
    pixel centres).
``valley_potential``
    ``P = -sigma**2 * max(lambda_max(Hessian(G_sigma * I)), 0)``: ravines along the
    centre line of *dark lines and bands* (eyebrows, furrows, lips, nostrils), whose
    cross-section has a large positive second derivative. A uniform dark region gives
    no response inside, so a contour is not dragged into the hair or the mouth cavity;
    a step edge gives a ravine on its dark side, about ``sigma`` from the edge. Use it
    where a feature's centre line is what is tracked (the face layout does so for the
    brows, furrows, nose, lips and chin); use an edge potential for boundaries.

``dark_below_potential``
    ``P = min(d(G_sigma * I)/dy, 0)``: a polarised edge, bright above and dark below
    (e.g. the lower border of the upper lip over a dark mouth line or cavity).

Every potential accepts ``roi=(x0, y0, x1, y1)`` (half-open pixel bounds) and then
computes only inside it (with an internal margin so the borders are exact) and
returns the cropped array whose pixel ``[0, 0]`` is image pixel ``(x0, y0)``.
"""

from __future__ import annotations

import cv2
import numba
import numpy as np

__all__ = [
    "to_gray",
    "gaussian_potential",
    "paper_potential",
    "valley_potential",
    "dark_below_potential",
    "potential_from_gray",
    "potentials_in_boxes",
]

_MIN_SIZE = 3


def to_gray(image, *, channel_order: str = "rgb") -> np.ndarray:
    """Validate a frame and convert it to a float32 grey image in 8-bit units.

    Parameters
    ----------
    image : array_like, shape (H, W) or (H, W, C) with C in {1, 3, 4}
        Grey or colour frame of any numeric or boolean dtype. Integers are scaled
        by their dtype's maximum (``uint16`` by 1/257), floats and booleans must
        span [0, 1] (a float frame outside [0, 1] raises rather than silently
        giving 255 times too strong forces).
    channel_order : {'rgb', 'bgr'}
        Order of colour channels (OpenCV frames are 'bgr'). Luminance weights are
        ITU-R BT.601 (0.299 R + 0.587 G + 0.114 B); alpha is ignored.

    Returns
    -------
    gray : ndarray of float32, shape (H, W)
        A new array in [0, 255] units (the input is never modified).

    Raises
    ------
    ValueError
        For an empty image, one smaller than 3x3, a bad number of channels or
        dimensions, a non-numeric dtype, NaN / infinite pixels, or a float image
        outside [0, 1].

    Examples
    --------
    >>> import numpy as np
    >>> float(to_gray(np.ones((4, 5))).max())
    255.0
    """
    if channel_order not in ("rgb", "bgr"):
        raise ValueError(f"channel_order must be 'rgb' or 'bgr', got {channel_order!r}")
    img = np.asarray(image)
    if img.dtype == object or not (np.issubdtype(img.dtype, np.number) or img.dtype == bool):
        raise ValueError(f"image must have a numeric dtype, got {img.dtype}")
    if np.iscomplexobj(img):
        raise ValueError("image must be real-valued, got a complex dtype")
    if img.ndim == 3 and img.shape[2] == 1:
        img = img[:, :, 0]
    if img.ndim not in (2, 3):
        raise ValueError(f"image must be 2-D (grey) or 3-D (colour), got shape {img.shape}")
    if img.ndim == 3 and img.shape[2] not in (3, 4):
        raise ValueError(f"colour image must have 1, 3 or 4 channels, got {img.shape[2]}")
    if img.size == 0 or img.shape[0] < _MIN_SIZE or img.shape[1] < _MIN_SIZE:
        raise ValueError(f"image must be at least {_MIN_SIZE}x{_MIN_SIZE} pixels, "
                         f"got shape {img.shape}")
    if img.dtype == bool:
        scale = 255.0
    elif np.issubdtype(img.dtype, np.integer):
        scale = 1.0 if img.dtype == np.uint8 else 255.0 / float(np.iinfo(img.dtype).max)
    else:
        scale = 255.0
        lo, hi = float(np.nanmin(img)), float(np.nanmax(img))
        if np.isfinite(lo) and np.isfinite(hi) and (lo < -1e-3 or hi > 1.0 + 1e-3):
            raise ValueError(f"floating-point images must lie in [0, 1] (got values in "
                             f"[{lo:.4g}, {hi:.4g}]); divide by 255 or pass uint8")
    if img.ndim == 3:
        rgb = img[:, :, :3]
        w = (0.299, 0.587, 0.114) if channel_order == "rgb" else (0.114, 0.587, 0.299)
        if img.dtype == np.uint8:
            gray = cv2.transform(np.ascontiguousarray(rgb), np.array([w], np.float32))
            gray = gray.astype(np.float32, copy=False)
        else:
            rgb = rgb.astype(np.float32)
            gray = rgb[:, :, 0] * w[0] + rgb[:, :, 1] * w[1] + rgb[:, :, 2] * w[2]
    else:
        gray = img.astype(np.float32)  # always a copy
    if scale != 1.0:
        gray *= np.float32(scale)
    # integer and boolean pixels are finite by construction
    if img.dtype.kind == "f" and not np.isfinite(gray).all():
        bad = np.argwhere(~np.isfinite(gray))[0]
        raise ValueError(f"image has NaN or infinite pixels (first at row {bad[0]}, "
                         f"col {bad[1]})")
    return gray


def _check_roi(roi, shape):
    if roi is None:
        return 0, 0, shape[1], shape[0]
    try:
        x0, y0, x1, y1 = (int(v) for v in roi)
    except (TypeError, ValueError):
        raise ValueError(f"roi must be (x0, y0, x1, y1), got {roi!r}") from None
    x0, y0 = max(x0, 0), max(y0, 0)
    x1, y1 = min(x1, shape[1]), min(y1, shape[0])
    if x1 - x0 < _MIN_SIZE or y1 - y0 < _MIN_SIZE:
        raise ValueError(f"roi {tuple(roi)} leaves less than {_MIN_SIZE}x{_MIN_SIZE} pixels "
                         f"inside the {shape[1]}x{shape[0]} image")
    return x0, y0, x1, y1


def _crop_with_margin(gray, roi, margin):
    x0, y0, x1, y1 = roi
    X0, Y0 = max(x0 - margin, 0), max(y0 - margin, 0)
    X1, Y1 = min(x1 + margin, gray.shape[1]), min(y1 + margin, gray.shape[0])
    return gray[Y0:Y1, X0:X1], (x0 - X0, y0 - Y0, x1 - x0, y1 - y0)


def _check_sigma(sigma):
    sigma = float(sigma)
    if not np.isfinite(sigma) or sigma <= 0:
        raise ValueError(f"sigma must be a positive number, got {sigma}")
    return sigma


def _blur(img, sigma):
    k = 2 * int(np.ceil(3.0 * sigma)) + 1
    return cv2.GaussianBlur(img, (k, k), sigmaX=sigma, sigmaY=sigma,
                            borderType=cv2.BORDER_REFLECT)


@numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _edge_at(g, y, x):
    H, W = g.shape
    y0 = y - 1 if y > 0 else 0
    y1 = y + 1 if y < H - 1 else H - 1
    x0 = x - 1 if x > 0 else 0
    x1 = x + 1 if x < W - 1 else W - 1
    gx = (g[y, x1] - g[y, x0]) / (x1 - x0)
    gy = (g[y1, x] - g[y0, x]) / (y1 - y0)
    return -np.sqrt(gx * gx + gy * gy)


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _edge_nb(g, P):
    # central differences inside, one-sided on the border; the inside loop has no
    # branch and no division, so that it vectorises (4.9 against 43 us on 80 x 140;
    # halving by * 0.5 is exact, as / 2 was)
    H, W = g.shape
    for y in range(H):
        if y == 0 or y == H - 1:
            for x in range(W):
                P[y, x] = _edge_at(g, y, x)
            continue
        P[y, 0] = _edge_at(g, y, 0)
        for x in range(1, W - 1):
            gx = (g[y, x + 1] - g[y, x - 1]) * 0.5
            gy = (g[y + 1, x] - g[y - 1, x]) * 0.5
            P[y, x] = -np.sqrt(gx * gx + gy * gy)
        if W > 1:
            P[y, W - 1] = _edge_at(g, y, W - 1)


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _dark_below_nb(g, P):
    H, W = g.shape
    for y in range(H):
        y0 = y - 1 if y > 0 else 0
        y1 = y + 1 if y < H - 1 else H - 1
        for x in range(W):
            gy = (g[y1, x] - g[y0, x]) / (y1 - y0)
            P[y, x] = gy if gy < 0.0 else 0.0


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _valley_nb(g, s2, P):
    H, W = g.shape
    gx = np.empty_like(g)
    for y in range(H):
        for x in range(W):
            x0 = x - 1 if x > 0 else 0
            x1 = x + 1 if x < W - 1 else W - 1
            gx[y, x] = (g[y, x1] - g[y, x0]) / (x1 - x0)
    for y in range(H):
        y0 = y - 1 if y > 0 else 0
        y1 = y + 1 if y < H - 1 else H - 1
        for x in range(W):
            gxx = 0.0
            gyy = 0.0
            if 0 < x < W - 1:
                gxx = g[y, x + 1] - 2.0 * g[y, x] + g[y, x - 1]
            if 0 < y < H - 1:
                gyy = g[y + 1, x] - 2.0 * g[y, x] + g[y - 1, x]
            gxy = (gx[y1, x] - gx[y0, x]) / (y1 - y0)
            d = 0.5 * (gxx - gyy)
            lam = 0.5 * (gxx + gyy) + np.sqrt(d * d + gxy * gxy)
            P[y, x] = -s2 * lam if lam > 0.0 else 0.0


def gaussian_potential(image, sigma: float = 2.0, *, roi=None,
                       channel_order: str = "rgb") -> np.ndarray:
    """Edge potential of eq. 13 of 004: ``P = -||grad(G_sigma * I)||``.

    Parameters
    ----------
    image : array_like, (H, W) or (H, W, C)
        Frame of any dtype (see :func:`to_gray`).
    sigma : float
        Standard deviation of the Gaussian in pixels; larger widens the ravines
        (longer capture range) at the cost of detail.
    roi : (x0, y0, x1, y1), optional
        Compute only inside these half-open pixel bounds; the result is cropped.
    channel_order : {'rgb', 'bgr'}

    Returns
    -------
    P : ndarray of float32, (H, W) or the ROI's shape
        Non-positive, in 8-bit intensity units per pixel.

    Examples
    --------
    >>> import numpy as np
    >>> img = np.zeros((32, 32)); img[:, 16:] = 1.0
    >>> P = gaussian_potential(img, sigma=1.5)
    >>> int(np.argmin(P[16]))  # the ravine lies on the step (between 15 and 16)
    15
    """
    sigma = _check_sigma(sigma)
    return potential_from_gray(to_gray(image, channel_order=channel_order), "edge", sigma,
                               roi=roi)


def _edge_from_gray(gray, sigma, roi, blurred=None):
    sub, (ox, oy, w, h) = _crop_with_margin(gray, roi, int(np.ceil(3 * sigma)) + 2)
    g = _blur(sub, sigma) if blurred is None else blurred
    P = np.empty_like(g)
    _edge_nb(g, P)
    return np.ascontiguousarray(P[oy:oy + h, ox:ox + w])


def paper_potential(image, *, roi=None, centred: bool = False,
                    channel_order: str = "rgb") -> np.ndarray:
    """The paper's potential (004 V-E): two four-neighbour averages, forward differences.

    Each averaging step replaces a pixel by the mean of itself and its four
    neighbours (borders reflected); the gradient is ``[v(i+1, j) - v(i, j),
    v(i, j+1) - v(i, j)]`` and ``P = -||gradient||``. The paper interpolates ``P``
    bilinearly between pixels; :func:`~trackers.sampling.sample_bilinear` does that.

    Parameters
    ----------
    image : array_like
        Frame of any dtype (see :func:`to_gray`).
    roi : (x0, y0, x1, y1), optional
        Compute only inside these bounds; the result is cropped.
    centred : bool
        The forward differences describe the point half a pixel right and below
        the pixel they are stored at. ``False`` (default) keeps the paper's filter
        exactly; ``True`` averages each 2x2 block so values sit on pixel centres.
    channel_order : {'rgb', 'bgr'}

    Returns
    -------
    P : ndarray of float32

    Examples
    --------
    >>> import numpy as np
    >>> img = np.zeros((16, 16), np.uint8); img[:, 8:] = 200
    >>> P = paper_potential(img)
    >>> int(np.argmin(P[8]))  # forward difference between pixel 7 and 8 is stored at 7
    7
    """
    return potential_from_gray(to_gray(image, channel_order=channel_order),
                               "paper_centred" if centred else "paper", roi=roi)


def _paper_from_gray(gray, centred, roi):
    sub, (ox, oy, w, h) = _crop_with_margin(gray, roi, 4)
    kernel = np.array([[0, 1, 0], [1, 1, 1], [0, 1, 0]], np.float32) / np.float32(5.0)
    v = cv2.filter2D(sub, -1, kernel, borderType=cv2.BORDER_REFLECT)
    v = cv2.filter2D(v, -1, kernel, borderType=cv2.BORDER_REFLECT)
    gx = np.zeros_like(v)
    gy = np.zeros_like(v)
    gx[:, :-1] = v[:, 1:] - v[:, :-1]
    gy[:-1] = v[1:] - v[:-1]
    P = -cv2.magnitude(gx, gy)
    if centred:
        Pc = P.copy()
        Pc[1:, 1:] = 0.25 * (P[1:, 1:] + P[:-1, 1:] + P[1:, :-1] + P[:-1, :-1])
        P = Pc
    return np.ascontiguousarray(P[oy:oy + h, ox:ox + w])


def valley_potential(image, sigma: float = 2.0, *, roi=None,
                     channel_order: str = "rgb") -> np.ndarray:
    """Dark-line potential: ``-sigma**2 * max(largest Hessian eigenvalue of G_sigma * I, 0)``.

    Ravines run along the centre line of dark lines and bands about ``2 * sigma``
    to ``4 * sigma`` wide (eyebrows, furrows, lips); bright lines and the inside of
    uniform regions give no response.

    Parameters
    ----------
    image : array_like
        Frame of any dtype (see :func:`to_gray`).
    sigma : float
        Gaussian scale in pixels; match it to about half the feature's width.
    roi : (x0, y0, x1, y1), optional
        Compute only inside these bounds; the result is cropped.
    channel_order : {'rgb', 'bgr'}

    Returns
    -------
    P : ndarray of float32
        Non-positive, in 8-bit intensity units (scale-normalised).

    Examples
    --------
    >>> import numpy as np
    >>> img = np.full((40, 40), 200.0, np.float32) / 255; img[18:23, :] = 0.2
    >>> P = valley_potential(img, sigma=2.5)
    >>> int(np.argmin(P[:, 20]))  # centre of the dark band (rows 18..22)
    20
    """
    sigma = _check_sigma(sigma)
    return potential_from_gray(to_gray(image, channel_order=channel_order), "valley", sigma,
                               roi=roi)


def _valley_from_gray(gray, sigma, roi, blurred=None):
    sub, (ox, oy, w, h) = _crop_with_margin(gray, roi, int(np.ceil(3 * sigma)) + 2)
    g = _blur(sub, sigma) if blurred is None else blurred
    P = np.empty_like(g)
    _valley_nb(g, np.float32(sigma * sigma), P)
    return np.ascontiguousarray(P[oy:oy + h, ox:ox + w])


KINDS = ("edge", "valley", "dark_below", "paper", "paper_centred")


def potential_from_gray(gray, kind: str, sigma: float = 2.0, *, roi=None) -> np.ndarray:
    """Potential of an image already converted by :func:`to_gray` (no re-validation).

    Parameters
    ----------
    gray : ndarray of float32, (H, W)
        Grey image in 8-bit units, as :func:`to_gray` returns.
    kind : {'edge', 'valley', 'dark_below', 'paper', 'paper_centred'}
        :func:`gaussian_potential`, :func:`valley_potential`,
        :func:`dark_below_potential` or :func:`paper_potential` (``centred=False`` /
        ``True``); ``sigma`` is ignored by the paper's filter.
    sigma : float
    roi : (x0, y0, x1, y1), optional

    Returns
    -------
    P : ndarray of float32

    Examples
    --------
    >>> import numpy as np
    >>> g = to_gray(np.eye(8))
    >>> potential_from_gray(g, "valley", 1.0, roi=(0, 0, 4, 4)).shape
    (4, 4)
    """
    if kind not in KINDS:
        raise ValueError(f"kind must be one of {KINDS}, got {kind!r}")
    gray = np.asarray(gray)
    if gray.ndim != 2 or gray.dtype != np.float32:
        raise ValueError(f"gray must be a 2-D float32 array from to_gray, got {gray.dtype} "
                         f"{gray.shape}")
    roi = _check_roi(roi, gray.shape)
    if kind == "edge":
        return _edge_from_gray(gray, _check_sigma(sigma), roi)
    if kind == "valley":
        return _valley_from_gray(gray, _check_sigma(sigma), roi)
    if kind == "dark_below":
        sigma = _check_sigma(sigma)
        sub, (ox, oy, w, h) = _crop_with_margin(gray, roi, int(np.ceil(3 * sigma)) + 2)
        g = _blur(sub, sigma)
        P = np.empty_like(g)
        _dark_below_nb(g, P)
        return np.ascontiguousarray(P[oy:oy + h, ox:ox + w])
    return _paper_from_gray(gray, kind == "paper_centred", roi)


def potentials_in_boxes(gray, specs, boxes):
    """Potentials of several (kind, sigma) pairs, each inside its own box.

    Each box is blurred with a margin of ``3 * sigma`` (so box borders are exact as
    long as ``gray`` extends that far beyond them), or, when the boxes of one
    ``sigma`` would cover more than the whole image, one blur of the whole image is
    shared; the potential is then evaluated in each box only. This is what the
    tracker uses: one small box per contour.

    Parameters
    ----------
    gray : ndarray of float32 (H, W)
        From :func:`to_gray`.
    specs : sequence of (kind, sigma)
        ``kind`` in {'edge', 'valley', 'dark_below'}.
    boxes : sequence of (x0, y0, x1, y1)
        Half-open pixel bounds in ``gray``, one per spec.

    Returns
    -------
    list of ndarray of float32
        ``P`` of each box (pixel [0, 0] = box corner).

    Examples
    --------
    >>> import numpy as np
    >>> g = to_gray(np.eye(20))
    >>> [P.shape for P in potentials_in_boxes(g, [("edge", 1.0), ("valley", 1.0)],
    ...                                       [(0, 0, 5, 6), (2, 2, 12, 12)])]
    [(6, 5), (10, 10)]
    """
    gray = np.asarray(gray)
    if gray.ndim != 2 or gray.dtype != np.float32:
        raise ValueError("gray must be a 2-D float32 array from to_gray")
    if len(specs) != len(boxes):
        raise ValueError(f"need one box per spec, got {len(specs)} specs and {len(boxes)} boxes")
    blurred = {}
    out = []
    checked = []
    area = {}
    for (kind, sigma), box in zip(specs, boxes):
        sigma = _check_sigma(sigma)
        if kind not in ("edge", "valley", "dark_below"):
            raise ValueError(f"kind must be 'edge', 'valley' or 'dark_below', got {kind!r}")
        b = _check_roi(box, gray.shape)
        checked.append((kind, sigma, b))
        m = int(np.ceil(3 * sigma)) + 2
        area[sigma] = area.get(sigma, 0) + (b[2] - b[0] + 2 * m) * (b[3] - b[1] + 2 * m)
    for kind, sigma, (x0, y0, x1, y1) in checked:
        if area[sigma] < gray.size:
            # small boxes: blur each (with its margin) rather than the whole image
            sub, (ox, oy, w, h) = _crop_with_margin(gray, (x0, y0, x1, y1),
                                                    int(np.ceil(3 * sigma)) + 2)
            g = _blur(sub, sigma)[oy:oy + h, ox:ox + w]
        else:
            if sigma not in blurred:
                blurred[sigma] = _blur(gray, sigma)
            g = blurred[sigma][y0:y1, x0:x1]
        # the kernels run on a contiguous copy: on a strided view Numba's loops do not
        # vectorise (2.5x slower on a contour's box, where the copy costs a tenth of that)
        g = np.ascontiguousarray(g)
        P = np.empty((y1 - y0, x1 - x0), np.float32)
        if kind == "edge":
            _edge_nb(g, P)
        elif kind == "dark_below":
            _dark_below_nb(g, P)
        else:
            _valley_nb(g, np.float32(sigma * sigma), P)
        out.append(P)
    return out


def dark_below_potential(image, sigma: float = 1.5, *, roi=None,
                         channel_order: str = "rgb") -> np.ndarray:
    """Polarised edge potential: ``P = min(d(G_sigma * I)/dy, 0)``.

    Ravines lie only on edges that go from bright (above) to dark (below) in the
    image, such as the lower border of the upper lip, whether the mouth is closed
    (a thin dark mouth line below it) or open (the dark cavity below it). Edges of
    the other polarity (the lower lip's top border) give no response.

    Parameters
    ----------
    image : array_like
        Frame of any dtype (see :func:`to_gray`).
    sigma : float
    roi : (x0, y0, x1, y1), optional
    channel_order : {'rgb', 'bgr'}

    Returns
    -------
    P : ndarray of float32

    Examples
    --------
    >>> import numpy as np
    >>> img = np.full((30, 10), 200, np.uint8); img[15:, :] = 40   # dark below row 15
    >>> P = dark_below_potential(img, 1.0)
    >>> int(np.argmin(P[:, 5])) in (14, 15), float(P[20:25, 5].max()) == 0.0
    (True, True)
    >>> float(dark_below_potential(255 - img, 1.0).min())  # opposite polarity: nothing
    0.0
    """
    sigma = _check_sigma(sigma)
    return potential_from_gray(to_gray(image, channel_order=channel_order), "dark_below",
                               sigma, roi=roi)
