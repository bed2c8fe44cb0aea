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

import enum
import logging
import math
import time
from collections import Counter, deque
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from common.errors import InputError
from common.estimation.buffer import Refusal, TimeOrderedBuffer
from common.estimation.ekf import AttitudeAltitudeEkf, EkfError, EkfSettings, EkfState, UpdateResult
from common.estimation.rectify import RectificationError, rectify_frame
from common.estimation.vo import (
    MotionModel,
    PreparedFrame,
    VoError,
    VoPose,
    VoSettings,
    compose_pose,
    estimate_relative_motion,
    metric_translation,
    prepare_frame,
)
from common.geometry import (
    R_BODY_CAMERA_DOWN,
    check_rotation_matrix,
    euler_from_matrix,
    euler_from_quaternion,
    matrix_from_euler,
    matrix_from_quaternion,
    quaternion_from_euler,
    quaternion_multiply,
)
from common.images import check_grey_image
from common.types import FloatArray

logger = logging.getLogger(__name__)

ImageU8 = npt.NDArray[np.uint8]


class Sensor(enum.Enum):
    """Input streams of the estimator."""

    IMU = "imu"
    RANGE = "range"
    CAMERA = "camera"
    YAW = "yaw"


class ScaleSource(enum.Enum):
    """Where the visual odometry takes its metric scale (the camera's height) from."""

    EKF = "ekf"
    RANGE = "range"


@dataclass(frozen=True)
class ImuMeasurement:
    """Gyro (rad/s, body) and specific force (m/s^2, body) at ``stamp_s``."""

    stamp_s: float
    gyro_rad_s: FloatArray
    accel_m_s2: FloatArray


@dataclass(frozen=True)
class RangeMeasurement:
    """Rangefinder reading along the body's -z axis."""

    stamp_s: float
    range_m: float


@dataclass(frozen=True)
class YawMeasurement:
    """An external yaw (e.g. from the yaw cluster), any unwrapping."""

    stamp_s: float
    yaw_rad: float


@dataclass(frozen=True)
class FrameMeasurement:
    """A grey camera frame."""

    stamp_s: float
    image: ImageU8


Measurement = ImuMeasurement | RangeMeasurement | YawMeasurement | FrameMeasurement


def check_imu(stamp_s: float, gyro_rad_s: npt.ArrayLike, accel_m_s2: npt.ArrayLike) -> ImuMeasurement:
    """Validated IMU sample (finite stamp, two finite 3-vectors) or InputError."""
    gyro = np.asarray(gyro_rad_s, dtype=np.float64)
    accel = np.asarray(accel_m_s2, dtype=np.float64)
    if gyro.shape != (3,) or accel.shape != (3,):
        raise InputError(f"gyro and accel must have shape (3,), got {gyro.shape} and {accel.shape}")
    if not (math.isfinite(stamp_s) and np.all(np.isfinite(gyro)) and np.all(np.isfinite(accel))):
        raise InputError("IMU sample has a non-finite stamp, gyro or accel value")
    return ImuMeasurement(stamp_s=float(stamp_s), gyro_rad_s=gyro, accel_m_s2=accel)


def check_range(stamp_s: float, range_m: float) -> RangeMeasurement:
    """Validated range sample (finite stamp, finite positive range) or InputError."""
    if not (math.isfinite(stamp_s) and math.isfinite(range_m) and range_m > 0.0):
        raise InputError(f"range sample must have a finite stamp and a finite range > 0, got {range_m}")
    return RangeMeasurement(stamp_s=float(stamp_s), range_m=float(range_m))


def check_yaw(stamp_s: float, yaw_rad: float) -> YawMeasurement:
    """Validated yaw sample or InputError."""
    if not (math.isfinite(stamp_s) and math.isfinite(yaw_rad)):
        raise InputError(f"yaw sample must be finite, got stamp {stamp_s}, yaw {yaw_rad}")
    return YawMeasurement(stamp_s=float(stamp_s), yaw_rad=float(yaw_rad))


