"""Pixel normalisation: any frame a video or image folder gives (grey, BGR, BGRA; 8-bit,
16-bit or float in [0, 1]) as grey float for measuring, as 8-bit BGR for drawing, or as
8-bit in its own layout for the analysis (:func:`to_uint8`: the analysis reads every
frame at 8 bits, so the same picture stored at another bit depth gives the same result)."""

from __future__ import annotations

import cv2
import numpy as np

__all__ = ["check_float_range", "fit_image", "to_bgr_uint8", "to_gray_float", "to_uint8"]


def _scale_of(dtype: np.dtype) -> float | None:
    if dtype == np.bool_:
        return 1.0
    if np.issubdtype(dtype, np.unsignedinteger):
        return float(np.iinfo(dtype).max)
    if np.issubdtype(dtype, np.signedinteger):
        return float(np.iinfo(dtype).max)
    if np.issubdtype(dtype, np.floating):
        return None
    raise ValueError(f"unsupported pixel type {dtype}; use integer or float images")


def _check_image(image) -> np.ndarray:
    image = np.asarray(image)
    if image.ndim == 3 and image.shape[2] in (1, 2, 3, 4):
        return image
    if image.ndim == 2:
        return image
    raise ValueError(f"image must be (H, W) grey or (H, W, 3|4) BGR(A), got shape {image.shape}")


def to_gray_float(image, *, dtype=np.float32) -> np.ndarray:
    """Convert any frame to a 2-D grey image of floats in [0, 1].

    Parameters
    ----------
    image : ndarray
        ``(H, W)`` grey, ``(H, W, 1)``, ``(H, W, 2)`` grey + alpha, ``(H, W, 3)`` BGR
        (OpenCV order) or ``(H, W, 4)`` BGRA. Integer images are divided by the
        largest value of their type (255 for ``uint8``, 65535 for ``uint16``);
        float images are taken to be in [0, 1] already and are not rescaled.
        Alpha is dropped. Not modified.
    dtype : numpy float dtype, keyword-only
        Output type, ``float32`` by default.

    Returns
    -------
    ndarray
        ``(H, W)`` array; colour is reduced with the Rec. 601 luma weights
        (0.299 R + 0.587 G + 0.114 B), like :func:`cv2.cvtColor`.

    Examples
    --------
    >>> import numpy as np
    >>> to_gray_float(np.full((2, 2), 65535, np.uint16))
    array([[1., 1.],
           [1., 1.]], dtype=float32)
    >>> bgr = np.zeros((1, 1, 3), np.uint8); bgr[..., 2] = 255   # pure red
    >>> round(float(to_gray_float(bgr)[0, 0]), 3)
    0.299
    """
    image = _check_image(image)
    scale = _scale_of(image.dtype)
    if image.ndim == 3:
        if image.shape[2] >= 3:
            b, g, r = (image[..., k].astype(np.float64) for k in range(3))
            grey = 0.114 * b + 0.587 * g + 0.299 * r
        else:
            grey = image[..., 0].astype(np.float64)
    else:
        grey = image.astype(np.float64)
    if scale is not None:
        grey = grey / scale
    return grey.astype(dtype, copy=False)


def to_bgr_uint8(image) -> np.ndarray:
    """Convert any frame to an 8-bit BGR image for drawing and video writing.

    Parameters
    ----------
    image : ndarray
        Same layouts and types as :func:`to_gray_float`; 16-bit is scaled by
        1/257 (full range), floats in [0, 1] by 255 and clipped. Not modified.

    Returns
    -------
    ndarray
        ``(H, W, 3)`` ``uint8``, a new array.

    Examples
    --------
    >>> import numpy as np
    >>> to_bgr_uint8(np.full((1, 2), 65535, np.uint16)).tolist()
    [[[255, 255, 255], [255, 255, 255]]]
    """
    image = _check_image(image)
    if image.ndim == 3 and image.shape[2] in (1, 2):
        image = image[..., 0]
    if image.ndim == 3:
        image = image[..., :3]
    if image.dtype != np.uint8:
        scale = _scale_of(image.dtype)
        values = image.astype(np.float64)
        values = values * (255.0 / scale) if scale is not None else values * 255.0
        image = np.clip(np.rint(values), 0, 255).astype(np.uint8)
    if image.ndim == 2:
        return cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)
    return np.ascontiguousarray(image).copy()


