"""Double coupling of paper C (Fig. 1): the EKF feeds attitude and altitude to the visual odometry
(orthogonal rectification and metric scale), the visual odometry feeds its yaw back to the EKF.

:class:`DoubleCouplingEstimator` takes timestamped samples from several sensors (IMU, rangefinder, camera,
optionally an external yaw such as the yaw cluster's), reorders them in a :class:`TimeOrderedBuffer` with a
bounded lag and applies them in stamp order (a range, yaw or frame between two IMU samples meets the state
carried to its own stamp, :meth:`~common.estimation.filter_side.FilterSide.carry_to`): IMU, range and yaw
samples to the filter's side
(:class:`~common.estimation.filter_side.FilterSide`: predict, accelerometer, range and yaw updates), frames
to the visual-odometry side (:class:`~common.estimation.coupled_vo.CoupledVo`: rectified with the filter's
roll and pitch (section III-C), the VO against the previous frame with the filter's altitude as scale
(Algorithms 1-2, eqs. 9-10)), whose yaw goes back to the filter as a yaw update (eq. 19) and, with the bias
filter, whose free-decomposition chain's position as a position update.

The filter is paper C's 5-state EKF or the error-state EKF with bias states (``CouplingSettings.filter``).

It returns :class:`AttitudeOutput` (one per IMU sample) and :class:`PoseOutput` (one per frame). Frames are
latest-wins: a frame still pending when a newer one arrives is dropped and counted.
"""

from __future__ import annotations

import logging
import math
from collections import Counter
from collections.abc import Callable

import numpy as np
import numpy.typing as npt

from common.camera import CameraModel
from common.camera_maps import PinholeResampling
from common.errors import InputError
from common.estimation.buffer import Refusal, Timed, TimeOrderedBuffer
from common.estimation.coupled_vo import CoupledVo
from common.estimation.coupling_types import CouplingSettings, Output, PoseOutput
from common.estimation.ekf import EkfSettings
from common.estimation.filter_side import FilterSide
from common.estimation.filters import AnyState
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
from common.estimation.vo import VoSettings
from common.estimation.vo_chain import VoChainSettings
from common.geometry import R_BODY_CAMERA_DOWN, check_rotation_matrix
from common.types import FloatArray

logger = logging.getLogger(__name__)


