"""Replay a flight through the estimator: the standard configurations, their outputs and their errors.

The stream itself, a flight's samples in stamp order, is the simulation's
(``common.sim.stream.flight_measurements``); the cores never import the simulator. Shared by the tests,
``capataz bench estimator`` and the demo.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from common.camera import CameraModel
from common.estimation.coupling import DoubleCouplingEstimator
from common.estimation.coupling_types import (
    AttitudeOutput,
    CouplingSettings,
    EkfKind,
    PoseOutput,
    ScaleSource,
    Vehicle,
    vehicle_settings,
)
from common.estimation.measurements import Measurement
from common.estimation.vo import MotionModel, VoPose, VoSettings
from common.estimation.vo_chain import (
    VoChainSettings,
    VoChainState,
    advance_vo_chain,
    prepare_view,
    start_vo_chain,
)
from common.geometry import R_BODY_CAMERA_DOWN, euler_from_quaternion, matrix_from_euler, wrap_angle_rad
from common.metrics import ate_rmse_m, rpe_along_cross, rpe_translation
from common.types import FloatArray, U8Array


class ImuSeriesLike(Protocol):
    """IMU samples with their truth (a recorded or simulated series)."""

    @property
    def stamps_s(self) -> FloatArray: ...
    @property
    def gyro_rad_s(self) -> FloatArray: ...
    @property
    def accel_m_s2(self) -> FloatArray: ...
    @property
    def true_q_world_body(self) -> FloatArray: ...
    @property
    def true_p_world_body_m(self) -> FloatArray: ...
    @property
    def R_body_imu(self) -> FloatArray: ...
    @property
    def time_offset_s(self) -> float: ...


class RangeSeriesLike(Protocol):
    """Rangefinder samples."""

    @property
    def stamps_s(self) -> FloatArray: ...
    @property
    def range_m(self) -> FloatArray: ...


class FlightRecord(Protocol):
    """What a replay needs of a flight with ground truth (``common.sim.flight.Flight`` is one): the sensor
    series, frames on demand, and the true pose at the frame stamps. The cores never import the simulator."""

    @property
    def camera(self) -> CameraModel: ...
    @property
    def R_body_camera(self) -> FloatArray: ...
    @property
    def frame_stamps_s(self) -> FloatArray: ...
    @property
    def p_world_body_m(self) -> FloatArray: ...
    @property
    def q_world_body(self) -> FloatArray: ...
    @property
    def euler_rad(self) -> FloatArray: ...
    @property
    def R_world_body(self) -> FloatArray: ...
    @property
    def imu(self) -> ImuSeriesLike: ...
    @property
    def range(self) -> RangeSeriesLike: ...
    @property
    def n_frames(self) -> int: ...
    @property
    def yaw_rad(self) -> FloatArray: ...
    def frame(self, i: int) -> U8Array: ...


def camera_model_of(flight: FlightRecord) -> CameraModel:
    """The flight's camera model (intrinsics; the mount is ``flight.R_body_camera``)."""
    return flight.camera


@dataclass(frozen=True)
class EstimatorRun:
    """Outputs of one run, as arrays."""

    attitude_stamps_s: FloatArray
    q_world_body: FloatArray  # (M, 4)
    pz_m: FloatArray
    pose_stamps_s: FloatArray
    p_world_body_m: FloatArray  # (N, 3)
    vo_yaw_rad: FloatArray
    rectification_weight: FloatArray


def collect(outputs: list[AttitudeOutput | PoseOutput]) -> EstimatorRun:
    """Stack the outputs of an estimator into arrays."""
    att = [o for o in outputs if isinstance(o, AttitudeOutput)]
    pos = [o for o in outputs if isinstance(o, PoseOutput)]
    return EstimatorRun(
        attitude_stamps_s=np.array([o.stamp_s for o in att]),
        q_world_body=np.array([o.q_world_body for o in att]).reshape(-1, 4),
        pz_m=np.array([o.pz_m for o in att]),
        pose_stamps_s=np.array([o.stamp_s for o in pos]),
        p_world_body_m=np.array([o.p_world_body_m for o in pos]).reshape(-1, 3),
        vo_yaw_rad=np.array([o.vo_yaw_rad for o in pos]),
        rectification_weight=np.array([o.rectification_weight for o in pos]),
    )


def run_estimators(
    estimators: dict[str, DoubleCouplingEstimator], measurements: Iterator[Measurement]
) -> dict[str, EstimatorRun]:
    """Feed the same stream to several estimators (frames are rendered once) and collect their outputs."""
    outputs: dict[str, list[AttitudeOutput | PoseOutput]] = {name: [] for name in estimators}
    for m in measurements:
        for name, estimator in estimators.items():
            estimator.push(m)
            outputs[name].extend(estimator.process_due())
    for name, estimator in estimators.items():
        outputs[name].extend(estimator.drain())
    return {name: collect(out) for name, out in outputs.items()}


