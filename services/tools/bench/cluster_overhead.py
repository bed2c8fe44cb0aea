"""What the cluster costs on small frames (752x480, 40 patches): the median master time per frame of local
paths minus the in-process median, and the reply hand-off that decided the scatter's solo path."""

from __future__ import annotations

import queue
import time
from pathlib import Path
from typing import Any

import numpy as np
import zenoh

from common.members import Topology
from common.wire import keys
from common.wire.codec import decode, encode
from common.wire.messages import PatchJob, PatchResult, YawJobSettings
from common.yaw import YawSettings, for_frame, make_patch_grid
from services.camera import CameraSettings, simulated_flight
from services.runtime.transport import open_session, zbytes
from services.tools.bench.cluster_workload import in_process_ms, write_frame_folder
from services.tools.cluster_file import ClusterSpec, HostSpec
from services.tools.demo_cluster import run_cluster_flight
from services.tools.up import LocalCluster

#: frames of each 752x480 overhead run left out of its median (the dispatcher's speeds settle)
OVERHEAD_WARMUP = 10

OVERHEAD_PATHS: tuple[tuple[str, str, tuple[int, ...]], ...] = (
    ("master-worker 1", "master-worker", (1,)),
    ("master-foreman-worker 1x1", "master-foreman-worker", (1,)),
    ("master-foreman-worker 2x2", "master-foreman-worker", (2, 2)),
)


def overhead_752x480(out_dir: Path, n_frames: int, shm: bool, repeats: int = 1) -> dict[str, Any]:
    """Median master time per frame of local cluster paths minus the in-process median, at 752x480.

    The machine is shared, so each repeat measures the in-process median before and after its cluster runs
    and takes their mean as that repeat's baseline; the reported overhead of a path is the median over
    repeats of (its median ms per frame - the repeat's baseline). Each run also records the share of CPU
    time the hypervisor stole (a busy host shows there) and the frames the master computed itself (a path
    that lost its members measures nothing but the master).
    """
    settings = YawSettings()
    flight = simulated_flight(CameraSettings(frames=n_frames))
    frames = [flight.frame(i) for i in range(n_frames)]
    frame_dir = out_dir / "cluster_frames_752"
    write_frame_folder(frame_dir, frames)
    warmup = OVERHEAD_WARMUP
    runs: dict[str, list[dict[str, float]]] = {label: [] for label, _t, _w in OVERHEAD_PATHS}
    extras: dict[str, dict[str, float]] = {}
    baselines: list[list[float]] = []
    for repeat in range(repeats):
        before = float(np.median(in_process_ms(frames, settings, warmup)[0]))
        medians: dict[str, tuple[float, int]] = {}
        for label, topology, workers in OVERHEAD_PATHS:
            spec = ClusterSpec(
                name=label.replace(" ", "-"),
                topology=topology,  # type: ignore[arg-type]
                hosts=tuple(HostSpec(name=f"h{i + 1}", workers=w) for i, w in enumerate(workers)),
            )
            steal_before = cpu_steal_ticks()
            estimates, _wall, _codes = run_cluster_flight(
                spec, n_frames, out_dir / "cluster_logs" / f"{spec.name}-{repeat}", fps=0.0, in_flight=1,
                camera_args=("--images", str(frame_dir), "--preload", "--no-sensors"), progress=False,
                shared_memory=shm,
            )  # fmt: skip
            ms = np.array([estimates[s].timings_ms["total"] for s in sorted(estimates) if s > warmup])
            medians[label] = (float(np.median(ms)) if ms.size else float("nan"), n_frames - len(estimates))
            extras[label] = {
                "host_steal_pct": steal_percent(steal_before, cpu_steal_ticks()),
                "frames_computed_by_master": float(
                    sum(1 for s, e in estimates.items() if s > warmup and "self" in e.members)
                ),
            }
        after = float(np.median(in_process_ms(frames, settings, warmup)[0]))
        baseline = 0.5 * (before + after)
        baselines.append([before, after])
        for label, (median, lost) in medians.items():
            runs[label].append(
                {"cluster_median_ms": median, "overhead_ms": median - baseline, "frames_lost": float(lost),
                 **extras[label]}
            )  # fmt: skip
            print(f"752x480 [{repeat + 1}/{repeats}] {label}: {median:.2f} ms vs in-process "
                  f"{baseline:.2f} ms (+{median - baseline:.2f} ms); host steal "
                  f"{extras[label]['host_steal_pct']:.1f} %, frames computed by the master "
                  f"{extras[label]['frames_computed_by_master']:.0f}", flush=True)  # fmt: skip
    paths: dict[str, dict[str, Any]] = {
        label: {
            "overhead_ms": float(np.median([r["overhead_ms"] for r in rows])),
            "cluster_median_ms": float(np.median([r["cluster_median_ms"] for r in rows])),
            "run_overheads_ms": [r["overhead_ms"] for r in rows],
            "run_host_steal_pct": [r["host_steal_pct"] for r in rows],
            "frames_lost": float(sum(r["frames_lost"] for r in rows)),
            "frames_computed_by_master": float(sum(r["frames_computed_by_master"] for r in rows)),
        }
        for label, rows in runs.items()
    }
    return {
        "in_process_median_ms": float(np.median(baselines)),
        "in_process_before_after_ms": baselines,
        "paths": paths,
        "overhead_ms": paths["master-foreman-worker 1x1"]["overhead_ms"],
        "frames": n_frames,
        "repeats": repeats,
    }


