"""Levelled correspondences: the yaw core's patch fit in the view of a level camera at each frame.

A camera tilted with the vehicle (roll, pitch) sees the floor obliquely, and the similarity the core fits
then reads two things that are not the vehicle's yaw (heading) change:

- a translation over the floor shears the image (the near side moves faster than the far side), and a
  shear's antisymmetric half is a turn: ``tilt x translation / height / 2`` per pair, of either sign;
- a turn about the body's z axis is not the heading's turn when the body is tilted (the ZYX yaw's rate is
  ``(q sin(roll) + r cos(roll)) / cos(pitch)``), so the integrated turns drift from the heading.

On the field suite's flights (2-4 deg of tilt) these two are about 1 deg of the yaw's error over 15 s, at
any frame rate (docs/methods.md, "Tilt"). Mapping each frame's undistorted correspondences into the view
of a virtual camera at the same place, looking straight down with the same heading
(:func:`levelling_homography`), removes both exactly for a planar floor: in the two level views the floor's
motion is a similarity whose turn is the heading change. The tilt comes from the IMU
(:func:`up_in_imu`: its specific force averaged over a window, each sample turned into the body's axes at
the frame by the gyro), or from any attitude the caller has.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from common.errors import InputError
from common.geometry import (
    R_BODY_CAMERA_DOWN,
    check_rotation_matrix,
    matrix_from_euler,
    matrix_from_quaternion,
    quaternion_from_rotation_vector,
)
from common.types import FloatArray

__all__ = [
    "LevelViews",
    "Levelling",
    "R_level_body_from_imu",
    "R_level_body_of_up",
    "levelling_homography",
    "up_in_imu",
]

#: how long the IMU's specific force is averaged for the tilt (s): long enough that a vehicle's own
#: acceleration averages out (a mean 0.1 m/s^2 over the window tilts the estimate by 0.6 deg)
DEFAULT_UP_WINDOW_S = 3.0
#: at most this many gyro steps turn the window's samples into the body at the frame (samples are
#: summed in blocks first; within a block the rotation is first order)
_MAX_BLOCKS = 100


def up_in_imu(
    stamps_s: npt.ArrayLike,
    gyro_rad_s: npt.ArrayLike,
    accel_m_s2: npt.ArrayLike,
    stamp_s: float,
    window_s: float = DEFAULT_UP_WINDOW_S,
) -> FloatArray | None:
    """The up direction (unit, (3,)) in the IMU's axes at the last sample at or before ``stamp_s``: the mean
    specific force of the samples in ``(stamp_s - window_s, stamp_s]``, each turned into the IMU's axes at
    that last sample by the gyro (trapezoids). None when fewer than half the window's span is covered or
    the mean force is not upward-sized (under 1 m/s^2: free fall, a broken sensor).

    At rest the specific force is ``-g`` in the body: up. A vehicle's own acceleration tilts the estimate
    by its mean over the window divided by g. Only the samples in the window are used, so any buffer
    holding them gives the same bits."""
    t = np.asarray(stamps_s, dtype=np.float64)
    w = np.asarray(gyro_rad_s, dtype=np.float64)
    a = np.asarray(accel_m_s2, dtype=np.float64)
    if t.ndim != 1 or w.shape != (t.size, 3) or a.shape != (t.size, 3):
        raise InputError(f"need stamps (M,), gyro (M, 3), accel (M, 3), got {t.shape}, {w.shape}, {a.shape}")
    if not (math.isfinite(stamp_s) and math.isfinite(window_s) and window_s > 0.0):
        raise InputError(f"need a finite stamp and a window > 0, got {stamp_s}, {window_s}")
    last = int(np.searchsorted(t, stamp_s, side="right"))
    first = int(np.searchsorted(t, stamp_s - window_s, side="right"))
    if last - first < 2 or t[last - 1] - t[first] < 0.5 * window_s:
        return None
    ts, gyro, force = t[first:last], w[first:last], a[first:last]
    if not (np.all(np.isfinite(gyro)) and np.all(np.isfinite(force))):
        return None
    # rotation vector of each interval (sample j -> j + 1; none after the last), summed per block: the turn
    # from a block's first sample to the next block's (first order within a block of at most 1/100 window)
    steps = np.vstack([0.5 * (gyro[1:] + gyro[:-1]) * np.diff(ts)[:, None], np.zeros((1, 3))])
    edges = np.arange(0, force.shape[0], -(-force.shape[0] // _MAX_BLOCKS))
    force_sums = np.add.reduceat(force, edges, axis=0)
    step_sums = np.add.reduceat(steps, edges, axis=0)
    # a world-fixed vector turns by exp(-theta) in the body's axes while the body turns by theta
    turns = matrix_from_quaternion(quaternion_from_rotation_vector(-step_sums))  # (B, 3, 3), one batch
    R_last_block = np.eye(3)  # block b's first sample's axes -> the last sample's
    total = np.zeros(3)
    for b in range(edges.size - 1, -1, -1):
        R_last_block = R_last_block @ turns[b]
        total += R_last_block @ force_sums[b]
    mean = total / force.shape[0]
    norm = float(np.linalg.norm(mean))
    if not norm > 1.0:
        return None
    return np.asarray(mean / norm, dtype=np.float64)


def R_level_body_of_up(up_body: npt.ArrayLike) -> FloatArray:
    """The body's tilt ``R_level_body = R_y(pitch) R_x(roll)`` (ZYX Euler, yaw 0) of its up direction in the
    body's axes: ``R_world_body`` without its heading, so that a level view's turn is the ZYX yaw's change."""
    up = np.asarray(up_body, dtype=np.float64)
    norm = float(np.linalg.norm(up)) if up.shape == (3,) else math.nan
    if not (math.isfinite(norm) and norm > 0.0):
        raise InputError(f"need a finite, non-zero up direction (3,), got {up!r}")
    ux, uy, uz = (float(v) / norm for v in up)
    roll, pitch = math.atan2(uy, uz), math.atan2(-ux, math.hypot(uy, uz))
    return matrix_from_euler(roll, pitch, 0.0)


