"""A camera's lens undone on whole images: :class:`PinholeResampling` resamples an image seen through a
:class:`~common.camera.CameraModel`'s lens onto its pinhole twin (the estimator's frames of a rig with a
lens)."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from common.camera import CameraModel
from common.errors import InputError


@dataclass(frozen=True, eq=False)
class PinholeResampling:
    """Pixel maps that resample an image seen through a camera's lens onto its pinhole twin
    (:meth:`CameraModel.pinhole`: the same size and intrinsics): one ``cv2.remap`` per image, the maps made
    once from :meth:`CameraModel.distort_px`. Pinhole pixels the lens does not see are 0."""

    width: int
    height: int
    map_x: np.ndarray
    map_y: np.ndarray

    @classmethod
    def of(cls, camera: CameraModel) -> PinholeResampling:
        u, v = np.meshgrid(
            np.arange(camera.width, dtype=np.float64), np.arange(camera.height, dtype=np.float64)
        )
        lens_px = camera.distort_px(np.stack([u.ravel(), v.ravel()], axis=1))
        lens_px[~np.isfinite(lens_px)] = -1.0
        shape = (camera.height, camera.width)
        return cls(
            camera.width,
            camera.height,
            lens_px[:, 0].reshape(shape).astype(np.float32),
            lens_px[:, 1].reshape(shape).astype(np.float32),
        )

    def apply(self, image: np.ndarray) -> np.ndarray:
        """``image`` (through the lens, ``height x width``) as its pinhole twin sees it."""
        if image.shape[:2] != (self.height, self.width):
            raise InputError(
                f"image is {image.shape[1]}x{image.shape[0]}, the lens {self.width}x{self.height}"
            )
        return np.asarray(
            cv2.remap(
                image, self.map_x, self.map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0
            )
        )
