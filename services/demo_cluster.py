"""The embedded default through a local cluster: router, camera, master, 2 foremen x 2 workers (127.0.0.1).

``run_demo(out_dir)`` starts the processes, replays the simulated hover flight through them, prints live
progress, then writes ``out/cluster/summary.json`` and plots: yaw vs truth, per-member shares per frame
and frame timings. Member shares and timings come from the published YawEstimates themselves.
"""

from __future__ import annotations

import logging
import time
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np

from common.metrics import yaw_error_stats
from common.sim.flight import HOVER_FRAMES, hover_flight
from common.transport import open_session
from services.report import write_json
from services.up import ClusterSpec, HostSpec, LocalCluster, YawCollector

logger = logging.getLogger(__name__)

DEMO_CLUSTER = ClusterSpec(
    name="local2x2",
    topology="master-foreman-worker",
    balance="time",
    hosts=(HostSpec(name="h1", workers=2), HostSpec(name="h2", workers=2)),
)


def run_cluster_flight(
    spec: ClusterSpec,
    n_frames: int,
    log_dir: Path,
    fps: float = 0.0,
    in_flight: int = 1,
    master_args: tuple[str, ...] = (),
    camera_args: tuple[str, ...] = (),
    progress: bool = True,
    shared_memory: bool = False,
) -> tuple[dict[int, Any], float, dict[str, int | None]]:
    """Run one flight through a fresh local cluster; returns (estimates by seq, wall seconds, exit codes)."""
    with LocalCluster(spec, log_dir, shared_memory=shared_memory, master_args=master_args) as cluster:
        t_start = time.monotonic()
        cluster.start()
        cluster.wait_alive(cluster.expected_members())
        logger.info(
            "cluster %s up in %.1f s (router %s)", spec.name, time.monotonic() - t_start, cluster.router
        )
        with open_session(cluster.observer_transport()) as session:
            collector = YawCollector(session, spec.uav)
            camera = [
                "--frames", str(n_frames), "--fps", str(fps), "--in-flight", str(in_flight), *camera_args,
            ]  # fmt: skip
            cluster.start_camera(camera)
            t0 = time.monotonic()
            last_print = t0
            timeout_s = 60.0 + n_frames * 0.5
            while len(collector.estimates) < n_frames and time.monotonic() - t0 < timeout_s:
                time.sleep(0.1)
                camera_process = cluster.processes["camera/camera/0"]
                if camera_process.poll() is not None and not collector.wait_for(n_frames, 2.0):
                    break
                if progress and time.monotonic() - last_print > 2.0:
                    last_print = time.monotonic()
                    _print_progress(collector, n_frames, last_print - t0)
            wall_s = time.monotonic() - t0
            estimates = dict(collector.estimates)
            collector.close()
        codes = cluster.stop()
    return estimates, wall_s, codes


def _print_progress(collector: YawCollector, n_frames: int, elapsed_s: float) -> None:
    done = len(collector.estimates)
    newest = collector.newest()
    if newest < 0:
        print(f"  waiting for the first yaw ({elapsed_s:.0f} s)", flush=True)
        return
    estimate = collector.estimates[newest]
    shares = {m: n for m, n in estimate.members.items() if ">" not in m}
    print(
        f"  {done}/{n_frames} frames, {done / elapsed_s:.1f} fps, frame {newest}: "
        f"yaw {np.degrees(estimate.yaw_rad):+8.2f} deg, {estimate.timings_ms.get('total', 0):.1f} ms, "
        f"shares {shares}",
        flush=True,
    )


def member_table(estimates: dict[int, Any]) -> list[dict[str, Any]]:
    """Per member: mean patches per frame, share of all patches, frames served, last speed (patches/s)."""
    seqs = sorted(s for s, e in estimates.items() if e.patch_count)
    totals: dict[str, list[int]] = {}
    for s in seqs:
        for member, count in estimates[s].members.items():
            totals.setdefault(member, []).append(count)
    all_patches = sum(estimates[s].patch_count for s in seqs) or 1
    rows = []
    for member in sorted(totals):
        counts = totals[member]
        speed = next(
            (estimates[s].timings_ms.get(f"speed:{member}") for s in reversed(seqs)
             if f"speed:{member}" in estimates[s].timings_ms),
            None,
        )  # fmt: skip
        rows.append(
            {
                "member": member,
                "frames": len(counts),
                "patches_per_frame": float(np.mean(counts)),
                "share": float(np.sum(counts)) / all_patches if ">" not in member else float("nan"),
                "speed_patches_s": speed if speed is not None else float("nan"),
            }
        )
    return rows


