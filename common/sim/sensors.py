"""Simulated sensors: IMU (gyro + accelerometer), downward rangefinder, camera image degradation.

Noise defaults (realistic MEMS, InvenSense MPU-6000 class, sampled at 400 Hz; a white-noise density ``d``
sampled at rate ``f`` gives a per-sample sigma ``d sqrt(f)``):

- gyro: noise density 0.005 deg/s/sqrt(Hz) (datasheet) -> 0.1 deg/s per sample; constant bias drawn per
  axis with sigma 0.3 deg/s (a calibrated-at-power-on residual); bias random walk 0.0005 deg/s/sqrt(s).
- accelerometer: noise density 400 ug/sqrt(Hz) (datasheet) -> 0.078 m/s^2 per sample; constant bias per axis
  with sigma 0.05 m/s^2 (about 5 mg); bias random walk 0.0005 m/s^2/sqrt(s).
- rangefinder (e.g. a LIDAR-Lite / sonar class sensor at 50 Hz): white noise sigma 0.02 m.
- camera (:class:`ImageDegradation`): read noise 1.5 DN plus shot noise (2.5 DN at full scale), no blur,
  gain drifting +-3 % and offset +-3 DN with periods of about 30 and 41 s. ``ImageDegradation.clean()``
  disables everything (noise-free frames, byte-identical to :func:`common.sim.ground.render_ground_view`).

Every random draw comes from a generator seeded by ``(stream label, seed, ...)``: same seed, same bytes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import cv2
import numpy as np
import numpy.typing as npt

from common.bounds import Bounded, bounded
from common.errors import CapatazError, InputError
from common.geometry import check_rotation_matrix
from common.sim.trajectory import Trajectory
from common.types import FloatArray, U8Array

IMU_STREAM = 0x1A0
RANGE_STREAM = 0x2A0
IMAGE_STREAM = 0x3A0


def _normal_quantiles(n: int) -> npt.NDArray[np.float32]:
    """Standard normal quantiles at ``(k + 0.5) / n`` (Acklam's inverse CDF, rel. error < 1.2e-9)."""
    p = (np.arange(n, dtype=np.float64) + 0.5) / n
    a = [-3.969683028665376e01, 2.209460984245205e02, -2.759285104469687e02, 1.383577518672690e02,
         -3.066479806614716e01, 2.506628277459239e00]  # fmt: skip
    b = [-5.447609879822406e01, 1.615858368580409e02, -1.556989798598866e02, 6.680131188771972e01,
         -1.328068155288572e01]  # fmt: skip
    c = [-7.784894002430293e-03, -3.223964580411365e-01, -2.400758277161838e00, -2.549732539343734e00,
         4.374664141464968e00, 2.938163982698783e00]  # fmt: skip
    d = [7.784695709041462e-03, 3.224671290700398e-01, 2.445134137142996e00, 3.754408661907416e00]
    p_low = 0.02425
    x = np.empty(n)
    lo = p < p_low
    hi = p > 1.0 - p_low
    mid = ~(lo | hi)
    q = np.sqrt(-2.0 * np.log(p[lo]))
    x[lo] = (((((c[0] * q + c[1]) * q + c[2]) * q + c[3]) * q + c[4]) * q + c[5]) / (
        (((d[0] * q + d[1]) * q + d[2]) * q + d[3]) * q + 1.0
    )
    q = np.sqrt(-2.0 * np.log(1.0 - p[hi]))
    x[hi] = -(((((c[0] * q + c[1]) * q + c[2]) * q + c[3]) * q + c[4]) * q + c[5]) / (
        (((d[0] * q + d[1]) * q + d[2]) * q + d[3]) * q + 1.0
    )
    q = p[mid] - 0.5
    r = q * q
    x[mid] = (
        (((((a[0] * r + a[1]) * r + a[2]) * r + a[3]) * r + a[4]) * r + a[5])
        * q
        / (((((b[0] * r + b[1]) * r + b[2]) * r + b[3]) * r + b[4]) * r + 1.0)
    )
    return x.astype(np.float32)


#: Standard normal quantiles at (k + 0.5) / 256, rescaled to unit variance (tails at +-2.9 sigma): a
#: uniform random byte -> a Gaussian sample in one lookup. Plenty for image noise of a few DN, which is
#: rounded to whole DN anyway.
NORMAL_QUANTILES_8BIT = _normal_quantiles(256).astype(np.float64)
NORMAL_QUANTILES_8BIT /= NORMAL_QUANTILES_8BIT.std()
NORMAL_QUANTILES_8BIT.setflags(write=False)


class SensorError(CapatazError):
    """A sensor cannot be simulated with the given settings."""


@dataclass(frozen=True)
class ImuNoise(Bounded):
    """IMU error model: white noise densities, constant biases (per-axis draw sigma), bias random walks."""

    gyro_noise_density_rad_s_sqrt_hz: float = bounded(float(np.radians(0.005)), ge=0.0)
    gyro_bias_sigma_rad_s: float = bounded(float(np.radians(0.3)), ge=0.0)
    gyro_bias_walk_rad_s2_sqrt_hz: float = bounded(float(np.radians(0.0005)), ge=0.0)
    accel_noise_density_m_s2_sqrt_hz: float = bounded(400e-6 * 9.80665, ge=0.0)
    accel_bias_sigma_m_s2: float = bounded(0.05, ge=0.0)
    accel_bias_walk_m_s3_sqrt_hz: float = bounded(0.0005, ge=0.0)

    @classmethod
    def ideal(cls) -> ImuNoise:
        """No noise, no bias: the IMU reads the true body rate and specific force."""
        return cls(0.0, 0.0, 0.0, 0.0, 0.0, 0.0)


@dataclass(frozen=True)
class RangeNoise(Bounded):
    """Rangefinder error model: white noise sigma (m) and a constant offset (m)."""

    sigma_m: float = bounded(0.02, ge=0.0)
    offset_m: float = bounded(0.0)

    @classmethod
    def ideal(cls) -> RangeNoise:
        """Exact geometric range."""
        return cls(0.0, 0.0)


@dataclass(frozen=True, eq=False)
class ImuSeries:
    """IMU samples at their own stamps: body gyro and specific force with noise and bias, and the truth."""

    stamps_s: FloatArray  # (M,)
    gyro_rad_s: FloatArray  # (M, 3) body (FLU) angular rate, noisy + biased
    accel_m_s2: FloatArray  # (M, 3) body specific force R^T (a + g e_z), noisy + biased
    true_q_world_body: FloatArray  # (M, 4)
    true_p_world_body_m: FloatArray  # (M, 3)
    true_gyro_rad_s: FloatArray  # (M, 3)
    true_accel_m_s2: FloatArray  # (M, 3)
    gyro_bias_rad_s: FloatArray  # (M, 3) the bias actually added (IMU axes)
    accel_bias_m_s2: FloatArray  # (M, 3)
    #: the IMU's axes on the body: ``gyro_rad_s`` and ``accel_m_s2`` are in the IMU's axes,
    #: ``R_body_imu @ gyro`` is the body rate (the truth fields stay in the body's axes)
    R_body_imu: FloatArray = field(default_factory=lambda: np.eye(3))
    #: the IMU's clock against the camera's: ``stamps_s = t_cam + time_offset_s`` (Kalibr's
    #: ``timeshift_cam_imu``); the truth fields are at the true times ``stamps_s - time_offset_s``
    time_offset_s: float = 0.0

    @property
    def n_samples(self) -> int:
        return int(self.stamps_s.shape[0])

    @property
    def true_stamps_s(self) -> FloatArray:
        """The samples' times on the camera's clock (the simulation's true time)."""
        return np.asarray(self.stamps_s - self.time_offset_s, dtype=np.float64)


@dataclass(frozen=True, eq=False)
class RangeSeries:
    """Rangefinder samples along the body -z axis to the ground plane, and the truth."""

    stamps_s: FloatArray  # (K,)
    range_m: FloatArray  # (K,) noisy
    true_range_m: FloatArray  # (K,) exact geometric range
    true_pz_m: FloatArray  # (K,) true altitude of the body origin
    true_q_world_body: FloatArray  # (K, 4)

    @property
    def n_samples(self) -> int:
        return int(self.stamps_s.shape[0])


def sample_stamps(duration_s: float, rate_hz: float) -> FloatArray:
    """Stamps ``k / rate_hz`` for ``k = 0 .. floor(duration_s * rate_hz)`` (exact multiples, no drift)."""
    if not (np.isfinite(rate_hz) and rate_hz > 0.0):
        raise InputError(f"rate_hz must be positive, got {rate_hz}")
    if not (np.isfinite(duration_s) and duration_s >= 0.0):
        raise InputError(f"duration_s must be >= 0, got {duration_s}")
    n = int(np.floor(duration_s * rate_hz + 1e-9)) + 1
    return np.arange(n, dtype=np.float64) / rate_hz


def _bias_path(
    rng: np.random.Generator, n: int, dt_s: float, sigma0: float, walk_density: float
) -> FloatArray:
    """Per-axis constant bias ``N(0, sigma0)`` plus a random walk, ``walk_density sqrt(dt)`` a step."""
    draws = rng.standard_normal((n + 1, 3))
    b0 = draws[0] * sigma0
    steps = draws[1:] * (walk_density * np.sqrt(dt_s))
    steps[0] = 0.0
    return np.asarray(b0 + np.cumsum(steps, axis=0), dtype=np.float64)


def simulate_imu(
    trajectory: Trajectory,
    stamps_s: FloatArray,
    noise: ImuNoise,
    seed: int,
    R_body_imu: npt.ArrayLike | None = None,
    time_offset_s: float = 0.0,
) -> ImuSeries:
    """IMU samples at the true times ``stamps_s`` (evenly spaced): exact body rate / specific force turned
    into the IMU's axes (``R_body_imu``, default the body's) + white noise + bias, stamped on the IMU's clock
    (``stamps_s + time_offset_s``)."""
    stamps = np.asarray(stamps_s, dtype=np.float64)
    R_bi = np.eye(3) if R_body_imu is None else check_rotation_matrix(R_body_imu, "R_body_imu")
    if not math.isfinite(time_offset_s) or abs(time_offset_s) > 1.0:
        raise InputError(f"time_offset_s must be finite and within 1 s, got {time_offset_s}")
    if stamps.ndim != 1 or stamps.size < 2:
        raise InputError(f"stamps_s must be (M,) with M >= 2, got shape {stamps.shape}")
    dt = float(stamps[1] - stamps[0])
    if dt <= 0.0:
        raise InputError("stamps_s must increase")
    truth = trajectory.sample(stamps)
    # One generator per component, so a shorter series is exactly the start of a longer one.
    rngs = [np.random.default_rng([IMU_STREAM, int(seed), k]) for k in range(4)]
    n = stamps.size
    rate = 1.0 / dt
    gyro_bias = _bias_path(rngs[0], n, dt, noise.gyro_bias_sigma_rad_s, noise.gyro_bias_walk_rad_s2_sqrt_hz)
    accel_bias = _bias_path(rngs[1], n, dt, noise.accel_bias_sigma_m_s2, noise.accel_bias_walk_m_s3_sqrt_hz)
    gyro_white = rngs[2].standard_normal((n, 3)) * (noise.gyro_noise_density_rad_s_sqrt_hz * np.sqrt(rate))
    accel_white = rngs[3].standard_normal((n, 3)) * (noise.accel_noise_density_m_s2_sqrt_hz * np.sqrt(rate))
    # body vectors v into the IMU's axes: R_body_imu^T v, i.e. v @ R_body_imu for rows
    return ImuSeries(
        stamps_s=stamps + float(time_offset_s),
        gyro_rad_s=truth.omega_body_rad_s @ R_bi + gyro_bias + gyro_white,
        accel_m_s2=truth.specific_force_body_m_s2 @ R_bi + accel_bias + accel_white,
        true_q_world_body=truth.q_world_body,
        true_p_world_body_m=truth.p_world_body_m,
        true_gyro_rad_s=truth.omega_body_rad_s,
        true_accel_m_s2=truth.specific_force_body_m_s2,
        gyro_bias_rad_s=gyro_bias,
        accel_bias_m_s2=accel_bias,
        R_body_imu=R_bi,
        time_offset_s=float(time_offset_s),
    )


def ray_ground_distance(
    R_world_body: npt.ArrayLike,
    p_world_body_m: npt.ArrayLike,
    direction_body: npt.ArrayLike = (0.0, 0.0, -1.0),
    p_body_sensor_m: npt.ArrayLike = (0.0, 0.0, 0.0),
) -> FloatArray:
    """Distance (N,) along a body-fixed ray to the ground plane ``z = 0`` (ray-plane intersection).

    The ray starts at ``p_world_body + R p_body_sensor`` with world direction ``R direction_body`` (unit);
    the distance is ``-origin_z / direction_z``. Raises SensorError if a ray does not point at the ground
    or starts below it.
    """
    R = np.asarray(R_world_body, dtype=np.float64).reshape(-1, 3, 3)
    p = np.asarray(p_world_body_m, dtype=np.float64).reshape(-1, 3)
    d_body = np.asarray(direction_body, dtype=np.float64)
    d_body = d_body / np.linalg.norm(d_body)
    origin = p + R @ np.asarray(p_body_sensor_m, dtype=np.float64)
    direction = R @ d_body
    if np.any(origin[:, 2] <= 0.0):
        raise SensorError("the rangefinder is at or below the ground")
    if np.any(direction[:, 2] >= -1e-9):
        raise SensorError("the rangefinder ray does not point at the ground")
    return np.asarray(-origin[:, 2] / direction[:, 2], dtype=np.float64)


def simulate_range(trajectory: Trajectory, stamps_s: FloatArray, noise: RangeNoise, seed: int) -> RangeSeries:
    """Rangefinder along body -z at ``stamps_s``: ray-plane distance (longer when tilted) + noise."""
    stamps = np.asarray(stamps_s, dtype=np.float64)
    if stamps.ndim != 1 or stamps.size < 1:
        raise InputError(f"stamps_s must be (K,) with K >= 1, got shape {stamps.shape}")
    truth = trajectory.sample(stamps)
    true_range = ray_ground_distance(truth.R_world_body, truth.p_world_body_m)
    rng = np.random.default_rng([RANGE_STREAM, int(seed)])
    measured = true_range + noise.offset_m + rng.standard_normal(stamps.size) * noise.sigma_m
    return RangeSeries(
        stamps_s=stamps,
        range_m=measured,
        true_range_m=true_range,
        true_pz_m=truth.p_world_body_m[:, 2].copy(),
        true_q_world_body=truth.q_world_body,
    )


@dataclass(frozen=True)
class ImageDegradation(Bounded):
    """Camera effects applied to a clean render, in this order: optical blur, exposure (gain, offset), noise.

    - ``blur_sigma_px``: Gaussian blur sigma (px), 0 = none.
    - exposure: ``gain(t) = 1 + gain_amplitude sin(2 pi t / gain_period_s + phase)``,
      ``offset(t) = offset_amplitude_dn sin(2 pi t / offset_period_s + phase)`` (slow drift;
      phases from the seed).
    - noise: Gaussian with ``sigma(I) = sqrt(read_noise_dn^2 + shot_noise_dn2_per_dn * I)`` (I in DN),
      fresh for every frame (256-level quantised normal), then rounded and clipped to uint8.
    """

    read_noise_dn: float = bounded(1.5, ge=0.0)
    shot_noise_dn2_per_dn: float = bounded((2.5**2 - 1.5**2) / 255.0, ge=0.0)
    blur_sigma_px: float = bounded(0.0, ge=0.0)
    gain_amplitude: float = bounded(0.03, ge=0.0, lt=1.0)
    gain_period_s: float = bounded(30.0, gt=0.0)
    offset_amplitude_dn: float = bounded(3.0, ge=0.0)
    offset_period_s: float = bounded(41.0, gt=0.0)

    @classmethod
    def clean(cls) -> ImageDegradation:
        """No degradation at all: frames are the exact noise-free renders."""
        return cls(read_noise_dn=0.0, shot_noise_dn2_per_dn=0.0, blur_sigma_px=0.0, gain_amplitude=0.0,
                   offset_amplitude_dn=0.0)  # fmt: skip

    @property
    def is_clean(self) -> bool:
        return (
            self.read_noise_dn == 0.0
            and self.shot_noise_dn2_per_dn == 0.0
            and self.blur_sigma_px == 0.0
            and self.gain_amplitude == 0.0
            and self.offset_amplitude_dn == 0.0
        )

    def exposure(self, t_s: float, seed: int) -> tuple[float, float]:
        """``(gain, offset_dn)`` at time ``t_s`` for a seed (deterministic, smooth in time)."""
        phases = np.random.default_rng([IMAGE_STREAM, int(seed), 0]).uniform(-np.pi, np.pi, 2)
        gain = 1.0 + self.gain_amplitude * np.sin(2.0 * np.pi * t_s / self.gain_period_s + phases[0])
        offset = self.offset_amplitude_dn * np.sin(2.0 * np.pi * t_s / self.offset_period_s + phases[1])
        return float(gain), float(offset)

    def apply(self, image: U8Array, t_s: float, seed: int, frame_index: int) -> U8Array:
        """Degraded copy of a clean ``uint8`` image; deterministic for ``(seed, frame_index)``."""
        if image.dtype != np.uint8 or image.ndim != 2:
            raise InputError(f"image must be a 2-D uint8 array, got {image.dtype} {image.shape}")
        if self.is_clean:
            return image.copy()
        out = image
        if self.blur_sigma_px > 0.0:
            out = np.asarray(cv2.GaussianBlur(out, (0, 0), self.blur_sigma_px), dtype=np.uint8)
        gain, offset = self.exposure(t_s, seed)
        signal_lut = np.arange(256, dtype=np.float64) * gain + offset
        if self.read_noise_dn == 0.0 and self.shot_noise_dn2_per_dn == 0.0:
            lut = np.clip(np.rint(signal_lut), 0.0, 255.0).astype(np.uint8)
            return np.asarray(cv2.LUT(out, lut), dtype=np.uint8)
        # The output pixel is a function of (clean grey level, uniform random byte) only: one 256 x 256
        # table per frame holds exposure + level-dependent Gaussian noise + rounding + clipping, and the
        # frame is a single lookup (about 5x faster than float arithmetic on the whole frame).
        sigma_lut = np.sqrt(self.read_noise_dn**2 + self.shot_noise_dn2_per_dn * np.maximum(signal_lut, 0.0))
        table = signal_lut[:, None] + sigma_lut[:, None] * NORMAL_QUANTILES_8BIT[None, :]
        table_u8 = np.clip(np.rint(table), 0.0, 255.0).astype(np.uint8).ravel()
        rng = np.random.default_rng([IMAGE_STREAM, int(seed), 1, int(frame_index)])
        uniform = np.frombuffer(rng.bytes(out.size), dtype=np.uint8).reshape(out.shape)
        index = (out.astype(np.uint16) << 8) | uniform
        return np.asarray(np.take(table_u8, index), dtype=np.uint8)
