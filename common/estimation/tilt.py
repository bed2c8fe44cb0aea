"""Explicit-state pieces of paper C's coupling: the vision tilt of rectified views and the manoeuvre
acceleration.

- :class:`VisionTilt`: the residual tilt of rectified views (the EKF's tilt error), an information-weighted,
  exponentially forgetting mean of the free decompositions' plane normals, and the horizontal offset
  ``h * d`` it causes (:func:`residual_tilt_offset`).
- :class:`VoOrigin`: the VO origin frame and its axis offset ``h_0 d_0``, re-estimated from the accelerometer
  bias; :func:`level_share`: the weight of the level chain in the uncertainty-aware output.
- :class:`AccelWindow`: the body-horizontal accelerometer readings averaged for the bias filter's multirotor
  thrust-axis update.
- :class:`ManoeuvreTrack`: the recent VO positions and the acceleration of a cubic fit to them
  (:func:`motion_acceleration`), which compensates the accelerometer model of eq. 16 in turns.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from common.geometry import matrix_from_euler
from common.types import FloatArray


def residual_tilt_offset(R_n_camera: FloatArray, altitude_m: float, normal_xy: FloatArray) -> FloatArray:
    """Horizontal offset ``(2,)`` (navigation frame) of the ground point on a rectified camera's optical axis
    from the point below it, when the rectified view is in fact tilted so that the ground normal is
    ``(nx, ny, ~1)`` in its frame: ``R_n_camera (-h nx, -h ny, 0)``. A VO chain of such views tracks
    that ground point instead of the camera."""
    n = np.asarray(normal_xy, dtype=np.float64)
    offset_cam = np.array([-altitude_m * n[0], -altitude_m * n[1], 0.0])
    return np.asarray((R_n_camera @ offset_cam)[:2], dtype=np.float64)


@dataclass(frozen=True)
class VisionTilt:
    """Forgetting, information-weighted sum of the free normals' ``(nx, ny)`` (weight ``|T/d|^2``)."""

    weighted_sum: tuple[float, float] = (0.0, 0.0)
    information: float = 0.0
    stamp_s: float = math.nan
    informed: bool = False

    def updated(
        self,
        stamp_s: float,
        t_over_d_free: FloatArray,
        normal_free: FloatArray,
        window_s: float,
        min_information: float,
    ) -> VisionTilt:
        """Add one pair (a pair says more about the normal the more it translates)."""
        n = np.asarray(normal_free, dtype=np.float64).reshape(3)
        n = n / n[2]
        weight = float(np.sum(np.asarray(t_over_d_free, dtype=np.float64)[:2] ** 2))
        sx, sy = self.weighted_sum
        info = self.information
        if math.isfinite(self.stamp_s):
            forget = math.exp(-(stamp_s - self.stamp_s) / window_s)
            sx, sy, info = sx * forget, sy * forget, info * forget
        info += weight
        return VisionTilt(
            (sx + weight * float(n[0]), sy + weight * float(n[1])),
            info,
            float(stamp_s),
            self.informed or info >= min_information,
        )

    def normal_xy(self) -> FloatArray | None:
        """Estimated ground normal ``(nx, ny)`` in the rectified camera (None until informed enough)."""
        if not self.informed or self.information <= 0.0:
            return None
        return np.asarray(self.weighted_sum, dtype=np.float64) / self.information


#: positions the cubic fit of :func:`motion_acceleration` needs
MIN_TRACK_SAMPLES = 5


def motion_acceleration(stamps_s: npt.ArrayLike, positions_m: npt.ArrayLike) -> FloatArray:
    """Acceleration at the last stamp of a cubic fit in time to positions ``(N, D)`` (N >= 5), else zeros."""
    t = np.asarray(stamps_s, dtype=np.float64)
    p = np.asarray(positions_m, dtype=np.float64)
    if len(t) < MIN_TRACK_SAMPLES:
        return np.zeros(p.shape[1] if p.ndim == 2 else 3)
    tau = t - t[-1]
    scale = max(float(-tau[0]), 1e-6)
    x = tau / scale
    A = np.stack([np.ones_like(x), x, x * x, x * x * x], axis=1)
    coeffs, *_ = np.linalg.lstsq(A, p, rcond=None)
    return np.asarray(2.0 * coeffs[2] / (scale * scale), dtype=np.float64)


