"""The workload every cluster measurement replays: the camera's frame folder and the in-process baseline."""

from __future__ import annotations

import time
from pathlib import Path

import cv2
import numpy as np

from common.yaw import YawSettings, YawTracker, make_patch_grid


def write_frame_folder(frame_dir: Path, frames: list[np.ndarray]) -> None:
    """The frames the camera replays (``--images``): exactly these, stale frames of a longer run removed."""
    frame_dir.mkdir(parents=True, exist_ok=True)
    for old in frame_dir.glob("*.pgm"):
        old.unlink()
    for i, frame in enumerate(frames):
        cv2.imwrite(str(frame_dir / f"{i:05d}.pgm"), frame)


def in_process_ms(
    frames: list[np.ndarray], settings: YawSettings, warmup: int
) -> tuple[np.ndarray, np.ndarray]:
    """Per-frame ms of the in-process tracker and its yaw (frame 0 = 0)."""
    tracker = YawTracker(settings, make_patch_grid(frames[0].shape, settings))
    state = tracker.initial_state(frames[0])
    times, yaw = [], [0.0]
    for frame in frames[1:]:
        t0 = time.perf_counter()
        state, estimate = tracker.track(state, frame)
        times.append((time.perf_counter() - t0) * 1e3)
        yaw.append(estimate.yaw_rad)
    return np.array(times[warmup:]), np.array(yaw)


def stats_ms(ms: np.ndarray) -> dict[str, float]:
    return {
        "median_ms": float(np.median(ms)),
        "p99_ms": float(np.percentile(ms, 99)),
        "mean_ms": float(np.mean(ms)),
    }
