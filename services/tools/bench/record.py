"""Record: the end-to-end latency of a 752x480 20 fps stream with and without ``capataz record`` running.

One local cluster (router, master, 2 workers on 127.0.0.1) and the simulated hover camera free-running at
``--fps``; an observer takes, per frame, the time from the frame's arrival to its yaw's arrival (both
received by the same process, one clock). Runs alternate without / with a recorder (order flipped each
repeat, so a change of the shared host's load hits both alike); the recorder writes every ``capataz/**``
message of the run into ``out/bench/record_run.mcap``. Reported: median and p95 latency per mode over all
frames after ``--warmup``, the median difference, and that difference as a share of the frame period (the
latency budget of a 20 fps stream: 50 ms).
"""

from __future__ import annotations

import argparse
import signal
import subprocess
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

from common.dispatch import Balance
from common.members import Topology
from common.recordings.mcap import open_recording
from common.wire import keys
from common.wire.codec import decode
from common.wire.messages import Frame, YawEstimate
from services.runtime.transport import open_session, zbytes
from services.tools.cluster_file import ClusterSpec, HostSpec
from services.tools.up import LocalCluster

NAME = "record"

SPEC = ClusterSpec(
    name="record",
    topology=Topology.MASTER_WORKER,
    balance=Balance.TIME,
    hosts=(HostSpec(name="h1", workers=2),),
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--frames", type=int, default=200, help="frames per run (default 200)")
    parser.add_argument("--repeats", type=int, default=3, help="runs per mode (default 3)")
    parser.add_argument("--fps", type=float, default=20.0, help="camera rate (default 20)")
    parser.add_argument("--warmup", type=int, default=10, help="first frames of a run not counted")


class _Latency:
    """Arrival times of frames and of their yaw at one observer; latency per seq."""

    def __init__(self, session: Any, uav: str) -> None:
        self.frames: dict[int, float] = {}
        self.yaw: dict[int, float] = {}
        self.lock = threading.Lock()
        self.subs = [
            session.declare_subscriber(keys.camera_key(uav), self._on_frame),
            session.declare_subscriber(keys.yaw_key(uav), self._on_yaw),
        ]

    def _on_frame(self, sample: Any) -> None:
        t = time.perf_counter()
        seq = decode(zbytes(sample.payload), zbytes(sample.attachment), Frame).seq
        with self.lock:
            self.frames[seq] = t

    def _on_yaw(self, sample: Any) -> None:
        t = time.perf_counter()
        seq = decode(zbytes(sample.payload), zbytes(sample.attachment), YawEstimate).seq
        with self.lock:
            self.yaw[seq] = t

    def latencies_ms(self, warmup: int) -> list[float]:
        with self.lock:
            return [
                1e3 * (self.yaw[s] - self.frames[s])
                for s in sorted(self.yaw)
                if s >= warmup and s in self.frames
            ]

    def close(self) -> None:
        for sub in self.subs:
            sub.undeclare()


def _one_run(
    cluster: LocalCluster, session: Any, args: argparse.Namespace, record: Path | None, k: int
) -> dict[str, Any]:
    recorder = None
    if record is not None:
        recorder = f"recorder/rec{k}/0"
        cluster.spawn(
            recorder, ["record", *cluster.transport_args(), "--node", f"rec{k}", "--out", str(record)]
        )
        cluster.wait_alive({recorder})
    latency = _Latency(session, SPEC.uav)
    time.sleep(0.3)  # routes of the observer's subscribers
    name = f"camera/cam{k}/0"
    camera = cluster.spawn(
        name,
        [
            "camera",
            *cluster.transport_args(),
            "--node",
            f"cam{k}",
            "--uav",
            SPEC.uav,
            "--frames",
            str(args.frames),
            "--fps",
            str(args.fps),
        ],
    )
    camera.wait(60.0 + 2.0 * args.frames / args.fps)
    cluster.signal(name, signal.SIGTERM)
    time.sleep(0.5)  # the last yaw estimates in flight
    values = latency.latencies_ms(args.warmup)
    latency.close()
    out: dict[str, Any] = {"recorder": record is not None, "frames_with_yaw": len(values) + args.warmup}
    if recorder is not None and record is not None:
        cluster.signal(recorder, signal.SIGTERM)
        try:
            out["recorder_exit"] = cluster.processes[recorder].wait(20.0)
        except subprocess.TimeoutExpired:
            cluster.signal(recorder, signal.SIGKILL)
            out["recorder_exit"] = None
        out["recorded_frames"] = open_recording(record).frames
        out["mcap_bytes"] = record.stat().st_size
    out["latencies_ms"] = values
    return out


def run(args: argparse.Namespace) -> dict[str, Any]:
    out_dir = Path(args.out)
    out_dir.mkdir(parents=True, exist_ok=True)
    runs: list[dict[str, Any]] = []
    with LocalCluster(SPEC, out_dir / "record_logs") as cluster:
        cluster.start()
        cluster.wait_alive(cluster.expected_members())
        with open_session(cluster.observer_transport()) as session:
            k = 0
            for repeat in range(args.repeats):
                modes = (False, True) if repeat % 2 == 0 else (True, False)
                for with_recorder in modes:
                    record = out_dir / "record_run.mcap" if with_recorder else None
                    runs.append(_one_run(cluster, session, args, record, k))
                    k += 1
    table: list[dict[str, Any]] = []
    pooled: dict[bool, np.ndarray] = {}
    for mode in (False, True):
        values = np.concatenate([r["latencies_ms"] for r in runs if r["recorder"] is mode] or [np.zeros(0)])
        pooled[mode] = values
        table.append(
            {
                "mode": "with recorder" if mode else "no recorder",
                "frames": int(values.size),
                "median_ms": float(np.median(values)) if values.size else float("nan"),
                "p95_ms": float(np.percentile(values, 95)) if values.size else float("nan"),
            }
        )
    overhead = table[1]["median_ms"] - table[0]["median_ms"]
    budget_ms = 1e3 / args.fps
    per_run = [
        {
            "recorder": r["recorder"],
            "median_ms": float(np.median(r["latencies_ms"])) if r["latencies_ms"] else None,
            **{k: v for k, v in r.items() if k not in ("latencies_ms", "recorder")},
        }
        for r in runs
    ]
    return {
        "table": table,
        "overhead_median_ms": overhead,
        "overhead_p95_ms": table[1]["p95_ms"] - table[0]["p95_ms"],
        "budget_ms": budget_ms,
        "overhead_share_of_budget": overhead / budget_ms,
        "runs": per_run,
        "settings": {"frames": args.frames, "repeats": args.repeats, "fps": args.fps, "warmup": args.warmup},
        "note": "host shared with other jobs: compare the two modes of this run only",
    }
