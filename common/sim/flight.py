"""Simulated flights: a trajectory seen by a downward camera (frames on demand), an IMU, a rangefinder.

Rates: camera 20 fps, IMU 400 Hz, rangefinder 50 Hz, all stamped from t = 0 on exact multiples of their
periods (unless a flight asks for bursty frame stamps, dropped frames or an IMU clock offset). Frames are
never stored: :meth:`Flight.frame` renders frame ``i`` from the true pose each time
(about 1-2 ms), deterministic for ``(seed, i)``.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass
from typing import TypedDict, Unpack

import numpy as np
import numpy.typing as npt

from common.camera import CameraModel
from common.errors import InputError
from common.geometry import R_BODY_CAMERA_DOWN
from common.sim.ground import GroundTexture, camera_pose_from_body, make_ground_texture, render_ground_view
from common.sim.sensors import (
    ImageDegradation,
    ImuNoise,
    ImuSeries,
    RangeNoise,
    RangeSeries,
    sample_stamps,
    simulate_imu,
    simulate_range,
)
from common.sim.trajectory import (
    NOMINAL_HOVER_DURATION_S,
    AttitudeMode,
    Trajectory,
    agile_trajectory,
    hover_trajectory,
    turns_trajectory,
)
from common.types import FloatArray, U8Array

CAMERA_RATE_HZ = 20.0
IMU_RATE_HZ = 400.0
RANGE_RATE_HZ = 50.0
#: Paper A's dataset length.
HOVER_FRAMES = 2041
#: Stream label of the frame stamps' jitter and drops (mixed into the seed).
FRAME_STREAM = 0x4A0
#: Bursty frame stamps are never closer than this (s).
MIN_FRAME_GAP_S = 0.002


@dataclass(frozen=True, eq=False)
class Flight:
    """One simulated flight: truth at the frame stamps, IMU and rangefinder series, frames on demand."""

    name: str
    seed: int
    trajectory: Trajectory
    camera: CameraModel
    R_body_camera: FloatArray  # (3, 3)
    texture: GroundTexture
    degradation: ImageDegradation
    frame_stamps_s: FloatArray  # (N,)
    p_world_body_m: FloatArray  # (N, 3)
    q_world_body: FloatArray  # (N, 4)
    euler_rad: FloatArray  # (N, 3) roll, pitch, yaw (yaw unwrapped)
    R_world_body: FloatArray  # (N, 3, 3)
    imu: ImuSeries
    range: RangeSeries

    @property
    def n_frames(self) -> int:
        return int(self.frame_stamps_s.shape[0])

    @property
    def yaw_rad(self) -> FloatArray:
        """Unwrapped ZYX yaw of ``q_world_body`` at the frame stamps (N,)."""
        return np.asarray(self.euler_rad[:, 2], dtype=np.float64)

    def _check_index(self, i: int) -> int:
        index = int(i)
        if index != i or not 0 <= index < self.n_frames:
            raise InputError(f"frame index must be an integer in [0, {self.n_frames}), got {i}")
        return index

    def camera_pose(self, i: int) -> tuple[FloatArray, FloatArray]:
        """True ``(R_world_camera, p_world_camera_m)`` of frame ``i``."""
        index = self._check_index(i)
        return camera_pose_from_body(self.R_world_body[index], self.p_world_body_m[index], self.R_body_camera)

    def clean_frame(self, i: int) -> U8Array:
        """Noise-free render of frame ``i`` (no degradation)."""
        R_world_camera, p_world_camera = self.camera_pose(i)
        return render_ground_view(self.texture, self.camera, R_world_camera, p_world_camera)

    def frame(self, i: int) -> U8Array:
        """Frame ``i`` ``(H, W) uint8``, rendered now with the flight's degradation (deterministic)."""
        index = self._check_index(i)
        clean = self.clean_frame(index)
        return self.degradation.apply(clean, float(self.frame_stamps_s[index]), self.seed, index)

    def frames(self, start: int = 0, stop: int | None = None) -> Iterator[U8Array]:
        """Frames ``start .. stop - 1`` rendered one at a time."""
        end = self.n_frames if stop is None else min(int(stop), self.n_frames)
        for i in range(int(start), end):
            yield self.frame(i)


