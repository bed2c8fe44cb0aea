"""A camera's lens on whole images, both ways, as ``cv2.remap`` maps: :func:`through_lens_maps` (for every
pixel through the lens, where it falls in the pinhole twin: how the simulator renders through a lens) and
:class:`PinholeResampling` (for every pixel of the pinhole twin, where it falls through the lens: the
estimator's frames of a rig with a lens)."""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numpy as np
import numpy.typing as npt

from common.camera import CameraModel
from common.errors import InputError
from common.types import FloatArray

Maps = tuple[npt.NDArray[np.float32], npt.NDArray[np.float32]]


def _pixel_maps(camera: CameraModel, to_source: Callable[[FloatArray], FloatArray]) -> Maps:
    """``cv2.remap`` maps of ``camera``'s size: for every output pixel, ``to_source`` of it (a pixel the
    model cannot map is sent outside the image, so it reads the border)."""
    rows, cols = np.mgrid[0 : camera.height, 0 : camera.width]
    source = to_source(np.stack([cols.ravel(), rows.ravel()], axis=1).astype(np.float64))
    source = np.where(np.isfinite(source), source, -1e4)
    shape = (camera.height, camera.width)
    return source[:, 0].reshape(shape).astype(np.float32), source[:, 1].reshape(shape).astype(np.float32)


@functools.lru_cache(maxsize=8)
def through_lens_maps(camera: CameraModel) -> Maps:
    """For every pixel of the image through ``camera``'s lens, where it falls in the pinhole twin.

    Memoised per camera (a frozen value; read-only maps): the simulator renders every frame of a flight
    through the same lens, and making the maps (an iterative undistortion of every pixel) took 0.5 s a frame
    at 752x480, a hundred times the remap itself."""
    maps = _pixel_maps(camera, camera.undistort_px)
    for array in maps:
        array.flags.writeable = False
    return maps


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
        return cls(camera.width, camera.height, *_pixel_maps(camera, camera.distort_px))

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