def check_frame(stamp_s: float, image: npt.ArrayLike, shape: tuple[int, int]) -> FrameMeasurement:
    """Validated grey frame of the camera's ``(height, width)`` or InputError."""
    img = check_grey_image(image, "image", min_side_px=8)
    if img.shape != shape:
        raise InputError(f"frame must have shape {shape} (height, width), got {img.shape}")
    if not math.isfinite(stamp_s):
        raise InputError("frame stamp must be finite")
    return FrameMeasurement(stamp_s=float(stamp_s), image=img)


@dataclass(frozen=True)
class CouplingSettings:
    """How the two layers are coupled."""

    #: Orthogonal rectification of each frame with the EKF's roll and pitch (False: the paper's
    #: "traditional" VO).
    rectify: bool = True
    #: Time constant (s) pulling the rectification attitude (gyro-propagated between frames) towards the
    #: EKF's; 0 rectifies with the EKF attitude of each frame as it is.
    rectification_smoothing_s: float = 0.0
    #: Metric scale of the VO: the EKF altitude (coupled) or the last rangefinder reading as it is
    #: (the uncoupled, traditional VO: longer than the height when tilted, and noisy).
    scale_from: ScaleSource = ScaleSource.EKF
    #: How rectified pairs are turned into a motion: the similarity of two level views for the
    #: translation and the free decomposition's rotation about the optical axis for the yaw (the
    #: default, :attr:`MotionModel.LEVEL_FREE_YAW`), or freely (``cv2.decomposeHomographyMat``), with the
    #: known plane normal, or the similarity alone (:attr:`MotionModel.LEVEL`).
    rectified_motion_model: MotionModel = MotionModel.LEVEL_FREE_YAW
    #: The VO's position origin (``initial_position_m``) is the first frame at least this long after the
    #: first IMU sample (frames before it already give the VO yaw). A rectified VO position is off by
    #: ``h * d`` (``d``: the EKF's tilt error when the frame was rectified); these offsets telescope
    #: along the chain, so the error is ``h_k d_k - h_0 d_0`` with ``0`` the origin frame. An origin
    #: before the EKF's tilt has settled from the first accelerometer sample leaves that transient in
    #: ``d_0`` for the whole flight.
    vo_origin_delay_s: float = 0.0
    #: Rectified VO with a level model only: estimate the residual tilt of the rectified views (the
    #: EKF's tilt error ``d``) from the free decompositions' plane normals and remove its offset
    #: ``h * d`` from the VO position (:func:`residual_tilt_offset`); the origin's offset is zero when
    #: it was rectified with the known initial attitude, else from the latest estimate.
    vision_tilt_correction: bool = True
    #: Forgetting time constant (s) of that estimate and the information (sum of ``|T/d|^2`` of the
    #: pairs) it needs before it is used.
    vision_tilt_window_s: float = 5.0
    vision_tilt_min_information: float = 1e-3
    #: Feed the VO yaw to the EKF (eq. 19). False leaves yaw to the gyro alone.
    visual_yaw: bool = True
    #: Apply yaw samples pushed as ``Sensor.YAW`` (e.g. the yaw cluster) as a second yaw source.
    external_yaw: bool = False
    vo_yaw_noise_rad: float = 0.005
    external_yaw_noise_rad: float = 0.02
    #: Samples are held until this much older than the newest stamp, then applied in order.
    max_lag_s: float = 0.02
    max_pending: int = 4096
    #: Altitude assumed before the first range reading, and its std.
    default_altitude_m: float = 1.0
    default_altitude_std_m: float = 2.0
    #: Compensate the accelerometer for the manoeuvre acceleration estimated from the VO positions (the
    #: hover model of eq. 16 alone reads the coordinated tilt of a turn as level).
    accel_compensation: bool = True
    #: Time span of the VO positions fitted (cubic in time) for that acceleration.
    accel_window_s: float = 0.6
    #: After the start, skip the accelerometer for up to this long until the VO acceleration is available
    #: (0: use the hover model meanwhile, right for a start at rest; > 0 for a start in mid-manoeuvre).
    accel_wait_for_vo_s: float = 0.0
    #: Initial yaw of the EKF and of the VO, and the VO's origin (navigation frame n = world).
    initial_yaw_rad: float = 0.0
    initial_position_m: tuple[float, float] = (0.0, 0.0)
    #: Known initial attitude ``q_world_body`` (else roll and pitch from the first accelerometer sample).
    initial_q_world_body: tuple[float, float, float, float] | None = None