def R_level_body_from_imu(
    stamps_s: npt.ArrayLike,
    gyro_rad_s: npt.ArrayLike,
    accel_m_s2: npt.ArrayLike,
    stamp_s: float,
    R_body_imu: npt.ArrayLike | None = None,
    window_s: float = DEFAULT_UP_WINDOW_S,
) -> FloatArray | None:
    """The body's tilt at ``stamp_s`` (the IMU's clock) from the IMU's samples (:func:`up_in_imu`, its axes
    ``R_body_imu`` on the body), or None without enough samples: what a master and an in-process tracker
    fed the same samples both give, to the bit."""
    up = up_in_imu(stamps_s, gyro_rad_s, accel_m_s2, stamp_s, window_s)
    if up is None:
        return None
    R_bi = np.eye(3) if R_body_imu is None else check_rotation_matrix(R_body_imu, "R_body_imu")
    return R_level_body_of_up(R_bi @ up)


@dataclass(frozen=True, eq=False)
class Levelling:
    """A pair's correspondences mapped into level views: undistorted frame k-1 pixels by ``before`` (3, 3),
    frame k's by ``after``, instead of the lens's fixed nadir view."""

    before: FloatArray
    after: FloatArray


class LevelViews:
    """A camera's level views (:func:`levelling_homography`), its intrinsics ``K`` and mount checked once."""

    def __init__(self, K: npt.ArrayLike, R_body_camera: npt.ArrayLike) -> None:
        K_ = np.asarray(K, dtype=np.float64)
        if K_.shape != (3, 3) or not np.all(np.isfinite(K_)) or abs(float(np.linalg.det(K_))) < 1e-12:
            raise InputError(f"need an invertible (3, 3) K, got {K_!r}")
        R_bc = check_rotation_matrix(R_body_camera, "R_body_camera")
        self._left = K_ @ R_BODY_CAMERA_DOWN.T
        self._right = R_bc @ np.linalg.inv(K_)

    def homography(self, R_level_body: FloatArray) -> FloatArray:
        """``K R_BODY_CAMERA_DOWN^T R_level_body R_body_camera K^-1`` of a checked rotation."""
        return np.asarray(self._left @ R_level_body @ self._right, dtype=np.float64)

    def pair(self, before: FloatArray, after: FloatArray) -> Levelling:
        """The level views of a pair whose frames' tilts are ``before`` and ``after`` (checked rotations)."""
        return Levelling(self.homography(before), self.homography(after))


def levelling_homography(
    K: npt.ArrayLike, R_level_body: npt.ArrayLike, R_body_camera: npt.ArrayLike
) -> FloatArray:
    """Undistorted camera pixels -> the pixels of a virtual camera with the same intrinsics ``K`` at the same
    place, looking straight down (``R_BODY_CAMERA_DOWN`` on a level body) with the same heading:
    ``K R_virtual_camera K^-1``, ``R_virtual_camera = R_BODY_CAMERA_DOWN^T R_level_body R_body_camera``.
    With a level body it is the fixed mount's nadir view (the identity for the down mount)."""
    return LevelViews(K, R_body_camera).homography(check_rotation_matrix(R_level_body, "R_level_body"))
