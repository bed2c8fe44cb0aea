"""What a master derives from a simulated flight's IMU stream, for an in-process tracker over the same
flight: the gyro's turn between frame stamps and each frame's tilt for the level views.

The master computes both from the IMU samples it buffered (:mod:`services.master.gyro`) with the same core
functions on the same samples, so a tracker fed :class:`FlightPrior` gives the master's yaw to the bit (the
cluster's references, ``make run``'s comparison) and a benchmark flies the core as a user's rig would.
"""

from __future__ import annotations

from dataclasses import replace
from enum import Enum

from common.geometry import matrix_from_euler
from common.sim.flight import Flight
from common.types import FloatArray
from common.yaw import YawSettings, YawTracker, for_frame, gyro_delta_yaw_rad, make_patch_grid
from common.yaw.level import R_level_body_from_imu
from common.yaw.mount import image_turn_axis_imu, imu_stamp_s


class Level(Enum):
    """Where each frame's tilt (:mod:`common.yaw.level`) comes from."""

    NONE = "none"  # no tilt: the mount's fixed view (a master's default)
    IMU = "imu"  # the IMU's specific force over a window, as a master with --level-views
    TRUTH = "truth"  # the flight's true attitude: what levelling can give at best


class FlightPrior:
    """The gyro prior and tilts of ``flight`` for frame k as a master with the flight's rig computes them:
    the gyro weighed by the image's turn in the IMU's axes, between the frame stamps moved onto the IMU's
    clock (none when ``use_imu`` is False: a rig without an IMU) and the tilt as ``level`` says (none
    without an IMU, unless the truth)."""

    def __init__(self, flight: Flight, use_imu: bool = True, level: Level = Level.NONE) -> None:
        self.flight = flight
        self.use_imu = use_imu
        self.level = level if use_imu or level is Level.TRUTH else Level.NONE
        self.axis_imu = image_turn_axis_imu(flight.R_body_camera, flight.imu.R_body_imu)

    def tracker(self, settings: YawSettings) -> YawTracker:
        """The tracker a master builds for the flight's frames: the rig's lens and mount."""
        shape = self.flight.camera.shape
        sized = for_frame(replace(settings, camera=self.flight.camera), shape)
        return YawTracker(sized, make_patch_grid(shape, sized), self.flight.R_body_camera)

    def gyro_delta_rad(self, k: int) -> float | None:
        """The gyro's turn from frame k-1 to frame k (None: no IMU, or no coverage)."""
        if not self.use_imu or k < 1:
            return None
        imu, stamps = self.flight.imu, self.flight.frame_stamps_s
        start = imu_stamp_s(float(stamps[k - 1]), imu.time_offset_s)
        stop = imu_stamp_s(float(stamps[k]), imu.time_offset_s)
        return gyro_delta_yaw_rad(imu.stamps_s, imu.gyro_rad_s, start, stop, self.axis_imu)

    def tilt(self, k: int) -> FloatArray | None:
        """Frame k's ``R_level_body`` (None: not known)."""
        flight = self.flight
        if self.level is Level.TRUTH:
            return matrix_from_euler(flight.euler_rad[k, 0], flight.euler_rad[k, 1], 0.0)
        if self.level is Level.IMU:
            imu = flight.imu
            stamp = imu_stamp_s(float(flight.frame_stamps_s[k]), imu.time_offset_s)
            return R_level_body_from_imu(imu.stamps_s, imu.gyro_rad_s, imu.accel_m_s2, stamp, imu.R_body_imu)
        return None
