"""Double coupling of paper C (Fig. 1): the EKF feeds attitude and altitude to the visual odometry
(orthogonal rectification and metric scale), the visual odometry feeds its yaw back to the EKF.

:class:`DoubleCouplingEstimator` takes timestamped samples from several sensors (IMU, rangefinder, camera,
optionally an external yaw such as the yaw cluster's), reorders them in a :class:`TimeOrderedBuffer` with a
bounded lag and applies them in stamp order:

- IMU: EKF predict with the gyro over the sample's true ``dt`` (eqs. 12-15), then the accelerometer
  update (eq. 16);
- range: rangefinder update (eq. 21);
- external yaw: yaw update (eq. 19);
- frame: (optionally) rectify with the EKF's roll and pitch (section III-C), visual odometry against the
  previous frame with the EKF altitude as scale (Algorithms 1-2, eqs. 9-10), then the VO yaw as a yaw
  update (eq. 19).

Rectified pairs are, by default, two level views of the ground: their motion is a 4-DOF similarity
(translation and scale from :func:`~common.estimation.vo.level_motion_from_matches`, the rotation about
the optical axis from the free decomposition, :attr:`MotionModel.LEVEL_FREE_YAW`). Such a chain follows
the ground point on the rectified optical axis: when the EKF's tilt is off by ``d`` that point is
``h * d`` from the point below the camera, and the VO error is ``h_k d_k - h_0 d_0`` (the offsets
telescope). Two things keep it small: the VO origin is set once the EKF's tilt has settled
(``vo_origin_delay_s``), and the residual tilt of the rectified views is estimated from the free
decompositions' plane normals and its offset removed (``vision_tilt_correction``).

It returns :class:`AttitudeOutput` (one per IMU sample) and :class:`PoseOutput` (one per frame). Frames are
latest-wins: a frame still pending when a newer one arrives is dropped and counted.
"""

from __future__ import annotations

import logging
import math
from collections import Counter
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from common.camera import CameraModel
from common.errors import InputError
from common.estimation.buffer import Refusal, TimeOrderedBuffer
from common.estimation.coupling_types import (
    AttitudeOutput,
    CouplingSettings,
    FilterKind,
    Output,
    PoseOutput,
    ScaleSource,
)
from common.estimation.ekf import (
    AttitudeAltitudeEkf,
    EkfError,
    EkfSettings,
    EkfState,
    altitude_from_range,
    propagate_quaternion,
)
from common.estimation.eskf import BiasAwareEkf, BiasEkfSettings, BiasEkfState
from common.estimation.homography import VoError
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
from common.estimation.rectify import RectificationError
from common.estimation.tilt import ManoeuvreTrack, VisionTilt, residual_tilt_offset
from common.estimation.vo import MotionModel, PreparedFrame, VoPose, VoSettings
from common.estimation.vo_chain import (
    VoChainSettings,
    VoChainState,
    advance_vo_chain,
    prepare_view,
    shifted,
    start_vo_chain,
)
from common.geometry import (
    R_BODY_CAMERA_DOWN,
    check_rotation_matrix,
    euler_from_matrix,
    euler_from_quaternion,
    matrix_from_euler,
    matrix_from_quaternion,
    quaternion_from_euler,
)

logger = logging.getLogger(__name__)

FloatArray = npt.NDArray[np.float64]
ImageU8 = npt.NDArray[np.uint8]


AnyFilter = AttitudeAltitudeEkf | BiasAwareEkf
AnyState = EkfState | BiasEkfState


def yaw_of_camera(R_world_camera: FloatArray, R_body_camera: FloatArray) -> float:
    """ZYX yaw of the body carrying a camera with orientation ``R_world_camera``."""
    return float(euler_from_matrix(R_world_camera @ R_body_camera.T)[2])


def tilt_std_rad(attitude_covariance_world: FloatArray) -> float:
    """Largest standard deviation of the horizontal (tilt) error angles."""
    C = np.asarray(attitude_covariance_world, dtype=np.float64)[:2, :2]
    return float(math.sqrt(max(float(np.linalg.eigvalsh(C)[-1]), 0.0)))


