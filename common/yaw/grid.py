"""The patch grid over a frame (paper A, Fig. 2) and the frame's check where it enters the yaw core."""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, replace

import cv2
import numpy as np
import numpy.typing as npt

from common.errors import InputError
from common.images import check_grey_image
from common.types import FloatArray, U8Array
from common.yaw.settings import YawSettings

IntArray = npt.NDArray[np.intp]


def pyramid_image(frame_u8: U8Array, level: int) -> U8Array:
    """``level`` successive ``cv2.pyrDown`` of a frame (level 0 returns the frame itself)."""
    image = frame_u8
    for _ in range(level):
        image = np.asarray(cv2.pyrDown(image), dtype=np.uint8)
    return image


def level_shape(frame_shape: tuple[int, int], level: int) -> tuple[int, int]:
    """Shape (H, W) of a frame after ``level`` pyrDowns (each gives ceil(n / 2))."""
    height, width = frame_shape
    for _ in range(level):
        height, width = (height + 1) // 2, (width + 1) // 2
    return height, width


#: The largest working size the defaults were measured at (paper A's 752x480 hover at level 1; the field
#: suite's 320x240 at level 1 is the smallest): a geometric-mean side (px) the default level keeps within.
AUTO_LEVEL_SIDE_PX = 320.0
#: The level the defaults (and their full-resolution pixel thresholds) were measured at; the default level
#: is never finer.
AUTO_REFERENCE_LEVEL = 1
MAX_PYRAMID_LEVEL = 4


def check_frame_shape(frame_shape: tuple[int, int]) -> tuple[int, int]:
    """``frame_shape`` as ``(H, W)`` positive integers, or InputError."""
    if (
        len(frame_shape) != 2
        or not all(isinstance(v, (int, np.integer)) and not isinstance(v, bool) for v in frame_shape)
        or min(frame_shape) <= 0
    ):
        raise InputError(f"frame_shape must be (H, W) positive integers, got {frame_shape}")
    return int(frame_shape[0]), int(frame_shape[1])


def auto_pyramid_level(frame_shape: tuple[int, int], settings: YawSettings) -> int:
    """The default pyramid level of frames of ``frame_shape`` (H, W): level 1, where the defaults were
    measured (320x240 to 752x480 frames), or the first coarser one at which the frame's geometric-mean side
    is at most :data:`AUTO_LEVEL_SIDE_PX` (1280x720 at 2, 1920x1080 at 3, 3840x2160 at 4); no coarser than
    leaves room for a patch inside the margins (a tiny frame: 0).

    Why (``capataz bench yaw --suite field --field-size 1280x720``): at level 1 a 1280x720 wide-angle flight
    moves four times as many pixels a frame as at 320x240; the patch fit kept under half of its patches and a
    quarter of the pairs were not measured (:func:`for_frame` also scales the pixel thresholds).
    """
    frame_shape = check_frame_shape(frame_shape)
    side = math.sqrt(frame_shape[0] * frame_shape[1]) / 2**AUTO_REFERENCE_LEVEL
    level = AUTO_REFERENCE_LEVEL + max(0, math.ceil(math.log2(side / AUTO_LEVEL_SIDE_PX) - 1e-9))
    level = min(level, MAX_PYRAMID_LEVEL)
    while level > 0 and min(_free_span(frame_shape, level, settings)) < 0:
        level -= 1
    return int(level)


def for_frame(settings: YawSettings, frame_shape: tuple[int, int]) -> YawSettings:
    """``settings`` resolved for frames of ``frame_shape``: unchanged when they give a pyramid level; else at
    :func:`auto_pyramid_level`, with the full-resolution pixel thresholds (``ransac_threshold_px``,
    ``max_residual_px``, stated for 320x240 frames at level 1) scaled by ``2**(level - 1)``, so that they stay
    the same in working-level pixels: a fit's residuals (the patches' shift noise, the perspective a
    similarity leaves out) grow with the frame's size: a fixed 1 px at 1280x720 refused over half the
    inliers of a wide-angle flight that 2 px at level 2 keeps. Resolving resolved settings changes nothing."""
    if settings.pyramid_level is not None:
        return settings
    level = auto_pyramid_level(frame_shape, settings)
    stretch = 2.0 ** (level - AUTO_REFERENCE_LEVEL)
    return replace(
        settings,
        pyramid_level=level,
        ransac_threshold_px=settings.ransac_threshold_px * stretch,
        max_residual_px=settings.max_residual_px * stretch,
    )


