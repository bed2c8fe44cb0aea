"""The filter's side of the double coupling (paper C, Fig. 1): the attitude/altitude filter fed by the IMU,
the rangefinder and yaw measurements, and what it gives the visual odometry.

- IMU: filter predict over the sample's true ``dt`` (paper C, eqs. 12-15), the accelerometer update (eq. 16)
  and, with the bias filter, every ``thrust_axis_interval_s`` the multirotor thrust-axis update;
- range: rangefinder update (eq. 21), the first reading (or one after ``range_reset_samples`` refused in a
  row) sets the altitude instead;
- yaw: the VO's or an external yaw as a yaw update (eq. 19);
- position (bias filter): the VO's free-chain position, reset to it when refused too long.

The filter is either :class:`~common.estimation.filters.AttitudeFilter`; its methods are called directly.
"""

from __future__ import annotations

import logging
import math
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from common.estimation.coupled_vo import FilterView
from common.estimation.coupling_types import AttitudeOutput, CouplingSettings, ScaleSource
from common.estimation.ekf import EkfSettings
from common.estimation.ekf_models import EkfError, altitude_from_range
from common.estimation.eskf import BiasAwareEkf
from common.estimation.eskf_state import BiasEkfState
from common.estimation.filters import (
    AnyState,
    AttitudeFilter,
    Update,
    make_filter,
    smoothed_attitude,
    tilt_std_rad,
)
from common.estimation.measurements import ImuMeasurement
from common.estimation.tilt import AccelWindow, ManoeuvreTrack
from common.geometry import euler_from_quaternion, quaternion_from_euler
from common.types import FloatArray

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class Carried:
    """The rates integrated over the part of an IMU interval the state was carried through (body axes):
    the angle (rad) and the specific force's velocity (m/s)."""

    gyro_rad: FloatArray
    velocity_m_s: FloatArray