def simulate_flight(
    trajectory: Trajectory,
    seed: int = 0,
    n_frames: int | None = None,
    camera: CameraModel | None = None,
    R_body_camera: npt.ArrayLike = R_BODY_CAMERA_DOWN,
    texture: GroundTexture | None = None,
    degradation: ImageDegradation | None = None,
    imu_noise: ImuNoise | None = None,
    range_noise: RangeNoise | None = None,
    camera_rate_hz: float = CAMERA_RATE_HZ,
    imu_rate_hz: float = IMU_RATE_HZ,
    range_rate_hz: float = RANGE_RATE_HZ,
    R_body_imu: npt.ArrayLike | None = None,
    imu_time_offset_s: float = 0.0,
    frame_jitter_s: float = 0.0,
    frame_drop_share: float = 0.0,
) -> Flight:
    """Sample a trajectory into a :class:`Flight` (frames at ``k / camera_rate_hz``, ``n_frames`` of them,
    default: the whole trajectory). IMU and rangefinder cover the same time span at their own rates.
    The texture defaults to ``make_ground_texture(seed)``; pass one to share it between flights.

    Field nuisances (all deterministic by seed, the truth exact at every stamp): the camera's mount
    ``R_body_camera``, the IMU's axes ``R_body_imu`` and clock offset ``imu_time_offset_s``
    (:func:`~common.sim.sensors.simulate_imu`), bursty frame stamps and dropped frames
    (:func:`frame_stamps`; ``n_frames`` counts the nominal frames before the drops).
    """
    if camera_rate_hz <= 0.0:
        raise InputError(f"camera_rate_hz must be positive, got {camera_rate_hz}")
    if n_frames is None:
        n_frames = int(np.floor(trajectory.duration_s * camera_rate_hz + 1e-9)) + 1
    if int(n_frames) != n_frames or n_frames < 2:
        raise InputError(f"n_frames must be an integer >= 2, got {n_frames}")
    R_bc = np.asarray(R_body_camera, dtype=np.float64)
    if R_bc.shape != (3, 3):
        raise InputError(f"R_body_camera must have shape (3, 3), got {R_bc.shape}")
    stamps = frame_stamps(int(n_frames), camera_rate_hz, seed, frame_jitter_s, frame_drop_share)
    span_s = float(stamps[-1])
    truth = trajectory.sample(stamps)
    imu = simulate_imu(
        trajectory,
        sample_stamps(span_s, imu_rate_hz),
        imu_noise or ImuNoise(),
        seed,
        R_body_imu=R_body_imu,
        time_offset_s=imu_time_offset_s,
    )
    rng_range = simulate_range(
        trajectory, sample_stamps(span_s, range_rate_hz), range_noise or RangeNoise(), seed
    )
    return Flight(
        name=trajectory.name,
        seed=int(seed),
        trajectory=trajectory,
        camera=camera or CameraModel.default(),
        R_body_camera=R_bc,
        texture=texture if texture is not None else make_ground_texture(seed),
        degradation=degradation if degradation is not None else ImageDegradation(),
        frame_stamps_s=stamps,
        p_world_body_m=truth.p_world_body_m,
        q_world_body=truth.q_world_body,
        euler_rad=truth.euler_rad,
        R_world_body=truth.R_world_body,
        imu=imu,
        range=rng_range,
    )