def vo_with_true_attitude(
    flight: FlightRecord,
    start_frame: int,
    stop_frame: int,
    rectify: bool = True,
    model: MotionModel = MotionModel.LEVEL_FREE_YAW,
    settings: VoSettings | None = None,
    roll_pitch_error_rad: tuple[float, float] = (0.0, 0.0),
    chain_settings: VoChainSettings | None = None,
) -> FloatArray:
    """VO alone on frames ``[start_frame, stop_frame)`` with the TRUE roll, pitch (plus an optional constant
    error) and altitude for rectification and scale, from the true initial pose: its camera positions
    ``(N, 3)``. The diagnosis of the VO itself, free of any filter error (rectify=False: raw frames and
    the free decomposition). The same chain step as the estimator's
    (:func:`~common.estimation.vo_chain.advance_vo_chain`)."""
    vo_settings = settings or VoSettings()
    K = flight.camera.K
    euler = flight.euler_rad
    chain: VoChainState | None = None
    out = []
    for i in range(start_frame, stop_frame):
        rp = (float(euler[i, 0]) + roll_pitch_error_rad[0], float(euler[i, 1]) + roll_pitch_error_rad[1])
        frame = prepare_view(flight.frame(i), K, flight.R_body_camera, rp if rectify else None, vo_settings)
        h = float(flight.p_world_body_m[i, 2])
        if chain is None:
            R_world_body = flight.R_world_body[i] if not rectify else matrix_from_euler(0.0, 0.0, euler[i, 2])
            mount = R_BODY_CAMERA_DOWN if rectify else flight.R_body_camera
            pose = VoPose(R_n_camera=R_world_body @ mount, p_n_camera_m=flight.p_world_body_m[i].copy())
            chain = start_vo_chain(frame, pose, h)
        else:
            chain = advance_vo_chain(
                chain, frame, h, K, vo_settings, model if rectify else MotionModel.FREE, chain_settings
            ).state
        out.append(chain.pose.p_n_camera_m.copy())
    return np.asarray(out, dtype=np.float64)


@dataclass(frozen=True)
class RunErrors:
    """Errors of one run against the flight's truth."""

    att_rmse_deg: FloatArray  # (3,) roll, pitch, yaw
    att_max_deg: FloatArray  # (3,)
    alt_rmse_m: float
    vo_final_error_m: float
    vo_max_error_m: float
    path_length_m: float
    yaw_error_deg: FloatArray  # (M,) over the attitude stamps
    vo_error_m: FloatArray  # (N,) horizontal VO error over the frames
    #: ATE RMSE and RPE per metre travelled of the horizontal VO position (:mod:`common.metrics`)
    ate_rmse_m: float
    rpe_pct: float
    #: the RPE pairs' error along the true displacement (scale) and across it (heading), RMS in % of 1 m
    rpe_along_pct: float = math.nan
    rpe_cross_pct: float = math.nan

    @property
    def vo_error_pct(self) -> float:
        if self.path_length_m <= 0.0:
            return float("nan")
        return 100.0 * self.vo_final_error_m / self.path_length_m


def path_length_m(flight: FlightRecord, start_frame: int = 0, stop_frame: int | None = None) -> float:
    """Length of the true path over the frames (sum of the 3-D steps)."""
    p = flight.p_world_body_m[start_frame:stop_frame]
    return float(np.sum(np.linalg.norm(np.diff(p, axis=0), axis=1)))


def evaluate(
    run: EstimatorRun, flight: FlightRecord, start_frame: int = 0, settle_s: float = 0.0
) -> RunErrors:
    """Attitude, altitude and VO errors of ``run`` against ``flight`` (outputs at the sensors' stamps).

    Attitude and altitude errors skip the first ``settle_s`` (for runs started mid-manoeuvre).
    """
    imu = flight.imu
    keep = run.attitude_stamps_s >= run.attitude_stamps_s[0] + settle_s
    # the outputs are on the camera's clock; the IMU's truth at its samples' true times
    idx = np.searchsorted(imu.stamps_s - imu.time_offset_s, run.attitude_stamps_s[keep] - 1e-9)
    err = wrap_angle_rad(
        euler_from_quaternion(run.q_world_body[keep]) - euler_from_quaternion(imu.true_q_world_body[idx])
    )
    err_deg = np.degrees(err)
    alt_err = run.pz_m[keep] - imu.true_p_world_body_m[idx, 2]
    frames = np.searchsorted(flight.frame_stamps_s, run.pose_stamps_s - 1e-9)
    est_xy, true_xy = run.p_world_body_m[:, :2], flight.p_world_body_m[frames, :2]
    vo_err = np.linalg.norm(est_xy - true_xy, axis=1)
    split = rpe_along_cross(est_xy, true_xy, 1.0, flight.p_world_body_m[frames]) if len(frames) else None
    first = int(frames[0]) if len(frames) else start_frame
    stop = int(frames[-1]) + 1 if len(frames) else start_frame + 1
    return RunErrors(
        att_rmse_deg=np.sqrt(np.mean(err_deg**2, axis=0)),
        att_max_deg=np.max(np.abs(err_deg), axis=0),
        alt_rmse_m=float(np.sqrt(np.mean(alt_err**2))),
        vo_final_error_m=float(vo_err[-1]) if len(vo_err) else float("nan"),
        vo_max_error_m=float(vo_err.max()) if len(vo_err) else float("nan"),
        path_length_m=path_length_m(flight, first, stop),
        yaw_error_deg=err_deg[:, 2],
        vo_error_m=vo_err,
        ate_rmse_m=ate_rmse_m(est_xy, true_xy) if len(frames) else math.nan,
        rpe_pct=rpe_translation(est_xy, true_xy, 1.0, flight.p_world_body_m[frames]).mean_pct
        if len(frames)
        else math.nan,
        rpe_along_pct=split.along_rmse_pct if split is not None else math.nan,
        rpe_cross_pct=split.cross_rmse_pct if split is not None else math.nan,
    )


