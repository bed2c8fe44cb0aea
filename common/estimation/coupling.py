"""Double coupling of paper C (Fig. 1): the EKF feeds attitude and altitude to the visual odometry
(orthogonal rectification and metric scale), the visual odometry feeds its yaw back to the EKF.

:class:`DoubleCouplingEstimator` takes timestamped samples from several sensors (IMU, rangefinder, camera,
optionally an external yaw such as the yaw cluster's), reorders them in a :class:`TimeOrderedBuffer` with a
bounded lag and applies them in stamp order:

- IMU: filter predict over the sample's true ``dt`` (eqs. 12-15), the accelerometer update (eq. 16) and,
  with the bias filter, every ``thrust_axis_interval_s`` the multirotor thrust-axis update;
- range: rangefinder update (eq. 21);
- external yaw: yaw update (eq. 19);
- frame: (optionally) rectify with the EKF's roll and pitch (section III-C), visual odometry against the
  previous frame with the EKF altitude as scale (Algorithms 1-2, eqs. 9-10), then the VO yaw as a yaw
  update (eq. 19) and, with the bias filter, the free-decomposition chain's position as a position update
  (its inertial navigation; refused too long, the position or the altitude is reset to the measurement).

The visual-odometry side is :class:`~common.estimation.coupled_vo.CoupledVo`; the filter paper C's 5-state
EKF or the error-state EKF with bias states (``CouplingSettings.filter``).

It returns :class:`AttitudeOutput` (one per IMU sample) and :class:`PoseOutput` (one per frame). Frames are
latest-wins: a frame still pending when a newer one arrives is dropped and counted.
"""

from __future__ import annotations

import logging
import math
from collections import Counter

import numpy as np
import numpy.typing as npt

from common.camera import CameraModel
from common.errors import InputError
from common.estimation.buffer import Refusal, TimeOrderedBuffer
from common.estimation.coupled_vo import CoupledVo, FilterView
from common.estimation.coupling_types import (
    AttitudeOutput,
    CouplingSettings,
    Output,
    PoseOutput,
    ScaleSource,
)
from common.estimation.ekf import EkfSettings
from common.estimation.ekf_models import EkfError, altitude_from_range
from common.estimation.eskf import BiasAwareEkf, BiasEkfState
from common.estimation.filters import (
    AnyFilter,
    AnyState,
    altitude_variance,
    attitude_covariance,
    filter_step,
    make_filter,
    smoothed_attitude,
    tilt_std_rad,
    with_altitude,
)
from common.estimation.measurements import (
    SENSOR_ORDER,
    FrameMeasurement,
    ImuMeasurement,
    Measurement,
    RangeMeasurement,
    Sensor,
    YawMeasurement,
    sensor_of,
)
from common.estimation.tilt import AccelWindow
from common.estimation.vo import VoSettings
from common.estimation.vo_chain import VoChainSettings
from common.geometry import (
    R_BODY_CAMERA_DOWN,
    check_rotation_matrix,
    euler_from_quaternion,
    quaternion_from_euler,
)
from common.types import FloatArray

logger = logging.getLogger(__name__)