def _plot(out_dir: Path, flight: Any, estimates: dict[int, Any], rows: list[dict[str, Any]]) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    seqs = np.array(sorted(estimates))
    yaw = np.array([estimates[s].yaw_rad for s in seqs])
    truth = flight.yaw_rad[seqs] - flight.yaw_rad[0]
    total_ms = np.array([estimates[s].timings_ms.get("total", np.nan) for s in seqs])
    paths = []
    fig, axes = plt.subplots(3, 1, figsize=(10, 9), sharex=True)
    axes[0].plot(seqs, np.degrees(truth), label="truth", lw=1)
    axes[0].plot(seqs, np.degrees(yaw), label="cluster", lw=1, ls="--")
    axes[0].set_ylabel("yaw [deg]")
    axes[0].legend()
    axes[1].plot(seqs, np.degrees(np.angle(np.exp(1j * (yaw - truth)))), lw=0.8)
    axes[1].set_ylabel("yaw error [deg]")
    top = [r["member"] for r in rows if ">" not in r["member"]]
    stack = np.array([[estimates[s].members.get(m, 0) for s in seqs] for m in top])
    axes[2].stackplot(seqs, stack, labels=top)
    axes[2].set_ylabel("patches per frame")
    axes[2].set_xlabel("frame")
    axes[2].legend(loc="upper right", fontsize=7)
    fig.tight_layout()
    paths.append(out_dir / "cluster_yaw_shares.png")
    fig.savefig(paths[-1], dpi=110)
    plt.close(fig)
    fig, ax = plt.subplots(figsize=(7, 4))
    ax.hist(total_ms[np.isfinite(total_ms)], bins=60)
    ax.set_xlabel("master time per frame [ms]")
    ax.set_ylabel("frames")
    fig.tight_layout()
    paths.append(out_dir / "cluster_timings.png")
    fig.savefig(paths[-1], dpi=110)
    plt.close(fig)
    return paths


def run_demo(out_dir: Path, n_frames: int = HOVER_FRAMES) -> dict[str, Any]:
    out = Path(out_dir) / "cluster"
    out.mkdir(parents=True, exist_ok=True)
    print(f"cluster demo: router, camera, master, 2 foremen x 2 workers on 127.0.0.1; {n_frames} frames")
    estimates, wall_s, codes = run_cluster_flight(DEMO_CLUSTER, n_frames, out / "logs")
    flight = hover_flight(seed=0, n_frames=n_frames)
    seqs = np.array(sorted(estimates))
    yaw = np.array([estimates[s].yaw_rad for s in seqs])
    stats = yaw_error_stats(yaw, flight.yaw_rad[seqs] - flight.yaw_rad[0])
    total_ms = np.array([estimates[s].timings_ms.get("total", np.nan) for s in seqs[1:]])
    rows = member_table(estimates)
    plots = _plot(out, flight, estimates, rows)
    summary: dict[str, Any] = {
        "frames": n_frames,
        "frames_with_yaw": len(estimates),
        "frames_lost": n_frames - len(estimates),
        "dropped_frames": max((e.dropped_frames for e in estimates.values()), default=0),
        "redispatched": sum(e.redispatched for e in estimates.values()),
        "wall_s": wall_s,
        "fps": len(estimates) / wall_s if wall_s > 0 else float("nan"),
        "median_frame_ms": float(np.nanmedian(total_ms)) if total_ms.size else float("nan"),
        "p99_frame_ms": float(np.nanpercentile(total_ms, 99)) if total_ms.size else float("nan"),
        "yaw_error": asdict(stats),
        "members": rows,
        "exit_codes": codes,
        "plots": [str(p) for p in plots],
    }
    write_json(out / "summary.json", summary)
    print(
        f"cluster: {len(estimates)}/{n_frames} frames with yaw, {summary['fps']:.1f} fps, "
        f"median {summary['median_frame_ms']:.1f} ms/frame (p99 {summary['p99_frame_ms']:.1f}), "
        f"yaw rms error {stats.rms_deg:.2f} deg, final {stats.final_deg:+.2f} deg"
    )
    for row in rows:
        if ">" not in row["member"]:
            print(
                f"  {row['member']:>16}: share {row['share']:.2f}, "
                f"{row['patches_per_frame']:.1f} patches/frame"
            )
    print(f"plots: {', '.join(str(p) for p in plots)}")
    return summary
