"""The dispatch bench's workload: the frames it flies (rendered once, replayed by the camera) and the yaw
settings, the same in-process (the baseline's CPU time a frame) and as the master's options."""

from __future__ import annotations

import argparse
import os
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from common.errors import CapatazError
from common.yaw import YawSettings, YawTracker, for_frame, make_patch_grid
from services.camera import CameraSettings, simulated_flight
from services.camera.settings import FlightName
from services.master.settings import MasterSettings
from services.runtime.cli import parse_size
from services.tools.bench.cluster_workload import write_frame_folder

#: paper C's turns fly straight for their first 218 frames: ``--flight turns`` starts near the first turn
TURNS_FROM_FRAME = 200


def workload_of(args: argparse.Namespace) -> tuple[tuple[int, int], YawSettings, tuple[str, ...]]:
    """The workload's frame size, yaw settings (in-process) and the same settings as master options."""
    size = parse_size(args.resolution, "--resolution", "752x480")
    cols, rows = parse_size(args.grid, "--grid", "8x5")
    patch, level = args.patch_size, args.pyramid_level
    # no level given: the master resolves it for the frames' size as the core does here (for_frame)
    given = replace(YawSettings(), grid_cols=cols, grid_rows=rows, patch_size_px=patch, pyramid_level=level)
    settings = for_frame(given, (size[1], size[0]))
    encoding = getattr(args, "job_encoding", MasterSettings().job_encoding)
    quality = getattr(args, "job_quality", MasterSettings().job_quality)
    level_args = () if level is None else ("--pyramid-level", str(level))
    master_args = ("--grid", args.grid, "--patch-size", str(patch), *level_args,
                   "--job-encoding", encoding, "--job-quality", str(quality))  # fmt: skip
    return size, settings, master_args


def flight_frames(args: argparse.Namespace) -> list[np.ndarray]:
    """The camera's ``--flight`` at the workload's size (``--frames``), rendered once per ``args`` and written
    to ``<out>/dispatch_frames`` for the camera to replay (``args.frame_dir``)."""
    if getattr(args, "frame_images", None) is None:
        size = parse_size(args.resolution, "--resolution", "752x480")
        flight = simulated_flight(
            CameraSettings(frames=args.frames, width=size[0], height=size[1], flight=FlightName(args.flight))
        )
        first = TURNS_FROM_FRAME if args.flight == FlightName.TURNS.value else 0
        if first + args.frames > flight.n_frames:
            left = flight.n_frames - first
            raise CapatazError(f"--flight {args.flight} has {left} frames; --frames asks {args.frames}")
        args.frame_images = [flight.frame(first + i) for i in range(args.frames)]
        args.frame_dir = Path(args.out) / "dispatch_frames"
        write_frame_folder(args.frame_dir, args.frame_images)
    images: list[np.ndarray] = args.frame_images
    return images


def in_process_cpu_ms(
    frames: list[np.ndarray], settings: YawSettings | None = None, cpu: str | None = None
) -> float:
    """CPU ms per frame of the in-process tracker on ``frames``, on ``cpu`` alone when given (one thread:
    its wall time per frame too)."""
    if cpu is not None:
        before = os.sched_getaffinity(0)
        os.sched_setaffinity(0, {int(cpu)})
        try:
            return in_process_cpu_ms(frames, settings)
        finally:
            os.sched_setaffinity(0, before)
    settings = settings or YawSettings()
    tracker = YawTracker(settings, make_patch_grid(frames[0].shape, settings))
    state = tracker.initial_state(frames[0])
    c0 = time.process_time()
    for image in frames[1:]:
        state, _ = tracker.track(state, image)
    return 1e3 * (time.process_time() - c0) / (len(frames) - 1)