def to_uint8(image) -> np.ndarray:
    """Convert any frame to ``uint8``, keeping its layout (grey, BGR, BGRA).

    The analysis works on 8-bit frames: a frame stored at 16 bits is brought to 8 bits
    once, where it is read, so that the same picture gives the same tracks and
    contractions whatever its bit depth (a ``uint16`` frame ``257 * x`` gives exactly
    the ``uint8`` frame ``x``).

    Parameters
    ----------
    image : ndarray
        Same layouts and types as :func:`to_gray_float`. ``uint8`` is returned as is;
        ``uint16`` is divided by 257 and rounded; other integers are scaled by their
        largest value; floats in [0, 1] and booleans are multiplied by 255; the result
        is rounded and clipped to [0, 255]. Not modified.

    Returns
    -------
    ndarray
        ``uint8`` array of the same shape (``image`` itself when it is already ``uint8``).

    Raises
    ------
    ValueError
        For floats that are not finite or lie outside [0, 1] (beyond a rounding slack of
        1e-3): a float frame in 0..255 would otherwise be clipped to white, and every
        frame then read as faceless.

    Examples
    --------
    >>> import numpy as np
    >>> to_uint8(np.array([[0, 257, 128, 65535]], np.uint16)).tolist()
    [[0, 1, 0, 255]]
    >>> to_uint8(np.array([[0.0, 0.5, 1.0]])).tolist()
    [[0, 128, 255]]
    """
    image = _check_image(image)
    if image.dtype == np.uint8:
        return image
    if image.dtype == np.uint16:
        # round(v / 257) in integers: 257 is odd, so there are no ties
        return ((image.astype(np.uint32) + 128) // 257).astype(np.uint8)
    scale = _scale_of(image.dtype)
    if scale is None:
        check_float_range(image)
    values = image.astype(np.float64)
    values = values * (255.0 / scale) if scale is not None else values * 255.0
    return np.clip(np.rint(values), 0, 255).astype(np.uint8)


def check_float_range(image) -> None:
    """Raise ValueError unless the float ``image`` is finite and within [0, 1] (1e-3 slack).

    Examples
    --------
    >>> import numpy as np
    >>> check_float_range(np.array([0.0, 1.0]))
    >>> check_float_range(np.array([0.0, 255.0]))  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    ValueError: float pixels must lie in [0, 1], got values in [0, 255]: divide by 255 ...
    """
    image = np.asarray(image)
    if image.size == 0:
        return
    lo, hi = float(np.min(image)), float(np.max(image))
    if not (np.isfinite(lo) and np.isfinite(hi)):
        raise ValueError("float pixels must be finite, got NaN or infinite values")
    if lo < -1e-3 or hi > 1.0 + 1e-3:
        raise ValueError(f"float pixels must lie in [0, 1], got values in [{lo:.4g}, {hi:.4g}]: "
                         "divide by 255 or use 8- or 16-bit integer pixels")


def fit_image(image, size) -> tuple[np.ndarray, tuple[float, float], tuple[float, float]]:
    """``image`` scaled to fit inside ``size`` and centred on a canvas of that size.

    For photographs of several sizes analysed together: each is measured on the first's
    canvas, its face's geometry kept (one scale for both axes; the analysis measures in
    the head's own units, so the scale does not change what it reads).

    Parameters
    ----------
    image : ndarray
        ``(h, w)`` or ``(h, w, C)``; not modified.
    size : (width, height)
        The canvas.

    Returns
    -------
    canvas : ndarray
        ``(height, width[, C])``, the image's dtype; the margins repeat the image's edge.
    scale : (float, float)
        Canvas pixels per image pixel along x and y (alike but for the rounding of the
        scaled image's size).
    offset : (float, float)
        Where the image's pixel (0, 0) lies on the canvas: a point ``p`` of the image is
        ``scale * p + offset`` there (pixel centres on integers).

    Examples
    --------
    >>> import numpy as np
    >>> canvas, scale, offset = fit_image(np.zeros((50, 200), np.uint8), (100, 100))
    >>> canvas.shape, scale, offset
    ((100, 100), (0.5, 0.5), (-0.25, 36.75))
    """
    image = _check_image(image)
    width, height = (int(v) for v in size)
    h, w = image.shape[:2]
    scale = min(width / w, height / h)
    new_w, new_h = max(1, round(w * scale)), max(1, round(h * scale))
    shrink = scale < 1
    resized = cv2.resize(image, (new_w, new_h),
                         interpolation=cv2.INTER_AREA if shrink else cv2.INTER_LINEAR)
    if resized.ndim < image.ndim:            # OpenCV drops a single channel
        resized = resized[..., None]
    left, top = (width - new_w) // 2, (height - new_h) // 2
    canvas = cv2.copyMakeBorder(resized, top, height - new_h - top, left,
                                width - new_w - left, cv2.BORDER_REPLICATE)
    if canvas.ndim < image.ndim:
        canvas = canvas[..., None]
    # pixel centres: image pixel i spans [i - 0.5, i + 0.5], mapped onto the canvas
    sx, sy = new_w / w, new_h / h
    return canvas, (float(sx), float(sy)), (float(left + 0.5 * sx - 0.5),
                                           float(top + 0.5 * sy - 0.5))
