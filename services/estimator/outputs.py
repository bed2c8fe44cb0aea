"""The estimator's output messages: one attitude per IMU step, one VO pose per frame, each with its own
uncertainty."""

from __future__ import annotations

import numpy as np

from common.estimation.coupling import AttitudeOutput, PoseOutput
from common.estimation.ekf import error_angle_covariance_world
from common.messages import AttitudeEstimate, PoseEstimate


def attitude_message(uav: str, seq: int, out: AttitudeOutput, covariance_q: np.ndarray) -> AttitudeEstimate:
    """The ``attitude`` message of one EKF output."""
    return AttitudeEstimate(
        uav=uav,
        seq=seq,
        stamp_s=out.stamp_s,
        q_world_body=out.q_world_body.copy(),
        covariance=error_angle_covariance_world(out.q_world_body, covariance_q),
    )


def pose_message(
    uav: str, seq: int, out: PoseOutput, covariance_q: np.ndarray, var_z: float, var_xy: float
) -> PoseEstimate:
    """The ``pose/vo`` message of one frame."""
    cov = np.zeros((6, 6))
    cov[0, 0] = cov[1, 1] = var_xy
    cov[2, 2] = var_z
    cov[3:, 3:] = error_angle_covariance_world(out.q_world_body, covariance_q)
    return PoseEstimate(
        uav=uav,
        seq=seq,
        stamp_s=out.stamp_s,
        p_world_body_m=out.p_world_body_m.copy(),
        q_world_body=out.q_world_body.copy(),
        covariance=cov,
        source="vo",
    )