def cpu_steal_ticks() -> tuple[int, int] | None:
    """(steal, total) jiffies of all CPUs from ``/proc/stat``; None where there is no such file."""
    try:
        fields = Path("/proc/stat").read_text().split("\n", 1)[0].split()[1:]
    except OSError:
        return None
    values = [int(v) for v in fields]
    return (values[7] if len(values) > 7 else 0), sum(values)


def steal_percent(before: tuple[int, int] | None, after: tuple[int, int] | None) -> float:
    """Share of CPU time stolen by the hypervisor between two readings (NaN when unknown)."""
    if before is None or after is None or after[1] <= before[1]:
        return float("nan")
    return 100.0 * (after[0] - before[0]) / (after[1] - before[1])


def reply_handoff(out_dir: Path, shm: bool, requests: int = 240, blocks: int = 6) -> dict[str, Any]:
    """What decided the scatter's solo path: the round trip of one 752x480 job (40 patches) to a real worker
    process, its reply handed over by a callback on zenoh's thread and a queue (how replies arrive when
    several requests are in flight) or received from the query's own FIFO channel (a request alone in
    flight). Alternating blocks of each; the requester pauses 2 ms between requests, as between frames."""
    flight = simulated_flight(CameraSettings(frames=3))
    settings = for_frame(YawSettings(), flight.frame(0).shape)
    grid = make_patch_grid(flight.frame(0).shape, settings)
    idx = grid.all_indices.astype(np.int32)
    crops = [grid.crop(flight.frame(i), idx) for i in range(3)]
    wire = YawJobSettings.of(settings)
    spec = ClusterSpec(
        name="handoff", topology=Topology.MASTER_WORKER, hosts=(HostSpec(name="handoff", workers=1),)
    )
    times: dict[str, list[float]] = {"callback": [], "channel": []}
    seq = 0
    with LocalCluster(spec, out_dir / "cluster_logs" / "handoff", shared_memory=shm) as cluster:
        cluster.start()
        cluster.wait_alive(cluster.expected_members())
        with open_session(cluster.observer_transport()) as session:
            key = zenoh.KeyExpr(keys.worker_key("handoff", 0))
            # the worker's liveliness can reach us before its queryable's route: a query sent before that
            # ends at once without a reply (one run of the suite on a busy host did); wait for the route
            querier: Any = session.declare_querier(key)  # (the stubs type matching_status as a bool)
            deadline = time.monotonic() + 30.0
            while not querier.matching_status.matching and time.monotonic() < deadline:
                time.sleep(0.01)
            querier.undeclare()
            events: queue.SimpleQueue[Any] = queue.SimpleQueue()
            options: dict[str, Any] = {
                "timeout": 5.0,
                "consolidation": zenoh.ConsolidationMode.NONE,
                "congestion_control": zenoh.CongestionControl.BLOCK,
            }
            for block in range(2 * blocks):
                mode = ("callback", "channel")[block % 2]
                for _ in range(requests // blocks):
                    seq += 1
                    job = PatchJob(
                        stream="handoff", seq=seq, prev_seq=seq - 1, settings=wire, indices=idx,
                        crops=crops[seq % 3], prev_indices=idx, prev_crops=crops[(seq - 1) % 3], budget_s=5.0,
                    )  # fmt: skip
                    payload, attachment = encode(job)
                    time.sleep(0.002)
                    t0 = time.perf_counter()
                    if mode == "callback":
                        on_done = lambda: events.put(None)  # noqa: E731
                        handler = zenoh.handlers.Callback(events.put, on_done, indirect=False)
                        session.get(key, handler, payload=payload, attachment=attachment, **options)
                        reply = events.get(timeout=10.0)
                    else:
                        channel = session.get(key, zenoh.handlers.FifoChannel(2), payload=payload,
                                              attachment=attachment, **options)  # fmt: skip
                        reply = channel.recv()
                    times[mode].append((time.perf_counter() - t0) * 1e3)
                    if mode == "callback" and reply is not None:
                        events.get(timeout=10.0)  # the query's end (None: it ended without a reply)
                    if reply is None or reply.ok is None:
                        raise RuntimeError(f"the hand-off benchmark's worker did not answer job {seq}")
                    decode(zbytes(reply.ok.payload), zbytes(reply.ok.attachment), PatchResult)
    callback_ms = float(np.median(times["callback"]))
    channel_ms = float(np.median(times["channel"]))
    print(f"752x480 job round trip to a worker: reply via callback + queue {callback_ms:.3f} ms, "
          f"via its own channel {channel_ms:.3f} ms", flush=True)  # fmt: skip
    return {
        "callback_ms": callback_ms,
        "channel_ms": channel_ms,
        "saved_ms": callback_ms - channel_ms,
        "requests_per_mode": len(times["channel"]),
    }