def _level_margin(settings: YawSettings, level: int) -> int:
    """``margin_px`` (full resolution) in pixels at ``level``, rounded up."""
    return int(np.ceil(settings.margin_px / 2**level))


def _free_span(frame_shape: tuple[int, int], level: int, settings: YawSettings) -> tuple[int, int]:
    """Room (H, W) left at ``level`` for the patches' origins inside the margins (negative: none)."""
    level_h, level_w = level_shape(frame_shape, level)
    margin = _level_margin(settings, level)
    n = settings.patch_size_px
    return level_h - n - 2 * margin, level_w - n - 2 * margin


def crops_at(image_u8: U8Array, rows: npt.ArrayLike, cols: npt.ArrayLike, side_px: int) -> U8Array:
    """The ``side_px`` square crops (n, s, s) uint8 of ``image_u8`` whose top-left corners are ``(rows[i],
    cols[i])`` (the caller checked they fit), as one contiguous array."""
    height, width = image_u8.shape
    n = side_px
    # every n x n window of the image as a read-only view, no copy (sliding_window_view's own checks cost
    # three times as much, on a path that runs for every frame of every member)
    windows = np.lib.stride_tricks.as_strided(
        image_u8, (height - n + 1, width - n + 1, n, n), image_u8.strides * 2, writeable=False
    )
    return np.ascontiguousarray(windows[np.asarray(rows), np.asarray(cols)])


