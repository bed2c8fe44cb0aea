"""The embedded default through a local cluster: router, camera, master, 2 foremen x 2 workers (127.0.0.1).

``run_demo(out_dir)`` starts the processes, replays the simulated hover flight through them (one frame in
flight, so no frame is dropped) while the in-process core tracks the same frames, prints live progress,
then reports with the yaw demo's ``report_yaw`` (``out/cluster/yaw_cluster.{png,json}``) plus per-member
shares, speeds and frame timings (``cluster_yaw_shares.png``, ``cluster_timings.png``, ``summary.json``).
Member shares and timings come from the published YawEstimates themselves.
"""

from __future__ import annotations

import logging
import subprocess
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

from common.dispatch import Balance
from common.geometry import wrap_angle_rad
from common.sim.flight import HOVER_FRAMES, hover_flight
from common.yaw import YawSettings
from services.demo_yaw import report_yaw, track_frames
from services.master.service import Topology
from services.report import write_json
from services.runtime.transport import open_session
from services.secure import SecureProfile
from services.up import ClusterSpec, HostSpec, LocalCluster, YawCollector

logger = logging.getLogger(__name__)

DEMO_CLUSTER = ClusterSpec(
    name="local2x2",
    topology=Topology.MASTER_FOREMAN_WORKER,
    balance=Balance.TIME,
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
    secure: SecureProfile | None = None,
) -> tuple[dict[int, Any], float, dict[str, int | None]]:
    """Run one flight through a fresh local cluster; returns (estimates by seq, wall seconds, exit codes)."""
    with LocalCluster(
        spec, log_dir, shared_memory=shared_memory, master_args=master_args, secure=secure
    ) as cluster:
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
        try:  # the camera ends by itself after its last frame; let it, rather than signal it mid-exit
            cluster.processes["camera/camera/0"].wait(5.0)
        except subprocess.TimeoutExpired:
            logger.warning("camera still running after its flight; stopping it")
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
            (estimates[s].speeds_patches_s[member] for s in reversed(seqs)
             if member in estimates[s].speeds_patches_s),
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
    axes[1].plot(seqs, np.degrees(wrap_angle_rad(yaw - truth)), lw=0.8)
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
    """The hover flight through the local cluster; the in-process core runs alongside for comparison."""
    out = Path(out_dir)
    cluster_dir = out / "cluster"
    cluster_dir.mkdir(parents=True, exist_ok=True)
    flight = hover_flight(seed=0, n_frames=n_frames)
    print(f"cluster demo: router, camera, master, 2 foremen x 2 workers on 127.0.0.1; {n_frames} frames")
    reference: dict[str, Any] = {}
    in_process = threading.Thread(
        target=lambda: reference.update(run=track_frames(flight.frames(), YawSettings())), daemon=True
    )
    in_process.start()
    estimates, wall_s, codes = run_cluster_flight(DEMO_CLUSTER, n_frames, cluster_dir / "logs")
    in_process.join()
    seqs = np.array(sorted(estimates))
    yaw = np.array([estimates[s].yaw_rad for s in seqs])
    total_ms = np.array([estimates[s].timings_ms.get("total", np.nan) for s in seqs])
    rows = member_table(estimates)
    max_diff_deg = (
        float(np.max(np.degrees(np.abs(yaw - reference["run"].yaw_rad[seqs])))) if seqs.size else None
    )
    extra: dict[str, Any] = {
        "frames_with_yaw": len(estimates),
        "frames_lost": n_frames - len(estimates),
        "dropped_frames": max((e.dropped_frames for e in estimates.values()), default=0),
        "redispatched": sum(e.redispatched for e in estimates.values()),
        "fps": len(estimates) / wall_s if wall_s > 0 else float("nan"),
        "p99_frame_ms": float(np.nanpercentile(total_ms[1:], 99)) if total_ms.size > 1 else float("nan"),
        "max_abs_diff_vs_in_process_deg": max_diff_deg,
        "in_process_ms_per_frame_median": float(np.median(reference["run"].ms_per_frame)),
        "exit_codes": codes,
    }
    summary = report_yaw(
        cluster_dir,
        flight.frame_stamps_s[seqs],
        yaw,
        flight.yaw_rad[seqs],
        ms_per_frame=total_ms[1:] if total_ms.size > 1 else None,
        label="yaw through the local cluster (2 foremen x 2 workers)",
        extra=extra,
        stem="yaw_cluster",
    )
    plots = _plot(cluster_dir, flight, estimates, rows)
    summary["members"] = rows
    summary["plots"] = [str(p) for p in plots]
    write_json(cluster_dir / "summary.json", summary)
    print(
        f"cluster: {len(estimates)}/{n_frames} frames with yaw, {extra['fps']:.1f} fps, "
        f"max |cluster - in-process| {max_diff_deg:.2e} deg, {extra['redispatched']} shares re-dispatched"
    )
    for row in rows:
        name = row["member"]
        speed = row["speed_patches_s"]
        share = f"share {row['share']:.2f}, " if ">" not in name else ""
        print(f"  {name:>34}: {share}{row['patches_per_frame']:.1f} patches/frame, {speed:.0f} patches/s")
    print(f"plots: {', '.join(str(p) for p in plots)}")
    return summary