@dataclass(frozen=True)
class CameraModel:
    """Intrinsics and mounting of the camera used by the visual odometry."""

    K: FloatArray
    width: int
    height: int
    R_body_camera: FloatArray = field(default_factory=lambda: R_BODY_CAMERA_DOWN.copy())

    def __post_init__(self) -> None:
        K = np.asarray(self.K, dtype=np.float64)
        if K.shape != (3, 3) or not np.all(np.isfinite(K)) or K[0, 0] <= 0 or K[1, 1] <= 0:
            raise InputError(f"K must be a finite (3, 3) intrinsic matrix, got {K}")
        check_rotation_matrix(self.R_body_camera, "R_body_camera")

    @property
    def shape(self) -> tuple[int, int]:
        return (int(self.height), int(self.width))


@dataclass(frozen=True)
class AttitudeOutput:
    """EKF estimate after one IMU sample."""

    stamp_s: float
    q_world_body: FloatArray
    pz_m: float
    covariance_diag: FloatArray


@dataclass(frozen=True)
class PoseOutput:
    """Visual-odometry pose after one frame: body position (x, y from VO, z from the EKF) and attitude."""

    stamp_s: float
    p_world_body_m: FloatArray
    q_world_body: FloatArray
    vo_yaw_rad: float
    n_inliers: int
    vo_ms: float
    ok: bool


Output = AttitudeOutput | PoseOutput


def motion_acceleration(stamps_s: npt.ArrayLike, positions_m: npt.ArrayLike) -> FloatArray:
    """Acceleration at the last stamp of a cubic fit in time to positions ``(N, D)`` (N >= 5), else zeros."""
    t = np.asarray(stamps_s, dtype=np.float64)
    p = np.asarray(positions_m, dtype=np.float64)
    if len(t) < 5:
        return np.zeros(p.shape[1] if p.ndim == 2 else 3)
    tau = t - t[-1]
    scale = max(float(-tau[0]), 1e-6)
    x = tau / scale
    A = np.stack([np.ones_like(x), x, x * x, x * x * x], axis=1)
    coeffs, *_ = np.linalg.lstsq(A, p, rcond=None)
    return np.asarray(2.0 * coeffs[2] / (scale * scale), dtype=np.float64)


def residual_tilt_offset(R_n_camera: FloatArray, altitude_m: float, normal_xy: FloatArray) -> FloatArray:
    """Horizontal offset ``(2,)`` (navigation frame) of the ground point on a rectified camera's optical axis
    from the point below it, when the rectified view is in fact tilted so that the ground normal is
    ``(nx, ny, ~1)`` in its frame: ``R_n_camera (-h nx, -h ny, 0)``. A VO chain of such views tracks
    that ground point instead of the camera."""
    n = np.asarray(normal_xy, dtype=np.float64)
    offset_cam = np.array([-altitude_m * n[0], -altitude_m * n[1], 0.0])
    return np.asarray((R_n_camera @ offset_cam)[:2], dtype=np.float64)


def yaw_of_camera(R_world_camera: FloatArray, R_body_camera: FloatArray) -> float:
    """ZYX yaw of the body carrying a camera with orientation ``R_world_camera``."""
    return float(euler_from_matrix(R_world_camera @ R_body_camera.T)[2])


