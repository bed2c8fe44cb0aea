"""The frames a load test sends: paper A's simulated hover, or a recording made by ``capataz record``.

Either way the frames are held in memory (at most ``max_frames``) and played in ping-pong order, so the
motion stays continuous however long the run; every stream plays them at its own phase and the harness
stamps each frame with the wall clock when it sends it (a recording's own stamps are not used).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import numpy as np

from common.estimation.measurements import FrameMeasurement
from common.recordings.mcap import RecordingError, open_recording
from common.sim.flight import hover_flight

#: most frames a recording may contribute (a 752x480 frame is 361 kB: 600 frames are 217 MB)
MAX_REPLAY_FRAMES = 600


@dataclass(frozen=True)
class FrameLoop:
    """Frames in ping-pong order with their true yaw (NaN when unknown: a recording), shared by streams."""

    frames: tuple[np.ndarray, ...]
    yaw_rad: tuple[float, ...]
    #: where the frames come from (for the report)
    source: str
    #: the source's own frame rate (Hz), NaN when it has none
    recorded_fps: float = math.nan

    def __post_init__(self) -> None:
        if len(self.frames) < 2 or len(self.frames) != len(self.yaw_rad):
            raise RecordingError(f"{self.source}: a load test needs at least 2 frames")

    @cached_property
    def order(self) -> list[int]:
        n = len(self.frames)
        return list(range(n)) + list(range(n - 2, 0, -1))

    def at(self, k: int) -> tuple[np.ndarray, float]:
        order = self.order
        index = order[k % len(order)]
        return self.frames[index], self.yaw_rad[index]

    @property
    def shape(self) -> tuple[int, int]:
        return self.frames[0].shape[0], self.frames[0].shape[1]


def simulated_frames(n_frames: int, seed: int) -> FrameLoop:
    """Paper A's hover flight, rendered once."""
    flight = hover_flight(seed=seed, n_frames=n_frames)
    frames = tuple(flight.frame(k) for k in range(n_frames))
    yaws = tuple(float(y) for y in np.asarray(flight.yaw_rad, dtype=np.float64)[:n_frames])
    return FrameLoop(frames, yaws, f"simulated hover (seed {seed}, {n_frames} frames)")


def recorded_frames(path: Path, uav: str | None = None, max_frames: int = MAX_REPLAY_FRAMES) -> FrameLoop:
    """The first ``max_frames`` frames of a recording's UAV stream (its only one, or ``uav``); the truth is
    unknown, so yaw continuity is not judged. Raises :class:`RecordingError` for a file that is not one."""
    if max_frames < 2:
        raise RecordingError(f"max_frames must be >= 2, got {max_frames}")
    recording = open_recording(path, uav)
    frames: list[np.ndarray] = []
    stamps: list[float] = []
    for measurement in recording.measurements():
        if not isinstance(measurement, FrameMeasurement):
            continue
        if frames and measurement.image.shape != frames[0].shape:
            raise RecordingError(f"{path}: frames of {recording.uav} change size within the recording")
        frames.append(np.ascontiguousarray(measurement.image))
        stamps.append(measurement.stamp_s)
        if len(frames) >= max_frames:
            break
    steps = np.diff(np.asarray(stamps))
    steps = steps[np.isfinite(steps) & (steps > 0)]
    fps = float(1.0 / np.median(steps)) if steps.size else math.nan
    source = f"{path} ({recording.uav}, {len(frames)} of {recording.frames} frames)"
    return FrameLoop(tuple(frames), (math.nan,) * len(frames), source, fps)