def frame_stamps(
    n_frames: int, rate_hz: float, seed: int = 0, jitter_s: float = 0.0, drop_share: float = 0.0
) -> FloatArray:
    """Frame stamps of ``n_frames`` nominal frames at ``k / rate_hz``: ``round(drop_share * (n - 2))`` of them
    dropped (never the first or the last), each kept one moved by a uniform ``[-jitter_s, jitter_s]`` (the
    first stays at 0), then put back in order at least :data:`MIN_FRAME_GAP_S` apart (bursty, as a camera
    driver on a loaded host stamps them). Deterministic by seed; exact multiples without nuisances."""
    nominal = np.arange(int(n_frames), dtype=np.float64) / rate_hz
    if jitter_s == 0.0 and drop_share == 0.0:
        return nominal
    if not (math.isfinite(jitter_s) and 0.0 <= jitter_s <= 1.0):
        raise InputError(f"frame jitter must be in [0, 1] s, got {jitter_s}")
    if not (math.isfinite(drop_share) and 0.0 <= drop_share < 0.5):
        raise InputError(f"frame drop share must be in [0, 0.5), got {drop_share}")
    rng = np.random.default_rng([FRAME_STREAM, int(seed)])
    inner = np.arange(1, n_frames - 1)
    dropped = rng.choice(inner, size=round(drop_share * inner.size), replace=False) if inner.size else inner
    kept = nominal[np.setdiff1d(np.arange(n_frames), dropped)]
    moved = kept + rng.uniform(-jitter_s, jitter_s, kept.size)
    moved[0] = 0.0
    moved = np.sort(np.maximum(moved, 0.0))
    # strictly increasing by at least MIN_FRAME_GAP_S: s_i - i g, running maximum, + i g
    ramp = MIN_FRAME_GAP_S * np.arange(moved.size)
    return np.asarray(np.maximum.accumulate(moved - ramp) + ramp, dtype=np.float64)


class FlightOptions(TypedDict, total=False):
    """What a named flight passes on to :func:`simulate_flight` (see there; None = its default)."""

    camera: CameraModel | None
    texture: GroundTexture | None
    degradation: ImageDegradation | None
    imu_noise: ImuNoise | None
    range_noise: RangeNoise | None
    R_body_camera: npt.ArrayLike
    R_body_imu: npt.ArrayLike | None
    imu_time_offset_s: float
    camera_rate_hz: float
    imu_rate_hz: float
    range_rate_hz: float
    frame_jitter_s: float


def hover_flight(
    seed: int = 0,
    n_frames: int = HOVER_FRAMES,
    altitude_m: float = 1.5,
    mode: AttitudeMode = AttitudeMode.PRESCRIBED,
    **options: Unpack[FlightOptions],
) -> Flight:
    """Paper A's hover: 2041 frames at 20 fps (102 s) at 1.5 m, yaw rates up to +-45 deg/s.

    A shorter ``n_frames`` gives exactly the first frames of the full flight (same trajectory shape).
    See :func:`common.sim.trajectory.hover_trajectory` for the motion.
    """
    if int(n_frames) != n_frames or n_frames < 2:
        raise InputError(f"n_frames must be an integer >= 2, got {n_frames}")
    duration_s = max((n_frames - 1) / CAMERA_RATE_HZ, NOMINAL_HOVER_DURATION_S)
    trajectory = hover_trajectory(seed=seed, duration_s=duration_s, altitude_m=altitude_m, mode=mode)
    return simulate_flight(trajectory, seed=seed, n_frames=n_frames, **options)


def turns_flight(
    seed: int = 0, heading_follows_path: bool = True, **options: Unpack[FlightOptions]
) -> Flight:
    """Paper C's flight: 5 s hover at 3.5 m, two climbing turns of radius 1.1 m in 40 s to 4.0 m, 5 s hover.

    1001 frames (50 s) at 20 fps; path length 13.832 m; coordinated tilt into the turns.
    See :func:`common.sim.trajectory.turns_trajectory`.
    """
    trajectory = turns_trajectory(seed=seed, heading_follows_path=heading_follows_path)
    return simulate_flight(trajectory, seed=seed, **options)


def agile_flight(seed: int = 0, **options: Unpack[FlightOptions]) -> Flight:
    """A longer, faster, more tilted indoor flight than paper C's: 60 s (1201 frames at 20 fps), a figure of
    eight with fast side-steps at 1-3 m, speed up to about 1.5 m/s, tilt up to about 20 deg, the heading
    swinging +-70 deg; 4 s of hover at both ends. See :func:`common.sim.trajectory.agile_trajectory`."""
    return simulate_flight(agile_trajectory(seed=seed), seed=seed, **options)
