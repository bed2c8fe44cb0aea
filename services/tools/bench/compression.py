"""Compression: size and CPU of ``capataz record``'s chunk compression (none, lz4, zstd) on a simulated run.

The stream of paper A's simulated hover (752x480 mono frames at 20 fps, its IMU samples, a range sample and
a pose estimate per frame; with ``--images FOLDER`` the frames are a real image folder's instead) is written
once per compression with the recorder's own writer
(:class:`~common.recordings.mcap.RecordingWriter`), in one thread, frames rendered beforehand. Reported per
compression: the file's size, MB per minute of flight, the ratio to the uncompressed file, the CPU time the
writer took per frame and as a share of one core at the flight's frame rate, and that every message reads
back. The CPU figures are process time on a shared host: compare the rows of one run.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path
from typing import Any

import numpy as np

from common.datasets.images import open_image_folder
from common.recordings.mcap import Compression, RecordingWriter
from common.sim.flight import hover_flight
from common.wire import keys
from common.wire.messages import Frame, ImuSample, PoseEstimate, RangeSample
from common.wire.schema import WireModel

NAME = "compression"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--frames", type=int, default=200, help="frames of the simulated hover (20 fps)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the simulated flight")
    parser.add_argument(
        "--images", type=Path, help="frames from this image folder instead of the simulator's"
    )


def simulated_run(
    frames: int, seed: int, images: list[np.ndarray] | None = None, uav: str = "uav0"
) -> list[tuple[str, WireModel, int]]:
    """(key, message, log time ns) of the hover's stream in stamp order: frames (the simulator's, or
    ``images`` in turn), IMU, range, poses."""
    flight = hover_flight(seed=seed, n_frames=frames)
    items: list[tuple[float, str, WireModel]] = []
    for i in range(flight.n_frames):
        stamp = float(flight.frame_stamps_s[i])
        pixels = flight.frame(i) if images is None else images[i % len(images)]
        height, width = pixels.shape
        frame = Frame(uav=uav, seq=i, stamp_s=stamp, width=width, height=height, pixels=pixels)
        items.append((stamp, keys.camera_key(uav), frame))
        items.append((stamp, keys.range_key(uav), RangeSample(uav=uav, seq=i, stamp_s=stamp, range_m=1.5)))
        pose = PoseEstimate(
            uav=uav, seq=i, stamp_s=stamp, p_world_body_m=flight.p_world_body_m[i],
            q_world_body=flight.q_world_body[i], covariance=np.eye(6) * 1e-4, source="vo",
        )  # fmt: skip
        items.append((stamp, keys.pose_vo_key(uav), pose))
    imu = flight.imu
    last = float(flight.frame_stamps_s[-1])
    for j in np.flatnonzero(imu.stamps_s <= last):
        stamp = float(imu.stamps_s[j])
        sample = ImuSample(
            uav=uav, seq=int(j), stamp_s=stamp, gyro_rad_s=imu.gyro_rad_s[j], accel_m_s2=imu.accel_m_s2[j]
        )
        items.append((stamp, keys.imu_key(uav), sample))
    items.sort(key=lambda item: item[0])
    return [(key, message, round(stamp * 1e9)) for stamp, key, message in items]


def write(path: Path, run: list[tuple[str, WireModel, int]], compression: Compression) -> float:
    """Write ``run`` into ``path``; the CPU seconds it took (this process's time, the writer's thread)."""
    t0 = time.process_time()
    writer = RecordingWriter(path, compression)
    for key, message, log_ns in run:
        writer.write(key, message, log_ns)
    writer.close()
    return time.process_time() - t0


def read_back(path: Path) -> int:
    """Messages in the file (the mcap reader decompresses every chunk)."""
    from mcap.reader import make_reader

    with path.open("rb") as f:
        return sum(1 for _ in make_reader(f).iter_messages())


def run(args: argparse.Namespace) -> dict[str, Any]:
    out_dir = Path(args.out)
    out_dir.mkdir(parents=True, exist_ok=True)
    images = None
    if args.images is not None:
        folder = open_image_folder(args.images, stop=args.frames)
        images = [frame.image for frame in folder.frames()]
    stream = simulated_run(args.frames, args.seed, images)
    frames = sum(1 for _, m, _ in stream if isinstance(m, Frame))
    poses = sum(1 for _, m, _ in stream if isinstance(m, PoseEstimate))
    duration_s = frames / 20.0
    rows: list[dict[str, Any]] = []
    for compression in (Compression.NONE, Compression.LZ4, Compression.ZSTD):
        path = out_dir / f"compression_{compression.value}.mcap"
        cpu_s = write(path, stream, compression)
        size = path.stat().st_size
        rows.append(
            {
                "compression": compression.value,
                "MB": size / 1e6,
                "MB_per_min": size / 1e6 / duration_s * 60.0,
                "cpu_ms_per_frame": 1e3 * cpu_s / frames,
                "core_share_at_20fps": cpu_s / duration_s,
                # a pose is written twice: its JSON channel and its Foxglove PoseInFrame channel
                "read_back": read_back(path) == len(stream) + poses,
                "bytes": size,
            }
        )
    base = rows[0]
    for row in rows:
        row["ratio"] = row["bytes"] / base["bytes"]
        row["extra_cpu_ms_per_frame"] = row["cpu_ms_per_frame"] - base["cpu_ms_per_frame"]
    return {
        "table": rows,
        "settings": {
            "frames": frames,
            "messages": len(stream),
            "seed": args.seed,
            "flight_s": duration_s,
            "images": str(args.images) if args.images else "simulated",
        },
        "note": "CPU is process time on a shared host: compare the rows of one run",
        # a real video's figures go beside the simulator's (docs/results.md shows both)
        **({"json_name": "compression_images"} if args.images else {}),
    }