#: Seconds after the start at which the rectified runs set their VO origin (the EKF's tilt has settled
#: from the first accelerometer sample; flight (b) hovers for its first 5 s).
RECTIFIED_ORIGIN_DELAY_S = 4.0

#: The simulated flights are a multirotor's in still air (coordinated: thrust along body z, no wind).
SIM_VEHICLE = vehicle_settings(Vehicle.STILL_AIR_MULTIROTOR)

#: The paper's proposal (rectified frames, filter altitude as scale) with the bias-estimating filter and
#: uncertainty-aware rectification, as the service runs it by default (any vehicle).
PROPOSAL: dict[str, Any] = {
    "rectify": True,
    "visual_yaw": True,
    "vo_origin_delay_s": RECTIFIED_ORIGIN_DELAY_S,
}

#: The configurations compared: the proposal, the same with paper C's 5-state EKF, its "traditional" VO
#: (raw frames, the rangefinder reading as scale: no inertial information), raw frames with the EKF altitude
#: (only the rectification missing), and the EKF without visual yaw. The bias filter's configurations know
#: the vehicle (:data:`SIM_VEHICLE`).
CONFIGURATIONS: dict[str, dict[str, Any]] = {
    "rectified": {**PROPOSAL, **SIM_VEHICLE},
    # paper C's 5-state EKF and the level model always trusted: the reference the bias filter improves on
    "rectified_paper_c": {
        **PROPOSAL,
        "filter": EkfKind.PAPER_C,
        "uncertainty_aware": False,
        "imu_midpoint": False,
        "vision_tilt_correction": True,
        "vo_altitude_smoothing_s": 0.0,
    },
    "traditional": {"rectify": False, "visual_yaw": True, "scale_from": ScaleSource.RANGE, **SIM_VEHICLE},
    "raw_ekf_scale": {"rectify": False, "visual_yaw": True, **SIM_VEHICLE},
    "gyro_yaw": {**PROPOSAL, "visual_yaw": False, **SIM_VEHICLE},
}


#: Configurations run on request only (the seed sweep's ``--any-vehicle``): the proposal without knowing
#: the vehicle (the service's default, :attr:`Vehicle.ANY`).
ABLATIONS: dict[str, dict[str, Any]] = {"rectified_any_vehicle": PROPOSAL}

_RUNNABLE = {**CONFIGURATIONS, **ABLATIONS}


def standard_estimators(
    flight: FlightRecord, start_frame: int = 0, names: tuple[str, ...] = tuple(CONFIGURATIONS)
) -> dict[str, DoubleCouplingEstimator]:
    """Estimators of :data:`CONFIGURATIONS` (and :data:`ABLATIONS`), started at ``start_frame`` with the true
    initial yaw and the true position at their VO origin (the navigation frame n is the world frame), and the
    attitude from the first accelerometer sample (or the true attitude when starting mid-flight)."""
    q0 = flight.q_world_body[start_frame]
    out = {}
    for name in names:
        config = dict(_RUNNABLE[name])
        # started mid-flight with the true attitude, the EKF has no tilt transient to wait for
        delay_s = float(config.pop("vo_origin_delay_s", 0.0))
        delay_s = delay_s if start_frame == 0 else 0.0
        t_origin = float(flight.frame_stamps_s[start_frame]) + delay_s
        origin = min(int(np.searchsorted(flight.frame_stamps_s, t_origin - 1e-9)), flight.n_frames - 1)
        p0 = flight.p_world_body_m[origin]
        settings = CouplingSettings(
            initial_yaw_rad=float(flight.yaw_rad[start_frame]),
            initial_position_m=(float(p0[0]), float(p0[1])),
            initial_q_world_body=None
            if start_frame == 0
            else (float(q0[0]), float(q0[1]), float(q0[2]), float(q0[3])),
            accel_wait_for_vo_s=0.0 if start_frame == 0 else 1.0,
            vo_origin_delay_s=delay_s,
            **config,
        )
        out[name] = DoubleCouplingEstimator(
            flight.camera,
            flight.R_body_camera,
            settings=settings,
            R_body_imu=flight.imu.R_body_imu,
            imu_time_offset_s=flight.imu.time_offset_s,
        )
    return out
