"""The visual-odometry side of the double coupling: rectification with the filter's roll and pitch, the VO
chain scaled by the filter's altitude, its yaw for the filter, and the position output.

Rectified pairs are, by default, two level views of the ground: their motion is a 4-DOF similarity
(translation and scale from :func:`~common.estimation.homography.level_motion_from_matches`, the rotation
about the optical axis from the free decomposition, :attr:`MotionModel.LEVEL_FREE_YAW`). Such a chain follows
the ground point on the rectified optical axis: when the filter's tilt is off by ``d`` that point is ``h d``
from the point below the camera, and the chain's error is ``h_k d_k - h_0 d_0`` (the offsets telescope).
What keeps it small: the VO origin set once the tilt has settled (``vo_origin_delay_s``); the residual tilt
of the rectified views estimated from the free decompositions' plane normals (``vision_tilt_correction``);
the origin's tilt error re-estimated from the accelerometer bias (``origin_tilt_from_bias``); and the
uncertainty-aware output, which weights toward the free decomposition's chain (the traditional path) while
the level chain's error is uncertain (``uncertainty_aware``).
"""

from __future__ import annotations

import logging
import math
from collections import Counter
from dataclasses import dataclass

import numpy as np

from common.camera import CameraModel
from common.estimation.coupling_types import CouplingSettings
from common.estimation.homography import VoError
from common.estimation.measurements import FrameMeasurement
from common.estimation.rectify import RectificationError
from common.estimation.tilt import ManoeuvreTrack, VisionTilt, VoOrigin, level_share, residual_tilt_offset
from common.estimation.vo import MotionModel, PreparedFrame, VoPose, VoSettings
from common.estimation.vo_chain import (
    VoChainSettings,
    VoChainState,
    advance_vo_chain,
    prepare_view,
    shifted,
    smoothed_vo_altitude,
    start_vo_chain,
    with_altitude,
)
from common.geometry import R_BODY_CAMERA_DOWN, euler_from_matrix, matrix_from_euler
from common.types import FloatArray

logger = logging.getLogger(__name__)


#: Rectified-pair models that follow the ground point on the optical axis (a similarity of level views).
LEVEL_MODELS = (MotionModel.LEVEL, MotionModel.LEVEL_FREE_YAW)


def yaw_of_camera(R_world_camera: FloatArray, R_body_camera: FloatArray) -> float:
    """ZYX yaw of the body carrying a camera with orientation ``R_world_camera``."""
    return float(euler_from_matrix(R_world_camera @ R_body_camera.T)[2])


@dataclass(frozen=True)
class FilterView:
    """What the VO takes from the filter at a frame: the rectification attitude, the scale, the tilt
    uncertainty and (bias filter) the accelerometer-bias estimate with its horizontal std."""

    roll_rad: float
    pitch_rad: float
    yaw_rad: float
    altitude_m: float
    tilt_std_rad: float
    accel_bias_m_s2: FloatArray | None
    accel_bias_std_m_s2: float
    gravity_m_s2: float
    since_first_imu_s: float


@dataclass(frozen=True)
class VoFrame:
    """One frame's VO result: whether the pair worked, the VO yaw (unwrapped), the output position (None
    before the origin), the inliers, the level chain's share in the position and the pair's median flow
    (px; nan without a pair)."""

    ok: bool
    vo_yaw_rad: float
    p_xy_m: FloatArray | None
    n_inliers: int
    rectification_weight: float
    flow_px: float = math.nan


