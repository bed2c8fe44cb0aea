"""The estimator's output messages: one attitude per IMU step, one VO pose per frame, each with its own
uncertainty."""

from __future__ import annotations

import numpy as np

from common.estimation.coupling_types import AttitudeOutput, PoseOutput
from common.messages import AttitudeEstimate, PoseEstimate


def attitude_message(uav: str, seq: int, out: AttitudeOutput) -> AttitudeEstimate:
    """The ``attitude`` message of one filter output, with that output's own covariance."""
    return AttitudeEstimate(
        uav=uav,
        seq=seq,
        stamp_s=out.stamp_s,
        q_world_body=out.q_world_body.copy(),
        covariance=out.attitude_covariance_world.copy(),
    )


def pose_message(uav: str, seq: int, out: PoseOutput, var_xy: float) -> PoseEstimate:
    """The ``pose/vo`` message of one frame (the filter's altitude and attitude covariance at that frame)."""
    cov = np.zeros((6, 6))
    cov[0, 0] = cov[1, 1] = var_xy
    cov[2, 2] = out.altitude_var_m2
    cov[3:, 3:] = out.attitude_covariance_world
    return PoseEstimate(
        uav=uav,
        seq=seq,
        stamp_s=out.stamp_s,
        p_world_body_m=out.p_world_body_m.copy(),
        q_world_body=out.q_world_body.copy(),
        covariance=cov,
        source="vo",
    )
