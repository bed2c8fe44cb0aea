"""Settings, camera model and outputs of paper C's double-coupling estimator
(:mod:`common.estimation.coupling`)."""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass
from typing import Any

from common.bounds import Bounded, bounded, setting
from common.estimation.vo import MotionModel
from common.types import FloatArray


class EkfKind(enum.Enum):
    """Which attitude/altitude filter the coupling runs."""

    #: Paper C's 5-state EKF (quaternion + altitude), kept as the reference.
    PAPER_C = "paper_c"
    #: The error-state EKF with gyro and accelerometer bias states (:mod:`common.estimation.eskf`).
    BIAS = "bias"


class ScaleSource(enum.Enum):
    """Where the visual odometry takes its metric scale (the camera's height) from."""

    EKF = "ekf"
    RANGE = "range"


#: The thrust-axis update's averaging interval for :attr:`Vehicle.STILL_AIR_MULTIROTOR` (s).
STILL_AIR_THRUST_AXIS_INTERVAL_S = 0.1


class Vehicle(enum.Enum):
    """What the estimator may assume of the vehicle's dynamics (:func:`vehicle_settings`)."""

    #: Nothing: any vehicle, any wind (the default). At hover an accelerometer bias reads as a tilt until the
    #: vehicle yaws; the VO corrects what that tilt error leaves in its position from the free
    #: decompositions' plane normals and from the bias re-estimated later.
    ANY = "any"
    #: A multirotor in still air (indoors): its thrust is along body z, so the body-horizontal specific force
    #: is the rotor drag, and the thrust-axis update measures the accelerometer bias at hover. Paper C's
    #: 20 seeds (``capataz bench estimator --seeds 20 --any-vehicle``, one sweep): attitude RMSE at most
    #: 0.26 deg against 0.33 for any vehicle (the hover's bias-as-tilt), rectified better than traditional
    #: on 19 of 20 against 16. With a tilt error of a few hundredths of a degree, the VO's two corrections
    #: above only add their noise: off.
    STILL_AIR_MULTIROTOR = "still_air_multirotor"


def vehicle_settings(vehicle: Vehicle) -> dict[str, Any]:
    """The :class:`CouplingSettings` fields ``vehicle`` sets (empty for :attr:`Vehicle.ANY`)."""
    if vehicle is Vehicle.STILL_AIR_MULTIROTOR:
        return {
            "thrust_axis_interval_s": STILL_AIR_THRUST_AXIS_INTERVAL_S,
            "vision_tilt_correction": False,
            "origin_tilt_from_bias": False,
        }
    return {}