class CoupledVo:
    """The VO chain fed frame by frame with the filter's view (single-threaded)."""

    def __init__(
        self,
        camera: CameraModel,
        R_body_camera: FloatArray,
        settings: CouplingSettings,
        vo_settings: VoSettings,
        chain_settings: VoChainSettings,
        counters: Counter[str],
    ) -> None:
        self.camera = camera
        self.R_body_camera = R_body_camera
        self.settings = settings
        self.vo_settings = vo_settings
        self.chain_settings = chain_settings
        self.counters = counters
        self.chain: VoChainState | None = None
        self.track = ManoeuvreTrack()
        self._tilt = VisionTilt()
        self._vo_yaw_unwrapped = math.nan
        self._origin: VoOrigin | None = None
        #: the free decomposition's chain: its position, the keyframe it is measured from (and the position
        #: there), its offset to the navigation frame (set with the origin) and its path since the origin
        self._free_position = np.zeros(3)
        self._free_keyframe: tuple[PreparedFrame | None, FloatArray] = (None, np.zeros(3))
        self._free_offset = np.zeros(2)
        self._free_path_m = 0.0
        #: stamps of the chain's newest frame and keyframe, and of its (re)start (the altitude smoothing's
        #: time constant grows from there)
        self._newest_stamp_s = math.nan
        self._keyframe_stamp_s = math.nan
        self._chain_start_s = math.nan

    def on_frame(self, m: FrameMeasurement, view: FilterView) -> VoFrame | None:
        """Rectify, advance the chain, and the output (None when the frame cannot be rectified)."""
        s = self.settings
        rp = (view.roll_rad, view.pitch_rad)
        try:
            frame = prepare_view(
                m.image, self.camera.K, self.R_body_camera, rp if s.rectify else None, self.vo_settings
            )
        except RectificationError as exc:
            self.counters["frames_unrectifiable"] += 1
            logger.warning("frame at %.4f s not rectified: %s", m.stamp_s, exc)
            return None
        ok = False
        n_inliers, flow_px = 0, math.nan
        if self.chain is None:
            self._chain_start_s = self._keyframe_stamp_s = m.stamp_s
            self.chain = start_vo_chain(frame, self._initial_pose(view), view.altitude_m)
            self._free_position = self.chain.pose.p_n_camera_m.copy()
            self._maybe_set_origin(view)
            self._vo_yaw_unwrapped = yaw_of_camera(self.chain.pose.R_n_camera, self._vo_camera_mount())
            ok = True
        else:
            try:
                n_inliers, flow_px = self._advance(m, frame, view)
                ok = True
                self.counters["vo_pairs"] += 1
            except VoError as exc:
                self.counters["vo_failures"] += 1
                self.track = self.track.cleared()
                self._chain_start_s = self._keyframe_stamp_s = m.stamp_s
                self.chain = start_vo_chain(frame, self.chain.pose, view.altitude_m)
                logger.info("VO pair ending at %.4f s failed: %s", m.stamp_s, exc)
        self._newest_stamp_s = m.stamp_s
        if ok and s.accel_compensation:
            p = self._free_position
            self.track = self.track.updated(m.stamp_s, float(p[0]), float(p[1]), s.accel_window_s)
        pose = self.chain.pose
        yaw_wrapped = yaw_of_camera(pose.R_n_camera, self._vo_camera_mount())
        self._vo_yaw_unwrapped += math.remainder(yaw_wrapped - self._vo_yaw_unwrapped, 2.0 * math.pi)
        if self._origin is None:
            return VoFrame(ok, self._vo_yaw_unwrapped, None, n_inliers, math.nan, flow_px)
        p_xy = pose.p_n_camera_m[:2] + self._tilt_offset_correction(pose.R_n_camera, view)
        p_free = self._free_position[:2] + self._free_offset
        weight = self._level_share(view, float(np.sum((p_xy - p_free) ** 2))) if s.rectify else math.nan
        if s.rectify and weight < 1.0:
            # uncertainty-aware: toward the free decomposition's chain while the tilt is uncertain
            p_xy = weight * p_xy + (1.0 - weight) * p_free
        return VoFrame(ok, self._vo_yaw_unwrapped, p_xy, n_inliers, weight, flow_px)

    def _advance(self, m: FrameMeasurement, frame: PreparedFrame, view: FilterView) -> tuple[int, float]:
        """Advance the chain by ``frame``: the pair's inliers and median flow (px)."""
        s = self.settings
        assert self.chain is not None
        model = s.rectified_motion_model if s.rectify else MotionModel.FREE
        previous = self.chain
        step = advance_vo_chain(
            previous, frame, view.altitude_m, self.camera.K, self.vo_settings, model, self.chain_settings
        )
        self.chain = step.state
        # the pair was measured from the keyframe or, when that pair failed, from the newest frame
        from_keyframe = step.keyframe_frame is previous.keyframe.frame
        kf_altitude_m = previous.keyframe.altitude_m if from_keyframe else previous.altitude_m
        kf_stamp_s = self._keyframe_stamp_s if from_keyframe else self._newest_stamp_s
        if s.rectify and model in LEVEL_MODELS and s.vo_altitude_smoothing_s > 0.0:
            self.chain = with_altitude(
                self.chain,
                smoothed_vo_altitude(
                    kf_altitude_m, float(step.motion.t_over_d[2]), view.altitude_m,
                    m.stamp_s - kf_stamp_s, s.vo_altitude_smoothing_s, m.stamp_s - self._chain_start_s,
                ),
            )  # fmt: skip
        if self.chain.keyframe.frame is frame:
            self._keyframe_stamp_s = m.stamp_s
        # the free decomposition's chain: the traditional path (it does not depend on the filter's tilt) for
        # the uncertainty-aware output and the accelerometer compensation (with the level model a tilt error
        # would leak into the translation and back into the filter: a loop)
        if step.keyframe_frame is not self._free_keyframe[0]:
            self._free_keyframe = (step.keyframe_frame, self._free_position)
        previous_free = self._free_position
        self._free_position = self._free_keyframe[1] + step.displacement_free_m
        if self._origin is not None:
            self._free_path_m += float(np.linalg.norm((self._free_position - previous_free)[:2]))
        if self.chain.keyframe.frame is frame:
            self._free_keyframe = (frame, self._free_position)
        self._maybe_set_origin(view)
        if s.rectify and s.vision_tilt_correction:
            self._tilt = self._tilt.updated(
                m.stamp_s, step.motion.t_over_d_free, step.motion.normal_km1_free,
                s.vision_tilt_window_s, s.vision_tilt_min_information,
            )  # fmt: skip
        return step.motion.n_inliers, step.flow_px

    def _bias_corrects_origin(self, view: FilterView) -> bool:
        origin = self._origin
        return (
            self.settings.origin_tilt_from_bias
            and view.accel_bias_m_s2 is not None
            and origin is not None
            and origin.accel_bias_m_s2 is not None
            and not origin.at_known_attitude
        )

    def _level_share(self, view: FilterView, disagreement_m2: float) -> float:
        """The level chain's share; ``disagreement_m2`` is the squared distance between the two chains: when
        it exceeds what their variances allow, the level chain's variance is raised to explain it (the
        filter's tilt std is then too optimistic, e.g. in hard manoeuvres)."""
        origin = self._origin
        if not self.settings.uncertainty_aware or origin is None:
            return 1.0
        origin_std = origin.tilt_std_rad
        if self._bias_corrects_origin(view):
            # the origin's tilt error is re-estimated from the bias: what is left is the bias' uncertainty
            origin_std = view.accel_bias_std_m_s2 / view.gravity_m_s2
        return level_share(
            view.altitude_m, view.tilt_std_rad, origin.altitude_m, origin_std,
            self.settings.free_drift_per_m, self._free_path_m, disagreement_m2,
        )  # fmt: skip

    def _tilt_offset_correction(self, R_n_camera: FloatArray, view: FilterView) -> FloatArray:
        """What to add to a rectified chain's position: the origin frame's axis offset ``h_0 d_0`` minus the
        current frame's ``h_k d_k`` (the chain follows the ground point on the rectified optical axis)."""
        s = self.settings
        origin = self._origin
        if origin is None or not s.rectify or s.rectified_motion_model not in LEVEL_MODELS:
            return np.zeros(2)
        correction = np.zeros(2)
        normal = self.vision_tilt()
        bias_origin = self._bias_corrects_origin(view)
        if normal is not None:
            # the current frame's offset from the vision tilt; without a better source the origin's is the
            # same estimate (the 5-state filter's tilt error being mostly a body-fixed bias), zero when the
            # origin had the known initial attitude
            correction -= residual_tilt_offset(R_n_camera, view.altitude_m, normal)
            if not origin.at_known_attitude and not bias_origin:
                correction += residual_tilt_offset(origin.R_n_camera, origin.altitude_m, normal)
        if bias_origin:
            assert view.accel_bias_m_s2 is not None
            correction += origin.offset_from_bias(view.accel_bias_m_s2, view.gravity_m_s2)
        return correction

    def _maybe_set_origin(self, view: FilterView) -> None:
        """Move the VO position to ``initial_position_m`` at the first frame after ``vo_origin_delay_s``."""
        if self._origin is not None or self.chain is None:
            return
        if view.since_first_imu_s < self.settings.vo_origin_delay_s - 1e-9:
            return
        x0, y0 = self.settings.initial_position_m
        pose = self.chain.pose
        self.chain = shifted(self.chain, np.array([x0, y0, 0.0]) - np.r_[pose.p_n_camera_m[:2], 0.0])
        self._free_offset = np.array([x0, y0]) - self._free_position[:2]
        at_known = self.settings.initial_q_world_body is not None and view.since_first_imu_s <= 1e-9
        bias = None if view.accel_bias_m_s2 is None else view.accel_bias_m_s2.copy()
        self._origin = VoOrigin(
            R_n_camera=pose.R_n_camera.copy(),
            altitude_m=view.altitude_m,
            yaw_rad=view.yaw_rad,
            roll_pitch_rad=(view.roll_rad, view.pitch_rad),
            accel_bias_m_s2=bias,
            at_known_attitude=at_known,
            # a known initial attitude is exact at the origin; else the filter's tilt std then
            tilt_std_rad=0.0 if at_known else view.tilt_std_rad,
        )

    @property
    def free_position_xy(self) -> FloatArray | None:
        """The free decomposition's chain position (continuous, not shifted to the origin; None before the
        first frame): independent of the filter's tilt, the bias filter's position measurement."""
        if self.chain is None:
            return None
        return np.array(self._free_position[:2])

    def vision_tilt(self) -> FloatArray | None:
        """Estimated ground normal ``(nx, ny)`` in the rectified camera (None until informed enough)."""
        s = self.settings
        if not (s.rectify and s.vision_tilt_correction and s.rectified_motion_model in LEVEL_MODELS):
            return None
        return self._tilt.normal_xy()

    def _vo_camera_mount(self) -> FloatArray:
        """Mounting of the camera whose poses the VO composes (the rectified one is level, looking down)."""
        return R_BODY_CAMERA_DOWN if self.settings.rectify else self.R_body_camera

    def _initial_pose(self, view: FilterView) -> VoPose:
        x0, y0 = self.settings.initial_position_m
        roll, pitch = (0.0, 0.0) if self.settings.rectify else (view.roll_rad, view.pitch_rad)
        R_n_camera = matrix_from_euler(roll, pitch, view.yaw_rad) @ self._vo_camera_mount()
        return VoPose(R_n_camera=R_n_camera, p_n_camera_m=np.array([x0, y0, view.altitude_m]))