def external_yaw_noise_rad(settings: CouplingSettings, measurement: YawMeasurement) -> float:
    """The noise an external yaw is fused with: the variance its source published (the yaw cluster's grows
    with the turns it accumulated) where it is larger than ``settings.external_yaw_noise_rad``'s, that floor
    otherwise: a yaw its source holds uncertain is not fused as if it were sure."""
    return math.sqrt(max(settings.external_yaw_noise_rad**2, measurement.variance_rad2))


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
        R_body_imu: npt.ArrayLike | None = None,
        imu_time_offset_s: float = 0.0,
    ) -> None:
        #: a camera with a lens: its frames are resampled onto the pinhole twin where they enter
        self.lens = PinholeResampling.of(camera) if camera.is_distorted else None
        camera = camera.pinhole()
        self.camera = camera
        #: mounting of the camera on the body (the camera model itself is the intrinsics only)
        self.R_body_camera = check_rotation_matrix(R_body_camera, "R_body_camera")
        #: the IMU's axes on the body (``gyro_body = R_body_imu gyro_imu``) and its clock's offset
        #: (``t_imu = t_cam + imu_time_offset_s``): IMU samples are turned and re-stamped where they enter
        self.R_body_imu = np.eye(3) if R_body_imu is None else check_rotation_matrix(R_body_imu, "R_body_imu")
        if not (math.isfinite(imu_time_offset_s) and abs(imu_time_offset_s) <= 1.0):
            raise InputError(f"imu_time_offset_s must be finite and within 1 s, got {imu_time_offset_s}")
        self.imu_time_offset_s = float(imu_time_offset_s)
        self._imu_in_body = not (np.array_equal(self.R_body_imu, np.eye(3)) and self.imu_time_offset_s == 0.0)
        self.settings = settings or CouplingSettings()
        self.vo_settings = vo_settings or VoSettings()
        self.chain_settings = chain_settings or VoChainSettings()
        self.buffer: TimeOrderedBuffer[Measurement] = TimeOrderedBuffer(
            self.settings.max_lag_s, self.settings.max_pending
        )
        self.counters: Counter[str] = Counter()
        self.filter = FilterSide(self.settings, ekf_settings, self.counters)
        self.vo = CoupledVo(
            camera, self.R_body_camera, self.settings, self.vo_settings, self.chain_settings, self.counters
        )
        self._latest_frame_stamp_s = -math.inf

    @property
    def state(self) -> AnyState | None:
        """The filter's state (None before the first IMU sample)."""
        return self.filter.state

    # ---- input ------------------------------------------------------------------------------------

    def push(self, measurement: Measurement) -> Refusal | None:
        """Queue one validated sample; returns why it was refused, if it was. An IMU sample is turned into
        the body's axes and its stamp moved onto the camera's clock first."""
        sensor = sensor_of(measurement)
        if self._imu_in_body and isinstance(measurement, ImuMeasurement):
            measurement = self.imu_in_body(measurement)
        if sensor is Sensor.CAMERA:
            if measurement.stamp_s <= self._latest_frame_stamp_s:
                self.counters["refused_camera_stale"] += 1
                return Refusal.STALE
            self._latest_frame_stamp_s = measurement.stamp_s
        refusal = self.buffer.push(measurement.stamp_s, sensor.value, measurement, SENSOR_ORDER[sensor])
        if refusal is not None:
            self.counters[f"refused_{sensor.value}_{refusal.value}"] += 1
        return refusal

    def imu_in_body(self, m: ImuMeasurement) -> ImuMeasurement:
        """An IMU sample in the body's axes, stamped on the camera's clock (``t_cam = t_imu - offset``)."""
        R = self.R_body_imu
        return ImuMeasurement(m.stamp_s - self.imu_time_offset_s, R @ m.gyro_rad_s, R @ m.accel_m_s2)

    def process_due(self) -> list[Output]:
        """Apply every sample that is older than the newest by ``max_lag_s``, in stamp order."""
        return self._apply(self.buffer.pop_due)

    def drain(self) -> list[Output]:
        """Apply everything pending (end of a stream)."""
        return self._apply(self.buffer.drain)

    def _apply(self, release: Callable[[], list[Timed[Measurement]]]) -> list[Output]:
        """Apply what ``release`` (the buffer's) gives, in stamp order."""
        released = release()
        outputs: list[Output] = []
        latest_frame = -math.inf
        for t in released:
            if isinstance(t.item, FrameMeasurement):
                latest_frame = max(latest_frame, t.stamp_s)
        # the IMU sample after each (a later released one, else the first still pending, looked up only when
        # a sample after the last released IMU sample needs it; None: none has come). Inline: an IMU sample's
        # walk enters this module no more than twice (test_walks.py; a comprehension is a frame)
        next_imu: list[ImuMeasurement | None] = [None] * len(released)
        upcoming: ImuMeasurement | None = None
        if released and not isinstance(released[-1].item, ImuMeasurement):
            pending = self.buffer.first_pending(Sensor.IMU.value)
            upcoming = pending if isinstance(pending, ImuMeasurement) else None
        for i in range(len(released) - 1, -1, -1):
            next_imu[i] = upcoming
            item = released[i].item
            if isinstance(item, ImuMeasurement):
                upcoming = item
        for i, t in enumerate(released):
            m = t.item
            if isinstance(m, ImuMeasurement):
                out = self.filter.on_imu(m, self.vo.track)
                if out is not None:
                    outputs.append(out)
                continue
            if isinstance(m, YawMeasurement) and not self.settings.external_yaw:
                self.counters["external_yaw_ignored"] += 1
                continue
            if isinstance(m, FrameMeasurement) and m.stamp_s < latest_frame:
                self.counters["frames_superseded"] += 1
                continue
            # a measurement between two IMU samples meets the state at its own stamp
            self.filter.carry_to(m.stamp_s, next_imu[i])
            if isinstance(m, RangeMeasurement):
                self.filter.on_range(m.range_m)
            elif isinstance(m, YawMeasurement):
                self.filter.on_yaw(m.yaw_rad, external_yaw_noise_rad(self.settings, m), "external_yaw")
            else:
                pose = self._on_frame(m)
                if pose is not None:
                    outputs.append(pose)
        return outputs

    # ---- frames: rectification, VO, yaw coupling --------------------------------------------------

    def _on_frame(self, m: FrameMeasurement) -> PoseOutput | None:
        side = self.filter
        if side.state is None:
            self.counters["frames_before_imu"] += 1
            return None
        if self.lens is not None:
            m = FrameMeasurement(m.stamp_s, self.lens.apply(m.image))
        result = self.vo.on_frame(m, side.view())
        if result is None:
            return None
        if result.ok and self.settings.visual_yaw:
            side.on_yaw(result.vo_yaw_rad, self.settings.vo_yaw_noise_rad, "vo_yaw")
        if result.ok:
            side.on_position(self.vo.free_position_xy)
        if result.p_xy_m is None:
            self.counters["frames_before_vo_origin"] += 1
            return None
        state = side.state
        assert state is not None
        return PoseOutput(
            stamp_s=m.stamp_s,
            p_world_body_m=np.array([result.p_xy_m[0], result.p_xy_m[1], state.pz_m]),
            q_world_body=state.q_world_body,
            attitude_covariance_world=side.attitude_covariance(),
            altitude_var_m2=side.altitude_variance(),
            vo_yaw_rad=result.vo_yaw_rad,
            n_inliers=result.n_inliers,
            rectification_weight=result.rectification_weight,
            ok=result.ok,
            vo_flow_px=result.flow_px,
        )

    @property
    def q_world_body(self) -> FloatArray | None:
        return None if self.state is None else self.state.q_world_body
