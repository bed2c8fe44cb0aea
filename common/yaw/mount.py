"""The rig in the yaw: about which axis of the IMU the image turns, and the IMU's clock.

The yaw core measures how the image turns about the optical axis. With a downward camera
(``R_BODY_CAMERA_DOWN``: optical axis = body -z) a yaw of +psi (CCW from above) turns the image content by
+psi, i.e. the image turns positively about *minus* the optical axis. For any mount that axis in the body is
``-R_body_camera[:, 2]``, and in the IMU's axes (``gyro_body = R_body_imu @ gyro_imu``)
``R_body_imu^T (-R_body_camera[:, 2])``: the gyro prior integrates the gyro about that axis
(:func:`~common.yaw.honest.gyro_delta_yaw_rad`'s ``axis_body``).

The image's turn is the vehicle's yaw times the cosine of the camera's tilt off the down mount
(:func:`yaw_per_image_turn`): the tracker integrates the image's turns (measured, or the gyro's about the
same axis) and publishes them as yaw scaled by that factor.

The IMU's stamps are on its own clock, ``t_imu = t_cam + time_offset_s`` (Kalibr's ``timeshift_cam_imu``):
the gyro's rotation between two frames is integrated between their stamps moved onto the IMU's clock.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from common.errors import InputError
from common.geometry import R_BODY_CAMERA_DOWN, check_rotation_matrix
from common.types import FloatArray

__all__ = ["MIN_AXIS_UP", "image_turn_axis_imu", "imu_stamp_s", "yaw_per_image_turn"]

#: The yaw core needs a camera that looks down: minus its optical axis at most 60 deg off the body's +z.
MIN_AXIS_UP = 0.5


def image_turn_axis_imu(
    R_body_camera: npt.ArrayLike = R_BODY_CAMERA_DOWN, R_body_imu: npt.ArrayLike | None = None
) -> FloatArray:
    """Unit axis (3,), in the IMU's axes, about which a rotation turns the image by the same angle in the
    yaw core's sign (``+z`` for the down camera on an IMU aligned with the body)."""
    R_bc = check_rotation_matrix(R_body_camera, "R_body_camera")
    R_bi = np.eye(3) if R_body_imu is None else check_rotation_matrix(R_body_imu, "R_body_imu")
    if R_bc.shape != (3, 3) or R_bi.shape != (3, 3):
        raise InputError(f"need one (3, 3) mount each, got {R_bc.shape} and {R_bi.shape}")
    axis = R_bi.T @ -R_bc[:, 2]
    return np.asarray(axis / np.linalg.norm(axis), dtype=np.float64)


def yaw_per_image_turn(R_body_camera: npt.ArrayLike = R_BODY_CAMERA_DOWN) -> float:
    """Vehicle yaw per radian the image turns: a yaw rate ``w`` about the body's +z turns the image about
    ``a = -R_body_camera[:, 2]`` by ``w a_z``, so the yaw is the image's turn over ``a_z`` (1 for the down
    mount; ``1 / cos(tilt)`` for a camera tilted off it). InputError for a camera that does not look down."""
    R_bc = check_rotation_matrix(R_body_camera, "R_body_camera")
    if R_bc.shape != (3, 3):
        raise InputError(f"R_body_camera must be one (3, 3) rotation, got {R_bc.shape}")
    up = float(-R_bc[2, 2])
    if up < MIN_AXIS_UP:
        raise InputError(
            f"the yaw core needs a camera looking down (optical axis within 60 deg of the body's -z), got "
            f"{math.degrees(math.acos(max(-1.0, min(1.0, up)))):.1f} deg off"
        )
    return 1.0 / up


def imu_stamp_s(camera_stamp_s: float, time_offset_s: float) -> float:
    """A camera stamp on the IMU's clock: ``t_imu = t_cam + time_offset_s``."""
    if not (math.isfinite(camera_stamp_s) and math.isfinite(time_offset_s)):
        raise InputError(f"stamp and time offset must be finite, got {camera_stamp_s}, {time_offset_s}")
    return float(camera_stamp_s + time_offset_s)
