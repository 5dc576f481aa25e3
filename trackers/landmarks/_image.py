"""Frame validation, regions and the affine sampling shared by the detectors and the landmark
models."""

from __future__ import annotations

import cv2
import numpy as np

CHANNEL_ORDERS = ("rgb", "bgr")


def check_image(image, channel_order: str) -> np.ndarray:
    """A uint8 (H, W) or (H, W, 3) view or copy of ``image``; channels are fixed after sampling.

    Floats must lie in [0, 1]; they are rounded to uint8 because the networks were trained on
    8-bit pictures and OpenCV samples uint8 fastest. Alpha is dropped ((H, W, 4) colour,
    (H, W, 2) grey), as the rest of the toolkit drops it: a PNG with an alpha channel is a
    picture like any other.
    """
    if channel_order not in CHANNEL_ORDERS:
        raise ValueError(f"channel_order={channel_order!r} is not one of 'rgb', 'bgr'")
    image = np.asarray(image)
    if image.ndim == 3 and image.shape[2] in (1, 2):
        image = image[:, :, 0]
    elif image.ndim == 3 and image.shape[2] == 4:
        image = image[:, :, :3]
    if not (image.ndim == 2 or (image.ndim == 3 and image.shape[2] == 3)) or min(
            image.shape[:2]) < 2:
        raise ValueError(f"image of shape {image.shape} is not a grey (H, W) or colour "
                         "(H, W, 3|4) frame")
    if not image.flags.c_contiguous:
        # OpenCV's warps read a contiguous buffer; a frame without its alpha is a strided view
        image = np.ascontiguousarray(image)
    if image.dtype == np.uint8:
        return image
    if image.dtype.kind != "f":
        raise ValueError(f"image dtype {image.dtype} is not uint8 or float in [0, 1]")
    if not np.isfinite(image).all() or image.min() < 0 or image.max() > 1:
        raise ValueError("a float image must be finite and within [0, 1]")
    return (image * 255 + 0.5).astype(np.uint8)


def sample(image: np.ndarray, crop_to_image: np.ndarray, size: int, channel_order: str, *,
           border: int) -> np.ndarray:
    """The (size, size, 3) uint8 RGB crop whose pixel (u, v) is ``crop_to_image @ (u, v, 1)``."""
    crop = cv2.warpAffine(image, crop_to_image, (size, size),
                          flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP, borderMode=border)
    if crop.ndim == 2:
        return np.repeat(crop[:, :, None], 3, axis=2)
    return crop[:, :, ::-1] if channel_order == "bgr" else crop


def region_crop(image: np.ndarray, region) -> tuple[np.ndarray, np.ndarray]:
    """The part of ``image`` within ``region`` (x0, y0, x1, y1; clipped to the image, out to
    whole pixels) and its top-left corner (x, y), by which what a detector finds there moves
    back into the image; ValueError where nothing of it is in the image."""
    h, w = image.shape[:2]
    x0, y0, x1, y1 = (float(v) for v in region)
    if not all(np.isfinite([x0, y0, x1, y1])):
        raise ValueError(f"region must be four finite numbers, got {region!r}")
    x0, y0 = max(0, int(np.floor(x0))), max(0, int(np.floor(y0)))
    x1, y1 = min(w, int(np.ceil(x1))), min(h, int(np.ceil(y1)))
    if x1 - x0 < 2 or y1 - y0 < 2:
        raise ValueError(f"region {region!r} lies outside the {w}x{h} image")
    return image[y0:y1, x0:x1], np.array([x0, y0], float)