class DoubleCouplingEstimator:
    """Filter + visual odometry with double coupling, fed sample by sample (single-threaded)."""

    def __init__(
        self,
        camera: CameraModel,
        R_body_camera: npt.ArrayLike = R_BODY_CAMERA_DOWN,
        ekf_settings: EkfSettings | None = None,
        vo_settings: VoSettings | None = None,
        settings: CouplingSettings | None = None,
        chain_settings: VoChainSettings | None = None,
    ) -> None:
        if camera.is_distorted:
            raise InputError(
                "the estimator needs an undistorted (pinhole) camera: undistort the frames first "
                f"(got {camera.distortion.model.value} distortion)"
            )
        self.camera = camera
        #: mounting of the camera on the body (the camera model itself is the intrinsics only)
        self.R_body_camera = check_rotation_matrix(R_body_camera, "R_body_camera")
        self.settings = settings or CouplingSettings()
        self.ekf: AnyFilter = make_filter(self.settings.filter, ekf_settings)
        self.vo_settings = vo_settings or VoSettings()
        self.chain_settings = chain_settings or VoChainSettings()
        self.buffer: TimeOrderedBuffer[Measurement] = TimeOrderedBuffer(
            self.settings.max_lag_s, self.settings.max_pending
        )
        self.state: AnyState | None = None
        self.counters: Counter[str] = Counter()
        self.vo = CoupledVo(
            camera, self.R_body_camera, self.settings, self.vo_settings, self.chain_settings, self.counters
        )
        self._last_range_m: float | None = None
        self._latest_frame_stamp_s = -math.inf
        self._altitude_from_range = False
        self._first_imu_s: float | None = None
        self._rect_q: FloatArray | None = None
        self._position_gated_run = 0
        self._range_gated_run = 0
        self._accel_window = AccelWindow()
        self._last_imu: ImuMeasurement | None = None

    # ---- input ------------------------------------------------------------------------------------

    def push(self, measurement: Measurement) -> Refusal | None:
        """Queue one validated sample; returns why it was refused, if it was."""
        sensor = sensor_of(measurement)
        if sensor is Sensor.CAMERA:
            if measurement.stamp_s <= self._latest_frame_stamp_s:
                self.counters["refused_camera_stale"] += 1
                return Refusal.STALE
            self._latest_frame_stamp_s = measurement.stamp_s
        refusal = self.buffer.push(measurement.stamp_s, sensor.value, measurement, SENSOR_ORDER[sensor])
        if refusal is not None:
            self.counters[f"refused_{sensor.value}_{refusal.value}"] += 1
        return refusal

    def process_due(self) -> list[Output]:
        """Apply every sample that is older than the newest by ``max_lag_s``, in stamp order."""
        return self._apply([t.item for t in self.buffer.pop_due()])

    def drain(self) -> list[Output]:
        """Apply everything pending (end of a stream)."""
        return self._apply([t.item for t in self.buffer.drain()])

    def _apply(self, items: list[Measurement]) -> list[Output]:
        outputs: list[Output] = []
        latest_frame = max((m.stamp_s for m in items if isinstance(m, FrameMeasurement)), default=-math.inf)
        for m in items:
            if isinstance(m, ImuMeasurement):
                out = self._on_imu(m)
                if out is not None:
                    outputs.append(out)
            elif isinstance(m, RangeMeasurement):
                self._on_range(m)
            elif isinstance(m, YawMeasurement):
                self._on_yaw(m)
            elif m.stamp_s < latest_frame:
                self.counters["frames_superseded"] += 1
            else:
                pose = self._on_frame(m)
                if pose is not None:
                    outputs.append(pose)
        return outputs

    # ---- filter inputs ----------------------------------------------------------------------------

    def _initial_state(self, m: ImuMeasurement) -> AnyState:
        ax, ay, az = m.accel_m_s2
        roll = math.atan2(ay, az)
        pitch = math.atan2(-ax, math.hypot(ay, az))
        q = quaternion_from_euler(roll, pitch, self.settings.initial_yaw_rad)
        if self.settings.initial_q_world_body is not None:
            q = np.asarray(self.settings.initial_q_world_body, dtype=np.float64)
        state = self.ekf.initial_state(q, self.settings.default_altitude_m, m.stamp_s)
        if self._last_range_m is not None:
            self._altitude_from_range = True
            return self._with_altitude(state, self._last_range_m, self.ekf.settings.range_noise_m)
        return self._with_altitude(state, None, self.settings.default_altitude_std_m)

    def _with_altitude(self, state: AnyState, range_m: float | None, std_m: float) -> AnyState:
        """The state with its altitude from a range reading (eq. 21 inverted), or the default."""
        q = state.q_world_body.tolist()
        pz = (
            self.settings.default_altitude_m
            if range_m is None
            else altitude_from_range((q[0], q[1], q[2], q[3]), range_m)
        )
        return with_altitude(self.ekf, state, pz, std_m)

    def _attitude_output(self, stamp_s: float) -> AttitudeOutput:
        assert self.state is not None
        return AttitudeOutput(
            stamp_s=stamp_s,
            q_world_body=self.state.q_world_body,
            pz_m=self.state.pz_m,
            attitude_covariance_world=self._attitude_covariance(),
            altitude_var_m2=self._altitude_var(),
        )

    def _attitude_covariance(self) -> FloatArray:
        assert self.state is not None
        return attitude_covariance(self.ekf, self.state)

    def _altitude_var(self) -> float:
        assert self.state is not None
        return altitude_variance(self.ekf, self.state)

    def _step(self, method: str, *args: object) -> tuple[AnyState, bool]:
        assert self.state is not None
        return filter_step(self.ekf, self.state, method, *args)

    def _on_imu(self, m: ImuMeasurement) -> AttitudeOutput | None:
        if self.state is None:
            self.state = self._initial_state(m)
            self._first_imu_s = m.stamp_s
        dt_s = m.stamp_s - self.state.stamp_s
        previous, gyro, accel = self.state, m.gyro_rad_s, m.accel_m_s2
        if self.settings.imu_midpoint and self._last_imu is not None:
            # rates at the stamps: the interval's mean (trapezoid); the newer alone leads by half a sample
            gyro, accel = 0.5 * (gyro + self._last_imu.gyro_rad_s), 0.5 * (accel + self._last_imu.accel_m_s2)
        self._last_imu = m
        try:
            if isinstance(self.ekf, BiasAwareEkf):
                # the inertial navigation of the bias filter integrates the accelerometer too
                self.state, _ = self._step("predict", gyro, dt_s, accel)
            else:
                self.state, _ = self._step("predict", gyro, dt_s)
            if self._accel_waits_for_vo(m.stamp_s):
                self.counters["accel_waiting_for_vo"] += 1
                accepted = True
            else:
                self.state, accepted = self._step(
                    "update_accelerometer", m.accel_m_s2, self.vo.track.accel_world_m_s2
                )
        except EkfError as exc:
            self.state = previous
            self.counters["ekf_errors"] += 1
            logger.warning("IMU sample at %.4f s not applied: %s", m.stamp_s, exc)
            return None
        self.counters["imu_applied"] += 1
        if not accepted:
            self.counters["accel_gated"] += 1
        self._thrust_axis(m)
        self._propagate_rectification_attitude(gyro, dt_s)
        return self._attitude_output(m.stamp_s)

    def _thrust_axis(self, m: ImuMeasurement) -> None:
        """Bias filter: the mean body-horizontal accelerometer reading over ``thrust_axis_interval_s`` as the
        multirotor thrust-axis update (:meth:`~common.estimation.eskf.BiasAwareEkf.update_thrust_axis`)."""
        interval = self.settings.thrust_axis_interval_s
        if interval <= 0.0 or not isinstance(self.ekf, BiasAwareEkf):
            return
        window = self._accel_window.added(m.stamp_s, m.accel_m_s2)
        self._accel_window = AccelWindow() if window.spans(m.stamp_s, interval) else window
        if window is not self._accel_window:
            self._apply_update("update_thrust_axis", "thrust_axis", window.mean_xy_m_s2(), window.n_samples)

    def _on_range(self, m: RangeMeasurement) -> None:
        self._last_range_m = m.range_m
        if self.state is None:
            return
        if not self._altitude_from_range:
            # first reading: take the altitude from it (eq. 21 inverted) instead of a huge innovation
            self.state = self._with_altitude(self.state, m.range_m, self.ekf.settings.range_noise_m)
            self._altitude_from_range = True
            self.counters["range_applied"] += 1
            return
        if self._range_gated_run >= self.settings.range_reset_samples:
            # refused too long (the altitude has run away): restart it from the reading (eq. 21 inverted)
            self.state = self._with_altitude(self.state, m.range_m, self.ekf.settings.range_noise_m)
            self._range_gated_run = 0
            self.counters["range_reset"] += 1
            return
        accepted = self._apply_update("update_range", "range", m.range_m)
        if accepted is not None:
            self._range_gated_run = 0 if accepted else self._range_gated_run + 1

    def _apply_update(self, method: str, counter: str, *args: object) -> bool | None:
        """One filter update, counted as ``<counter>_applied`` / ``_gated``: whether the gate accepted it
        (None without a state or on a filter error, which is logged)."""
        if self.state is None:
            return None
        try:
            self.state, accepted = self._step(method, *args)
        except EkfError as exc:
            self.counters["ekf_errors"] += 1
            logger.warning("%s not applied: %s", method, exc)
            return None
        self.counters[f"{counter}_applied" if accepted else f"{counter}_gated"] += 1
        return accepted

    def _on_yaw(self, m: YawMeasurement) -> None:
        if self.settings.external_yaw:
            self._apply_update("update_yaw", "external_yaw", m.yaw_rad, self.settings.external_yaw_noise_rad)
        else:
            self.counters["external_yaw_ignored"] += 1

    # ---- frames: rectification, VO, yaw coupling --------------------------------------------------

    def _filter_view(self) -> FilterView:
        """The filter's attitude (or the smoothed rectification attitude), scale and tilt uncertainty."""
        assert self.state is not None and self._first_imu_s is not None
        s = self.settings
        roll, pitch, yaw = (float(v) for v in euler_from_quaternion(self.state.q_world_body))
        if self._rect_q is not None and s.rectification_smoothing_s > 0.0:
            roll, pitch, _ = (float(v) for v in euler_from_quaternion(self._rect_q))
        altitude_m = self.state.pz_m
        if s.scale_from is ScaleSource.RANGE and self._last_range_m is not None:
            altitude_m = self._last_range_m
        bias, bias_std = None, math.nan
        if isinstance(self.state, BiasEkfState):
            bias = self.state.accel_bias_m_s2
            bias_std = math.sqrt(float(np.max(np.diag(self.state.covariance)[7:9])))
        return FilterView(
            roll_rad=roll,
            pitch_rad=pitch,
            yaw_rad=yaw,
            altitude_m=altitude_m,
            tilt_std_rad=tilt_std_rad(self._attitude_covariance()),
            accel_bias_m_s2=bias,
            accel_bias_std_m_s2=bias_std,
            gravity_m_s2=self.ekf.settings.gravity_m_s2,
            since_first_imu_s=self.state.stamp_s - self._first_imu_s,
        )

    def _on_frame(self, m: FrameMeasurement) -> PoseOutput | None:
        if self.state is None:
            self.counters["frames_before_imu"] += 1
            return None
        result = self.vo.on_frame(m, self._filter_view())
        if result is None:
            return None
        if result.ok and self.settings.visual_yaw:
            self._apply_update("update_yaw", "vo_yaw", result.vo_yaw_rad, self.settings.vo_yaw_noise_rad)
        if result.ok:
            self._apply_position()
        if result.p_xy_m is None:
            self.counters["frames_before_vo_origin"] += 1
            return None
        return PoseOutput(
            stamp_s=m.stamp_s,
            p_world_body_m=np.array([result.p_xy_m[0], result.p_xy_m[1], self.state.pz_m]),
            q_world_body=self.state.q_world_body,
            attitude_covariance_world=self._attitude_covariance(),
            altitude_var_m2=self._altitude_var(),
            vo_yaw_rad=result.vo_yaw_rad,
            n_inliers=result.n_inliers,
            rectification_weight=result.rectification_weight,
            ok=result.ok,
        )

    def _apply_position(self) -> None:
        """The free chain's position (independent of the filter's tilt) as the bias filter's position
        measurement: the first one, or one after ``position_reset_frames`` refused in a row, resets it."""
        p_xy = self.vo.free_position_xy
        if not isinstance(self.ekf, BiasAwareEkf) or not isinstance(self.state, BiasEkfState) or p_xy is None:
            return
        if (
            self.counters["position_applied"] == 0
            or self._position_gated_run >= self.settings.position_reset_frames
        ):
            self.state = self.ekf.with_position(self.state, p_xy, self.ekf.settings.position_noise_m)
            self._position_gated_run = 0
            self.counters[
                "position_applied" if self.counters["position_applied"] == 0 else "position_reset"
            ] += 1
            return
        accepted = self._apply_update("update_position", "position", p_xy)
        if accepted is not None:
            self._position_gated_run = 0 if accepted else self._position_gated_run + 1

    def _propagate_rectification_attitude(self, gyro_rad_s: FloatArray, dt_s: float) -> None:
        """Attitude used to rectify (:func:`~common.estimation.filters.smoothed_attitude`)."""
        assert self.state is not None
        tau = self.settings.rectification_smoothing_s
        if self._rect_q is None or tau <= 0.0:
            self._rect_q = self.state.q_world_body
            return
        self._rect_q = smoothed_attitude(self._rect_q, gyro_rad_s, dt_s, self.state.q_world_body, tau)

    def _accel_waits_for_vo(self, stamp_s: float) -> bool:
        """At a start in mid-manoeuvre the hover model is wrong until the VO gives the acceleration."""
        s = self.settings
        return (
            s.accel_compensation
            and not self.vo.track.fitted
            and self._first_imu_s is not None
            and stamp_s - self._first_imu_s < s.accel_wait_for_vo_s
        )

    @property
    def q_world_body(self) -> FloatArray | None:
        return None if self.state is None else self.state.q_world_body