@dataclass(frozen=True)
class ManoeuvreTrack:
    """The VO's horizontal positions over the last ``window_s`` and the acceleration they give."""

    samples: tuple[tuple[float, float, float], ...] = ()
    accel_world_m_s2: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def updated(self, stamp_s: float, x_m: float, y_m: float, window_s: float) -> ManoeuvreTrack:
        """The track with one more position: those of the last ``window_s``, but at least the last
        :data:`MIN_TRACK_SAMPLES` (sparse frames, e.g. a busy host's, would leave the fit too few and
        the turn's acceleration at zero)."""
        samples = (*self.samples, (stamp_s, x_m, y_m))
        recent = sum(1 for s in samples if s[0] >= stamp_s - window_s)
        kept = samples[-max(recent, MIN_TRACK_SAMPLES) :]
        track = np.array(kept)
        ax, ay = motion_acceleration(track[:, 0], track[:, 1:])
        return ManoeuvreTrack(kept, (float(ax), float(ay), 0.0))

    def cleared(self) -> ManoeuvreTrack:
        """After a VO failure: no track, the last acceleration kept until a new one is fitted."""
        return ManoeuvreTrack((), self.accel_world_m_s2)

    @property
    def fitted(self) -> bool:
        return len(self.samples) >= MIN_TRACK_SAMPLES


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
class VoOrigin:
    """The VO origin frame: its rectified camera, altitude, the attitude it was rectified with and the
    accelerometer-bias estimate then (for the later re-estimate of its tilt error)."""

    R_n_camera: FloatArray
    altitude_m: float
    yaw_rad: float
    roll_pitch_rad: tuple[float, float]
    accel_bias_m_s2: FloatArray | None
    at_known_attitude: bool
    tilt_std_rad: float

    def tilt_from_bias(self, accel_bias_now_m_s2: FloatArray, gravity_m_s2: float) -> tuple[float, float]:
        """The origin frame's roll and pitch re-estimated with today's accelerometer bias: at hover a bias
        error ``db`` (body) read as a tilt error of ``(db_y, -db_x) / g``."""
        assert self.accel_bias_m_s2 is not None
        db = np.asarray(accel_bias_now_m_s2, dtype=np.float64) - self.accel_bias_m_s2
        roll, pitch = self.roll_pitch_rad
        return roll - float(db[1]) / gravity_m_s2, pitch + float(db[0]) / gravity_m_s2

    def offset_from_bias(self, accel_bias_now_m_s2: FloatArray, gravity_m_s2: float) -> FloatArray:
        """The origin frame's axis offset ``h_0 d_0`` with its tilt error re-estimated from the bias."""
        true_rp = self.tilt_from_bias(accel_bias_now_m_s2, gravity_m_s2)
        return rectified_axis_offset(self.yaw_rad, self.roll_pitch_rad, true_rp, self.altitude_m)


def level_share(
    altitude_m: float,
    tilt_std_now_rad: float,
    origin_altitude_m: float,
    origin_tilt_std_rad: float,
    free_drift_per_m: float,
    free_path_m: float,
    disagreement_m2: float = 0.0,
) -> float:
    """Share of the level chain in the uncertainty-aware output, ``var_free / (var_free + var_level)``:
    the level chain's error ``h_k d_k - h_0 d_0`` against the free chain's drift over its path. A squared
    distance between the chains beyond ``var_free + var_level`` raises ``var_level`` to explain it
    (``var_level >= disagreement - var_free``): evidence that the tilt std is too optimistic."""
    var_level = (altitude_m * tilt_std_now_rad) ** 2 + (origin_altitude_m * origin_tilt_std_rad) ** 2
    var_free = (free_drift_per_m * free_path_m) ** 2
    var_level = max(var_level, disagreement_m2 - var_free)
    if var_free + var_level <= 0.0:
        return 1.0
    return var_free / (var_free + var_level)


@dataclass(frozen=True)
class AccelWindow:
    """Body-horizontal accelerometer readings since ``first_stamp_s``: their sum and count."""

    sum_xy_m_s2: tuple[float, float] = (0.0, 0.0)
    n_samples: int = 0
    first_stamp_s: float = math.nan

    def added(self, stamp_s: float, accel_m_s2: FloatArray) -> AccelWindow:
        sx, sy = self.sum_xy_m_s2
        first = stamp_s if self.n_samples == 0 else self.first_stamp_s
        return AccelWindow((sx + float(accel_m_s2[0]), sy + float(accel_m_s2[1])), self.n_samples + 1, first)

    def spans(self, stamp_s: float, interval_s: float) -> bool:
        """Whether the readings cover ``interval_s`` up to ``stamp_s``."""
        return self.n_samples > 0 and stamp_s - self.first_stamp_s >= interval_s - 1e-9

    def mean_xy_m_s2(self) -> FloatArray:
        return np.asarray(self.sum_xy_m_s2, dtype=np.float64) / max(self.n_samples, 1)
