"""The estimator's output messages: one attitude per IMU step, one VO pose per frame, each with its own
uncertainty, and the horizontal uncertainty of the VO path (which grows for good where the chain broke).

What is published is not the filter's covariance as it is (:class:`PublishedUncertainty`, issue 26); each
output's estimate is left as it is:

- Tilt: the filter's noise settings are tuned for its estimate, several times the sensors' (gyro 0.01 rad/s
  per sample against the simulated IMU's 0.0017; the hover model's 0.5 m/s^2 against 0.08). A Kalman filter
  whose process and measurement noises are all ``1/alpha`` times the true ones has the same gain and
  ``1/alpha`` times the true error covariance (the Riccati recursion is linear in a common scale of P0, Q and
  R; the gain depends on their ratios only): the tilt block is published times ``alpha`` (fit 0.0882; the
  settings' ratio to the IMU's alone gives about 0.03, the rest is what the model leaves out, such as the
  manoeuvre the accelerometer is compensated for).
- Yaw: the filter takes the VO yaw as independent measurements, but it is a chain with an offset of its
  own: paper C's flight gains 0.1-0.2 deg where its manoeuvre starts and stops (0.05 deg claimed). There
  the ground moves a fraction of a pixel between frames, and the VO's tracker over-reads such motion by up
  to 14 % (:data:`common.estimation.vo.SUBPIXEL_OVER_READ`, ``capataz bench flow``); from half a pixel it
  reads true, so a fast turn adds nothing. The published yaw variance adds
  ``(over_read_scale * sum over the pairs of over_read(flow) |turn|)^2``, the over-reads adding up
  along the chain (they share a sign), plus a floor and ``(drift_per_rad * turned)^2`` (both fit to 0
  beside it). One fit over both flights: the agile flight, which turns ten radians at speed, is no longer
  published with paper C's drift per radian.
- Position: each VO pair adds a small error in proportion to the camera height it was measured at (a pixel
  is ``h / f`` metres), and the pairs' errors add up along the chain: the horizontal std grows as
  ``drift_per_pair * sum of h``. The errors of paper C's and the agile flight follow it, not the distance
  travelled (the agile flight goes 2.6 times as far at half the height with smaller errors). The rectified
  VO's offset ``h_k d_k - h_0 d_0`` (the camera height times the filter's tilt error,
  :mod:`common.estimation.tilt`) can be added at the published tilt std (``level_tilt_factor``; the fit
  gives 0). The altitude's variance is scaled as the tilt's is.

The constants were fit on seeds 0-9 of paper C's and the agile flight (the altitude on 400 frames; the
horizontal drift, the tilt and the yaw on the whole flights: ``capataz bench consistency --fit-drift`` and
``--fit-attitude``) and are reported on seeds 10-19 (``capataz bench consistency --suites estimator``,
:mod:`services.tools.bench.consistency`).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from common.estimation.coupling_types import AttitudeOutput, PoseOutput
from common.estimation.filters import tilt_std_rad
from common.estimation.vo import subpixel_over_read
from common.geometry import wrap_angle_rad
from common.types import FloatArray
from common.wire.messages import AttitudeEstimate, PoseEstimate
from common.wire.schema import WireModel


@dataclass(frozen=True)
class YawChainUncertainty:
    """What the VO yaw chain adds to the filter's yaw variance (the module's text): ``floor_rad2 +
    (drift_per_rad * turned)^2 + (over_read_scale * over_read)^2``. Fit by maximum likelihood on both whole
    flights of seeds 0-9 together (``capataz bench consistency --fit-attitude --seeds 20``)."""

    #: 1-sigma error per radian turned (fit: 0 beside ``over_read_scale``; it was 2.35e-4 without it, fit on
    #: paper C's flight alone, which published the agile flight's yaw cautious, mean NEES 0.12 on seeds
    #: 10-19)
    drift_per_rad: float = 0.0
    #: the floor (rad^2; fit: 0 beside ``over_read_scale``; it was 2.24e-6, a std of 0.086 deg)
    floor_rad2: float = 0.0
    #: the std per radian of the over-read turn ``sum over pairs of over_read(flow) |turn|``
    #: (:func:`common.estimation.vo.subpixel_over_read`): the share of the tracker's over-read that reaches
    #: the filter's yaw (fit: 0.6, with the drift and the floor 0; seeds 0-4 alone 0.52, seeds 5-9 0.67)
    over_read_scale: float = 0.6


@dataclass(frozen=True)
class PublishedUncertainty:
    """How the filter's and the VO path's uncertainties become the published ones (see the module's text).
    Fit on seeds 0-9 (the altitude: ``capataz bench consistency --suites estimator --seeds 20
    --estimator-frames 400``; the horizontal drift and floor: ``capataz bench consistency --fit-drift --seeds
    20``; the tilt and the yaw: ``--fit-attitude --seeds 20``); :data:`AS_FILTERED` publishes the filter's
    covariance as it is."""

    #: nominal horizontal drift of the VO as a fraction of the distance travelled (fit: 0 beside
    #: ``drift_per_pair``; it was 0.0002, which left paper C's position overconfident, mean NEES 3.9 of 2 on
    #: the fit seeds' whole flights, and the agile flight's, with 2.6 times the distance, cautious, 0.8)
    drift_fraction: float = 0.0
    #: 1-sigma horizontal error each VO pair adds, per metre of camera height: the pairs' errors add up
    #: (``(drift_per_pair * sum of h)^2``, a bias over the chain, not a random walk). The errors of the two
    #: flights grow with the pairs chained and the height flown, not with the distance (fit by maximum
    #: likelihood on the whole flights of seeds 0-9 with ``MIN_VAR_XY_M2``: mean NEES of x, y 2.09 and 1.90
    #: of 2; fit on seeds 0-4, seeds 5-9 gave 2.04 and 1.73, and the reverse 2.19 and 2.14)
    drift_per_pair: float = 1.84e-6
    #: ``alpha``: the published tilt (world x, y) block is the filter's times this (fit by maximum
    #: likelihood on both whole flights, seeds 0-9: 0.0882, a std 0.30 times the filter's; the noise
    #: settings' ratio to the simulated IMU's alone gives about 0.03; it was 0.06, fit on 400 frames)
    tilt_variance_scale: float = 0.0882
    #: the yaw chain's terms (:class:`YawChainUncertainty`)
    yaw: YawChainUncertainty = YawChainUncertainty()
    #: the published altitude variance is the filter's times this (fit: 0.55, the fit seeds' altitude
    #: mean NEES; its altitude random walk is tuned above what the rangefinder's noise leaves)
    altitude_variance_scale: float = 0.55
    #: the level chain's offset ``h_k d_k - h_0 d_0``: its variance is this times ``(h_k s_k)^2`` with
    #: ``s_k`` the published tilt std (2 for the current and the origin's term, each at the current std,
    #: was the default; the fit with ``drift_per_pair`` gives 0: the tilt errors of the two ends are
    #: correlated, and the rest is in ``MIN_VAR_XY_M2``)
    level_tilt_factor: float = 0.0


#: the filter's covariances as they are (the published ones before issue 26)
AS_FILTERED = PublishedUncertainty(
    drift_fraction=0.001,
    drift_per_pair=0.0,
    tilt_variance_scale=1.0,
    yaw=YawChainUncertainty(drift_per_rad=0.0, floor_rad2=0.0, over_read_scale=0.0),
    altitude_variance_scale=1.0,
    level_tilt_factor=0.0,
)
#: the floor of the horizontal variance (m^2; fit with ``drift_per_pair``: 1.3e-6, a std of 1.1 mm)
MIN_VAR_XY_M2 = 1.3e-6
#: 1-sigma error of a VO pair wider than the service's ``max_pair_s``, as a share of its displacement: every
#: 8th frame of paper C's flight (125 pairs of about 12 cm, 0.4 s apart) ended 26 cm off
WIDE_PAIR_FRACTION = 0.2


@dataclass(frozen=True)
class VoPath:
    """What the service knows of the VO path for its uncertainty: the last pose, the distance travelled
    (the nominal drift grows with it), the speed of the last good pair, the variance of the motion the
    VO did not see (pairs that failed: the chain restarted at the previous pose), and the VO yaw's last value,
    the angle turned and the part of it the tracker over-read (the yaw chain's error grows with them)."""

    last_xy_m: FloatArray | None = None
    last_stamp_s: float = math.nan
    travelled_m: float = 0.0
    speed_m_s: float = 0.0
    unseen_var_m2: float = 0.0
    last_vo_yaw_rad: float = math.nan
    turned_rad: float = 0.0
    #: ``sum over the pairs of over_read(flow) |turn|`` (rad; :func:`common.estimation.vo.subpixel_over_read`)
    over_read_rad: float = 0.0
    #: the camera heights of the measured pairs, summed (m; the per-pair drift grows with it)
    height_sum_m: float = 0.0


def _turned(path: VoPath, out: PoseOutput) -> tuple[float, float, float]:
    """The VO yaw after ``out``, the angle turned up to it and the part of it over-read (a non-finite yaw
    keeps all three)."""
    yaw = float(out.vo_yaw_rad)
    if not math.isfinite(yaw):
        return path.last_vo_yaw_rad, path.turned_rad, path.over_read_rad
    if not math.isfinite(path.last_vo_yaw_rad):
        return yaw, path.turned_rad, path.over_read_rad
    turn = abs(float(wrap_angle_rad(yaw - path.last_vo_yaw_rad)))
    over_read = subpixel_over_read(float(out.vo_flow_px)) * turn
    return yaw, path.turned_rad + turn, path.over_read_rad + over_read


def advance_path(path: VoPath, out: PoseOutput, max_pair_s: float = math.inf) -> VoPath:
    """The path after the pose ``out``. A failed pair (``out.ok`` False) adds the variance of the motion it
    missed, ``(v dt)^2`` with ``v`` the speed of the last good pair and ``dt`` since the previous frame; a
    pair wider than ``max_pair_s`` adds ``(WIDE_PAIR_FRACTION * step)^2``."""
    xy = np.asarray(out.p_world_body_m[:2], dtype=np.float64)
    yaw, turned, over_read = _turned(path, out)
    if path.last_xy_m is None:
        return VoPath(xy, out.stamp_s, last_vo_yaw_rad=yaw, turned_rad=turned, over_read_rad=over_read)
    dt_s = out.stamp_s - path.last_stamp_s
    step_m = float(np.linalg.norm(xy - path.last_xy_m))
    moved = replace(path, last_xy_m=xy, last_stamp_s=out.stamp_s, travelled_m=path.travelled_m + step_m,
                    last_vo_yaw_rad=yaw, turned_rad=turned, over_read_rad=over_read)  # fmt: skip
    if not out.ok:
        return replace(moved, unseen_var_m2=path.unseen_var_m2 + (path.speed_m_s * dt_s) ** 2)
    return replace(
        moved,
        speed_m_s=step_m / dt_s if dt_s > 0.0 else path.speed_m_s,
        unseen_var_m2=path.unseen_var_m2 + ((WIDE_PAIR_FRACTION * step_m) ** 2 if dt_s > max_pair_s else 0.0),
        height_sum_m=path.height_sum_m + abs(float(out.p_world_body_m[2])),
    )


def horizontal_variance(path: VoPath, model: PublishedUncertainty) -> float:
    """Variance (m^2) of x and y: the nominal drift over the distance travelled, the pairs' drift over the
    heights they were measured at, the unseen motion and the floor."""
    drift_m = model.drift_fraction * path.travelled_m
    pairs_m = model.drift_per_pair * path.height_sum_m
    return drift_m**2 + pairs_m**2 + path.unseen_var_m2 + MIN_VAR_XY_M2


def published_attitude_covariance(
    covariance_world: FloatArray, turned_rad: float, model: PublishedUncertainty, over_read_rad: float = 0.0
) -> FloatArray:
    """The published world-frame attitude covariance: the filter's with its tilt block (and the tilt's
    correlations) scaled by ``tilt_variance_scale``, and the yaw chain's floor, drift over ``turned_rad`` and
    over-read turn ``over_read_rad`` added."""
    root = math.sqrt(model.tilt_variance_scale)
    D = np.diag([root, root, 1.0])
    published = D @ np.asarray(covariance_world, dtype=np.float64) @ D
    published[2, 2] += (
        model.yaw.floor_rad2
        + (model.yaw.drift_per_rad * turned_rad) ** 2
        + (model.yaw.over_read_scale * over_read_rad) ** 2
    )
    return published


def attitude_message(
    uav: str, seq: int, out: AttitudeOutput, covariance_world: FloatArray | None = None
) -> AttitudeEstimate:
    """The ``attitude`` message of one filter output, with that output's own covariance (as published:
    ``covariance_world``; None: the filter's as it is)."""
    covariance = out.attitude_covariance_world if covariance_world is None else covariance_world
    return AttitudeEstimate(
        uav=uav,
        seq=seq,
        stamp_s=out.stamp_s,
        q_world_body=out.q_world_body.copy(),
        covariance=np.array(covariance, dtype=np.float64),
    )


def pose_message(
    uav: str,
    seq: int,
    out: PoseOutput,
    var_xy: float,
    model: PublishedUncertainty | None = None,
    turned_rad: float = 0.0,
    over_read_rad: float = 0.0,
) -> PoseEstimate:
    """The ``pose/vo`` message of one frame: ``var_xy`` (the VO path's, :func:`horizontal_variance`) plus
    the level chain's tilt offset, the filter's altitude and attitude covariance at that frame, each as
    ``model`` publishes them (None: :class:`PublishedUncertainty`'s defaults). A frame whose pair failed
    is ``lost``: its position is the previous one, not a measurement."""
    m = model or PublishedUncertainty()
    attitude = published_attitude_covariance(out.attitude_covariance_world, turned_rad, m, over_read_rad)
    height_m = abs(float(out.p_world_body_m[2]))
    level_var = m.level_tilt_factor * (height_m * tilt_std_rad(attitude)) ** 2
    cov = np.zeros((6, 6))
    cov[0, 0] = cov[1, 1] = var_xy + level_var
    cov[2, 2] = m.altitude_variance_scale * out.altitude_var_m2
    cov[3:, 3:] = attitude
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

    def __init__(self, uav: str, max_pair_s: float, model: PublishedUncertainty) -> None:
        self.uav = uav
        self.max_pair_s = max_pair_s
        self.model = model
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
                covariance = published_attitude_covariance(
                    out.attitude_covariance_world, self.path.turned_rad, self.model, self.path.over_read_rad
                )
                msg = attitude_message(self.uav, self.attitude_seq, out, covariance)
                self.attitude_seq += 1
                publisher, counter = attitude_pub, "attitudes_out"
            else:
                self.path = advance_path(self.path, out, self.max_pair_s)
                var_xy = horizontal_variance(self.path, self.model)
                msg = pose_message(
                    self.uav,
                    self.pose_seq,
                    out,
                    var_xy,
                    self.model,
                    self.path.turned_rad,
                    self.path.over_read_rad,
                )
                self.pose_seq += 1
                publisher, counter = pose_pub, "poses_out"
            if not put(publisher, msg):
                break  # shutting down: the session is closing under us
            if tap is not None:
                tap.write(msg)
            counts[counter] = counts.get(counter, 0) + 1
        return counts