class DoubleCouplingEstimator:
    """EKF + visual odometry with double coupling, fed sample by sample (single-threaded, not thread-safe)."""

    def __init__(
        self,
        camera: CameraModel,
        ekf_settings: EkfSettings | None = None,
        vo_settings: VoSettings | None = None,
        settings: CouplingSettings | None = None,
    ) -> None:
        self.camera = camera
        self.settings = settings or CouplingSettings()
        self.ekf = AttitudeAltitudeEkf(ekf_settings)
        self.vo_settings = vo_settings or VoSettings()
        self.buffer: TimeOrderedBuffer[Measurement] = TimeOrderedBuffer(
            self.settings.max_lag_s, self.settings.max_pending
        )
        self.state: EkfState | None = None
        self.pose: VoPose | None = None
        self.counters: Counter[str] = Counter()
        self._prev_frame: PreparedFrame | None = None
        self._prev_altitude_m = math.nan
        self._last_range_m: float | None = None
        self._latest_frame_stamp_s = -math.inf
        self._vo_yaw_unwrapped = math.nan
        self._altitude_from_range = False
        self._vo_track: deque[tuple[float, float, float]] = deque()
        self._motion_accel: tuple[float, float, float] = (0.0, 0.0, 0.0)
        self._first_imu_s: float | None = None
        self._rect_q: FloatArray | None = None
        self._accel_position = np.zeros(3)
        self._tilt_sum = np.zeros(2)
        self._tilt_information = 0.0
        self._tilt_stamp_s = math.nan
        self._tilt_informed = False
        self._origin_set = False
        self._origin_at_known_attitude = False
        self._anchor: tuple[FloatArray, float] | None = None

    # ---- input ------------------------------------------------------------------------------------

    def push(self, measurement: Measurement) -> Refusal | None:
        """Queue one validated sample; returns why it was refused, if it was."""
        sensor = _sensor_of(measurement)
        if sensor is Sensor.CAMERA:
            if measurement.stamp_s <= self._latest_frame_stamp_s:
                self.counters["refused_camera_stale"] += 1
                return Refusal.STALE
            self._latest_frame_stamp_s = measurement.stamp_s
        refusal = self.buffer.push(measurement.stamp_s, sensor.value, measurement, _RANK[sensor])
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

    # ---- EKF inputs -------------------------------------------------------------------------------

    def _initial_state(self, m: ImuMeasurement) -> EkfState:
        ax, ay, az = m.accel_m_s2
        roll = math.atan2(ay, az)
        pitch = math.atan2(-ax, math.hypot(ay, az))
        q = quaternion_from_euler(roll, pitch, self.settings.initial_yaw_rad)
        if self.settings.initial_q_world_body is not None:
            q = np.asarray(self.settings.initial_q_world_body, dtype=np.float64)
        if self._last_range_m is not None:
            R33 = float(matrix_from_quaternion(q)[2, 2])
            state = self.ekf.initial_state(q, self._last_range_m * R33, m.stamp_s)
            P = state.covariance.copy()
            P[4, 4] = self.ekf.settings.range_noise_m**2
            state = EkfState(state.q_world_body, state.pz_m, P, state.stamp_s)
            self._altitude_from_range = True
        else:
            state = self.ekf.initial_state(q, self.settings.default_altitude_m, m.stamp_s)
            P = state.covariance.copy()
            P[4, 4] = self.settings.default_altitude_std_m**2
            state = EkfState(state.q_world_body, state.pz_m, P, state.stamp_s)
        return state

    def _on_imu(self, m: ImuMeasurement) -> AttitudeOutput | None:
        if self.state is None:
            self.state = self._initial_state(m)
            self._first_imu_s = m.stamp_s
        dt_s = m.stamp_s - self.state.stamp_s
        try:
            state = self.ekf.predict(self.state, m.gyro_rad_s, dt_s)
            if self._accel_waits_for_vo(m.stamp_s):
                self.counters["accel_waiting_for_vo"] += 1
                result = UpdateResult(state=state, accepted=True, nis=math.nan)
            else:
                result = self.ekf.update_accelerometer(state, m.accel_m_s2, self._motion_accel)
        except EkfError as exc:
            self.counters["ekf_errors"] += 1
            logger.warning("IMU sample at %.4f s not applied: %s", m.stamp_s, exc)
            return None
        self.counters["imu_applied"] += 1
        self._propagate_rectification_attitude(m, dt_s, result.state)
        if not result.accepted:
            self.counters["accel_gated"] += 1
        self.state = result.state
        return AttitudeOutput(
            stamp_s=m.stamp_s,
            q_world_body=self.state.q_world_body,
            pz_m=self.state.pz_m,
            covariance_diag=np.diag(self.state.covariance).copy(),
        )

    def _on_range(self, m: RangeMeasurement) -> None:
        self._last_range_m = m.range_m
        if self.state is None:
            return
        if not self._altitude_from_range:
            # first reading: take the altitude from it (eq. 21 inverted) instead of a huge innovation
            q0, q1, q2, q3 = self.state.q_world_body.tolist()
            P = self.state.covariance.copy()
            P[4, :] = 0.0
            P[:, 4] = 0.0
            P[4, 4] = self.ekf.settings.range_noise_m**2
            pz = m.range_m * (q0 * q0 - q1 * q1 - q2 * q2 + q3 * q3)
            self.state = EkfState(self.state.q_world_body, pz, P, self.state.stamp_s)
            self._altitude_from_range = True
            self.counters["range_applied"] += 1
            return
        try:
            result = self.ekf.update_range(self.state, m.range_m)
        except EkfError as exc:
            self.counters["ekf_errors"] += 1
            logger.warning("range sample at %.4f s not applied: %s", m.stamp_s, exc)
            return
        self.counters["range_applied" if result.accepted else "range_gated"] += 1
        self.state = result.state

    def _apply_yaw(self, yaw_rad: float, noise_rad: float, counter: str) -> None:
        if self.state is None:
            return
        try:
            result = self.ekf.update_yaw(self.state, yaw_rad, noise_rad)
        except EkfError as exc:
            self.counters["ekf_errors"] += 1
            logger.warning("yaw update not applied: %s", exc)
            return
        self.counters[f"{counter}_applied" if result.accepted else f"{counter}_gated"] += 1
        self.state = result.state

    def _on_yaw(self, m: YawMeasurement) -> None:
        if self.settings.external_yaw:
            self._apply_yaw(m.yaw_rad, self.settings.external_yaw_noise_rad, "external_yaw")
        else:
            self.counters["external_yaw_ignored"] += 1

    # ---- frames: rectification, VO, yaw coupling --------------------------------------------------

    def _on_frame(self, m: FrameMeasurement) -> PoseOutput | None:
        if self.state is None:
            self.counters["frames_before_imu"] += 1
            return None
        t0 = time.perf_counter()
        roll, pitch, yaw_ekf = (float(v) for v in euler_from_quaternion(self.state.q_world_body))
        if self._rect_q is not None and self.settings.rectification_smoothing_s > 0.0:
            roll, pitch, _ = (float(v) for v in euler_from_quaternion(self._rect_q))
        altitude_m = self.state.pz_m
        if self.settings.scale_from is ScaleSource.RANGE and self._last_range_m is not None:
            altitude_m = self._last_range_m
        cam = self.camera
        try:
            if self.settings.rectify:
                rect = rectify_frame(
                    m.image, cam.K, roll, pitch, cam.R_body_camera, border_px=self.vo_settings.mask_margin_px
                )
                frame = prepare_frame(rect.image, rect.valid_mask, self.vo_settings)
            else:
                frame = prepare_frame(m.image, None, self.vo_settings)
        except RectificationError as exc:
            self.counters["frames_unrectifiable"] += 1
            logger.warning("frame at %.4f s not rectified: %s", m.stamp_s, exc)
            return None
        ok = False
        n_inliers = 0
        if self.pose is None or self._prev_frame is None:
            self.pose = self._initial_pose(roll, pitch, yaw_ekf, altitude_m)
            self._anchor = (self.pose.R_n_camera.copy(), altitude_m)
            self._maybe_set_origin(m.stamp_s, altitude_m)
            self._accel_position = self.pose.p_n_camera_m.copy()
            self._vo_yaw_unwrapped = yaw_of_camera(self.pose.R_n_camera, self._vo_camera_mount())
            ok = True
        else:
            try:
                model = self.settings.rectified_motion_model if self.settings.rectify else MotionModel.FREE
                motion = estimate_relative_motion(
                    self._prev_frame, frame, cam.K, self.vo_settings, model=model
                )
                t_m = metric_translation(motion.t_over_d, self._prev_altitude_m)
                self.pose = compose_pose(self.pose, motion.R_k_km1, t_m)
                # the accelerometer compensation follows the free decomposition: with the level model a
                # tilt error of the EKF would leak into the translation and back into the EKF (a loop)
                t_free = metric_translation(motion.t_over_d_free, self._prev_altitude_m)
                self._accel_position = self._accel_position - self.pose.R_n_camera @ t_free
                n_inliers = motion.n_inliers
                self._maybe_set_origin(m.stamp_s, altitude_m)
                if self.settings.rectify and self.settings.vision_tilt_correction:
                    self._update_vision_tilt(m.stamp_s, motion.t_over_d_free, motion.normal_km1_free)
                ok = True
                self.counters["vo_pairs"] += 1
            except VoError as exc:
                self.counters["vo_failures"] += 1
                self._vo_track.clear()
                logger.info("VO pair ending at %.4f s failed: %s", m.stamp_s, exc)
        self._prev_frame = frame
        self._prev_altitude_m = altitude_m
        if ok and self.settings.accel_compensation:
            self._update_motion_accel(m.stamp_s)
        vo_ms = (time.perf_counter() - t0) * 1e3
        yaw_wrapped = yaw_of_camera(self.pose.R_n_camera, self._vo_camera_mount())
        self._vo_yaw_unwrapped += math.remainder(yaw_wrapped - self._vo_yaw_unwrapped, 2.0 * math.pi)
        if ok and self.settings.visual_yaw:
            self._apply_yaw(self._vo_yaw_unwrapped, self.settings.vo_yaw_noise_rad, "vo_yaw")
        if not self._origin_set:
            self.counters["frames_before_vo_origin"] += 1
            return None
        p = self.pose.p_n_camera_m.copy()
        tilt = self.vision_tilt()
        if tilt is not None and self._anchor is not None:
            # the chain follows the ground point on the axis of the (tilted) rectified views: remove the
            # current frame's offset and add the origin frame's. The origin's tilt error was not
            # measurable then (hovering): the EKF's tilt error being mostly a body-fixed bias, the latest
            # (best-informed) estimate stands for it; zero when the origin had the known initial attitude.
            anchor_offset = (
                np.zeros(2)
                if self._origin_at_known_attitude
                else residual_tilt_offset(self._anchor[0], self._anchor[1], tilt)
            )
            p[:2] += anchor_offset - residual_tilt_offset(self.pose.R_n_camera, altitude_m, tilt)
        return PoseOutput(
            stamp_s=m.stamp_s,
            p_world_body_m=np.array([p[0], p[1], self.state.pz_m]),
            q_world_body=self.state.q_world_body,
            vo_yaw_rad=self._vo_yaw_unwrapped,
            n_inliers=n_inliers,
            vo_ms=vo_ms,
            ok=ok,
        )

    def _propagate_rectification_attitude(self, m: ImuMeasurement, dt_s: float, state: EkfState) -> None:
        """Attitude used to rectify: the gyro's rotation between frames, pulled towards the EKF with the
        time constant ``rectification_smoothing_s`` (consecutive frames are rectified consistently; the
        EKF's accelerometer corrections would otherwise make them jitter against each other)."""
        tau = self.settings.rectification_smoothing_s
        if self._rect_q is None or tau <= 0.0:
            self._rect_q = state.q_world_body
            return
        half = 0.5 * dt_s
        w = m.gyro_rad_s
        q = quaternion_multiply(self._rect_q, [1.0, half * w[0], half * w[1], half * w[2]])
        ekf_q = state.q_world_body if float(np.dot(q, state.q_world_body)) >= 0.0 else -state.q_world_body
        alpha = min(1.0, dt_s / tau)
        q = (1.0 - alpha) * q + alpha * ekf_q
        self._rect_q = q / np.linalg.norm(q)

    def _maybe_set_origin(self, stamp_s: float, altitude_m: float) -> None:
        """Move the VO position to ``initial_position_m`` at the first frame after ``vo_origin_delay_s``."""
        if self._origin_set or self.pose is None or self._first_imu_s is None:
            return
        if stamp_s < self._first_imu_s + self.settings.vo_origin_delay_s - 1e-9:
            return
        x0, y0 = self.settings.initial_position_m
        p = np.array([x0, y0, self.pose.p_n_camera_m[2]])
        self.pose = VoPose(R_n_camera=self.pose.R_n_camera, p_n_camera_m=p)
        self._anchor = (self.pose.R_n_camera.copy(), altitude_m)
        self._origin_set = True
        self._origin_at_known_attitude = (
            self.settings.initial_q_world_body is not None and stamp_s <= self._first_imu_s + 1e-9
        )

    def _update_vision_tilt(self, stamp_s: float, t_over_d_free: FloatArray, normal_free: FloatArray) -> None:
        """Information-weighted, exponentially forgetting mean of the free normals' tilt (a pair says more
        about the normal the more it translates: weight ``|T/d|^2``)."""
        n = np.asarray(normal_free, dtype=np.float64).reshape(3)
        n = n / n[2]
        weight = float(np.sum(np.asarray(t_over_d_free, dtype=np.float64)[:2] ** 2))
        if math.isfinite(self._tilt_stamp_s):
            forget = math.exp(-(stamp_s - self._tilt_stamp_s) / self.settings.vision_tilt_window_s)
            self._tilt_sum *= forget
            self._tilt_information *= forget
        self._tilt_stamp_s = stamp_s
        self._tilt_sum += weight * n[:2]
        self._tilt_information += weight

    def vision_tilt(self) -> FloatArray | None:
        """Estimated ground normal ``(nx, ny)`` in the rectified camera (None until informed enough)."""
        s = self.settings
        if not (s.rectify and s.vision_tilt_correction and s.rectified_motion_model in _LEVEL_MODELS):
            return None
        if self._tilt_information >= self.settings.vision_tilt_min_information:
            self._tilt_informed = True
        if not self._tilt_informed or self._tilt_information <= 0.0:
            return None
        return np.asarray(self._tilt_sum / self._tilt_information, dtype=np.float64)

    def _accel_waits_for_vo(self, stamp_s: float) -> bool:
        """At a start in mid-manoeuvre the hover model is wrong until the VO gives the acceleration."""
        s = self.settings
        return (
            s.accel_compensation
            and len(self._vo_track) < 5
            and self._first_imu_s is not None
            and stamp_s - self._first_imu_s < s.accel_wait_for_vo_s
        )

    def _update_motion_accel(self, stamp_s: float) -> None:
        p = self._accel_position
        self._vo_track.append((stamp_s, float(p[0]), float(p[1])))
        while self._vo_track and self._vo_track[0][0] < stamp_s - self.settings.accel_window_s:
            self._vo_track.popleft()
        track = np.array(self._vo_track)
        ax, ay = motion_acceleration(track[:, 0], track[:, 1:])
        self._motion_accel = (float(ax), float(ay), 0.0)

    def _vo_camera_mount(self) -> FloatArray:
        """Mounting of the camera whose poses the VO composes (the rectified one is level, looking down)."""
        return R_BODY_CAMERA_DOWN if self.settings.rectify else self.camera.R_body_camera

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

#: Application order of samples with equal stamps: the range first (it initialises the altitude).
_RANK = {Sensor.RANGE: 0, Sensor.IMU: 1, Sensor.YAW: 2, Sensor.CAMERA: 3}


def _sensor_of(measurement: Measurement) -> Sensor:
    if isinstance(measurement, ImuMeasurement):
        return Sensor.IMU
    if isinstance(measurement, RangeMeasurement):
        return Sensor.RANGE
    if isinstance(measurement, YawMeasurement):
        return Sensor.YAW
    if isinstance(measurement, FrameMeasurement):
        return Sensor.CAMERA
    raise InputError(f"unknown measurement type {type(measurement).__name__}")
