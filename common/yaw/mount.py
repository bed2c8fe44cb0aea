"""The rig in the yaw: about which axis of the IMU the image turns, and the IMU's clock.

The yaw core measures how the image turns about the optical axis. With a downward camera
(``R_BODY_CAMERA_DOWN``: optical axis = body -z) a yaw of +psi (CCW from above) turns the image content by
+psi, i.e. the image turns positively about *minus* the optical axis, ``a = -R_body_camera[:, 2]`` in the
body.

The image's turn is the vehicle's yaw times the cosine of the camera's tilt off the down mount, ``a_z``
(:func:`yaw_per_image_turn`): the tracker integrates the image's turns (measured, or the gyro's) and
publishes them as yaw scaled by ``1 / a_z``. The gyro's turn is the body's yaw rate times ``a_z``
(:func:`image_turn_axis_imu`), not its rate about ``a``: with a tilted camera that rate also holds
``a_x w_x + a_y w_y``, the roll and pitch rates leaking in (``tan(tilt)`` of them in the yaw), which the
measured turns do not show (they are fitted in a virtual down camera's view).

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
    """Weights (3,), in the IMU's axes, that make a gyro reading the image's turn rate in the yaw core's sign:
    the body's yaw rate (about its +z) times ``a_z``, the cosine of the camera's tilt off the down mount
    (``+z`` for the down camera on an IMU aligned with the body). InputError for a camera that does not look
    down (:func:`yaw_per_image_turn`).

    Not the rate about minus the optical axis ``a``: on a tilted mount that picks up the roll and pitch
    rates (``a_x w_x + a_y w_y``), and the field suite's mounted rig (10 deg) bridged its pairs with
    ``tan(10 deg)`` = 0.18 times the roll turned in each (0.17-0.27 fitted on seeds 0-2, 80-90 % of their
    error), which its measured pairs do not show."""
    up = _axis_up(R_body_camera)
    R_bi = np.eye(3) if R_body_imu is None else check_rotation_matrix(R_body_imu, "R_body_imu")
    if R_bi.shape != (3, 3):
        raise InputError(f"R_body_imu must be one (3, 3) rotation, got {R_bi.shape}")
    return np.asarray(R_bi.T @ np.array([0.0, 0.0, up]), dtype=np.float64)


def yaw_per_image_turn(R_body_camera: npt.ArrayLike = R_BODY_CAMERA_DOWN) -> float:
    """Vehicle yaw per radian the image turns: a yaw rate ``w`` about the body's +z turns the image about
    ``a = -R_body_camera[:, 2]`` by ``w a_z``, so the yaw is the image's turn over ``a_z`` (1 for the down
    mount; ``1 / cos(tilt)`` for a camera tilted off it). InputError for a camera that does not look down."""
    return 1.0 / _axis_up(R_body_camera)


def _axis_up(R_body_camera: npt.ArrayLike) -> float:
    """``a_z`` of minus the optical axis in the body (the cosine of the camera's tilt off the down mount);
    InputError for a mount that is not one rotation or a camera that does not look down."""
    R_bc = check_rotation_matrix(R_body_camera, "R_body_camera")
    if R_bc.shape != (3, 3):
        raise InputError(f"R_body_camera must be one (3, 3) rotation, got {R_bc.shape}")
    up = float(-R_bc[2, 2])
    if up < MIN_AXIS_UP:
        raise InputError(
            f"the yaw core needs a camera looking down (optical axis within 60 deg of the body's -z), got "
            f"{math.degrees(math.acos(max(-1.0, min(1.0, up)))):.1f} deg off"
        )
    return up


def imu_stamp_s(camera_stamp_s: float, time_offset_s: float) -> float:
    """A camera stamp on the IMU's clock: ``t_imu = t_cam + time_offset_s``."""
    if not (math.isfinite(camera_stamp_s) and math.isfinite(time_offset_s)):
        raise InputError(f"stamp and time offset must be finite, got {camera_stamp_s}, {time_offset_s}")
    return float(camera_stamp_s + time_offset_s)
