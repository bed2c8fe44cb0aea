"""The one check of a grey image at a core's boundary (the yaw cluster, the estimator's vision, the
localizer's scoring each had their own)."""

from __future__ import annotations

import numpy as np

from common.errors import InputError
from common.types import U8Array


def check_grey_image(
    image: object, name: str = "image", min_side_px: int = 1, shape: tuple[int, int] | None = None
) -> U8Array:
    """Return ``image`` if it is a numpy uint8 array of shape (H, W) (one grey channel) with H and W at least
    ``min_side_px`` (and exactly ``shape`` when given), else raise :class:`InputError` saying what was
    expected. Not converted: a list or a float image is refused rather than silently cast."""
    if not isinstance(image, np.ndarray):
        raise InputError(f"{name} must be a numpy array of shape (H, W) and dtype uint8, got {type(image)}")
    if image.ndim != 2:
        raise InputError(f"{name} must be a grey image of shape (H, W) (one channel), got {image.shape}")
    if image.dtype != np.uint8:
        raise InputError(f"{name} must have dtype uint8 (grey 0..255), got {image.dtype}")
    if image.size == 0:
        raise InputError(f"{name} is empty, shape {image.shape}")
    if min(image.shape) < min_side_px:
        raise InputError(f"{name} must be at least {min_side_px}x{min_side_px} px, got {image.shape}")
    if shape is not None and image.shape != shape:
        raise InputError(f"{name} must have shape {shape}, got {image.shape}")
    return image