def crop_mosaic(crops_u8: U8Array) -> tuple[U8Array, IntArray]:
    """Crops (n, s, s) laid side by side as one image, ``ceil(sqrt(n))`` to a row (the last row's rest zero),
    and each crop's top-left corner ``[row, col]`` in it: :func:`crops_at` cuts the same crops back. How a
    scattered share travels as one compressed band. At least one crop."""
    n, side = crops_u8.shape[0], crops_u8.shape[1]
    if n < 1:
        raise InputError("a crop mosaic needs at least one crop")
    per_row = int(np.ceil(np.sqrt(n)))
    rows = -(-n // per_row)
    padded = np.zeros((rows * per_row, side, side), np.uint8)
    padded[:n] = crops_u8
    tiles = padded.reshape(rows, per_row, side, side).transpose(0, 2, 1, 3)
    image = np.ascontiguousarray(tiles).reshape(rows * side, per_row * side)
    k = np.arange(n)
    corners = np.stack([k // per_row * side, k % per_row * side], axis=1).astype(np.int64)
    return image, corners


@dataclass(frozen=True, eq=False)
class PatchGrid:
    """Where the patches are: origins at the working pyramid level and centres at full resolution.

    ``centres_px`` (P, 2) float [x, y] full-resolution pixels are the correspondence points of the fit.
    """

    frame_shape: tuple[int, int]
    pyramid_level: int
    patch_size_px: int
    origins_level_px: IntArray  # (P, 2) int [x0, y0] at the working level
    centres_px: FloatArray  # (P, 2) float [x, y] at full resolution

    @property
    def n_patches(self) -> int:
        return int(self.origins_level_px.shape[0])

    @functools.cached_property
    def patches_overlap(self) -> bool:
        """Whether some patches may overlap: False means none does (distinct origins at least a patch apart
        in x and in y), so a band of patches never holds fewer pixels than their crops
        (:meth:`band_level`); True may also be said of a grid whose overlapping columns are in rows apart."""
        n = self.patch_size_px
        xs, ys = (np.unique(self.origins_level_px[:, axis]) for axis in (0, 1))
        return bool((np.diff(xs) < n).any() or (np.diff(ys) < n).any())

    @property
    def all_indices(self) -> IntArray:
        return np.arange(self.n_patches, dtype=np.intp)

    def slices(self, index: int) -> tuple[slice, slice]:
        """(rows, cols) slices of patch ``index`` in the level image."""
        x0, y0 = (int(v) for v in self.origins_level_px[index])
        n = self.patch_size_px
        return slice(y0, y0 + n), slice(x0, x0 + n)

    def check_indices(self, indices: npt.ArrayLike) -> IntArray:
        """Validate patch indices: 1-D integers in [0, n_patches), unique."""
        arr = np.asarray(indices)
        if arr.ndim != 1 or (arr.size and not np.issubdtype(arr.dtype, np.integer)):
            raise InputError(f"indices must be a 1-D integer array, got shape {arr.shape} dtype {arr.dtype}")
        arr = arr.astype(np.intp, copy=False)
        if arr.size and arr[0] >= 0 and arr[-1] < self.n_patches and bool((arr[1:] > arr[:-1]).all()):
            return arr  # ascending (how dispatchers and grids list them): in range and unique
        if arr.size and (arr.min() < 0 or arr.max() >= self.n_patches):
            raise InputError(f"indices must be in [0, {self.n_patches}), got {arr.min()}..{arr.max()}")
        if np.unique(arr).size != arr.size:
            raise InputError("indices must be unique")
        return arr

    def level_image(self, frame_u8: U8Array) -> U8Array:
        """The frame at the grid's pyramid level (the frame was checked where it entered the core)."""
        return pyramid_image(frame_u8, self.pyramid_level)

    def _level_indices(self, level_u8: U8Array, indices: npt.ArrayLike) -> IntArray:
        """``indices`` checked, and ``level_u8`` checked to be an image at the grid's level."""
        idx = self.check_indices(indices)
        expected = level_shape(self.frame_shape, self.pyramid_level)
        if level_u8.shape != expected:
            raise InputError(f"level image must have shape {expected}, got {level_u8.shape}")
        return idx

    def crop_level(self, level_u8: U8Array, indices: npt.ArrayLike) -> U8Array:
        """Crops (n, s, s) uint8 of the patches ``indices`` from an image already at the grid's level."""
        idx = self._level_indices(level_u8, indices)
        origins = self.origins_level_px[idx]
        return crops_at(level_u8, origins[:, 1], origins[:, 0], self.patch_size_px)

    def band_level(self, level_u8: U8Array, indices: npt.ArrayLike) -> tuple[U8Array, IntArray] | None:
        """The patches ``indices`` as one band of an image already at the grid's level, when it has fewer
        pixels than their crops (patches that overlap, a contiguous share): the band (a view of the level
        image) and each patch's crop corner ``[row, col]`` in it (:func:`crops_at` cuts the same crops from
        it); None when the crops are smaller (patches apart, a scattered share)."""
        idx = self._level_indices(level_u8, indices)
        if not idx.size:
            return None
        n = self.patch_size_px
        corners = self.origins_level_px[idx][:, ::-1]  # [row, col]
        top, left = corners.min(axis=0)
        bottom, right = corners.max(axis=0) + n
        if (bottom - top) * (right - left) >= idx.size * n * n:
            return None
        return level_u8[top:bottom, left:right], corners - np.array([top, left])

    def packed_level(self, level_u8: U8Array, indices: npt.ArrayLike) -> tuple[U8Array, IntArray, int]:
        """The patches ``indices`` of an image already at the grid's level packed into one image for a
        compressing codec: each row of patches as the strip of rows and columns its patches span, strips of
        consecutive rows with the same columns merged (their overlap then held once), stacked top to bottom,
        zero to the widest. Returns the image, each patch's corner ``[row, col]`` in it (:func:`crops_at`
        cuts the same crops) and the pixels the strips hold (the zeros aside). A run of 49 overlapping 128
        px patches at 1080p (three rows and one patch) holds 0.74 of its crops' pixels, where the
        :meth:`band_level` bounding it holds 0.93."""
        idx = self._level_indices(level_u8, indices)
        if not idx.size:
            raise InputError("packing needs at least one patch")
        n = self.patch_size_px
        corners = self.origins_level_px[idx][:, ::-1].astype(np.int64)  # [row, col] in the level image
        strips: list[list[int]] = []  # [top, bottom, left, right]
        strip_of = np.empty(idx.size, np.intp)
        for top in np.unique(corners[:, 0]):
            at = corners[:, 0] == top
            left, right = int(corners[at, 1].min()), int(corners[at, 1].max()) + n
            last = strips[-1] if strips else None
            if last is not None and (last[2], last[3]) == (left, right) and top <= last[1]:
                last[1] = int(top) + n  # the next row of the same columns, overlapping: one strip
            else:
                strips.append([int(top), int(top) + n, left, right])
            strip_of[at] = len(strips) - 1
        offsets = np.cumsum([0] + [b - t for t, b, _, _ in strips])
        image = np.zeros((int(offsets[-1]), max(r - c for _, _, c, r in strips)), np.uint8)
        for k, (top, bottom, left, right) in enumerate(strips):
            image[offsets[k] : offsets[k + 1], : right - left] = level_u8[top:bottom, left:right]
        held = np.array([(top, left) for top, _, left, _ in strips], np.int64)
        inside = corners - held[strip_of] + np.stack([offsets[strip_of], np.zeros_like(strip_of)], axis=1)
        pixels = sum((b - t) * (r - c) for t, b, c, r in strips)
        return image, inside, pixels

    def crop(self, frame_u8: U8Array, indices: npt.ArrayLike) -> U8Array:
        """Crops (n, s, s) uint8 at the working level of the patches ``indices`` of a full frame.

        Only these pixels need to travel to a worker; ``patch_spectra_from_crops`` turns them into
        the same spectra as ``patch_spectra`` on the whole frame, bit for bit.
        """
        frame = check_grey_image(frame_u8, "frame", shape=self.frame_shape)
        return self.crop_level(self.level_image(frame), indices)


def make_patch_grid(frame_shape: tuple[int, int], settings: YawSettings) -> PatchGrid:
    """A ``grid_cols`` x ``grid_rows`` grid of square patches evenly spread over the frame.

    Patches are laid out at the working pyramid level, leaving ``margin_px`` (full resolution) free
    on each side; neighbours may overlap when the grid is denser than the frame allows.
    """
    height, width = check_frame_shape(frame_shape)
    settings = for_frame(settings, (height, width))
    n = settings.patch_size_px
    margin = _level_margin(settings, settings.level)
    span_h, span_w = _free_span((height, width), settings.level, settings)
    if span_w < 0 or span_h < 0:
        level_h, level_w = level_shape((height, width), settings.level)
        raise InputError(
            f"frame {frame_shape} at pyramid level {settings.level} ({level_h}x{level_w}) "
            f"is too small for {n} px patches with a {settings.margin_px} px margin"
        )
    xs = np.rint(np.linspace(margin, margin + span_w, settings.grid_cols)).astype(np.intp)
    ys = np.rint(np.linspace(margin, margin + span_h, settings.grid_rows)).astype(np.intp)
    grid_x, grid_y = np.meshgrid(xs, ys)
    origins = np.stack([grid_x.ravel(), grid_y.ravel()], axis=1)
    # Centre of the (symmetric) window of a patch, mapped to full resolution (level pixel i ~ 2**L * i).
    centres = (origins.astype(np.float64) + (n - 1) / 2.0) * settings.scale
    return PatchGrid(
        frame_shape=(height, width),
        pyramid_level=settings.level,
        patch_size_px=n,
        origins_level_px=origins,
        centres_px=centres,
    )
