"""The estimator's output messages: one attitude per IMU step, one VO pose per frame, each with its own
uncertainty, and the horizontal uncertainty of the VO path (which grows for good where the chain broke)."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from common.estimation.coupling_types import AttitudeOutput, PoseOutput
from common.types import FloatArray
from common.wire.messages import AttitudeEstimate, PoseEstimate
from common.wire.schema import WireModel

#: the floor of the horizontal variance (m^2)
MIN_VAR_XY_M2 = 1e-6
#: 1-sigma error of a VO pair wider than the service's ``max_pair_s``, as a share of its displacement: every
#: 8th frame of paper C's flight (125 pairs of about 12 cm, 0.4 s apart) ended 26 cm off
WIDE_PAIR_FRACTION = 0.2


@dataclass(frozen=True)
class VoPath:
    """What the service knows of the VO path for its uncertainty: the last pose, the distance travelled
    (the nominal drift grows with it), the speed of the last good pair and the variance of the motion the
    VO did not see (pairs that failed: the chain restarted at the previous pose)."""

    last_xy_m: FloatArray | None = None
    last_stamp_s: float = math.nan
    travelled_m: float = 0.0
    speed_m_s: float = 0.0
    unseen_var_m2: float = 0.0


def advance_path(path: VoPath, out: PoseOutput, max_pair_s: float = math.inf) -> VoPath:
    """The path after the pose ``out``. A failed pair (``out.ok`` False) adds the variance of the motion it
    missed, ``(v dt)^2`` with ``v`` the speed of the last good pair and ``dt`` since the previous frame; a
    pair wider than ``max_pair_s`` adds ``(WIDE_PAIR_FRACTION * step)^2``."""
    xy = np.asarray(out.p_world_body_m[:2], dtype=np.float64)
    if path.last_xy_m is None:
        return VoPath(xy, out.stamp_s)
    dt_s = out.stamp_s - path.last_stamp_s
    step_m = float(np.linalg.norm(xy - path.last_xy_m))
    if not out.ok:
        unseen = path.unseen_var_m2 + (path.speed_m_s * dt_s) ** 2
        return VoPath(xy, out.stamp_s, path.travelled_m + step_m, path.speed_m_s, unseen)
    speed = step_m / dt_s if dt_s > 0.0 else path.speed_m_s
    unseen = path.unseen_var_m2 + ((WIDE_PAIR_FRACTION * step_m) ** 2 if dt_s > max_pair_s else 0.0)
    return VoPath(xy, out.stamp_s, path.travelled_m + step_m, speed, unseen)


def horizontal_variance(path: VoPath, drift_fraction: float) -> float:
    """Variance (m^2) of x and y: the nominal drift over the distance travelled and the unseen motion."""
    return (drift_fraction * path.travelled_m) ** 2 + path.unseen_var_m2 + MIN_VAR_XY_M2


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
    """The ``pose/vo`` message of one frame (the filter's altitude and attitude covariance at that frame).
    A frame whose pair failed is ``lost``: its position is the previous one, not a measurement."""
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
        tracking_state="tracking" if out.ok else "lost",
    )


class Publication:
    """What the service publishes of the estimator's outputs: each numbered, each pose with the VO path's
    horizontal uncertainty (advanced pose by pose)."""

    def __init__(self, uav: str, max_pair_s: float, drift_fraction: float) -> None:
        self.uav = uav
        self.max_pair_s = max_pair_s
        self.drift_fraction = drift_fraction
        self.attitude_seq = 0
        self.pose_seq = 0
        self.path = VoPath()

    def publish(
        self,
        outputs: list[AttitudeOutput | PoseOutput],
        put: Callable[[Any, WireModel], bool],
        attitude_pub: Any,
        pose_pub: Any,
        tap: Any = None,
    ) -> dict[str, int]:
        """Put each output's message (``put(publisher, message)``: False when the service is stopping, which
        ends the batch), written to ``tap`` when given; the counts of ``attitudes_out`` and ``poses_out``."""
        counts: dict[str, int] = {}
        for out in outputs:
            msg: AttitudeEstimate | PoseEstimate
            if isinstance(out, AttitudeOutput):
                # each output with its own uncertainty, not the batch's last state's (issue 9 section 5)
                msg = attitude_message(self.uav, self.attitude_seq, out)
                self.attitude_seq += 1
                publisher, counter = attitude_pub, "attitudes_out"
            else:
                self.path = advance_path(self.path, out, self.max_pair_s)
                msg = pose_message(
                    self.uav, self.pose_seq, out, horizontal_variance(self.path, self.drift_fraction)
                )
                self.pose_seq += 1
                publisher, counter = pose_pub, "poses_out"
            if not put(publisher, msg):
                break  # shutting down: the session is closing under us
            if tap is not None:
                tap.write(msg)
            counts[counter] = counts.get(counter, 0) + 1
        return counts