def rectified_axis_offset(
    yaw_rad: float,
    roll_pitch_used_rad: tuple[float, float],
    roll_pitch_true_rad: tuple[float, float],
    altitude_m: float,
) -> FloatArray:
    """Horizontal offset ``(2,)`` of the ground point on the optical axis of a view rectified with
    ``roll_pitch_used`` when the attitude was ``roll_pitch_true``: the axis is
    ``Rz R_tilt_true R_tilt_used^T (0, 0, -1)`` and the chain tracks where it meets the ground."""
    Rt = matrix_from_euler(roll_pitch_true_rad[0], roll_pitch_true_rad[1], yaw_rad)
    Ru = matrix_from_euler(roll_pitch_used_rad[0], roll_pitch_used_rad[1], yaw_rad)
    axis = Rt @ Ru.T @ np.array([0.0, 0.0, -1.0])
    return np.asarray(altitude_m * axis[:2] / -axis[2], dtype=np.float64)


@dataclass(frozen=True)
class _Origin:
    """The VO origin frame: its rectified camera, altitude, the attitude it was rectified with and the
    accelerometer-bias estimate then (for the later re-estimate of its tilt error)."""

    R_n_camera: FloatArray
    altitude_m: float
    yaw_rad: float
    roll_pitch_rad: tuple[float, float]
    accel_bias_m_s2: FloatArray | None
    at_known_attitude: bool
    tilt_std_rad: float


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
        self.ekf: AnyFilter
        if self.settings.filter is FilterKind.BIAS:
            self.ekf = BiasAwareEkf(ekf_settings if isinstance(ekf_settings, BiasEkfSettings) else None)
        else:
            self.ekf = AttitudeAltitudeEkf(ekf_settings)
        self.vo_settings = vo_settings or VoSettings()
        self.chain_settings = chain_settings or VoChainSettings()
        self.buffer: TimeOrderedBuffer[Measurement] = TimeOrderedBuffer(
            self.settings.max_lag_s, self.settings.max_pending
        )
        self.state: AnyState | None = None
        self.chain: VoChainState | None = None
        self.counters: Counter[str] = Counter()
        self._last_range_m: float | None = None
        self._latest_frame_stamp_s = -math.inf
        self._vo_yaw_unwrapped = math.nan
        self._altitude_from_range = False
        self._track = ManoeuvreTrack()
        self._tilt = VisionTilt()
        self._first_imu_s: float | None = None
        self._rect_q: FloatArray | None = None
        self._free_position = np.zeros(3)
        #: the keyframe the free chain's positions are measured from, and its position; the free chain's
        #: offset to the navigation frame (set with the VO origin)
        self._free_keyframe: tuple[PreparedFrame | None, FloatArray] = (None, np.zeros(3))
        self._free_offset = np.zeros(2)
        self._free_path_m = 0.0
        self._origin: _Origin | None = None

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
        if isinstance(state, BiasEkfState) and isinstance(self.ekf, BiasAwareEkf):
            return self.ekf.with_altitude(state, pz, std_m)
        if isinstance(state, EkfState) and isinstance(self.ekf, AttitudeAltitudeEkf):
            return self.ekf.with_altitude(state, pz, std_m)
        raise EkfError("filter and state kinds differ")

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
        state, ekf = self.state, self.ekf
        if isinstance(state, BiasEkfState) and isinstance(ekf, BiasAwareEkf):
            return ekf.attitude_covariance_world(state)
        if isinstance(state, EkfState) and isinstance(ekf, AttitudeAltitudeEkf):
            return ekf.attitude_covariance_world(state)
        raise EkfError("no state")

    def _altitude_var(self) -> float:
        state, ekf = self.state, self.ekf
        if isinstance(state, BiasEkfState) and isinstance(ekf, BiasAwareEkf):
            return ekf.altitude_variance(state)
        if isinstance(state, EkfState) and isinstance(ekf, AttitudeAltitudeEkf):
            return ekf.altitude_variance(state)
        raise EkfError("no state")

    def _step(self, kind: str, *args: object) -> tuple[AnyState, bool]:
        """One filter call on the current state (the two filters share the method names)."""
        method = getattr(self.ekf, kind)
        result = method(self.state, *args)
        if kind == "predict":
            return result, True
        return result.state, bool(result.accepted)

    def _on_imu(self, m: ImuMeasurement) -> AttitudeOutput | None:
        if self.state is None:
            self.state = self._initial_state(m)
            self._first_imu_s = m.stamp_s
        dt_s = m.stamp_s - self.state.stamp_s
        previous = self.state
        try:
            self.state, _ = self._step("predict", m.gyro_rad_s, dt_s)
            if self._accel_waits_for_vo(m.stamp_s):
                self.counters["accel_waiting_for_vo"] += 1
                accepted = True
            else:
                self.state, accepted = self._step(
                    "update_accelerometer", m.accel_m_s2, self._track.accel_world_m_s2
                )
        except EkfError as exc:
            self.state = previous
            self.counters["ekf_errors"] += 1
            logger.warning("IMU sample at %.4f s not applied: %s", m.stamp_s, exc)
            return None
        self.counters["imu_applied"] += 1
        if not accepted:
            self.counters["accel_gated"] += 1
        self._propagate_rectification_attitude(m, dt_s)
        return self._attitude_output(m.stamp_s)

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
        try:
            self.state, accepted = self._step("update_range", m.range_m)
        except EkfError as exc:
            self.counters["ekf_errors"] += 1
            logger.warning("range sample at %.4f s not applied: %s", m.stamp_s, exc)
            return
        self.counters["range_applied" if accepted else "range_gated"] += 1

    def _apply_yaw(self, yaw_rad: float, noise_rad: float, counter: str) -> None:
        if self.state is None:
            return
        try:
            self.state, accepted = self._step("update_yaw", yaw_rad, noise_rad)
        except EkfError as exc:
            self.counters["ekf_errors"] += 1
            logger.warning("yaw update not applied: %s", exc)
            return
        self.counters[f"{counter}_applied" if accepted else f"{counter}_gated"] += 1

    def _on_yaw(self, m: YawMeasurement) -> None:
        if self.settings.external_yaw:
            self._apply_yaw(m.yaw_rad, self.settings.external_yaw_noise_rad, "external_yaw")
        else:
            self.counters["external_yaw_ignored"] += 1

    # ---- frames: rectification, VO, yaw coupling --------------------------------------------------

    def _rectification_weight(self, tilt_std_now_rad: float, altitude_m: float) -> float:
        """Share of the level chain in the output: ``var_free / (var_free + var_level)``."""
        origin = self._origin
        if not self.settings.uncertainty_aware or origin is None:
            return 1.0
        origin_std = origin.tilt_std_rad
        bias_state = self.state if isinstance(self.state, BiasEkfState) else None
        if self._origin_tilt_from_bias() and not origin.at_known_attitude and bias_state is not None:
            # the origin's tilt error is re-estimated from the bias: what is left is the bias' uncertainty
            g = self.ekf.settings.gravity_m_s2
            origin_std = math.sqrt(float(np.max(np.diag(bias_state.covariance)[7:9]))) / g
        var_level = (altitude_m * tilt_std_now_rad) ** 2 + (origin.altitude_m * origin_std) ** 2
        var_free = (self.settings.free_drift_per_m * self._free_path_m) ** 2
        if var_free + var_level <= 0.0:
            return 1.0
        return var_free / (var_free + var_level)

    def _on_frame(self, m: FrameMeasurement) -> PoseOutput | None:
        if self.state is None:
            self.counters["frames_before_imu"] += 1
            return None
        s = self.settings
        roll, pitch, yaw_ekf = (float(v) for v in euler_from_quaternion(self.state.q_world_body))
        if self._rect_q is not None and s.rectification_smoothing_s > 0.0:
            roll, pitch, _ = (float(v) for v in euler_from_quaternion(self._rect_q))
        altitude_m = self.state.pz_m
        if s.scale_from is ScaleSource.RANGE and self._last_range_m is not None:
            altitude_m = self._last_range_m
        tilt_std_now = tilt_std_rad(self._attitude_covariance())
        cam = self.camera
        try:
            frame = prepare_view(
                m.image, cam.K, self.R_body_camera, (roll, pitch) if s.rectify else None, self.vo_settings
            )
        except RectificationError as exc:
            self.counters["frames_unrectifiable"] += 1
            logger.warning("frame at %.4f s not rectified: %s", m.stamp_s, exc)
            return None
        ok = False
        n_inliers = 0
        if self.chain is None:
            self.chain = start_vo_chain(
                frame, self._initial_pose(roll, pitch, yaw_ekf, altitude_m), altitude_m
            )
            self._free_position = self.chain.pose.p_n_camera_m.copy()
            self._maybe_set_origin(m.stamp_s, altitude_m, roll, pitch, yaw_ekf)
            self._vo_yaw_unwrapped = yaw_of_camera(self.chain.pose.R_n_camera, self._vo_camera_mount())
            ok = True
        else:
            try:
                model = s.rectified_motion_model if s.rectify else MotionModel.FREE
                step = advance_vo_chain(
                    self.chain, frame, altitude_m, cam.K, self.vo_settings, model, self.chain_settings
                )
                self.chain = step.state
                # the free decomposition's chain: the traditional path (it does not depend on the filter's
                # tilt) for the uncertainty-aware output and the accelerometer compensation (with the level
                # model a tilt error would leak into the translation and back into the filter: a loop)
                if step.keyframe_frame is not self._free_keyframe[0]:
                    self._free_keyframe = (step.keyframe_frame, self._free_position)
                previous_free = self._free_position
                self._free_position = self._free_keyframe[1] + step.displacement_free_m
                if self._origin is not None:
                    self._free_path_m += float(np.linalg.norm((self._free_position - previous_free)[:2]))
                if self.chain.keyframe.frame is frame:
                    self._free_keyframe = (frame, self._free_position)
                n_inliers = step.motion.n_inliers
                self._maybe_set_origin(m.stamp_s, altitude_m, roll, pitch, yaw_ekf)
                if s.rectify and s.vision_tilt_correction:
                    self._tilt = self._tilt.updated(
                        m.stamp_s, step.motion.t_over_d_free, step.motion.normal_km1_free,
                        s.vision_tilt_window_s, s.vision_tilt_min_information,
                    )  # fmt: skip
                ok = True
                self.counters["vo_pairs"] += 1
            except VoError as exc:
                self.counters["vo_failures"] += 1
                self._track = self._track.cleared()
                self.chain = start_vo_chain(frame, self.chain.pose, altitude_m)
                logger.info("VO pair ending at %.4f s failed: %s", m.stamp_s, exc)
        if ok and s.accel_compensation:
            p = self._free_position
            self._track = self._track.updated(m.stamp_s, float(p[0]), float(p[1]), s.accel_window_s)
        pose = self.chain.pose
        yaw_wrapped = yaw_of_camera(pose.R_n_camera, self._vo_camera_mount())
        self._vo_yaw_unwrapped += math.remainder(yaw_wrapped - self._vo_yaw_unwrapped, 2.0 * math.pi)
        if ok and s.visual_yaw:
            self._apply_yaw(self._vo_yaw_unwrapped, s.vo_yaw_noise_rad, "vo_yaw")
        if self._origin is None:
            self.counters["frames_before_vo_origin"] += 1
            return None
        p = pose.p_n_camera_m.copy()
        p[:2] += self._tilt_offset_correction(pose.R_n_camera, altitude_m)
        weight = self._rectification_weight(tilt_std_now, altitude_m) if s.rectify else math.nan
        if s.rectify and weight < 1.0:
            # uncertainty-aware: toward the free decomposition's chain while the tilt is uncertain
            p[:2] = weight * p[:2] + (1.0 - weight) * (self._free_position[:2] + self._free_offset)
        return PoseOutput(
            stamp_s=m.stamp_s,
            p_world_body_m=np.array([p[0], p[1], self.state.pz_m]),
            q_world_body=self.state.q_world_body,
            attitude_covariance_world=self._attitude_covariance(),
            altitude_var_m2=self._altitude_var(),
            vo_yaw_rad=self._vo_yaw_unwrapped,
            n_inliers=n_inliers,
            rectification_weight=weight,
            ok=ok,
        )

    def _tilt_offset_correction(self, R_n_camera: FloatArray, altitude_m: float) -> FloatArray:
        """What to add to a rectified chain's position: the origin frame's axis offset ``h_0 d_0`` minus the
        current frame's ``h_k d_k`` (the chain follows the ground point on the rectified optical axis)."""
        s = self.settings
        origin = self._origin
        if origin is None or not s.rectify or s.rectified_motion_model not in _LEVEL_MODELS:
            return np.zeros(2)
        correction = np.zeros(2)
        normal = self.vision_tilt()
        if normal is not None:
            # the current frame's offset from the vision tilt; without a better source the origin's is
            # the same estimate (the 5-state filter's tilt error being mostly a body-fixed bias), zero when
            # the origin had the known initial attitude
            correction -= residual_tilt_offset(R_n_camera, altitude_m, normal)
            if not origin.at_known_attitude and not self._origin_tilt_from_bias():
                correction += residual_tilt_offset(origin.R_n_camera, origin.altitude_m, normal)
        if self._origin_tilt_from_bias() and not origin.at_known_attitude:
            assert isinstance(self.state, BiasEkfState) and origin.accel_bias_m_s2 is not None
            db = self.state.accel_bias_m_s2 - origin.accel_bias_m_s2
            g = self.ekf.settings.gravity_m_s2
            roll_used, pitch_used = origin.roll_pitch_rad
            true_rp = (roll_used - float(db[1]) / g, pitch_used + float(db[0]) / g)
            correction += rectified_axis_offset(
                origin.yaw_rad, origin.roll_pitch_rad, true_rp, origin.altitude_m
            )
        return correction

    def _origin_tilt_from_bias(self) -> bool:
        return (
            self.settings.origin_tilt_from_bias
            and isinstance(self.state, BiasEkfState)
            and self._origin is not None
            and self._origin.accel_bias_m_s2 is not None
        )

    def _propagate_rectification_attitude(self, m: ImuMeasurement, dt_s: float) -> None:
        """Attitude used to rectify: the gyro's rotation between frames (eq. 12), pulled towards the
        filter's with the time constant ``rectification_smoothing_s`` (consecutive frames are rectified
        consistently; the accelerometer corrections would otherwise make them jitter against each other)."""
        assert self.state is not None
        tau = self.settings.rectification_smoothing_s
        if self._rect_q is None or tau <= 0.0:
            self._rect_q = self.state.q_world_body
            return
        half = 0.5 * dt_s
        w = m.gyro_rad_s
        r = self._rect_q.tolist()
        q = np.array(propagate_quaternion((r[0], r[1], r[2], r[3]), half * w[0], half * w[1], half * w[2]))
        target = self.state.q_world_body
        ekf_q = target if float(np.dot(q, target)) >= 0.0 else -target
        alpha = min(1.0, dt_s / tau)
        q = (1.0 - alpha) * q + alpha * ekf_q
        self._rect_q = q / np.linalg.norm(q)

    def _maybe_set_origin(
        self, stamp_s: float, altitude_m: float, roll: float, pitch: float, yaw: float
    ) -> None:
        """Move the VO position to ``initial_position_m`` at the first frame after ``vo_origin_delay_s``."""
        if self._origin is not None or self.chain is None or self._first_imu_s is None:
            return
        if stamp_s < self._first_imu_s + self.settings.vo_origin_delay_s - 1e-9:
            return
        x0, y0 = self.settings.initial_position_m
        pose = self.chain.pose
        self.chain = shifted(self.chain, np.array([x0, y0, 0.0]) - np.r_[pose.p_n_camera_m[:2], 0.0])
        self._free_offset = np.array([x0, y0]) - self._free_position[:2]
        bias = self.state.accel_bias_m_s2.copy() if isinstance(self.state, BiasEkfState) else None
        at_known = self.settings.initial_q_world_body is not None and stamp_s <= self._first_imu_s + 1e-9
        self._origin = _Origin(
            R_n_camera=pose.R_n_camera.copy(),
            altitude_m=altitude_m,
            yaw_rad=yaw,
            roll_pitch_rad=(roll, pitch),
            accel_bias_m_s2=bias,
            at_known_attitude=at_known,
            # a known initial attitude is exact at the origin; else the filter's tilt std then
            tilt_std_rad=0.0 if at_known else tilt_std_rad(self._attitude_covariance()),
        )

    def vision_tilt(self) -> FloatArray | None:
        """Estimated ground normal ``(nx, ny)`` in the rectified camera (None until informed enough)."""
        s = self.settings
        if not (s.rectify and s.vision_tilt_correction and s.rectified_motion_model in _LEVEL_MODELS):
            return None
        return self._tilt.normal_xy()

    def _accel_waits_for_vo(self, stamp_s: float) -> bool:
        """At a start in mid-manoeuvre the hover model is wrong until the VO gives the acceleration."""
        s = self.settings
        return (
            s.accel_compensation
            and not self._track.fitted
            and self._first_imu_s is not None
            and stamp_s - self._first_imu_s < s.accel_wait_for_vo_s
        )

    def _vo_camera_mount(self) -> FloatArray:
        """Mounting of the camera whose poses the VO composes (the rectified one is level, looking down)."""
        return R_BODY_CAMERA_DOWN if self.settings.rectify else self.R_body_camera

    def _initial_pose(self, roll: float, pitch: float, yaw: float, altitude_m: float) -> VoPose:
        x0, y0 = self.settings.initial_position_m
        if self.settings.rectify:
            R_world_body = matrix_from_euler(0.0, 0.0, yaw)
        else:
            R_world_body = matrix_from_euler(roll, pitch, yaw)
        R_n_camera = R_world_body @ self._vo_camera_mount()
        return VoPose(R_n_camera=R_n_camera, p_n_camera_m=np.array([x0, y0, altitude_m]))

    @property
    def q_world_body(self) -> FloatArray | None:
        return None if self.state is None else self.state.q_world_body

    def attitude_matrix(self) -> FloatArray | None:
        return None if self.state is None else matrix_from_quaternion(self.state.q_world_body)


#: Rectified-pair models that follow the ground point on the optical axis (a similarity of level views).
_LEVEL_MODELS = (MotionModel.LEVEL, MotionModel.LEVEL_FREE_YAW)