class FilterSide:
    """The filter and its state, fed sample by sample in stamp order (single-threaded)."""

    def __init__(
        self, settings: CouplingSettings, ekf_settings: EkfSettings | None, counters: Counter[str]
    ) -> None:
        self.settings = settings
        self.ekf: AttitudeFilter[Any] = make_filter(settings.filter, ekf_settings)
        self.counters = counters
        self.state: AnyState | None = None
        self.last_range_m: float | None = None
        self.first_imu_s: float | None = None
        self._altitude_from_range = False
        self._rect_q: FloatArray | None = None
        self._position_gated_run = 0
        self._range_gated_run = 0
        self._accel_window = AccelWindow()
        self._last_imu: ImuMeasurement | None = None
        #: the interval between the last two IMU samples: how far :meth:`carry_to` may carry the state
        self._imu_interval_s = 0.0
        #: what :meth:`carry_to` integrated since the last IMU sample (None: nothing)
        self._carried: Carried | None = None

    # ---- state ----------------------------------------------------------------------------------------

    def _initial_state(self, m: ImuMeasurement) -> AnyState:
        ax, ay, az = m.accel_m_s2
        roll = math.atan2(ay, az)
        pitch = math.atan2(-ax, math.hypot(ay, az))
        q = quaternion_from_euler(roll, pitch, self.settings.initial_yaw_rad)
        if self.settings.initial_q_world_body is not None:
            q = np.asarray(self.settings.initial_q_world_body, dtype=np.float64)
        state = self.ekf.initial_state(q, self.settings.default_altitude_m, m.stamp_s)
        if self.last_range_m is not None:
            self._altitude_from_range = True
            return self._with_altitude(state, self.last_range_m, self.ekf.settings.range_noise_m)
        return self._with_altitude(state, None, self.settings.default_altitude_std_m)

    def _with_altitude(self, state: AnyState, range_m: float | None, std_m: float) -> AnyState:
        """The state with its altitude from a range reading (eq. 21 inverted), or the default."""
        q = state.q_world_body.tolist()
        pz = (
            self.settings.default_altitude_m
            if range_m is None
            else altitude_from_range((q[0], q[1], q[2], q[3]), range_m)
        )
        updated: AnyState = self.ekf.with_altitude(state, pz, std_m)  # the filter's own kind of state
        return updated

    def attitude_covariance(self) -> FloatArray:
        assert self.state is not None
        return self.ekf.attitude_covariance_world(self.state)

    def altitude_variance(self) -> float:
        assert self.state is not None
        return self.ekf.altitude_variance(self.state)

    # ---- IMU ------------------------------------------------------------------------------------------

    def on_imu(self, m: ImuMeasurement, track: ManoeuvreTrack) -> AttitudeOutput | None:
        """Predict and accelerometer update; the attitude after the sample (None when the filter refused it).
        ``track`` is the VO's manoeuvre (the acceleration the accelerometer is compensated for)."""
        if self.state is None:
            self.state = self._initial_state(m)
            self.first_imu_s = m.stamp_s
        s = self.settings
        # at a start in mid-manoeuvre the hover model is wrong until the VO gives the acceleration
        waits = (
            s.accel_compensation and not track.fitted and m.stamp_s - self.first_imu_s < s.accel_wait_for_vo_s  # type: ignore[operator]
        )
        dt_s = m.stamp_s - self.state.stamp_s
        gyro, accel = m.gyro_rad_s, m.accel_m_s2
        last = self._last_imu
        if s.imu_midpoint and last is not None:
            # rates at the stamps: the interval's mean (trapezoid); the newer alone leads by half a sample
            gyro, accel = 0.5 * (gyro + last.gyro_rad_s), 0.5 * (accel + last.accel_m_s2)
            if self._carried is not None and dt_s > 0.0:
                # the state was carried into the interval (:meth:`carry_to`): the rest of it takes what makes
                # the whole interval's integral the trapezoid's
                interval_s = m.stamp_s - last.stamp_s
                gyro = (gyro * interval_s - self._carried.gyro_rad) / dt_s
                accel = (accel * interval_s - self._carried.velocity_m_s) / dt_s
        if last is not None:
            self._imu_interval_s = m.stamp_s - last.stamp_s
        self._last_imu = m
        self._carried = None
        try:
            # predict (the inertial navigation of the bias filter integrates the accelerometer too, the
            # 5-state one ignores it), the accelerometer update and the read-outs: one call
            step = self.ekf.imu_step(
                self.state, gyro, accel, dt_s, None if waits else m.accel_m_s2, track.accel_world_m_s2
            )
        except EkfError as exc:
            self.counters["ekf_errors"] += 1
            logger.warning("IMU sample at %.4f s not applied: %s", m.stamp_s, exc)
            return None
        self.state = state = step.state
        covariance, altitude_var_m2 = step.attitude_covariance_world, step.altitude_var_m2
        self.counters["imu_applied"] += 1
        if waits:
            self.counters["accel_waiting_for_vo"] += 1
        elif not step.accepted:
            self.counters["accel_gated"] += 1
        if (
            s.thrust_axis_interval_s > 0.0
            and isinstance(self.ekf, BiasAwareEkf)
            and self._thrust_axis(self.ekf, m)
        ):
            # the thrust-axis update moved the state: its read-outs again
            state = self.state
            covariance, altitude_var_m2 = self.attitude_covariance(), self.altitude_variance()
        q = state.q_world_body
        if self._rect_q is None or s.rectification_smoothing_s <= 0.0:
            self._rect_q = q
        else:
            # the attitude used to rectify (:func:`~common.estimation.filters.smoothed_attitude`)
            self._rect_q = smoothed_attitude(self._rect_q, gyro, dt_s, q, s.rectification_smoothing_s)
        return AttitudeOutput(
            stamp_s=m.stamp_s,
            q_world_body=q,
            pz_m=state.pz_m,
            attitude_covariance_world=covariance,
            altitude_var_m2=altitude_var_m2,
        )

    def _thrust_axis(self, ekf: BiasAwareEkf, m: ImuMeasurement) -> bool:
        """Bias filter: the mean body-horizontal accelerometer reading over ``thrust_axis_interval_s`` as the
        multirotor thrust-axis update (:meth:`~common.estimation.eskf.BiasAwareEkf.update_thrust_axis`);
        whether it moved the state."""
        window = self._accel_window.added(m.stamp_s, m.accel_m_s2)
        done = window.spans(m.stamp_s, self.settings.thrust_axis_interval_s)
        self._accel_window = AccelWindow() if done else window
        if done and isinstance(self.state, BiasEkfState):
            mean_xy, n = window.mean_xy_m_s2(), window.n_samples
            accepted = self._update("update_thrust_axis", lambda x: ekf.update_thrust_axis(x, mean_xy, n))
            self._count(accepted, "thrust_axis")
            return accepted is True
        return False

    def carry_to(self, stamp_s: float, next_imu: ImuMeasurement | None) -> None:
        """Predict the state from its stamp to ``stamp_s``, between the last IMU sample and ``next_imu``, so
        that a range, yaw or frame stamped between two IMU samples meets the state at its own time (applied
        to the state of the last sample, a frame at 100 Hz and 45 deg/s is rectified with a tilt up to 0.45
        deg old). The rates are interpolated between the two samples (the trapezoid's, on the part of the
        interval), held at the last sample's where the next has not come (a live stream); the next IMU
        sample integrates the rest of its interval (:meth:`on_imu`). Not past one IMU interval: beyond it the
        IMU has stalled, and the state stays at its stamp (counted as ``carry_beyond_imu``)."""
        last = self._last_imu
        if self.state is None or last is None:
            return
        start_s = self.state.stamp_s
        dt_s = stamp_s - start_s
        if dt_s <= 0.0:
            return
        if next_imu is None and stamp_s - last.stamp_s > self._imu_interval_s:
            self.counters["carry_beyond_imu"] += 1
            return
        gyro, accel = last.gyro_rad_s, last.accel_m_s2
        if next_imu is not None:
            if not self.settings.imu_midpoint:
                gyro, accel = next_imu.gyro_rad_s, next_imu.accel_m_s2  # eq. 12 as written: the newer's
            else:
                interval_s = next_imu.stamp_s - last.stamp_s
                # the mean of the rates at the two ends of the piece, each interpolated between the samples
                share = 0.5 * ((start_s - last.stamp_s) + (stamp_s - last.stamp_s)) / interval_s
                gyro = last.gyro_rad_s + share * (next_imu.gyro_rad_s - last.gyro_rad_s)
                accel = last.accel_m_s2 + share * (next_imu.accel_m_s2 - last.accel_m_s2)
        try:
            self.state = self.ekf.predict(self.state, gyro, dt_s, accel)
        except EkfError as exc:
            self.counters["ekf_errors"] += 1
            logger.warning("state not carried to %.4f s: %s", stamp_s, exc)
            return
        carried = self._carried or Carried(np.zeros(3), np.zeros(3))
        self._carried = Carried(carried.gyro_rad + gyro * dt_s, carried.velocity_m_s + accel * dt_s)

    # ---- updates --------------------------------------------------------------------------------------

    def _update(self, what: str, step: Callable[[Any], Update[Any]]) -> bool | None:
        """``step(state)``, one filter update: whether its gate accepted it (None without a state or on a
        filter error, which is logged)."""
        if self.state is None:
            return None
        try:
            update = step(self.state)
        except EkfError as exc:
            self.counters["ekf_errors"] += 1
            logger.warning("%s not applied: %s", what, exc)
            return None
        self.state = update.state
        return bool(update.accepted)

    def _count(self, accepted: bool | None, counter: str) -> bool | None:
        """Count an update as ``<counter>_applied`` / ``_gated``."""
        if accepted is not None:
            self.counters[f"{counter}_applied" if accepted else f"{counter}_gated"] += 1
        return accepted

    def on_range(self, range_m: float) -> None:
        self.last_range_m = range_m
        if self.state is None:
            return
        if not self._altitude_from_range:
            # first reading: take the altitude from it (eq. 21 inverted) instead of a huge innovation
            self.state = self._with_altitude(self.state, range_m, self.ekf.settings.range_noise_m)
            self._altitude_from_range = True
            self.counters["range_applied"] += 1
            return
        if self._range_gated_run >= self.settings.range_reset_samples:
            # refused too long (the altitude has run away): restart it from the reading (eq. 21 inverted)
            self.state = self._with_altitude(self.state, range_m, self.ekf.settings.range_noise_m)
            self._range_gated_run = 0
            self.counters["range_reset"] += 1
            return
        accepted = self._count(
            self._update("update_range", lambda x: self.ekf.update_range(x, range_m)), "range"
        )
        if accepted is not None:
            self._range_gated_run = 0 if accepted else self._range_gated_run + 1

    def on_yaw(self, yaw_rad: float, noise_rad: float, counter: str) -> None:
        """A yaw update (the VO's, counted as ``vo_yaw``, or an external one)."""
        self._count(self._update("update_yaw", lambda x: self.ekf.update_yaw(x, yaw_rad, noise_rad)), counter)

    def on_position(self, p_xy: FloatArray | None) -> None:
        """The free chain's position (independent of the filter's tilt) as the bias filter's position
        measurement: the first one, or one after ``position_reset_frames`` refused in a row, resets it."""
        ekf = self.ekf
        if not isinstance(ekf, BiasAwareEkf) or not isinstance(self.state, BiasEkfState) or p_xy is None:
            return
        first = self.counters["position_applied"] == 0
        if first or self._position_gated_run >= self.settings.position_reset_frames:
            self.state = ekf.with_position(self.state, p_xy, ekf.settings.position_noise_m)
            self._position_gated_run = 0
            self.counters["position_applied" if first else "position_reset"] += 1
            return
        accepted = self._count(
            self._update("update_position", lambda x: ekf.update_position(x, p_xy)), "position"
        )
        if accepted is not None:
            self._position_gated_run = 0 if accepted else self._position_gated_run + 1

    # ---- what the VO takes --------------------------------------------------------------------------------

    def view(self) -> FilterView:
        """The filter's attitude (or the smoothed rectification attitude), scale and tilt uncertainty."""
        assert self.state is not None and self.first_imu_s is not None
        s = self.settings
        roll, pitch, yaw = (float(v) for v in euler_from_quaternion(self.state.q_world_body))
        if self._rect_q is not None and s.rectification_smoothing_s > 0.0:
            roll, pitch, _ = (float(v) for v in euler_from_quaternion(self._rect_q))
        altitude_m = self.state.pz_m
        if s.scale_from is ScaleSource.RANGE and self.last_range_m is not None:
            altitude_m = self.last_range_m
        bias, bias_std = None, math.nan
        if isinstance(self.state, BiasEkfState):
            bias = self.state.accel_bias_m_s2
            bias_std = math.sqrt(float(np.max(np.diag(self.state.covariance)[7:9])))
        return FilterView(
            roll_rad=roll,
            pitch_rad=pitch,
            yaw_rad=yaw,
            altitude_m=altitude_m,
            tilt_std_rad=tilt_std_rad(self.attitude_covariance()),
            accel_bias_m_s2=bias,
            accel_bias_std_m_s2=bias_std,
            gravity_m_s2=self.ekf.settings.gravity_m_s2,
            since_first_imu_s=self.state.stamp_s - self.first_imu_s,
        )