@dataclass(frozen=True)
class CouplingSettings(Bounded):
    """How the two layers are coupled."""

    #: Orthogonal rectification of each frame with the EKF's roll and pitch (False: the paper's
    #: "traditional" VO).
    rectify: bool = setting(
        True,
        help="VO on frames rectified with the filter's roll and pitch (--no-rectify: "
        "the paper's traditional VO on raw frames)",
    )
    #: Time constant (s) pulling the rectification attitude (gyro-propagated between frames) towards the
    #: EKF's; 0 rectifies with the EKF attitude of each frame as it is.
    rectification_smoothing_s: float = bounded(0.0, ge=0.0)
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
    vo_origin_delay_s: float = bounded(
        0.0, ge=0.0, le=60.0, help="seconds before the VO sets its origin (at --initial-xy)"
    )
    #: Rectified VO with a level model only: estimate the residual tilt of the rectified views (the
    #: EKF's tilt error ``d``) from the free decompositions' plane normals and remove its offset
    #: ``h * d`` from the VO position (:func:`residual_tilt_offset`); the origin's offset is zero when
    #: it was rectified with the known initial attitude, else from the latest estimate. On by default, as
    #: the thrust-axis update is off by default: with that update the filter's tilt error is about 0.03 deg
    #: and this noisier estimate made the chain worse (paper C seed 3: ATE 0.78 -> 0.51 cm without it and
    #: without ``origin_tilt_from_bias``); without it, paper C's 20 seeds need both (ATE median 1.66 cm and
    #: rectified better on 10 of 20 with both off).
    vision_tilt_correction: bool = True
    #: Forgetting time constant (s) of that estimate and the information (sum of ``|T/d|^2`` of the
    #: pairs) it needs before it is used.
    vision_tilt_window_s: float = bounded(5.0, gt=0.0)
    vision_tilt_min_information: float = bounded(1e-3, ge=0.0)
    #: Rectified VO with a level model: the altitude that scales each pair is the keyframe's times the pair's
    #: own height ratio, pulled toward the filter's altitude with this time constant (s; 0: the filter's
    #: altitude as it is, paper C), :func:`~common.estimation.vo_chain.smoothed_vo_altitude`. The filter's
    #: altitude follows the rangefinder's noise from frame to frame (0.34 % of the height RMS on the agile
    #: flight), and every pair's translation is scaled by it. Estimator seed sweep (shared host, one run
    #: each), agile seeds 0-9: RPE median 0.168 -> 0.112 %/m (10 s: 0.121), ATE median 0.45 -> 0.29 cm;
    #: paper C seeds 0-19: ATE median 0.516 -> 0.486 cm, rectified better on 19 of 20 either way.
    vo_altitude_smoothing_s: float = bounded(3.0, ge=0.0)
    #: Feed the VO yaw to the EKF (eq. 19). False leaves yaw to the gyro alone.
    visual_yaw: bool = setting(True, help="feed the VO yaw to the filter")
    #: Apply yaw samples pushed as ``Sensor.YAW`` (e.g. the yaw cluster) as a second yaw source.
    external_yaw: bool = setting(
        False,
        help="also use the measured yaw samples on capataz/uav/{uav}/yaw, each fused with the variance "
        "published with it (never below external_yaw_noise_rad)",
    )
    vo_yaw_noise_rad: float = bounded(0.005, gt=0.0)
    #: The external yaw's noise where its source published a smaller variance (or none): the floor of
    #: :func:`common.estimation.coupling.external_yaw_noise_rad`.
    external_yaw_noise_rad: float = bounded(0.02, gt=0.0)
    #: Samples are held until this much older than the newest stamp, then applied in order.
    max_lag_s: float = bounded(0.02, ge=0.0, le=1.0, help="reordering lag of the input (s)")
    max_pending: int = bounded(4096, ge=1)
    #: Altitude assumed before the first range reading, and its std.
    default_altitude_m: float = bounded(1.0, ge=0.0)
    default_altitude_std_m: float = bounded(2.0, gt=0.0)
    #: Compensate the accelerometer for the manoeuvre acceleration estimated from the VO positions (the
    #: hover model of eq. 16 alone reads the coordinated tilt of a turn as level).
    accel_compensation: bool = True
    #: Time span of the VO positions fitted (cubic in time) for that acceleration.
    accel_window_s: float = bounded(0.6, gt=0.0)
    #: After the start, skip the accelerometer for up to this long until the VO acceleration is available
    #: (0: use the hover model meanwhile, right for a start at rest; > 0 for a start in mid-manoeuvre).
    accel_wait_for_vo_s: float = bounded(0.0, ge=0.0)
    #: The attitude/altitude filter: the bias-estimating error-state EKF (default) or paper C's 5-state EKF.
    filter: EkfKind = setting(
        EkfKind.BIAS,
        help="attitude/altitude filter: bias (error-state EKF with gyro and accel biases) or paper_c (paper "
        "C's 5-state EKF)",
    )
    #: Uncertainty-aware rectification: the output position is the inverse-variance blend
    #: ``w * level + (1 - w) * free`` of two chains over the same rectified pairs: the level model's (error
    #: ``h_k d_k - h_0 d_0``, std ``sqrt((h_k s_k)^2 + (h_0 s_0)^2)`` from the filter's current tilt std
    #: ``s_k`` and the origin's ``s_0``) and the free decomposition's (the traditional path, independent of
    #: the filter's tilt; std ``free_drift_per_m`` times the path since the origin). An uncertain tilt
    #: falls back to the free chain; False always trusts the level model (paper C's rectified VO).
    uncertainty_aware: bool = True
    #: Drift of the free chain per metre travelled (1-sigma, the traditional VO's RPE on the simulator).
    free_drift_per_m: float = bounded(0.004, ge=0.0)
    #: With the bias filter: correct the VO origin's offset ``h_0 d_0`` with the tilt error its frame had,
    #: re-estimated from how much the accelerometer-bias estimate changed since (at hover a bias error
    #: ``db`` reads as a tilt error of ``db / g``). On by default (see ``vision_tilt_correction``).
    origin_tilt_from_bias: bool = True
    #: Predict with the mean of consecutive IMU samples (trapezoid) instead of the newer one (paper C's eq. 12
    #: as written, which makes the attitude lead by half a sample period times the rate).
    imu_midpoint: bool = True
    #: With the bias filter: the mean body-horizontal accelerometer reading over this span as the multirotor
    #: thrust-axis update (thrust along body z: the reading is the bias plus rotor drag), which separates
    #: the accelerometer bias from the tilt at hover, where the accelerometer alone cannot; 0 disables.
    #: Off by default: it holds for a multirotor in still air only. A vehicle that tilts without
    #: accelerating (hovering in wind, or paper A's simulated hover) breaks it: roll/pitch RMS 1.0 deg with
    #: it against 0.18 deg without on that hover's first 400 frames.
    thrust_axis_interval_s: float = bounded(0.0, ge=0.0)
    #: With the bias filter: position updates refused this many frames in a row reset its position to the
    #: visual one (as EKF2 resets a state whose aiding has been rejected for too long).
    position_reset_frames: int = 10
    #: Range updates refused this many samples in a row restart the altitude from the reading.
    range_reset_samples: int = 25
    #: Initial yaw of the EKF and of the VO, and the VO's origin (navigation frame n = world).
    initial_yaw_rad: float = bounded(0.0, help="initial yaw (rad)")
    initial_position_m: tuple[float, float] = setting(
        (0.0, 0.0), help="initial horizontal position of the VO path (m)"
    )
    #: Known initial attitude ``q_world_body`` (else roll and pitch from the first accelerometer sample).
    initial_q_world_body: tuple[float, float, float, float] | None = None


@dataclass(frozen=True)
class AttitudeOutput:
    """Filter estimate after one IMU sample, with its own uncertainty (world-frame error angles, altitude)."""

    stamp_s: float
    q_world_body: FloatArray
    pz_m: float
    attitude_covariance_world: FloatArray  # (3, 3) rad^2
    altitude_var_m2: float


@dataclass(frozen=True)
class PoseOutput:
    """Visual-odometry pose after one frame: body position (x, y from VO, z from the filter) and attitude.

    ``rectification_weight`` is the share of the level (rectified) model in the frame's translation
    (0: the free decomposition, the traditional path; nan for raw frames); ``vo_flow_px`` the median image
    flow of the pair the pose was measured with (px; nan without a pair)."""

    stamp_s: float
    p_world_body_m: FloatArray
    q_world_body: FloatArray
    attitude_covariance_world: FloatArray  # (3, 3) rad^2
    altitude_var_m2: float
    vo_yaw_rad: float
    n_inliers: int
    rectification_weight: float
    ok: bool
    vo_flow_px: float = math.nan


Output = AttitudeOutput | PoseOutput
